"""Task returns of a pre-trained skill policy under fixed skills, before any fine-tuning.

For a pre-training snapshot of a skill method (CIC, MOSS, ...), the mean return of deterministic episodes on each
task with one skill fixed for the whole episode: constant skills ``c * 1`` (the kind a fine-tuning sweep picks from)
and skills drawn from the method's own prior at given episode steps (for MOSS's mixture prior, step 0 draws an
explore skill and step 999 a control skill; a fresh draw for each episode). It shows which skills the pre-trained
policy already does well with on a task, so a fine-tuning skill choice can be checked against them. ::

    MUJOCO_GL=disable python benchmarks/skill_returns.py --snapshot STUDY/pretrain/moss_quadruped/snapshot_500000.zip \\
        --tasks URLB/quadruped-stand-v0 URLB/quadruped-walk-v0 --constants -1 -0.5 0 0.5 --prior-steps 0 999
"""

from __future__ import annotations

import argparse
import os
import sys

os.environ.setdefault("MUJOCO_GL", "disable")
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
import torch as th  # noqa: E402
from stable_baselines3.common.evaluation import evaluate_policy  # noqa: E402
from stable_baselines3.common.monitor import Monitor  # noqa: E402

from sb3_cic import envs  # noqa: E402, F401  (registers the URLB ids)
from sb3_cic import zoo  # noqa: E402
from sb3_cic.common.save_util import read_saved_data  # noqa: E402


def episode_return(model, env: gym.Env, skill: np.ndarray, seed: int) -> float:
    """Return of one deterministic episode of ``env`` (reset with ``seed``) with ``skill`` fixed."""
    model.finetune_skill = np.asarray(skill, dtype=np.float32)
    env.reset(seed=seed)
    returns, _ = evaluate_policy(model, env, n_eval_episodes=1, deterministic=True, return_episode_rewards=True)
    return float(returns[0])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--snapshot", required=True, help="a pre-training snapshot of a skill method")
    parser.add_argument("--tasks", nargs="+", required=True, help="task env ids of the snapshot's domain")
    parser.add_argument("--constants", nargs="*", type=float, default=[], help="c of the constant skills c * 1")
    parser.add_argument("--prior-steps", nargs="*", type=int, default=[], help="draw skills from the prior at these episode steps")
    parser.add_argument("--episodes", type=int, default=5, help="episodes per skill and task")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    th.set_num_threads(1)
    data = read_saved_data(args.snapshot)
    model = zoo.get_algo(data["algorithm"]).load(args.snapshot, device="cpu")
    if model.skill_prior is None:
        parser.error(f"{args.snapshot} is a {type(model).__name__}, which has no skill")
    rng = np.random.default_rng(args.seed)
    task_envs = {task: Monitor(gym.make(task)) for task in args.tasks}
    print(f"# Task returns under fixed skills: {os.path.basename(args.snapshot)} ({type(model).__name__}, "
          f"{args.episodes} deterministic episodes per skill, one skill per episode)\n")
    print("| skill | " + " | ".join(args.tasks) + " |")
    print("|---|" + "---:|" * len(args.tasks))
    rows = [(f"c = {c:g}", lambda c=c: np.full(model.skill_dim, c)) for c in args.constants]
    rows += [(f"prior at step {s}", lambda s=s: model.skill_prior.sample_at(rng, s)) for s in args.prior_steps]
    for name, draw in rows:
        cells = []
        for task in args.tasks:
            returns = [episode_return(model, task_envs[task], draw(), args.seed + e) for e in range(args.episodes)]
            cells.append(f"{np.mean(returns):.1f} ± {np.std(returns, ddof=1) / np.sqrt(len(returns)):.1f}")
        print(f"| {name} | " + " | ".join(cells) + " |", flush=True)
    for env in task_envs.values():
        env.close()


if __name__ == "__main__":
    main()
