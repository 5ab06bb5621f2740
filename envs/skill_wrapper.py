"""Observation wrappers that append the current skill to the state: ``obs = [state, skill]``.

:class:`SkillObservationWrapper` wraps one env; :class:`VecSkillObservation` adds the skill to a VecEnv of
plain envs. Both keep each env's skill in a :class:`SkillSchedule` and answer the same calls
(``set_skill``, ``get_skill``, ``set_fixed``, ``fixed``...) through ``VecEnv.env_method``/``get_attr``.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper
from stable_baselines3.common.vec_env.base_vec_env import VecEnvObs, VecEnvStepReturn


def skill_observation_space(space: spaces.Space, prior: Any) -> spaces.Box:
    """The float32 Box of ``[state, skill]`` for a flat Box state space (``ValueError`` for any other space).

    :param space: the state observation space
    :param prior: the skill prior (``dim``, ``low``, ``high``)
    """
    if not isinstance(space, spaces.Box) or len(space.shape) != 1:
        raise ValueError(f"a skill observation needs a flat Box observation space, got {space}")
    return spaces.Box(
        low=np.concatenate([space.low, np.full(prior.dim, prior.low)]).astype(np.float32),
        high=np.concatenate([space.high, np.full(prior.dim, prior.high)]).astype(np.float32),
        dtype=np.float32,
    )


class SkillSchedule:
    """One env's current skill: resampled from ``prior`` at every reset and every ``resample_every``
    steps, unless fixed. A prior with ``sample_at(rng, episode_step)`` is told the step of the episode
    (MOSS's skills depend on it).

    :param prior: a skill prior (see :mod:`sb3_cic.skills`): ``dim``, ``low``, ``high``,
        ``sample(rng)``, ``grid(n)`` and ``validate(z)``
    :param resample_every: resample the skill every this many steps; ``None``: only at reset
    """

    def __init__(self, prior: Any, resample_every: int | None = 50) -> None:
        if resample_every is not None and resample_every < 1:
            raise ValueError(f"resample_every must be >= 1 or None, got {resample_every}")
        self.prior = prior
        self.resample_every = resample_every
        self.fixed = False
        self.rng = np.random.default_rng()
        self.skill = prior.sample(self.rng)
        self.steps = 0
        self.episode_steps = 0

    def get_skill(self) -> np.ndarray:
        """The current skill (a copy)."""
        return self.skill.copy()

    def set_skill(self, skill: np.ndarray, fixed: bool = True) -> None:
        """Set the skill (``ValueError`` outside the prior's support); ``fixed`` keeps it."""
        self.skill = self.prior.validate(skill).copy()
        self.fixed = fixed
        self.steps = 0

    def set_fixed(self, fixed: bool) -> None:
        """Switch between a fixed skill (True) and resampling (False)."""
        self.fixed = bool(fixed)

    def reset(self, seed: int | None = None) -> None:
        """A new episode: re-seed if ``seed`` is given, resample unless fixed."""
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        self.steps = 0
        self.episode_steps = 0
        if not self.fixed:
            self.skill = self._draw()

    def step(self) -> None:
        """One env step: resample when the period is over, unless fixed."""
        self.steps += 1
        self.episode_steps += 1
        if not self.fixed and self.resample_every is not None and self.steps % self.resample_every == 0:
            self.skill = self._draw()

    def _draw(self) -> np.ndarray:
        """A skill of the prior for the current step of the episode (``sample_at``; a prior without it: ``sample``)."""
        sample_at = getattr(self.prior, "sample_at", None)
        return self.prior.sample(self.rng) if sample_at is None else sample_at(self.rng, self.episode_steps)

    def observe(self, state: np.ndarray) -> np.ndarray:
        """``[state, skill]`` as float32."""
        return np.concatenate([state, self.skill]).astype(np.float32, copy=False)

    def get_state(self) -> dict[str, Any]:
        """The schedule's state (random generator, skill, mode, step counts), for checkpoints."""
        return {
            "rng": copy.deepcopy(self.rng), "skill": self.skill.copy(), "fixed": self.fixed, "steps": self.steps,
            "episode_steps": self.episode_steps,
        }

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore what :meth:`get_state` returned."""
        self.rng = copy.deepcopy(state["rng"])
        self.skill = np.array(state["skill"], copy=True)
        self.fixed = bool(state["fixed"])
        self.steps = int(state["steps"])
        self.episode_steps = int(state.get("episode_steps", state["steps"]))  # older checkpoints: the same count


class SkillObservationWrapper(gym.Wrapper):
    """Own the current skill of an unsupervised RL agent and append it to the observation.

    The skill is resampled from ``prior`` at every reset and every ``resample_every`` steps, unless
    the wrapper is in fixed mode (:meth:`set_skill` with ``fixed=True``), as used for fine-tuning.
    All methods work through ``VecEnv.env_method``.

    :param env: environment with a flat ``Box`` observation
    :param prior: a skill prior (see :mod:`sb3_cic.skills`): ``dim``, ``low``, ``high``,
        ``sample(rng)``, ``grid(n)`` and ``validate(z)``
    :param resample_every: resample the skill every this many steps; ``None``: only at reset
    """

    def __init__(self, env: gym.Env, prior: Any, resample_every: int | None = 50) -> None:
        super().__init__(env)
        self.observation_space = skill_observation_space(env.observation_space, prior)
        self.schedule = SkillSchedule(prior, resample_every)
        self.state_dim = int(env.observation_space.shape[0])
        self.skill_dim = int(prior.dim)

    @property
    def prior(self) -> Any:
        """The skill prior."""
        return self.schedule.prior

    @property
    def resample_every(self) -> int | None:
        """The resampling period (None: only at reset)."""
        return self.schedule.resample_every

    @property
    def fixed(self) -> bool:
        """Whether the skill is fixed (no resampling)."""
        return self.schedule.fixed

    @property
    def skill(self) -> np.ndarray:
        """The current skill (a copy)."""
        return self.schedule.get_skill()

    def get_skill(self) -> np.ndarray:
        """Return the current skill (for ``VecEnv.env_method``)."""
        return self.schedule.get_skill()

    def set_skill(self, skill: np.ndarray, fixed: bool = True) -> None:
        """Set the current skill.

        :param skill: the new skill; must be in the prior's support (else ``ValueError``)
        :param fixed: keep it until :meth:`set_fixed` (False) is called, instead of resampling
        """
        self.schedule.set_skill(skill, fixed)

    def set_fixed(self, fixed: bool) -> None:
        """Switch between a fixed skill (True) and resampling (False)."""
        self.schedule.set_fixed(fixed)

    def get_checkpoint_state(self) -> dict[str, Any]:
        """The skill schedule's state, for checkpoints."""
        return self.schedule.get_state()

    def set_checkpoint_state(self, state: dict[str, Any]) -> None:
        """Restore what :meth:`get_checkpoint_state` returned."""
        self.schedule.set_state(state)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        # options only when given: envs with the older ``reset(seed=None)`` signature keep working
        state, info = self.env.reset(seed=seed) if options is None else self.env.reset(seed=seed, options=options)
        self.schedule.reset(seed)
        return self.schedule.observe(state), info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        state, reward, terminated, truncated, info = self.env.step(action)
        info["skill"] = self.schedule.skill
        self.schedule.step()
        return self.schedule.observe(state), reward, terminated, truncated, info


class VecSkillObservation(VecEnvWrapper):
    """Append each env's current skill to the observations of a VecEnv of plain envs (SB3-style).

    The same schedule as :class:`SkillObservationWrapper`, one per env, including the
    ``terminal_observation`` of an ended episode (which keeps the skill it was reached with). It answers
    the skill wrapper's calls through ``env_method`` (``set_skill``, ``get_skill``, ``set_fixed``) and
    ``get_attr`` (``fixed``, ``skill``, ``skill_dim``, ``state_dim``, ``resample_every``, ``prior``), and
    ``env_is_wrapped(SkillObservationWrapper)`` is True for every env: each behaves as if it were wrapped.

    :param venv: VecEnv with a flat Box observation
    :param prior: a skill prior
    :param resample_every: resample the skill every this many steps; ``None``: only at reset
    """

    _METHODS = frozenset({"set_skill", "get_skill", "set_fixed"})
    _ATTRS = frozenset({"fixed", "skill", "skill_dim", "state_dim", "resample_every", "prior"})

    def __init__(self, venv: VecEnv, prior: Any, resample_every: int | None = 50) -> None:
        super().__init__(venv, observation_space=skill_observation_space(venv.observation_space, prior))
        self.schedules = [SkillSchedule(prior, resample_every) for _ in range(venv.num_envs)]
        self.state_dim = int(venv.observation_space.shape[0])
        self.skill_dim = int(prior.dim)
        self._seed: int | None = None

    def _observe(self, states: np.ndarray) -> np.ndarray:
        skills = np.stack([schedule.skill for schedule in self.schedules])
        return np.concatenate([states, skills], axis=1).astype(np.float32, copy=False)

    def seed(self, seed: int | None = None) -> Sequence[None | int]:
        self._seed = seed
        return self.venv.seed(seed)

    def reset(self) -> VecEnvObs:
        states = self.venv.reset()
        for i, schedule in enumerate(self.schedules):
            schedule.reset(None if self._seed is None else self._seed + i)
        self._seed = None
        return self._observe(states)  # type: ignore[arg-type]

    def step_wait(self) -> VecEnvStepReturn:
        states, rewards, dones, infos = self.venv.step_wait()
        for schedule, done, info in zip(self.schedules, dones, infos):
            info["skill"] = schedule.skill
            schedule.step()
            if done:
                if "terminal_observation" in info:
                    info["terminal_observation"] = schedule.observe(info["terminal_observation"])
                schedule.reset()
        return self._observe(states), rewards, dones, infos  # type: ignore[arg-type]

    def get_checkpoint_state(self) -> dict[str, Any]:
        """The skill schedules' states, for checkpoints."""
        return {"schedules": [schedule.get_state() for schedule in self.schedules]}

    def set_checkpoint_state(self, state: dict[str, Any]) -> None:
        """Restore what :meth:`get_checkpoint_state` returned."""
        for schedule, saved in zip(self.schedules, state["schedules"], strict=True):
            schedule.set_state(saved)

    def _indices(self, indices: None | int | Sequence[int]) -> list[int]:
        if indices is None:
            return list(range(self.num_envs))
        return [indices] if isinstance(indices, int) else list(indices)

    def env_method(
        self, method_name: str, *method_args: Any, indices: None | int | Sequence[int] = None, **method_kwargs: Any
    ) -> list[Any]:
        if method_name not in self._METHODS:
            return self.venv.env_method(method_name, *method_args, indices=indices, **method_kwargs)
        return [getattr(self.schedules[i], method_name)(*method_args, **method_kwargs) for i in self._indices(indices)]

    def get_attr(self, attr_name: str, indices: None | int | Sequence[int] = None) -> list[Any]:
        if attr_name not in self._ATTRS:
            return self.venv.get_attr(attr_name, indices)
        if attr_name in ("skill_dim", "state_dim"):
            return [getattr(self, attr_name)] * len(self._indices(indices))
        return [getattr(self.schedules[i], attr_name) for i in self._indices(indices)]

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: None | int | Sequence[int] = None) -> list[bool]:
        if wrapper_class is SkillObservationWrapper:
            return [True] * len(self._indices(indices))
        return self.venv.env_is_wrapped(wrapper_class, indices)
