"""Loaders of the URLB tasks: the control suite's tasks as they are, and the tasks URLB adds.

Each loader is ``load(task, seed) -> dm_env.Environment``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Callable

if TYPE_CHECKING:  # dm_control loads when an env is made, not when the ids are registered
    import dm_env

#: task names of each URLB domain; the first one is the primal task the reward-free
#: pre-training environment runs on. ``point_mass`` (a small test domain) and ``hopper`` (the CIC paper's
#: Appendix I: DMC's fixed-length episodes against Gym's early termination) are not URLB's: no expert score
DOMAIN_TASKS: dict[str, tuple[str, ...]] = {
    "walker": ("stand", "walk", "run", "flip"),
    "quadruped": ("walk", "run", "stand", "jump"),
    "jaco": ("reach_top_left", "reach_top_right", "reach_bottom_left", "reach_bottom_right"),
    "point_mass": ("reach",),
    "hopper": ("hop",),
}

#: the 12 URLB downstream tasks
URLB_TASKS: tuple[str, ...] = tuple(
    f"{domain}_{task}" for domain in ("walker", "quadruped", "jaco") for task in DOMAIN_TASKS[domain]
)


def _suite(domain: str, task: str) -> Callable[[int | None], dm_env.Environment]:
    from dm_control import suite

    return lambda seed: suite.load(domain, task, task_kwargs={"random": seed})


def loader(domain: str, task: str) -> Callable[[int | None], dm_env.Environment]:
    """Return ``load(seed) -> dm_env.Environment`` for a URLB task.

    :param domain: ``walker``, ``quadruped``, ``jaco``, ``point_mass`` or ``hopper``
    :param task: a task of that domain (see :data:`DOMAIN_TASKS`)
    """
    if domain not in DOMAIN_TASKS or task not in DOMAIN_TASKS[domain]:
        raise ValueError(f"unknown URLB task {domain}/{task}; known: {DOMAIN_TASKS}")
    if domain == "walker":
        if task == "flip":
            from sb3_cic.envs.tasks import walker

            return walker.flip
        return _suite("walker", task)
    if domain == "quadruped":
        if task in ("stand", "jump"):
            from sb3_cic.envs.tasks import quadruped

            return getattr(quadruped, task)
        return _suite("quadruped", task)
    if domain == "jaco":
        from sb3_cic.envs.tasks import jaco

        return lambda seed: jaco.make(task, seed)
    if domain == "point_mass":
        return _suite("point_mass", "easy")
    return _suite(domain, task)
