"""Checks of a CIC pre-training that rule out (or reveal) a bug, printed as markdown tables.

Given a pre-training snapshot (and optionally the tensorboard run of its pre-training):

* **pre-training curves**: contrastive loss, discriminator top-1 accuracy, intrinsic reward mean
  and std, read from tensorboard every ``--every`` steps;
* **discriminator on batches of distinct skills** (:mod:`sb3_cic.diagnostics`): each batch holds one
  transition ``(s_t, z, s_{t+3})`` per distinct skill, so chance is exactly ``log B`` and ``1 / B`` (and 0.5
  for the rank: the share of the other skills' keys scored above the right one);
  from fresh rollouts of the policy (exploration noise 0.2, a skill every 50 steps, as in pre-training)
  and, given ``--checkpoint`` (a study run's ``checkpoint.zip``, which holds the replay buffer), from
  the replayed transitions the discriminator was trained on, both scored by the checkpoint's
  discriminator;
* **intrinsic reward** mean and std on random batches of fresh rollouts;
* **coverage**: particle entropy (mean ``log(1 + mean 12-NN distance)``) of visited states and the
  range of the walker's torso height, for the snapshot with random skills, an untrained CIC actor
  and uniformly random actions;
* **skill dependence**: mean distance between the actor's actions under two random skills at the
  same visited state, for the pre-trained and an untrained actor (0: the policy ignores the skill);
* **skill sweep**: per task, the paper's grid sweep (40 constant skills ``c * 1``, 100 steps each,
  acting with the pre-trained policy) as fine-tuning runs it: the window returns and the best ``c``.

    MUJOCO_GL=disable python benchmarks/cic_diagnostics.py --snapshot STUDY/pretrain/cic_walker/snapshot_250000.zip \\
        --tensorboard STUDY/tensorboard/pretrain_cic_walker_1 --tasks walker_flip walker_run \\
        --checkpoint COPY_OF_A_PRETRAINING_CHECKPOINT.zip
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "disable")
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import numpy as np  # noqa: E402
import torch as th  # noqa: E402

import sb3_cic  # noqa: E402,F401
from sb3_cic import CIC, SkillGridSweepCallback  # noqa: E402
from sb3_cic.diagnostics import discriminator_scores, one_per_skill, replay_one_per_skill, skill_rollout  # noqa: E402
from sb3_cic.rewards.particle import knn_distances  # noqa: E402

#: index of the torso height in the walker observation (orientations 14, height 1, velocity 9)
WALKER_HEIGHT = 14


def pretraining_curves(logdir: str, every: int) -> list[str]:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(logdir, size_guidance={"scalars": 0})
    events.Reload()
    tags = ["reward/contrastive_loss", "reward/disc_accuracy", "reward/intrinsic_reward_mean", "reward/intrinsic_reward_std"]
    series = {tag: {s.step: s.value for s in events.Scalars(tag)} for tag in tags if tag in events.Tags()["scalars"]}
    if not series:
        return ["(no reward metrics in the tensorboard run)"]
    steps = sorted(next(iter(series.values())))
    lines = ["| step | contrastive loss | disc. accuracy | intrinsic reward mean | intrinsic reward std |", "|---:|---:|---:|---:|---:|"]
    for target in range(every, steps[-1] + every, every):
        step = min(steps, key=lambda s: abs(s - target))
        values = [series[tag].get(step, math.nan) for tag in tags]
        lines.append(f"| {step} | " + " | ".join(f"{v:.3f}" for v in values) + " |")
    return lines


def rollout(model: CIC | None, env_id: str, steps: int, seed: int, skill_dim: int, n_step: int = 3) -> dict[str, np.ndarray]:
    """The states of ``steps`` env steps of fresh rollouts, a new skill every 50 steps (``model=None``: uniformly random
    actions), and the states ``n_step`` steps after a state of the same skill (the states CIC's reward embeds)."""
    segments = skill_rollout(model, env_id, -(-steps // 50), skill_dim, seed=seed)
    states = np.concatenate([segment[:-1, :-skill_dim] for segment in segments])[:steps]
    next_states = np.concatenate([segment[n_step:, :-skill_dim] for segment in segments])
    return {"states": states, "next_states": next_states}


def particle_entropy(states: np.ndarray, scale: np.ndarray, n: int = 2000, k: int = 12) -> float:
    x = th.as_tensor(states[:: max(1, len(states) // n)] / scale)
    return float(th.log1p(knn_distances(x, x, k + 1)[:, 1:].mean(dim=1)).mean())


def intrinsic_reward(model: CIC, next_states: np.ndarray, batch: int) -> tuple[float, float]:
    """Mean and std of the intrinsic reward on 20 random batches of ``next_states``."""
    rng = np.random.default_rng(0)
    rewards = []
    for _ in range(20):
        b = rng.choice(len(next_states), size=batch, replace=False)
        with th.no_grad():
            embedding = model.reward_module.state_net(th.as_tensor(next_states[b], device=model.device))
            rewards.append(model.reward_module.particle(embedding).cpu().numpy())
    r = np.concatenate(rewards)
    return float(r.mean()), float(r.std())


def distinct_skill_scores(model: CIC, domain_id: str, batch: int, batches: int, seed: int,
                          buffer_model: CIC | None = None) -> list[str]:
    """Markdown rows: the discriminator on batches of ``batch`` distinct skills, fresh and (given) replayed."""
    rows = []
    segments = skill_rollout(model, domain_id, batch * batches, model.skill_dim, seed=seed + 1)
    rng = np.random.default_rng(seed)
    fresh = [discriminator_scores(model.reward_module, *one_per_skill(segments[i * batch : (i + 1) * batch], 3, rng))
             for i in range(batches)]
    rows.append(("fresh rollouts of the policy", fresh))
    if buffer_model is not None:
        replayed = []
        for _ in range(batches):
            sample = replay_one_per_skill(buffer_model.replay_buffer, batch, rng)
            replayed.append(discriminator_scores(model.reward_module, sample.observations, sample.next_observations))
        rows.append((f"replayed (its buffer, {buffer_model.replay_buffer.pos} transitions)", replayed))
    lines = ["| batches of distinct skills | contrastive loss | accuracy | rank |", "|---|---:|---:|---:|"]
    for name, scores in rows:
        loss, acc, rank = [np.array([s[key] for s in scores]) for key in ("loss", "accuracy", "rank")]
        lines.append(f"| {name} | {loss.mean():.3f} +- {loss.std():.3f} | {acc.mean():.4f} +- {acc.std():.4f} | "
                     f"{rank.mean():.3f} +- {rank.std():.3f} |")
    lines.append(f"| chance | {math.log(batch):.3f} | {1 / batch:.4f} | 0.500 |")
    return lines


def skill_dependence(model: CIC, states: np.ndarray, n: int = 1000, seed: int = 0) -> float:
    """Mean L2 distance between ``mu(s, z1)`` and ``mu(s, z2)`` for random skills, over visited states."""
    rng = np.random.default_rng(seed)
    s = states[rng.choice(len(states), size=min(n, len(states)), replace=False)]
    actions = [
        model.predict(np.concatenate([s, rng.uniform(size=(len(s), model.skill_dim))], 1).astype(np.float32), deterministic=True)[0]
        for _ in range(2)
    ]
    return float(np.linalg.norm(actions[0] - actions[1], axis=1).mean())


def sweep(snapshot: str, env_id: str, seed: int) -> list[tuple[float, float]]:
    """The fine-tuning grid sweep (4,000 steps, no updates) of the snapshot on a task."""
    model = CIC.load_pretrained(snapshot, env_id, seed=seed, learning_starts=4000)
    callback = SkillGridSweepCallback(sweep_steps=4000, window=100)
    model.learn(4000, callback=callback)
    return [(float(np.mean(z)), ret) for z, ret in callback.results]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--snapshot", required=True, help="pre-trained CIC (.zip)")
    parser.add_argument("--tensorboard", default=None, help="tensorboard run of the pre-training")
    parser.add_argument("--every", type=int, default=25_000, help="steps between rows of the pre-training curves")
    parser.add_argument("--domain-id", default="URLB/walker-v0")
    parser.add_argument("--height-index", type=int, default=WALKER_HEIGHT,
                        help="state entry whose range is shown (walker: 14, its torso height)")
    parser.add_argument("--tasks", nargs="*", default=["walker_flip", "walker_run"])
    parser.add_argument("--steps", type=int, default=5000, help="env steps per coverage rollout")
    parser.add_argument("--batch", type=int, default=256)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--checkpoint", default=None,
                        help="a pre-training's checkpoint.zip (a copy): its discriminator on its buffer and on fresh rollouts")
    parser.add_argument("--disc-batches", type=int, default=4, help="batches of distinct skills per measure")
    args = parser.parse_args()
    th.set_num_threads(1)

    model = CIC.load(args.snapshot, device="cpu")
    print(f"# CIC diagnostics: {Path(args.snapshot).name}\n")
    print(f"## Discriminator on batches of {args.batch} distinct skills ({args.disc_batches} batches, mean +- std)\n")
    print("Snapshot:\n")
    print("\n".join(distinct_skill_scores(model, args.domain_id, args.batch, args.disc_batches, args.seed)) + "\n")
    if args.checkpoint:
        from sb3_cic.study.checkpoint import RunFolder

        folder = RunFolder(os.path.dirname(os.path.abspath(args.checkpoint)))
        checkpointed = folder.load_model(CIC, args.domain_id, device="cpu")
        print(f"Checkpoint at step {checkpointed.num_timesteps} (its own discriminator):\n")
        print("\n".join(distinct_skill_scores(checkpointed, args.domain_id, args.batch, args.disc_batches, args.seed,
                                             buffer_model=checkpointed)) + "\n")
        del checkpointed
    untrained = CIC("MlpPolicy", args.domain_id, skill_dim=model.skill_dim, policy_kwargs=model.policy_kwargs,
                    buffer_size=1024, seed=args.seed, device="cpu")
    if args.tensorboard:
        print("## Pre-training curves (tensorboard)\n")
        print("\n".join(pretraining_curves(args.tensorboard, args.every)) + "\n")

    runs = {
        "pre-trained policy, random skills": rollout(model, args.domain_id, args.steps, args.seed, model.skill_dim),
        "untrained CIC actor, random skills": rollout(untrained, args.domain_id, args.steps, args.seed, model.skill_dim),
        "uniformly random actions": rollout(None, args.domain_id, args.steps, args.seed, model.skill_dim),
    }
    scale = runs["uniformly random actions"]["states"].std(0) + 1e-6
    print(f"## Intrinsic reward and coverage on fresh rollouts ({args.steps} steps each, random batches of {args.batch})\n")
    print("Particle entropy on states divided by the random-action std per dimension.\n")
    print(f"| rollout | intrinsic reward mean +- std | particle entropy | state[{args.height_index}] min / max |")
    print("|---|---:|---:|---:|")
    for name, data in runs.items():
        mean, std = intrinsic_reward(model, data["next_states"], args.batch)
        height = data["states"][:, args.height_index]
        print(f"| {name} | {mean:.3f} +- {std:.3f} | {particle_entropy(data['states'], scale):.3f} | "
              f"{height.min():.2f} / {height.max():.2f} |")

    states = runs["pre-trained policy, random skills"]["states"]
    print(f"\nSkill dependence (mean |mu(s, z1) - mu(s, z2)|, actions in [-1, 1]^{model.action_space.shape[0]}): "
          f"pre-trained {skill_dependence(model, states):.3f}, untrained {skill_dependence(untrained, states):.3f}")

    for task in args.tasks:
        domain, name = task.split("_", 1)
        results = sweep(args.snapshot, f"URLB/{domain}-{name}-v0", args.seed)
        returns = np.array([r for _, r in results])
        best = int(returns.argmax())
        print(f"\n## Skill sweep on {task} (40 candidates x 100 steps)\n")
        print(f"best c = {results[best][0]:.3f} (window return {returns[best]:.1f}); window returns min {returns.min():.1f}, "
              f"median {np.median(returns):.1f}, max {returns.max():.1f}\n")
        print("| c | " + " | ".join(f"{c:.2f}" for c, _ in results[::4]) + " |")
        print("|---|" + "---:|" * len(results[::4]))
        print("| return | " + " | ".join(f"{r:.1f}" for _, r in results[::4]) + " |")


if __name__ == "__main__":
    main()
