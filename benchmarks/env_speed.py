"""Environment stepping speed: raw dm_control vs shimmy vs our Gymnasium adapter.

For each environment, steps per second with random actions (episodes are reset when they end,
resets included in the time) are measured for

* ``raw``: the ``dm_env.Environment`` itself (``suite.load`` or the URLB task loaders of
  :mod:`envs.tasks`), stepped with actions drawn uniformly within the physics bounds;
* ``shimmy``: ``FlattenObservation(DmControlCompatibilityV0(dm_env))``;
* ``ours``: ``gymnasium.make("URLB/<domain>-<task>-v0")`` (:class:`envs.dmc.DMCEnv`).

Actions are drawn before the timed loops, so only the environments are timed. The three kinds run
in turn, ``--block`` steps at a time, until each has run ``--steps`` steps, and each kind's speed is
that of its fastest block: the one least disturbed by other processes, so that the ratios hold on a
shared machine. ``ovh`` (overhead) is raw steps/s divided by the wrapper's (1.00 = no overhead).

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

import envs  # noqa: E402,F401  (registers the URLB ids)
from envs.tasks import loader  # noqa: E402

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


def _actions(low: np.ndarray, high: np.ndarray, seed: int, dtype: type = np.float64) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(low, high, size=(_ACTION_ROWS, *np.shape(low))).astype(dtype)


def raw_runner(env: dm_env.Environment, seed: int = 0) -> Callable[[int], float]:
    """A timer of a dm_env environment stepped with random actions within the physics bounds.

    :param env: the dm_control environment
    :param seed: seed of the actions
    :return: ``run(n)``: step ``n`` times (resetting at episode ends), return the seconds taken
    """
    spec = env.action_spec()
    actions = _actions(spec.minimum, spec.maximum, seed)
    env.reset()

    def run(n: int) -> float:
        rows = [actions[i % _ACTION_ROWS] for i in range(n)]
        start = time.perf_counter()
        for action in rows:
            if env.step(action).last():
                env.reset()
        return time.perf_counter() - start

    return run


def gym_runner(env: gym.Env, seed: int = 0) -> Callable[[int], float]:
    """A timer of a Gymnasium environment stepped with random actions in its (Box) action space.

    :param env: the Gymnasium environment
    :param seed: seed of the actions
    :return: ``run(n)``: step ``n`` times (resetting at episode ends), return the seconds taken
    """
    space = env.action_space
    actions = _actions(space.low, space.high, seed, space.dtype)
    env.reset(seed=seed)

    def run(n: int) -> float:
        rows = [actions[i % _ACTION_ROWS] for i in range(n)]
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
    envs_ = {
        "raw": load(0),
        "shimmy": FlattenObservation(DmControlCompatibilityV0(load(0))),
        "ours": gym.make(f"URLB/{domain}-{task}-v0"),
    }
    runners = {
        name: raw_runner(env) if name == "raw" else gym_runner(env)  # type: ignore[arg-type]
        for name, env in envs_.items()
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
