"""Observation wrapper that appends the current skill to the state: ``obs = [state, skill]``."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces


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
        space = env.observation_space
        if not isinstance(space, spaces.Box) or len(space.shape) != 1:
            raise ValueError(f"SkillObservationWrapper needs a flat Box observation space, got {space}")
        if resample_every is not None and resample_every < 1:
            raise ValueError(f"resample_every must be >= 1 or None, got {resample_every}")
        self.prior = prior
        self.resample_every = resample_every
        self.state_dim = int(space.shape[0])
        self.skill_dim = int(prior.dim)
        self.observation_space = spaces.Box(
            low=np.concatenate([space.low, np.full(self.skill_dim, prior.low)]).astype(np.float32),
            high=np.concatenate([space.high, np.full(self.skill_dim, prior.high)]).astype(np.float32),
            dtype=np.float32,
        )
        self.fixed = False
        self._rng = np.random.default_rng()
        self._skill = prior.sample(self._rng)
        self._steps = 0

    @property
    def skill(self) -> np.ndarray:
        """The current skill (a copy)."""
        return self._skill.copy()

    def get_skill(self) -> np.ndarray:
        """Return the current skill (for ``VecEnv.env_method``)."""
        return self.skill

    def set_skill(self, skill: np.ndarray, fixed: bool = True) -> None:
        """Set the current skill.

        :param skill: the new skill; must be in the prior's support (else ``ValueError``)
        :param fixed: keep it until :meth:`set_fixed` (False) is called, instead of resampling
        """
        self._skill = self.prior.validate(skill).copy()
        self.fixed = fixed
        self._steps = 0

    def set_fixed(self, fixed: bool) -> None:
        """Switch between a fixed skill (True) and resampling (False)."""
        self.fixed = bool(fixed)

    def _observation(self, state: np.ndarray) -> np.ndarray:
        return np.concatenate([state, self._skill]).astype(np.float32, copy=False)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        state, info = self.env.reset(seed=seed, options=options)
        if not self.fixed:
            self._skill = self.prior.sample(self._rng)
        self._steps = 0
        return self._observation(state), info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        state, reward, terminated, truncated, info = self.env.step(action)
        info["skill"] = self._skill
        self._steps += 1
        if not self.fixed and self.resample_every is not None and self._steps % self.resample_every == 0:
            self._skill = self.prior.sample(self._rng)
        return self._observation(state), reward, terminated, truncated, info
