"""The CIC paper's Fig. 8 check: pre-train CIC with skill_dim 1 on the point mass, draw the skill flow field.

For skill values evenly spaced in [0, 1] and positions on a grid over the arena (velocity 0), the
arrow is the deterministic action (the force on the mass), i.e. the direction of motion that skill
starts at that position. Distinct skills should point in distinct directions.

The embedding size of the discriminator's networks is 16 (``cic_embed_dim``): with the CIC code's
default (``skill_dim``, here 1) the normalised embeddings are +-1 and the loss stays at log(batch).
Small-study settings (those of ``tests/test_cic.py::test_cic_learns_on_the_point_mass``): hidden 64,
batch 64, learning rate 1e-3 for actor, critic and discriminator, one update per env step.

    MUJOCO_GL=disable python benchmarks/skill_flow_field.py --steps 20000 --out docs/skill_flow_field.png
"""

from __future__ import annotations

import argparse
import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch as th  # noqa: E402

import sb3_cic  # noqa: E402,F401
from sb3_cic import CIC  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--hidden-dim", type=int, default=64)
    parser.add_argument("--batch-size", type=int, default=64)
    parser.add_argument("--lr", type=float, default=1e-3)
    parser.add_argument("--embed-dim", type=int, default=16)
    parser.add_argument("--skills", type=int, default=6)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="docs/skill_flow_field.png")
    args = parser.parse_args()
    th.set_num_threads(1)
    start = time.time()
    model = CIC("MlpPolicy", "URLB/point_mass-v0", skill_dim=1, cic_embed_dim=args.embed_dim, policy_kwargs={"hidden_dim": args.hidden_dim},
                batch_size=args.batch_size, buffer_size=args.steps, learning_starts=1000, train_freq=1,
                learning_rate=args.lr, cic_lr=args.lr, seed=args.seed)
    model.learn(args.steps)
    metrics = model.logger.name_to_value
    grid = np.linspace(-0.25, 0.25, 9)
    xs, ys = np.meshgrid(grid, grid)
    fig, ax = plt.subplots(figsize=(6, 6))
    colors = plt.cm.viridis(np.linspace(0, 1, args.skills))
    for z, color in zip(np.linspace(0, 1, args.skills), colors):
        obs = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size), np.zeros(xs.size), np.full(xs.size, z)], 1)
        actions, _ = model.predict(obs.astype(np.float32), deterministic=True)
        ax.quiver(xs.ravel(), ys.ravel(), actions[:, 0], actions[:, 1], color=color, alpha=0.8, label=f"z = {z:.2f}")
    ax.set(xlim=(-0.3, 0.3), ylim=(-0.3, 0.3), xlabel="x", ylabel="y",
           title=f"CIC skill flow field, point mass, {args.steps} steps\n"
                 f"contrastive loss {metrics['reward/contrastive_loss']:.2f} (log B = {np.log(args.batch_size):.2f})")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(args.out, dpi=100)
    print(f"wrote {args.out}; contrastive loss {metrics['reward/contrastive_loss']:.3f}, "
          f"discriminator accuracy {metrics['reward/disc_accuracy']:.3f}, wall {time.time() - start:.0f} s")


if __name__ == "__main__":
    main()
