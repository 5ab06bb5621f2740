"""The main job at CPU size: CIC pre-training on walker, fine-tuning on a walker task, the score.

Run with ``python -m sb3_cic.demo`` (``make demo``). Full-size settings (hidden 1024, batch 1024,
2M + 100k steps) are GPU work; this demo uses small networks and short budgets so that it runs in
a few minutes on 2 CPU cores. The score it prints is therefore far below the paper's.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor

from envs import SkillObservationWrapper
from sb3_cic import CIC, normalized_score


def main(argv: list[str] | None = None) -> float:
    """Pre-train CIC reward-free, fine-tune with the skill grid sweep, print the normalised score.

    :param argv: command-line arguments (see ``--help``)
    :return: the normalised score of the fine-tuned agent
    """
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--domain", default="walker")
    parser.add_argument("--task", default="flip", help="task of the domain to fine-tune on")
    parser.add_argument("--pretrain-steps", type=int, default=10_000)
    parser.add_argument("--finetune-steps", type=int, default=10_000)
    parser.add_argument("--learning-starts", type=int, default=2_000, help="random steps (and skill sweep) of each phase")
    parser.add_argument("--hidden-dim", type=int, default=128)
    parser.add_argument("--batch-size", type=int, default=128)
    parser.add_argument("--eval-episodes", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=None, help="folder for the pre-trained model (default: a temp dir)")
    args = parser.parse_args(argv)
    small = dict(policy_kwargs={"hidden_dim": args.hidden_dim}, batch_size=args.batch_size,
                 learning_starts=args.learning_starts, buffer_size=max(args.pretrain_steps, args.finetune_steps))
    out = args.out or Path(tempfile.mkdtemp(prefix="sb3_cic_demo_"))
    out.mkdir(parents=True, exist_ok=True)

    start = time.time()
    print(f"[1/3] pre-training CIC reward-free on URLB/{args.domain}-v0 for {args.pretrain_steps} steps ...", flush=True)
    model = CIC("MlpPolicy", f"URLB/{args.domain}-v0", seed=args.seed, **small)
    model.learn(args.pretrain_steps, progress_bar=True)
    metrics = model.logger.name_to_value
    print(f"      contrastive loss {metrics['reward/contrastive_loss']:.3f}, discriminator accuracy "
          f"{metrics['reward/disc_accuracy']:.3f}, intrinsic reward {metrics['reward/intrinsic_reward_mean']:.3f} "
          f"({time.time() - start:.0f} s)")
    model.save(out / "cic_pretrained")

    task_id = f"URLB/{args.domain}-{args.task}-v0"
    print(f"[2/3] fine-tuning on {task_id} for {args.finetune_steps} steps (skill grid sweep first) ...", flush=True)
    finetuned = CIC.load_pretrained(out / "cic_pretrained", env=task_id, seed=args.seed)
    finetuned.learn(args.finetune_steps, progress_bar=True)
    skill = finetuned.finetune_skill
    print(f"      chosen skill: c = {float(skill[0]):.3f} (constant skill c * 1)")

    print(f"[3/3] evaluating {args.eval_episodes} deterministic episodes ...", flush=True)
    import gymnasium as gym

    eval_env = SkillObservationWrapper(gym.make(task_id), finetuned.skill_prior)
    eval_env.set_skill(skill)
    mean, std = evaluate_policy(finetuned, Monitor(eval_env), n_eval_episodes=args.eval_episodes)
    score = normalized_score(f"{args.domain}_{args.task}", mean)
    print(f"\n{task_id}: return {mean:.1f} +- {std:.1f}, normalised score {score:.3f} "
          f"(total {time.time() - start:.0f} s; URLB full size, CIC: {np.round(631 / 799, 2) if args.task == 'flip' else 'see README'})")
    return score


if __name__ == "__main__":
    main()
