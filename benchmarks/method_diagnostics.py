"""What a pre-training did, for any method: checks that tell a method that learns its objective from one that does not.

Given a pre-training snapshot of any method (and optionally the tensorboard run of its pre-training), printed as
markdown tables:

* **pre-training curves**: every ``reward/`` scalar of the pre-training (the intrinsic reward's mean and std, the
  reward module's losses), read from tensorboard every ``--every`` steps;
* **its objective and its coverage on fresh rollouts**, for the pre-trained policy (skills drawn as in
  pre-training, exploration noise 0.2), an untrained model of the same method and uniformly random actions:
  the method's own intrinsic reward on random batches of their ``n_steps``-step transitions (the snapshot's
  reward module, a fresh copy for each rollout, so its running statistics start from the snapshot's), the
  particle entropy of the visited states (mean ``log(1 + mean 12-NN distance)`` on states divided by the
  random-action std per dimension) and where the body went (quadruped: 1 m cells of the torso's ground
  position and the farthest distance from the start; walker: the torso height's range and the farthest x) and
  the share of the action entries at the bounds (``|a| > 0.99``: the deterministic action of the policies, before
  the noise; the random actions themselves).

A pre-training that optimises its objective earns more of its own reward than random actions; an
exploration method should also cover more. ::

    MUJOCO_GL=disable python benchmarks/method_diagnostics.py --snapshot STUDY/pretrain/icm_quadruped/snapshot_500000.zip \\
        --tensorboard STUDY/tensorboard/pretrain_icm_quadruped_1
"""

from __future__ import annotations

import argparse
import copy
import math
import os
import sys
from typing import Any

os.environ.setdefault("MUJOCO_GL", "disable")
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import numpy as np  # noqa: E402
import torch as th  # noqa: E402
from stable_baselines3.common.type_aliases import ReplayBufferSamples  # noqa: E402

import sb3_cic  # noqa: E402,F401
from sb3_cic import zoo  # noqa: E402
from sb3_cic.common.save_util import read_saved_data  # noqa: E402
from sb3_cic.rewards.particle import knn_distances  # noqa: E402


def pretraining_curves(logdir: str, every: int) -> list[str]:
    """Markdown rows of every ``reward/`` scalar of a tensorboard run, about every ``every`` steps."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(logdir, size_guidance={"scalars": 0})
    events.Reload()
    tags = sorted(tag for tag in events.Tags()["scalars"] if tag.startswith("reward/"))
    if not tags:
        return ["(no reward/ scalars in the run)"]
    series = {tag: {s.step: s.value for s in events.Scalars(tag)} for tag in tags}
    steps = sorted(set().union(*series.values()))
    lines = ["| step | " + " | ".join(t.removeprefix("reward/") for t in tags) + " |", "|---:|" + "---:|" * len(tags)]
    for target in range(every, steps[-1] + every, every):
        step = min(steps, key=lambda s: abs(s - target))
        lines.append(f"| {step} | " + " | ".join(f"{series[t].get(step, math.nan):.4g}" for t in tags) + " |")
    return lines


def body_position(env: Any) -> np.ndarray:
    """The torso's world position of a VecEnv's first env (a DeepMind Control env)."""
    return np.array(env.envs[0].unwrapped.physics.named.data.xpos["torso"], dtype=float)


def rollout(model: Any, steps: int, seed: int, random_actions: bool = False, noise: float = 0.2) -> dict[str, np.ndarray]:
    """``steps`` env steps in the model's own (reward-free, skill-wrapped) env: its deterministic action plus
    Gaussian ``noise``, clipped (or uniformly random actions); observations with the skill, actions, the actions
    before the noise, episode ends and torso positions."""
    env = model.get_env()
    env.seed(seed)
    rng = np.random.default_rng(seed)
    obs = env.reset()
    observations, actions, means, starts, positions = [], [], [], [], []
    start = True
    for _ in range(steps):
        if random_actions:
            mean = action = rng.uniform(-1, 1, size=(1, *model.action_space.shape))
        else:
            mean = model.predict(obs, deterministic=True)[0]
            action = mean + rng.normal(0, noise, size=(1, *model.action_space.shape))
        action = np.clip(action, -1, 1).astype(np.float32)
        observations.append(obs[0])
        actions.append(action[0])
        means.append(mean[0])
        starts.append(start)
        positions.append(body_position(env))
        obs, _, done, _ = env.step(action)
        start = bool(done[0])
    return {"obs": np.array(observations), "actions": np.array(actions), "means": np.array(means),
            "starts": np.array(starts), "positions": np.array(positions)}


def transitions(data: dict[str, np.ndarray], n_step: int, state_dim: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(obs, action, next obs)`` of every ``n_step`` window inside one episode, the next observation carrying the
    window's first skill (as the replay buffer's skill-consistent windows)."""
    obs, index = data["obs"], []
    episode = np.cumsum(data["starts"])
    for t in range(len(obs) - n_step):
        if episode[t] == episode[t + n_step]:
            index.append(t)
    index = np.array(index)
    next_obs = obs[index + n_step].copy()
    next_obs[:, state_dim:] = obs[index, state_dim:]
    return obs[index], data["actions"][index], next_obs


def intrinsic_reward(model: Any, data: dict[str, np.ndarray], batch: int, batches: int = 20) -> tuple[float, float]:
    """Mean and std of the method's intrinsic reward on ``batches`` random batches of a rollout's transitions."""
    obs, actions, next_obs = transitions(data, model.n_steps, model.state_dim)
    module = copy.deepcopy(model.reward_module)  # the snapshot's running statistics, for each rollout
    rng = np.random.default_rng(0)
    rewards = []
    for _ in range(batches):
        b = rng.choice(len(obs), size=min(batch, len(obs)), replace=False)
        zeros = th.zeros(len(b), 1)
        sample = ReplayBufferSamples(*(th.as_tensor(x[b]) for x in (obs, actions, next_obs)), zeros, zeros, zeros + 1)
        with th.no_grad():
            rewards.append(module.reward(sample).numpy())
    r = np.concatenate(rewards)
    return float(r.mean()), float(r.std())


def particle_entropy(states: np.ndarray, scale: np.ndarray, n: int = 2000, k: int = 12) -> float:
    x = th.as_tensor(states[:: max(1, len(states) // n)] / scale)
    return float(th.log1p(knn_distances(x, x, k + 1)[:, 1:].mean(dim=1)).mean())


def where_it_went(domain: str, positions: np.ndarray) -> str:
    """Quadruped: distinct 1 m cells of the torso's (x, y) and the farthest distance; walker: torso height range
    and the farthest x."""
    if domain == "quadruped":
        cells = len({tuple(c) for c in np.floor(positions[:, :2]).astype(int)})
        return f"{cells} cells, {np.linalg.norm(positions[:, :2] - positions[0, :2], axis=1).max():.1f} m"
    return f"height {positions[:, 2].min():.2f} / {positions[:, 2].max():.2f}, x {np.abs(positions[:, 0]).max():.1f} m"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--snapshot", required=True, help="a pre-training snapshot (.zip) of any method")
    parser.add_argument("--tensorboard", default=None, help="tensorboard run of the pre-training")
    parser.add_argument("--every", type=int, default=50_000, help="steps between rows of the pre-training curves")
    parser.add_argument("--steps", type=int, default=5000, help="env steps per rollout")
    parser.add_argument("--batch", type=int, default=256)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    th.set_num_threads(1)

    data = read_saved_data(args.snapshot)
    cls, env_id = zoo.get_algo(data["algorithm"]), data["env_id"]
    domain = env_id.split("/")[1].split("-")[0]
    model = cls.load(args.snapshot, env=env_id, device="cpu")
    untrained = cls("MlpPolicy", env_id, policy_kwargs=model.policy_kwargs, buffer_size=1024, seed=args.seed, device="cpu")
    print(f"# {data['algorithm']} diagnostics: {os.path.basename(args.snapshot)} ({env_id}, {data['num_timesteps']} steps)\n")
    if args.tensorboard:
        print("## Pre-training curves (tensorboard)\n")
        print("\n".join(pretraining_curves(args.tensorboard, args.every)) + "\n")

    runs = {
        "pre-trained policy": rollout(model, args.steps, args.seed),
        f"untrained {data['algorithm']}": rollout(untrained, args.steps, args.seed),
        "uniformly random actions": rollout(model, args.steps, args.seed, random_actions=True),
    }
    scale = runs["uniformly random actions"]["obs"][:, : model.state_dim].std(0) + 1e-6
    print(f"## Its objective and its coverage on fresh rollouts ({args.steps} steps each)\n")
    print(f"Intrinsic reward: the snapshot's reward module on 20 random batches of {args.batch} {model.n_steps}-step "
          "transitions. Particle entropy: states divided by the random-action std per dimension.\n")
    print("| rollout | intrinsic reward mean +- std | particle entropy of states | where the body went | actions at the bounds |")
    print("|---|---:|---:|---|---:|")
    for name, run in runs.items():
        mean, std = intrinsic_reward(model, run, args.batch)
        entropy = particle_entropy(run["obs"][:, : model.state_dim], scale)
        bounds = np.mean(np.abs(run["means"]) > 0.99)
        print(f"| {name} | {mean:.4g} +- {std:.3g} | {entropy:.3f} | {where_it_went(domain, run['positions'])} | {bounds:.1%} |")


if __name__ == "__main__":
    main()
