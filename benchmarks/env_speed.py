"""Environment stepping speed: raw dm_control vs shimmy vs our Gymnasium adapter.

For each environment, steps per second with random actions (episodes are reset when they end,
resets included in the time) are measured for

* ``raw``: the ``dm_env.Environment`` itself (``suite.load`` or the URLB task loaders of
  :mod:`sb3_cic.envs.tasks`), stepped with actions drawn uniformly within the physics bounds;
* ``shimmy``: ``FlattenObservation(DmControlCompatibilityV0(dm_env))``;
* ``ours``: ``gymnasium.make("URLB/<domain>-<task>-v0")`` (:class:`sb3_cic.envs.dmc.DMCEnv`).

Actions are drawn before the timed loops, so only the environments are timed. The three kinds start
from the same seed and get the same actions (ours in [-1, 1], the others the same controls in physics
units), so they step through the same trajectory: the cost of a MuJoCo step depends on the state
(contacts), and different trajectories would skew the ratio. The three kinds run in turn,
``--block`` steps at a time, until each has run ``--steps`` steps, and each kind's speed is that of
its fastest block: the one least disturbed by other processes, so that the ratios hold on a shared
machine. ``ovh`` (overhead) is raw steps/s divided by the wrapper's (1.00 = no overhead).

Usage: ``MUJOCO_GL=disable python benchmarks/env_speed.py --steps 4000 --block 100``
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from typing import Callable

os.environ.setdefault("MUJOCO_GL", "disable")
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import dm_env  # noqa: E402
import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
from gymnasium.wrappers import FlattenObservation  # noqa: E402
from shimmy import DmControlCompatibilityV0  # noqa: E402

from sb3_cic import envs  # noqa: E402,F401  (registers the URLB ids)
from sb3_cic.envs.tasks import loader  # noqa: E402

#: (domain, task, fraction of --steps): jaco steps ~5-10x slower, so it runs fewer steps
ENVIRONMENTS: list[tuple[str, str, float]] = [
    ("walker", "walk", 1.0),
    ("walker", "flip", 1.0),
    ("quadruped", "walk", 1.0),
    ("quadruped", "jump", 1.0),
    ("jaco", "reach_top_left", 0.2),
]


#: actions are cycled from a pre-drawn table of this many rows
_ACTION_ROWS = 1000


def _actions(shape: tuple[int, ...], seed: int) -> np.ndarray:
    """The action table: float32, uniform in [-1, 1] (the Gymnasium action space)."""
    return np.random.default_rng(seed).uniform(-1.0, 1.0, size=(_ACTION_ROWS, *shape)).astype(np.float32)


def raw_runner(env: dm_env.Environment, actions: np.ndarray) -> Callable[[int], float]:
    """A timer of a dm_env environment stepped with the action table in physics units.

    :param env: the dm_control environment, seeded at construction
    :param actions: the action table in physics units
    :return: ``run(n)``: step ``n`` times (resetting at episode ends), return the seconds taken
    """
    env.reset()
    step = 0

    def run(n: int) -> float:
        nonlocal step
        rows = [actions[i % _ACTION_ROWS] for i in range(step, step + n)]
        step += n
        start = time.perf_counter()
        for action in rows:
            if env.step(action).last():
                env.reset()
        return time.perf_counter() - start

    return run


def gym_runner(env: gym.Env, actions: np.ndarray) -> Callable[[int], float]:
    """A timer of a Gymnasium environment stepped with the action table.

    :param env: the Gymnasium environment, seeded at construction
    :param actions: the action table, in the env's action space
    :return: ``run(n)``: step ``n`` times (resetting at episode ends), return the seconds taken
    """
    env.reset()
    step = 0

    def run(n: int) -> float:
        nonlocal step
        rows = [actions[i % _ACTION_ROWS] for i in range(step, step + n)]
        step += n
        start = time.perf_counter()
        for action in rows:
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset()
        return time.perf_counter() - start

    return run


def benchmark(domain: str, task: str, steps: int, block: int) -> dict[str, float]:
    """Steps/s of each kind of environment for one task.

    The three kinds run in turn, ``block`` steps at a time, until each has run ``steps`` steps;
    a kind's speed is that of its fastest block (the one least disturbed by other processes).

    :param domain: URLB domain
    :param task: task of the domain
    :param steps: steps per kind
    :param block: steps per timed block
    """
    load = loader(domain, task)
    ours = gym.make(f"URLB/{domain}-{task}-v0")
    ours.unwrapped._random_state().seed(0)  # type: ignore[attr-defined]  # the seed of load(0)
    envs_ = {"raw": load(0), "shimmy": FlattenObservation(DmControlCompatibilityV0(load(0))), "ours": ours}
    actions = _actions(ours.action_space.shape, seed=0)
    # the controls the adapter sends to the physics for those actions (computed before timing)
    controls = np.stack([ours.unwrapped._control(a) for a in actions]).astype(np.float64)  # type: ignore[attr-defined]
    runners = {
        "raw": raw_runner(envs_["raw"], controls),  # type: ignore[arg-type]
        "shimmy": gym_runner(envs_["shimmy"], controls),  # type: ignore[arg-type]
        "ours": gym_runner(ours, actions),
    }
    block = max(1, min(block, steps))
    best = {name: float("inf") for name in runners}
    for _ in range(max(1, steps // block)):
        for name, run in runners.items():
            best[name] = min(best[name], run(block))
    for env in envs_.values():
        env.close()
    return {name: block / seconds for name, seconds in best.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--steps", type=int, default=4000, help="steps per kind of environment (jaco: a fifth)")
    parser.add_argument("--block", type=int, default=100, help="steps per timed block (jaco: a fifth)")
    args = parser.parse_args()

    header = f"{'environment':<26}{'steps':>7}{'raw/s':>10}{'shimmy/s':>10}{'ours/s':>10}{'shimmy ovh':>12}{'ours ovh':>10}"
    rows = [header, "-" * len(header)]
    for domain, task, fraction in ENVIRONMENTS:
        steps = max(1, int(args.steps * fraction))
        speed = benchmark(domain, task, steps, max(1, int(args.block * fraction)))
        rows.append(
            f"{domain + '-' + task:<26}{steps:>7}{speed['raw']:>10.0f}{speed['shimmy']:>10.0f}{speed['ours']:>10.0f}"
            f"{speed['raw'] / speed['shimmy']:>11.3f}x{speed['raw'] / speed['ours']:>9.3f}x"
        )
    print("\n".join(rows))


if __name__ == "__main__":
    main()
