"""The skill plumbing of a URLB agent: set the skill, act on plain state observations, wrap an env as the
training env is."""

from __future__ import annotations

from typing import Any

import numpy as np
from stable_baselines3.common.type_aliases import GymEnv
from stable_baselines3.common.vec_env import VecEnv

from sb3_cic.common.env_util import dict_layout_of, find_skill_wrapper, prepare_env, vec_normalize_of
from sb3_cic.envs.dict_obs import StateDictLayout
from sb3_cic.skills import SkillPrior


class SkillMixin:
    """Skill handling for an SB3 off-policy algorithm whose observations are ``[state, skill]``.

    Mixed in before the algorithm (``class URLBDDPG(SkillMixin, DDPG)``): it reads the model's
    ``skill_prior`` (None: no skill), ``skill_resample_every``, ``finetune_skill``, ``env`` and ``_last_obs``.
    The training envs own the current skill (:class:`~sb3_cic.envs.SkillObservationWrapper`); the model sets it
    through ``env_method("set_skill", z, fixed)``.
    """

    skill_prior: SkillPrior | None
    skill_resample_every: int | None
    #: Dict observations are flattened (the model was built with ``"MultiInputPolicy"``)
    multi_input: bool
    #: how a Dict observation of the env is flattened (None: the model was built on flat observations)
    dict_layout: StateDictLayout | None
    _vec_normalize_env: Any
    #: the skill chosen for fine-tuning, once a skill-selection callback has chosen it
    finetune_skill: np.ndarray | None
    #: the skill last given to :meth:`set_skill` (appended to plain observations when there is no env)
    skill: np.ndarray | None
    env: VecEnv | None
    env_id: str | None
    observation_space: Any
    action_space: Any
    _last_obs: Any

    @property
    def skill_dim(self) -> int:
        """Size of the skill appended to the observation (0 without a skill prior)."""
        return 0 if self.skill_prior is None else self.skill_prior.dim

    @property
    def state_dim(self) -> int:
        """Size of the state part of the observation."""
        return int(self.observation_space.shape[0]) - self.skill_dim

    @property
    def action_dim(self) -> int:
        """Number of action entries (a multi-dimensional Box action is flattened)."""
        return int(np.prod(self.action_space.shape))

    def set_skill(self, skill: np.ndarray, fixed: bool = True) -> None:
        """Set the skill of every training env (and of the pending observation) and of :meth:`predict`.

        :param skill: a skill of the prior's support
        :param fixed: keep it fixed instead of resampling
        """
        if self.skill_prior is None:
            raise ValueError(f"{type(self).__name__} has no skill")
        z = self.skill_prior.validate(skill)
        self.skill = z.copy()
        if self.env is not None:
            self.env.env_method("set_skill", z, fixed)
        if self._last_obs is not None:
            self._last_obs[:, -self.skill_dim :] = z

    def current_skill(self) -> np.ndarray:
        """The skill the model acts with on a plain observation: the fine-tuning skill once chosen, else the
        first training env's current skill, else the last :meth:`set_skill`; ``ValueError`` if none."""
        if self.skill_prior is None:
            raise ValueError(f"{type(self).__name__} has no skill")
        if self.finetune_skill is not None:
            return self.finetune_skill
        if self.env is not None:
            return np.asarray(self.env.env_method("get_skill", indices=[0])[0], dtype=np.float32)
        if self.skill is None:
            raise ValueError(
                f"{type(self).__name__} has no current skill to append to a state observation "
                f"(no env): call model.set_skill(z) first, or pass [state, skill] observations"
            )
        return self.skill

    def predict(
        self,
        observation: np.ndarray | dict[str, np.ndarray],
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """The action for ``observation`` (see SB3's ``predict``).

        A skill-based model also takes plain state observations (as a plain env or a VecEnv of plain envs
        returns them, for example in ``evaluate_policy`` or SB3's ``EvalCallback``): it appends
        :meth:`current_skill`. ``[state, skill]`` observations are used as they are. A model built with
        ``"MultiInputPolicy"`` takes the env's own Dict observations (single, or a VecEnv's batch): they are flattened
        as the training env flattens them (:class:`~sb3_cic.envs.dict_obs.StateDictLayout`), the skill appended, and the
        actions returned are the env's (its bounds and dtype), as SB3's ``predict`` returns them.

        :param observation: the input observation(s)
        :param state: the last hidden states (unused: no recurrent policy)
        :param episode_start: the last masks (unused)
        :param deterministic: return deterministic actions
        """
        layout = None
        if isinstance(observation, dict):
            layout = self.dict_layout
            if layout is None:
                raise ValueError(
                    f"{type(self).__name__} was built on flat observations, not a Dict: a Dict env needs a model "
                    "built with MultiInputPolicy on it"
                )
            observation = layout.flatten(observation)
        if isinstance(observation, np.ndarray) and observation.ndim > 0:
            size = observation.shape[-1]
            if self.skill_prior is not None and size == self.state_dim:
                skill = np.broadcast_to(self.current_skill(), (*observation.shape[:-1], self.skill_dim))
                observation = np.concatenate([observation, skill], axis=-1)
            elif size not in (self.state_dim, self.observation_space.shape[0]):
                skill = f" + skill {self.skill_dim}" if self.skill_dim else ""
                raise ValueError(
                    f"{type(self).__name__} acts on observations of state {self.state_dim}{skill} (env "
                    f"{self.env_id or 'unknown'}), got shape {observation.shape}: is this env of another domain? "
                    "model.wrap_env(env) wraps an env of the model's domain as the training env is"
                )
        actions, state = super().predict(observation, state, episode_start, deterministic)  # type: ignore[misc]
        return (actions, state) if layout is None else (layout.env_action(actions), state)

    def wrap_env(self, env: GymEnv | str) -> GymEnv:
        """``env`` (an id, an env or a VecEnv) wrapped as the training env is, for evaluation or SB3 callbacks.

        A skill-based model adds its skill wrapper (:class:`~sb3_cic.envs.SkillObservationWrapper`, or
        :class:`~sb3_cic.envs.VecSkillObservation` for a VecEnv of plain envs), with the skill fixed to the
        fine-tuning skill once one is chosen; other models check the env only. ``predict`` also takes
        plain state observations, so SB3's ``EvalCallback(plain_env)`` works without it.

        :param env: environment id, environment or VecEnv
        """
        env = prepare_env(env, self.skill_prior, self.skill_resample_every, self.multi_input)
        if self.skill_prior is not None and self.finetune_skill is not None:
            if isinstance(env, VecEnv):
                env.env_method("set_skill", self.finetune_skill, True)
            else:
                wrapper = find_skill_wrapper(env)
                assert wrapper is not None
                wrapper.set_skill(self.finetune_skill, True)
        return env

    def set_env(self, env: GymEnv | str, force_reset: bool = True) -> None:
        """Use ``env`` for training from now on (see SB3's ``set_env``); a plain env gets the model's skill wrapper, a
        Dict env is flattened (:func:`~sb3_cic.common.env_util.prepare_env`).

        :param env: environment id, environment or VecEnv
        :param force_reset: reset the env before the next ``learn``
        """
        env = prepare_env(env, self.skill_prior, self.skill_resample_every, self.multi_input)
        super().set_env(env, force_reset)  # type: ignore[misc]
        self.dict_layout = dict_layout_of(self.env) or self.dict_layout
        self._vec_normalize_env = vec_normalize_of(self.env)  # type: ignore[arg-type]
