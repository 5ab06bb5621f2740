"""Environment stepping speed: raw dm_control vs shimmy vs our Gymnasium adapter.

For each environment, steps per second with random actions (episodes are reset when they end,
resets included in the time) are measured for

* ``raw``: the ``dm_env.Environment`` itself (``suite.load`` or the URLB task loaders of
  :mod:`envs.tasks`), stepped with actions drawn uniformly within the physics bounds;
* ``shimmy``: ``FlattenObservation(DmControlCompatibilityV0(dm_env))``;
* ``ours``: ``gymnasium.make("URLB/<domain>-<task>-v0")`` (:class:`envs.dmc.DMCEnv`).

Actions are drawn before the timed loop, so only the environments are timed. Each measurement is
repeated ``--repeats`` times, interleaving the three kinds, and the best is kept (the least
disturbed by other processes). ``overhead`` is raw steps/s divided by ours (1.00 = no overhead).

Usage: ``MUJOCO_GL=disable python benchmarks/env_speed.py --steps 2000 --repeats 5``
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


def _actions(low: np.ndarray, high: np.ndarray, n: int, seed: int, dtype: type = np.float64) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(low, high, size=(n, *np.shape(low))).astype(dtype)


def time_raw(env: dm_env.Environment, steps: int, seed: int = 0) -> float:
    """Steps/s of a dm_env environment with random actions within the physics bounds.

    :param env: the dm_control environment
    :param steps: number of steps to time
    :param seed: seed of the actions
    """
    spec = env.action_spec()
    actions = _actions(spec.minimum, spec.maximum, steps, seed)
    env.reset()
    start = time.perf_counter()
    for action in actions:
        if env.step(action).last():
            env.reset()
    return steps / (time.perf_counter() - start)


def time_gym(env: gym.Env, steps: int, seed: int = 0) -> float:
    """Steps/s of a Gymnasium environment with random actions in its (Box) action space.

    :param env: the Gymnasium environment
    :param steps: number of steps to time
    :param seed: seed of the actions
    """
    space = env.action_space
    actions = _actions(space.low, space.high, steps, seed, space.dtype)
    env.reset(seed=seed)
    start = time.perf_counter()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    return steps / (time.perf_counter() - start)


def benchmark(domain: str, task: str, steps: int, repeats: int) -> dict[str, float]:
    """Best steps/s over ``repeats`` runs of each kind of environment for one task.

    :param domain: URLB domain
    :param task: task of the domain
    :param steps: steps per run
    :param repeats: runs per kind
    """
    load = loader(domain, task)
    raw = load(0)
    shimmy_env = FlattenObservation(DmControlCompatibilityV0(load(0)))
    ours = gym.make(f"URLB/{domain}-{task}-v0")
    runners: dict[str, Callable[[], float]] = {
        "raw": lambda: time_raw(raw, steps),
        "shimmy": lambda: time_gym(shimmy_env, steps),
        "ours": lambda: time_gym(ours, steps),
    }
    best = {name: 0.0 for name in runners}
    for _ in range(repeats):
        for name, run in runners.items():
            best[name] = max(best[name], run())
    for env in (raw, shimmy_env, ours):
        env.close()
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--steps", type=int, default=2000, help="steps per run (jaco runs a fifth of them)")
    parser.add_argument("--repeats", type=int, default=5, help="runs per kind; the best is kept")
    args = parser.parse_args()

    header = f"{'environment':<26}{'steps':>7}{'raw/s':>10}{'shimmy/s':>10}{'ours/s':>10}{'shimmy ovh':>12}{'ours ovh':>10}"
    rows = [header, "-" * len(header)]
    for domain, task, fraction in ENVIRONMENTS:
        steps = max(1, int(args.steps * fraction))
        speed = benchmark(domain, task, steps, args.repeats)
        rows.append(
            f"{domain + '-' + task:<26}{steps:>7}{speed['raw']:>10.0f}{speed['shimmy']:>10.0f}{speed['ours']:>10.0f}"
            f"{speed['raw'] / speed['shimmy']:>11.3f}x{speed['raw'] / speed['ours']:>9.3f}x"
        )
    print("\n".join(rows))


if __name__ == "__main__":
    main()
