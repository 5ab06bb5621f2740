"""Does CIC's discriminator generalise to transitions it was not trained on? Small, decisive experiments.

From a pre-training checkpoint (a study run's ``checkpoint.zip``: model and replay buffer), the stored skills
are split into training skills (90%) and held-out skills (10%). A fresh discriminator (CIC's three networks)
is trained offline on replayed batches of the training skills' transitions, as pre-training trains it
(uniform batches of 256, n-step next state), and scored on batches holding one transition per distinct skill
(chance exactly log B, 1/B; :mod:`sb3_cic.diagnostics`) from

* **train**: the training skills' transitions (seen in training),
* **held-out**: the held-out skills' transitions (same buffer, same policies, never seen),
* **fresh**: new rollouts of the checkpoint's policy (exploration noise 0.2, a skill every 50 steps).

Each variant changes one thing: the width, the learning rate, the loss (the paper's or the code's), or the
number of updates (how often each transition is seen). The checkpoint's own discriminator is scored on the
same batches first. Prints markdown tables.

    python benchmarks/discriminator_generalisation.py --checkpoint COPY/checkpoint.zip --domain-id URLB/walker-v0
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
import sys
import time

os.environ.setdefault("MUJOCO_GL", "disable")
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import numpy as np  # noqa: E402
import torch as th  # noqa: E402

from sb3_cic import CIC  # noqa: E402
from sb3_cic.diagnostics import (  # noqa: E402
    discriminator_scores,
    one_per_skill,
    replay_one_per_skill,
    skill_rollout,
    stored_skills,
)
from sb3_cic.rewards.cic import CICReward  # noqa: E402
from sb3_cic.study.checkpoint import RunFolder  # noqa: E402


def score_sets(module: CICReward, sets: dict[str, list[tuple]]) -> dict[str, tuple[float, float, float]]:
    """Mean loss, accuracy and rank of ``module`` on each named list of ``(obs, next_obs)`` batches."""
    out = {}
    for name, batches in sets.items():
        scores = [discriminator_scores(module, obs, next_obs) for obs, next_obs in batches]
        out[name] = tuple(float(np.mean([s[key] for s in scores])) for key in ("loss", "accuracy", "rank"))
    return out


def cells(scores: dict[str, tuple[float, float, float]]) -> str:
    """``loss / accuracy / rank`` per set, as markdown table cells."""
    return " | ".join(f"{loss:.3f} / {acc:.3f} / {rank:.3f}" for loss, acc, rank in scores.values())


def row(name: str, scores: dict[str, tuple[float, float, float]], extra: str = "") -> str:
    return f"| {name} | {cells(scores)} | {extra} |"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", required=True, help="a pre-training's checkpoint.zip (a copy)")
    parser.add_argument("--domain-id", default="URLB/walker-v0")
    parser.add_argument("--batch", type=int, default=256)
    parser.add_argument("--score-batches", type=int, default=4, help="batches of distinct skills per scored set")
    parser.add_argument("--updates", type=int, default=4000, help="updates of each variant")
    parser.add_argument("--every", type=int, default=1000, help="updates between the rows of the default variant's curve")
    parser.add_argument("--variants", nargs="*", default=["default", "lr1e-3", "hidden1024", "code", "updates4x"])
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    th.set_num_threads(1)
    th.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)

    model = RunFolder(os.path.dirname(os.path.abspath(args.checkpoint))).load_model(CIC, args.domain_id, device="cpu")
    buffer, own = model.replay_buffer, model.reward_module
    skill_of = stored_skills(buffer)
    n_skills = skill_of.max() + 1
    held = rng.permutation(n_skills)[: n_skills // 10]
    is_held = np.isin(skill_of, held)
    train_idx, held_idx = np.flatnonzero(~is_held), np.flatnonzero(is_held)
    sets = {
        "train": [replay_one_per_skill(buffer, args.batch, rng, train_idx, skill_of) for _ in range(args.score_batches)],
        "held-out": [replay_one_per_skill(buffer, min(args.batch, len(held)), rng, held_idx, skill_of)
                     for _ in range(args.score_batches)],
    }
    sets = {k: [(b.observations, b.next_observations) for b in v] for k, v in sets.items()}
    segments = skill_rollout(model, args.domain_id, args.batch * args.score_batches, model.skill_dim, seed=args.seed + 1)
    sets["fresh"] = [one_per_skill(segments[i * args.batch : (i + 1) * args.batch], model.n_steps, rng)
                     for i in range(args.score_batches)]
    b_held = min(args.batch, len(held))
    print(f"# Discriminator generalisation: {Path(args.checkpoint).name}\n")
    print(f"Checkpoint at step {model.num_timesteps}: {len(skill_of)} stored transitions of {n_skills} skills; "
          f"{len(held)} skills held out ({len(held_idx)} transitions). Batches of {args.batch} distinct skills "
          f"(held-out: {b_held}); chance loss log B = {np.log(args.batch):.3f} (held-out {np.log(b_held):.3f}), "
          f"accuracy 1/B = {1 / args.batch:.4f}, rank 0.5. Each cell: loss / accuracy / rank (the share of the other "
          f"skills' keys scored above the right one), mean of {args.score_batches} batches.\n")
    header = "| discriminator | " + " | ".join(sets) + " | |\n|---|" + "---:|" * len(sets) + "---|"
    print(header)
    print(row("the checkpoint's own (trained on all skills)", score_sets(own, sets)))

    state_dim, action_dim = model.state_dim, model.action_dim
    hidden, lr = own.state_net[0].out_features, own.lr
    variants = {
        "default": dict(hidden_dim=hidden, lr=lr, variant=own.variant, updates=args.updates),
        "lr1e-3": dict(hidden_dim=hidden, lr=1e-3, variant=own.variant, updates=args.updates),
        "hidden1024": dict(hidden_dim=1024, lr=lr, variant=own.variant, updates=args.updates),
        "code": dict(hidden_dim=hidden, lr=lr, variant="code", updates=args.updates),
        "updates4x": dict(hidden_dim=hidden, lr=lr, variant=own.variant, updates=4 * args.updates),
    }
    curve = []
    for name in args.variants:
        spec = variants[name]
        module = CICReward(state_dim, action_dim, skill_dim=model.skill_dim, hidden_dim=spec["hidden_dim"], lr=spec["lr"],
                           temperature=own.temperature, variant=spec["variant"])
        start = time.perf_counter()
        for update in range(1, spec["updates"] + 1):
            module.update(buffer._get_samples(rng.choice(train_idx, size=args.batch)))
            if name == "default" and update % args.every == 0:
                curve.append((update, score_sets(module, sets)))
        seen = spec["updates"] * args.batch / len(train_idx)
        extra = (f"hidden {spec['hidden_dim']}, lr {spec['lr']:g}, loss {spec['variant']}, {spec['updates']} updates "
                 f"(each training transition seen {seen:.1f} times), {time.perf_counter() - start:.0f} s")
        print(row(f"fresh, trained offline: {name}", score_sets(module, sets), extra), flush=True)
    if curve:
        print("\nThe default variant over its updates (loss / accuracy / rank):\n")
        print("| updates | " + " | ".join(sets) + " |\n|---:|" + "---:|" * len(sets))
        for update, scores in curve:
            print(f"| {update} | {cells(scores)} |")


if __name__ == "__main__":
    main()
