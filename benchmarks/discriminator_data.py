"""Which training data let CIC's discriminator generalise to new skills? Two small experiments.

``discriminator_generalisation.py`` trains fresh discriminators on a pre-training's replay buffer (every
transition so far, from the policies of every stage) and finds that they memorise. These two change the data:

* ``one-policy``: fresh rollouts of ONE snapshot's policy (``--skills`` skills of 50 steps, exploration
  noise 0.2); a fresh discriminator is trained offline on 90% of the skills (uniform batches of n-step pairs
  drawn within a skill) and scored on distinct-skill batches of its training skills and of the held-out
  ones, every 1,000 updates; the snapshot's own discriminator is scored on the same batches.
* ``recent``: from a pre-training checkpoint (its replay buffer), one fresh discriminator trained on the
  newest ``--recent`` transitions (10% of their skills held out) and one on as many transitions drawn from
  the whole buffer (the held-out skills excluded); both scored on the held-out recent skills and on fresh
  rollouts of the checkpoint's policy.

Scores are the paper's cross-entropy, top-1 accuracy and rank on batches of one transition per distinct skill
(:mod:`sb3_cic.diagnostics`: chance is exactly log B, 1/B and 0.5). Prints markdown.

    python benchmarks/discriminator_data.py one-policy --snapshot SNAPSHOT.zip --domain-id URLB/quadruped-v0
    python benchmarks/discriminator_data.py recent --checkpoint COPY/checkpoint.zip --domain-id URLB/quadruped-v0
"""

from __future__ import annotations

import argparse
import os
import sys
import time

os.environ.setdefault("MUJOCO_GL", "disable")
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import numpy as np  # noqa: E402
import torch as th  # noqa: E402
from stable_baselines3.common.type_aliases import ReplayBufferSamples  # noqa: E402

from sb3_cic import CIC  # noqa: E402
from discriminator_generalisation import cells, score_sets  # noqa: E402  (this folder is on sys.path when run)
from sb3_cic.diagnostics import (  # noqa: E402
    one_per_skill,
    replay_one_per_skill,
    skill_rollout,
    stored_skills,
)
from sb3_cic.rewards.cic import CICReward  # noqa: E402
from sb3_cic.study.checkpoint import RunFolder  # noqa: E402

BATCH = 256


def fresh_module(model: CIC) -> CICReward:
    """A discriminator of the model's sizes with CIC's defaults (hidden 256 as the studies, lr 1e-4, T 0.5)."""
    return CICReward(model.state_dim, model.action_dim, skill_dim=model.skill_dim, hidden_dim=256, lr=1e-4, temperature=0.5)


def scores(module: CICReward, sets: dict[str, list[tuple[np.ndarray, np.ndarray]]]) -> str:
    """``loss / accuracy / rank`` (mean over the batches, :func:`discriminator_generalisation.score_sets`) as table cells."""
    return cells(score_sets(module, sets))


def one_policy(args: argparse.Namespace, rng: np.random.Generator) -> None:
    model = CIC.load(args.snapshot, device="cpu")
    start = time.perf_counter()
    segments = skill_rollout(model, args.domain_id, args.skills, model.skill_dim, seed=5)
    segments = [s for s in segments if len(s) > model.n_steps]
    rollout_s = time.perf_counter() - start
    order = rng.permutation(len(segments))
    n_held = len(segments) // 10
    held, train = [segments[i] for i in order[:n_held]], [segments[i] for i in order[n_held:]]
    n = model.n_steps
    pairs = [(seg, t) for seg in train for t in range(len(seg) - n)]
    obs_all = np.stack([seg[t] for seg, t in pairs])
    next_all = np.stack([seg[t + n] for seg, t in pairs])

    def batches(group: list[np.ndarray], size: int) -> list[tuple[np.ndarray, np.ndarray]]:
        return [one_per_skill([group[i] for i in rng.choice(len(group), size=size, replace=False)], n, rng) for _ in range(4)]

    b_held = min(BATCH, len(held))
    sets = {"training skills": batches(train, BATCH), "held-out skills": batches(held, b_held)}
    print(f"# Discriminator trained on one policy's rollouts: {os.path.basename(args.snapshot)}\n")
    print(f"{len(segments)} skills rolled out ({rollout_s:.0f} s), {len(train)} for training ({len(obs_all)} n-step pairs), "
          f"{len(held)} held out. Chance: training batches log {BATCH} = {np.log(BATCH):.3f} / {1 / BATCH:.4f}, "
          f"held-out log {b_held} = {np.log(b_held):.3f} / {1 / b_held:.4f}. Cells: loss / accuracy / rank (chance 0.5), "
          "mean of 4 batches.\n")
    print("| discriminator | " + " | ".join(sets) + " |\n|---|---:|---:|")
    print(f"| the snapshot's own | {scores(model.reward_module, sets)} |")
    module = fresh_module(model)
    zeros = th.zeros(BATCH, 1)
    for update in range(1, args.updates + 1):
        idx = rng.choice(len(obs_all), size=BATCH)
        module.update(ReplayBufferSamples(th.as_tensor(obs_all[idx]), zeros, th.as_tensor(next_all[idx]), zeros, zeros, None))
        if update % 1000 == 0:
            seen = update * BATCH / len(obs_all)
            print(f"| fresh, {update} updates (each pair seen {seen:.1f} times) | {scores(module, sets)} |", flush=True)


def recent(args: argparse.Namespace, rng: np.random.Generator) -> None:
    model = RunFolder(os.path.dirname(os.path.abspath(args.checkpoint))).load_model(CIC, args.domain_id, device="cpu")
    buffer = model.replay_buffer
    skill_of = stored_skills(buffer)
    stored = len(skill_of)
    newest = np.arange(stored - args.recent, stored - model.n_steps)  # n-step targets inside the buffer
    newest_skills = np.unique(skill_of[newest])
    held = rng.choice(newest_skills, size=len(newest_skills) // 10, replace=False)
    recent_train = newest[~np.isin(skill_of[newest], held)]
    recent_held = newest[np.isin(skill_of[newest], held)]
    anywhere = rng.choice(np.flatnonzero(~np.isin(skill_of[: stored - model.n_steps], held)), size=len(recent_train),
                          replace=False)
    segments = skill_rollout(model, args.domain_id, 4 * BATCH, model.skill_dim, seed=7)
    b_held = min(BATCH, len(held))
    held_batches = [replay_one_per_skill(buffer, b_held, rng, recent_held, skill_of) for _ in range(4)]
    sets = {
        "held-out recent skills": [(b.observations, b.next_observations) for b in held_batches],
        "fresh rollouts": [one_per_skill(segments[i * BATCH : (i + 1) * BATCH], model.n_steps, rng) for i in range(4)],
    }
    print(f"# Discriminator trained on a buffer's newest transitions: {os.path.basename(args.checkpoint)}\n")
    print(f"Checkpoint at step {model.num_timesteps}: {stored} stored transitions; the newest {args.recent} hold "
          f"{len(newest_skills)} skills, {len(held)} held out. Chance: held-out log {b_held} = {np.log(b_held):.3f} / "
          f"{1 / b_held:.4f}, fresh log {BATCH} = {np.log(BATCH):.3f} / {1 / BATCH:.4f}. Cells: loss / accuracy / "
          f"rank (chance 0.5), mean of 4 batches.\n")
    print("| discriminator | " + " | ".join(sets) + " | |\n|---|---:|---:|---|")
    print(f"| the checkpoint's own (trained on all of it) | {scores(model.reward_module, sets)} | |")
    for name, indices in (("the newest transitions", recent_train), ("as many from the whole buffer", anywhere)):
        module = fresh_module(model)
        start = time.perf_counter()
        for _ in range(args.updates):
            module.update(buffer._get_samples(rng.choice(indices, size=BATCH)))
        extra = f"{len(indices)} transitions, {args.updates} updates, {time.perf_counter() - start:.0f} s"
        print(f"| fresh, trained on {name} | {scores(module, sets)} | {extra} |", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("mode", choices=["one-policy", "recent"])
    parser.add_argument("--snapshot", help="one-policy: a pre-trained CIC (.zip)")
    parser.add_argument("--checkpoint", help="recent: a pre-training's checkpoint.zip (a copy)")
    parser.add_argument("--domain-id", default="URLB/walker-v0")
    parser.add_argument("--skills", type=int, default=2000, help="one-policy: skills rolled out")
    parser.add_argument("--recent", type=int, default=20_000, help="recent: the newest transitions trained on")
    parser.add_argument("--updates", type=int, default=4000)
    args = parser.parse_args()
    if (args.mode == "one-policy") != (args.snapshot is not None) or (args.mode == "recent") != (args.checkpoint is not None):
        parser.error("one-policy needs --snapshot, recent needs --checkpoint")
    th.set_num_threads(1)
    th.manual_seed(0)
    rng = np.random.default_rng(0)
    (one_policy if args.mode == "one-policy" else recent)(args, rng)


if __name__ == "__main__":
    main()
