"""The main job at CPU size: a pre-trained CIC fine-tuned on a task beside DDPG from scratch.

Run with ``sb3-cic demo`` or ``python -m sb3_cic.demo`` (``make demo``). The package ships two CIC snapshots pre-trained
reward-free (``sb3_cic/pretrained/``, hidden 256, batch 256): on ``URLB/quadruped-v0`` for 500k steps (the
quadruped study's, ``docs/results/quadruped_reduced``) and on ``URLB/walker-v0`` for 100k steps. The demo
fine-tunes the quadruped one on quadruped jump for 20k steps (the paper's skill grid sweep first) and trains
DDPG from scratch with the same networks, batch and budget, evaluating both as URLB does (10 deterministic
episodes) every ``--eval-every`` steps, with one torch thread as the study's runs. Jump is where the study's gain is
clearest and where this snapshot's 20k-step fine-tuning was furthest ahead of DDPG's of the four tasks (the
figures: ``docs/guide/quickstart.md``). It prints both learning curves, returns and normalised scores, and
writes into ``--out``:

* ``learning_curves.png``: return against fine-tuning steps, CIC and DDPG;
* ``skills.mp4``: the snapshot's policy under 9 skills side by side, 150 steps each (needs OpenGL: ``MUJOCO_GL=egl``;
  without it the video is skipped with the reason);
* the fine-tuned models.

The budgets are a few minutes of a 2-core CPU: far below URLB's 100k fine-tuning steps, so the scores
show the start of learning, not the paper's numbers. ``--domain walker`` fine-tunes the walker snapshot on
walker flip; ``--snapshot`` another snapshot of the domain; ``--pretrain-steps N`` pre-trains a fresh CIC for
N steps instead.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sb3_cic.command_line import argument_parser, option_type
from sb3_cic.common.arguments import NON_NEGATIVE_INT, POSITIVE_INT, SEED
from sb3_cic.constants import EXPERT_SCORES
from sb3_cic.study.settings import Settings

#: the ranges of the options that set what a study setting sets (the width, the batch...)
SETTINGS = Settings.RANGES

if TYPE_CHECKING:
    from sb3_cic.callbacks import URLBEvalCallback

#: the shipped snapshot of each domain: CIC pre-trained reward-free on URLB/<domain>-v0, hidden 256, batch 256
#: (quadruped: the quadruped study's 500k-step snapshot, networks only; walker: 100k steps)
SNAPSHOTS = {
    "quadruped": Path(__file__).parent / "pretrained" / "cic_quadruped_h256_500k.zip",
    "walker": Path(__file__).parent / "pretrained" / "cic_walker_h256_100k.zip",
}
#: each domain's tasks, the demo's default first
TASKS = {"walker": ("flip", "stand", "walk", "run"), "quadruped": ("jump", "stand", "walk", "run")}


def pretrain(steps: int, out: Path, seed: int, hidden_dim: int = 256, batch_size: int = 256, domain: str = "walker") -> Path:
    """Pre-train a CIC on ``URLB/<domain>-v0`` for ``steps`` steps and save it under ``out``; return its path."""
    from sb3_cic import CIC

    model = CIC("MlpPolicy", f"URLB/{domain}-v0", seed=seed, policy_kwargs={"hidden_dim": hidden_dim},
                batch_size=batch_size, buffer_size=max(steps, 1), learning_starts=min(4000, steps // 2))
    model.learn(steps, progress_bar=True)
    model.save(out / "cic_pretrained")
    return out / "cic_pretrained.zip"


def plot_curves(curves: dict[str, list[tuple[int, float, float]]], task: str, path: Path, learning_starts: int) -> None:
    """Return against steps, one line per method (``curves``: URLBEvalCallback histories)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.5))
    for name, history in curves.items():
        ax.plot([h[0] for h in history], [h[1] for h in history], marker="o", label=name)
    ax.axvline(learning_starts, color="gray", linestyle=":", label="learning starts (CIC: skill fixed)")
    ax.set_xlabel("fine-tuning steps")
    ax.set_ylabel("return (deterministic episodes)")
    ax.set_title(task)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Fine-tune the snapshot and train DDPG from scratch on the task; print and plot both.

    :param argv: command-line arguments (see ``--help``)
    :return: ``{"CIC": history, "DDPG": history, "files": [...]}``, a history being URLBEvalCallback's
        ``(step, mean return, normalised score)`` list
    """
    parser = argument_parser(
        "sb3-cic demo",
        "The main job at CPU size: a pre-trained CIC (a shipped snapshot) fine-tuned on a task beside DDPG from "
        "scratch with the same networks, batch and budget, both evaluated as URLB does; prints both learning curves "
        "and writes the plot, a skill video and the models into --out.",
    )
    parser.add_argument("--domain", default="quadruped", choices=sorted(TASKS), help="URLB domain")
    parser.add_argument("--task", default=None, help="task of the domain (default: quadruped jump, walker flip)")
    parser.add_argument("--snapshot", type=Path, default=None, help="pre-trained CIC of the domain (default: the shipped one)")
    parser.add_argument("--pretrain-steps", type=NON_NEGATIVE_INT.parse, default=0,
                        help="pre-train a fresh CIC for this long instead (0: use the snapshot)")
    parser.add_argument("--hidden-dim", type=option_type(SETTINGS["hidden_dim"]), default=256,
                        help="width of the fresh pre-training's networks")
    parser.add_argument("--batch-size", type=option_type(SETTINGS["batch_size"]), default=256, help="batch of the fresh pre-training")
    parser.add_argument("--steps", type=option_type(POSITIVE_INT), default=20_000,
                        help="fine-tuning / from-scratch steps of each method, above --learning-starts")
    parser.add_argument("--learning-starts", type=option_type(SETTINGS["learning_starts"]), default=4_000,
                        help="random steps before learning (CIC: its skill sweep, 100 steps per candidate)")
    parser.add_argument("--eval-every", type=option_type(SETTINGS["eval_freq"]), default=2_000, help="steps between evaluations")
    parser.add_argument("--eval-episodes", type=option_type(SETTINGS["eval_episodes"]), default=10,
                        help="deterministic episodes per evaluation (URLB: 10)")
    parser.add_argument("--skills", type=option_type(NON_NEGATIVE_INT), default=9, help="skills in the video (0: no video)")
    parser.add_argument("--seed", type=option_type(SEED), default=0, help="seed of both runs")
    parser.add_argument("--num-threads", type=option_type(SETTINGS["num_threads"]), default=1,
                        help="torch threads (the study's runs use 1)")
    parser.add_argument("--out", type=Path, default=Path("demo_output"), help="folder for the video, the plot and the models")
    args = parser.parse_args(argv)
    args.task = args.task or TASKS[args.domain][0]
    if args.task not in TASKS[args.domain]:
        parser.error(f"{args.domain} has no task {args.task!r}; its tasks: {', '.join(TASKS[args.domain])}")
    if args.steps <= args.learning_starts:
        parser.error(f"--steps {args.steps} must be above --learning-starts {args.learning_starts}")
    import torch as th  # (here: --help needs no torch)

    threads = th.get_num_threads()
    th.set_num_threads(args.num_threads)
    try:
        return run(args)
    finally:
        th.set_num_threads(threads)


def run(args: argparse.Namespace) -> dict[str, Any]:
    """The demo's work for parsed arguments (see :func:`main`)."""
    from sb3_cic import CIC, URLBDDPG
    from sb3_cic.common.save_util import read_saved_data
    from sb3_cic.protocol import evaluation_callback

    args.out.mkdir(parents=True, exist_ok=True)
    task, env_id = f"{args.domain}_{args.task}", f"URLB/{args.domain}-{args.task}-v0"
    start = time.time()

    snapshot = args.snapshot or SNAPSHOTS[args.domain]
    if args.pretrain_steps > 0:
        print(f"[0/4] pre-training CIC reward-free on URLB/{args.domain}-v0 for {args.pretrain_steps} steps ...", flush=True)
        snapshot = pretrain(args.pretrain_steps, args.out, args.seed, args.hidden_dim, args.batch_size, args.domain)
    data = read_saved_data(snapshot)
    print(f"[1/4] snapshot {snapshot}: {data.get('algorithm', '?')} pre-trained reward-free on {data.get('env_id', '?')}, "
          f"hidden {data['policy_kwargs'].get('hidden_dim')}, batch {data['batch_size']}, {data['num_timesteps']} steps")

    def evaluation() -> URLBEvalCallback:
        return evaluation_callback(env_id, task, args.seed, args.eval_episodes, args.eval_every)

    print(f"[2/4] CIC: fine-tuning on {env_id} for {args.steps} steps (skill grid sweep over the first "
          f"{args.learning_starts}) ...", flush=True)
    cic = CIC.load_pretrained(snapshot, env=env_id, seed=args.seed, learning_starts=args.learning_starts,
                              buffer_size=args.steps)
    cic_eval = evaluation()
    cic.learn(args.steps, callback=cic_eval, progress_bar=True)
    cic.save(args.out / "cic_finetuned")
    print(f"      chosen skill: c = {float(cic.finetune_skill[0]):.3f} (the constant skill c * 1)")

    print(f"[3/4] DDPG from scratch on {env_id} for {args.steps} steps (same networks, batch and budget) ...", flush=True)
    ddpg = URLBDDPG("MlpPolicy", env_id, seed=args.seed, policy_kwargs={"hidden_dim": cic.hidden_dim},
                    batch_size=cic.batch_size, learning_starts=args.learning_starts, buffer_size=args.steps)
    ddpg_eval = evaluation()
    ddpg.learn(args.steps, callback=ddpg_eval, progress_bar=True)
    ddpg.save(args.out / "ddpg")

    print("[4/4] writing the learning curves and the skill video ...", flush=True)
    curves = {"CIC (pre-trained)": cic_eval.history, "DDPG (from scratch)": ddpg_eval.history}
    files = [args.out / "learning_curves.png"]
    plot_curves(curves, env_id, files[0], args.learning_starts)
    if args.skills > 0:
        from sb3_cic.skill_video import show_skills

        try:
            show_skills(snapshot, n=args.skills, steps=150, size=128, out=args.out / "skills.mp4", seed=args.seed)
            files.append(args.out / "skills.mp4")
        except RuntimeError as error:  # no OpenGL backend (MUJOCO_GL unset or disable)
            print(f"      no skill video: {error}")

    print(f"\n{env_id}, {args.eval_episodes} deterministic episodes every {args.eval_every} steps (return):\n")
    print(f"| step | {' | '.join(curves)} |\n|---:|" + "---:|" * len(curves))
    for (step, cic_return, _), (_, ddpg_return, _) in zip(cic_eval.history, ddpg_eval.history):
        print(f"| {step} | {cic_return:.1f} | {ddpg_return:.1f} |")
    print(f"\nafter {args.steps} steps (normalised: return / expert {EXPERT_SCORES[task]}):")
    for name, history in curves.items():
        print(f"  {name:20s} return {history[-1][1]:7.1f}   normalised {history[-1][2]:.3f}")
    print(f"\nwritten: {', '.join(str(f) for f in files)} (total {time.time() - start:.0f} s)")
    return {"CIC": cic_eval.history, "DDPG": ddpg_eval.history, "files": files}


if __name__ == "__main__":
    main()
