"""URLB environments as Gymnasium ids, registered on import.

* ``URLB/<domain>-<task>-v0``: the 12 URLB tasks (for example ``URLB/walker-flip-v0``,
  ``URLB/jaco-reach_top_left-v0``), ``URLB/point_mass-reach-v0`` and ``URLB/hopper-hop-v0`` (dm_control's
  hopper hop: 1,000 steps, no early termination);
* ``URLB/<domain>-v0``: the reward-free pre-training environment of a domain, on its primal task's
  physics (walker stand, quadruped walk, jaco reach_top_left, point_mass reach, hopper hop); the reward is 0
  and the task reward is reported in ``info["task_reward"]``;
* ``URLB/gridworld-v0``: the reward-free 10 x 10 gridworld of the CIC paper's Appendix G
  (:class:`~sb3_cic.envs.gridworld.GridWorldEnv`).

On Linux without a display (no ``DISPLAY`` or ``WAYLAND_DISPLAY``) and with ``MUJOCO_GL`` unset, importing
this package sets ``MUJOCO_GL`` to the headless backend that can load (``egl``, else ``osmesa``, else
``disable``) before dm_control is imported: dm_control would otherwise pick glfw, warn that there is no
display, and fail to render.
"""

from __future__ import annotations

import ctypes.util
import os
import sys


def _headless_gl_backend() -> str:
    """The MuJoCo GL backend for a machine without a display: egl, else osmesa, else disable."""
    for backend, library in (("egl", "EGL"), ("osmesa", "OSMesa")):
        if ctypes.util.find_library(library):
            return backend
    return "disable"


if "MUJOCO_GL" not in os.environ and sys.platform.startswith("linux"):
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        os.environ["MUJOCO_GL"] = _headless_gl_backend()

from typing import TYPE_CHECKING, Any  # noqa: E402

import gymnasium as gym  # noqa: E402

from sb3_cic.envs.dict_obs import FlatStateDict  # noqa: E402
from sb3_cic.envs.gridworld import GRID_EPISODE_LENGTH, GridWorldEnv  # noqa: E402
from sb3_cic.envs.reward_free import RewardFree  # noqa: E402
from sb3_cic.envs.tasks import DOMAIN_TASKS, URLB_TASKS, loader  # noqa: E402

if TYPE_CHECKING:
    from sb3_cic.envs.dmc import DMCEnv
    from sb3_cic.envs.skill_wrapper import SkillObservationWrapper, VecSkillObservation

#: the names that load their module on first use (dm_control, Stable-Baselines3 and torch are not imported by
#: registering the ids: ``sb3-cic --help`` stays fast)
_LAZY = {
    "DMCEnv": "sb3_cic.envs.dmc",
    "SkillObservationWrapper": "sb3_cic.envs.skill_wrapper",
    "VecSkillObservation": "sb3_cic.envs.skill_wrapper",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'sb3_cic.envs' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})

#: episode length of each domain (time limit / control timestep)
EPISODE_LENGTH = {
    "walker": 1000, "quadruped": 1000, "jaco": 250, "point_mass": 1000, "hopper": 1000, "gridworld": GRID_EPISODE_LENGTH
}
#: the ids of the envs that are not dm_control's, and their entry points
OTHER_ENVS = {"URLB/gridworld-v0": "sb3_cic.envs.gridworld:GridWorldEnv"}


def make_dmc(domain: str, task: str, reward_free: bool = False, **kwargs) -> DMCEnv:
    """Build a URLB environment (the entry point behind every registered id).

    :param domain: URLB domain
    :param task: task of that domain
    :param reward_free: return reward 0 (pre-training), keeping the task reward in ``info``
    :param kwargs: passed to :class:`sb3_cic.envs.dmc.DMCEnv` (``render_mode``, ``render_size``, ...)
    """
    from sb3_cic.envs.dmc import DMCEnv

    return DMCEnv(loader(domain, task), reward_free=reward_free, **kwargs)


def env_ids() -> list[str]:
    """All registered URLB ids: pre-training ids first (the gridworld last of them), then tasks."""
    pretrain = [f"URLB/{domain}-v0" for domain in DOMAIN_TASKS] + list(OTHER_ENVS)
    tasks = [f"URLB/{domain}-{task}-v0" for domain, tasks in DOMAIN_TASKS.items() for task in tasks]
    return pretrain + tasks


def register_envs() -> None:
    """Register the URLB ids with Gymnasium (idempotent)."""
    for domain, tasks in DOMAIN_TASKS.items():
        entries = [(f"URLB/{domain}-v0", tasks[0], True)] + [(f"URLB/{domain}-{t}-v0", t, False) for t in tasks]
        for env_id, task, reward_free in entries:
            if env_id in gym.registry:
                continue
            gym.register(
                env_id,
                entry_point="sb3_cic.envs:make_dmc",
                kwargs={"domain": domain, "task": task, "reward_free": reward_free},
                # the dm_control time limit ends the episode; no extra TimeLimit wrapper
                max_episode_steps=None,
                # no per-step wrappers: DMCEnv steps correctly before a reset too (dm_env resets itself)
                order_enforce=False,
                disable_env_checker=True,
            )
    for env_id, entry_point in OTHER_ENVS.items():
        if env_id not in gym.registry:  # the env ends its episodes itself, as DMCEnv
            gym.register(
                env_id, entry_point=entry_point, max_episode_steps=None, order_enforce=False, disable_env_checker=True
            )


register_envs()

__all__ = [
    "DMCEnv",
    "FlatStateDict",
    "GridWorldEnv",
    "RewardFree",
    "SkillObservationWrapper",
    "VecSkillObservation",
    "URLB_TASKS",
    "DOMAIN_TASKS",
    "EPISODE_LENGTH",
    "make_dmc",
    "env_ids",
]
