"""Learning study: URLB DDPG from scratch on walker stand, at CPU size (hidden 256, batch 256).

Prints the evaluation curve (10 deterministic episodes every 10k steps and at step 0) and the wall
time. URLB's full-size figure (hidden 1024, batch 1024, 100k steps): 899 +- 23.

    MUJOCO_GL=disable python benchmarks/learning_ddpg.py --steps 100000
"""

from __future__ import annotations

import argparse
import time

import torch as th

import sb3_cic  # noqa: F401
from sb3_cic import URLBDDPG, URLBEvalCallback


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", default="walker_stand")
    parser.add_argument("--steps", type=int, default=100_000)
    parser.add_argument("--hidden-dim", type=int, default=256)
    parser.add_argument("--batch-size", type=int, default=256)
    parser.add_argument("--eval-freq", type=int, default=10_000)
    parser.add_argument("--eval-episodes", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    th.set_num_threads(args.threads)
    domain, task = args.task.split("_", 1)
    env_id = f"URLB/{domain}-{task}-v0"
    model = URLBDDPG("MlpPolicy", env_id, policy_kwargs={"hidden_dim": args.hidden_dim}, batch_size=args.batch_size,
                     buffer_size=args.steps, seed=args.seed)
    evaluation = URLBEvalCallback(env_id, task=args.task, n_eval_episodes=args.eval_episodes, eval_freq=args.eval_freq)
    start = time.time()
    model.learn(args.steps, callback=evaluation)
    wall = time.time() - start
    print(f"\n{env_id}, URLB DDPG from scratch, hidden {args.hidden_dim}, batch {args.batch_size}, seed {args.seed}")
    print(f"| step | mean return ({args.eval_episodes} episodes) | normalised score |")
    print("|---:|---:|---:|")
    for step, mean_return, score in evaluation.history:
        print(f"| {step} | {mean_return:.1f} | {score:.3f} |")
    print(f"wall time: {wall:.0f} s ({args.steps / wall:.1f} env steps/s while training)")


if __name__ == "__main__":
    main()
