"""Making an env ready for a URLB agent, and reading its Gymnasium id."""

from __future__ import annotations

import re
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from stable_baselines3.common.type_aliases import GymEnv
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper, VecNormalize, unwrap_vec_normalize

from sb3_cic.envs.dict_obs import FlatStateDict, StateDictLayout
from sb3_cic.envs.reward_free import RewardFree
from sb3_cic.envs.skill_wrapper import SkillObservationWrapper, VecSkillObservation
from sb3_cic.envs.vec_dict_obs import VecFlatStateDict
from sb3_cic.skills import SkillPrior

#: the ids of URLB's reward-free pre-training envs (``URLB/walker-v0``): a domain, no task
REWARD_FREE_ID = re.compile(r"URLB/[A-Za-z0-9_]+-v0")


def find_skill_wrapper(env: gym.Env) -> SkillObservationWrapper | None:
    """The :class:`~sb3_cic.envs.SkillObservationWrapper` among the wrappers of ``env``, or None.

    :param env: a gymnasium env and its wrappers
    """
    while isinstance(env, gym.Wrapper):
        if isinstance(env, SkillObservationWrapper):
            return env
        env = env.env
    return None


def env_id_of(env: GymEnv | str | None) -> str | None:
    """The Gymnasium id of ``env`` (an id, an env or a VecEnv), or None when it has none.

    :param env: environment id, environment or VecEnv
    """
    if env is None or isinstance(env, str):
        return env
    try:
        spec = env.get_attr("spec", indices=[0])[0] if isinstance(env, VecEnv) else env.spec
    except AttributeError:
        spec = None
    return None if spec is None else spec.id


def is_reward_free_env(env: GymEnv | str | None) -> bool:
    """Whether ``env`` is one of URLB's reward-free pre-training envs (``URLB/<domain>-v0``) or an env wrapped with
    :class:`~sb3_cic.envs.reward_free.RewardFree`, whose reward is 0.

    :param env: environment id, environment or VecEnv
    """
    if isinstance(env, VecEnv):
        if all(env.env_is_wrapped(RewardFree)):
            return True
    elif isinstance(env, gym.Env):
        layer = env
        while isinstance(layer, gym.Wrapper) and not isinstance(layer, RewardFree):
            layer = layer.env
        if isinstance(layer, RewardFree):
            return True
    env_id = env_id_of(env)
    return env_id is not None and REWARD_FREE_ID.fullmatch(env_id) is not None


def make_env(env_id: str) -> gym.Env:
    """``gym.make(env_id)``; a ``dm_control/...`` id first imports shimmy, which registers its ids on import
    (gymnasium 1.x no longer loads them by itself).

    :param env_id: a Gymnasium id
    """
    if env_id.startswith("dm_control/") and env_id not in gym.registry:
        import shimmy  # noqa: F401

    return gym.make(env_id)


def prepare_env(
    env: GymEnv | str, prior: SkillPrior | None, resample_every: int | None = 50, multi_input: bool = False
) -> GymEnv:
    """Make ``env`` (an id, an env or a VecEnv) ready for a URLB agent.

    A Dict observation of state entries (shimmy's ``dm_control/...`` ids) needs ``multi_input`` (the model's
    ``"MultiInputPolicy"``; without it a ``ValueError`` says so, as SB3's): an env is wrapped with
    :class:`~sb3_cic.envs.dict_obs.FlatStateDict`, a VecEnv (a ``VecFrameStack`` or ``VecNormalize`` of Dicts
    included) with :class:`~sb3_cic.envs.vec_dict_obs.VecFlatStateDict` (the rule of both:
    :class:`~sb3_cic.envs.dict_obs.StateDictLayout`). Checks that actions are continuous and observations flat
    states, and adds the skill when the agent has a skill prior and the env does not carry it yet: an env is
    wrapped with :class:`~sb3_cic.envs.SkillObservationWrapper`, a VecEnv of plain envs with
    :class:`~sb3_cic.envs.VecSkillObservation`. A wrapper with another skill size is a ``ValueError``, and so is a
    VecNormalize of flat observations below the skill (its statistics would have the state's size; a VecNormalize
    of Dicts is seen through :class:`FlatVecNormalize`).

    :param env: environment id, environment or VecEnv
    :param prior: the agent's skill prior, or None
    :param resample_every: skill resampling period given to a new wrapper
    :param multi_input: flatten a Dict observation of state vectors (an env already flat is left as it is)
    """
    if isinstance(env, str):
        env = make_env(env)
    if isinstance(env.observation_space, spaces.Dict):
        if not multi_input:
            raise ValueError(
                "You must use `MultiInputPolicy` when working with dict observation space, not MlpPolicy: "
                "MultiInputPolicy flattens a Dict of state entries in its key order (sb3_cic.envs.FlatStateDict)"
            )
        env = VecFlatStateDict(env) if isinstance(env, VecEnv) else FlatStateDict(env)
    if not isinstance(env.action_space, spaces.Box):
        raise ValueError(f"URLB agents need a continuous (Box) action space, got {env.action_space}")
    obs_space = env.observation_space
    if not isinstance(obs_space, spaces.Box) or len(obs_space.shape) != 1:
        raise ValueError(
            f"URLB agents work on flat state observations (a 1-D Box), got {obs_space}; "
            "image observations are not supported (a Dict of state vectors: MultiInputPolicy)"
        )
    if prior is None:
        return env
    if isinstance(env, VecEnv):
        if not all(env.env_is_wrapped(SkillObservationWrapper)):
            if unwrap_vec_normalize(env) is not None and find_vec_flat_state_dict(env) is None:
                raise ValueError(
                    "a skill-based agent cannot add its skill above VecNormalize: wrap each env in "
                    "SkillObservationWrapper first (make_vec_env(..., wrapper_class=...)), then VecNormalize"
                )
            return VecSkillObservation(env, prior, resample_every=resample_every)
        dims = set(env.get_attr("skill_dim"))
        if dims != {prior.dim}:
            raise ValueError(f"the env's SkillObservationWrapper has skill_dim {dims}, the agent's prior {prior.dim}")
        return env
    wrapper = find_skill_wrapper(env)
    if wrapper is None:
        return SkillObservationWrapper(env, prior, resample_every=resample_every)
    if wrapper.skill_dim != prior.dim:
        raise ValueError(f"the env's SkillObservationWrapper has skill_dim {wrapper.skill_dim}, the agent's prior {prior.dim}")
    return env


def find_vec_flat_state_dict(env: VecEnv) -> VecFlatStateDict | None:
    """The :class:`~sb3_cic.envs.vec_dict_obs.VecFlatStateDict` among the VecEnv wrappers of ``env``, or None.

    :param env: a VecEnv and its wrappers
    """
    while isinstance(env, VecEnvWrapper):
        if isinstance(env, VecFlatStateDict):
            return env
        env = env.venv
    return None


def dict_layout_of(env: GymEnv | None) -> StateDictLayout | None:
    """The :class:`~sb3_cic.envs.dict_obs.StateDictLayout` by which ``env`` (as :func:`prepare_env` returned it, or
    as SB3 wrapped that) flattens a Dict observation, or None when it flattens none.

    :param env: an env, a VecEnv or None
    """
    if isinstance(env, VecEnv):
        flat = find_vec_flat_state_dict(env)
        if flat is not None:
            return flat.layout
        while isinstance(env, VecEnvWrapper):
            env = env.venv
        envs = getattr(env, "envs", None)  # a DummyVecEnv of FlatStateDict envs (a SubprocVecEnv's are not read)
        env = envs[0] if envs else None
    while isinstance(env, gym.Wrapper):
        if isinstance(env, FlatStateDict):
            return env.layout
        env = env.env
    return None


class FlatVecNormalize:
    """A ``VecNormalize`` of Dict observations as a model on flat ``[state, skill]`` observations sees it: what SB3's
    off-policy algorithm and replay buffer call (``get_original_obs``, ``normalize_obs``, ``unnormalize_obs``) take and
    return flat observations, with the Dict's normalised entries normalised by the ``VecNormalize``'s own statistics
    and rule, the other entries and the skill as they are. Anything else (``save``, ``obs_rms``, the rewards, ``training``)
    is the ``VecNormalize``'s.

    :param vec_normalize: the ``VecNormalize`` of Dict observations
    :param flat: the :class:`~sb3_cic.envs.vec_dict_obs.VecFlatStateDict` above it
    :param top: the model's env (the skills are read from it: ``get_attr("skill")``)
    """

    def __init__(self, vec_normalize: VecNormalize, flat: VecFlatStateDict, top: VecEnv) -> None:
        self.vec_normalize = vec_normalize
        self.layout = flat.layout
        self.top = top

    def __getattr__(self, name: str) -> Any:
        if name == "vec_normalize":  # not set yet (a copy being built)
            raise AttributeError(name)
        return getattr(self.vec_normalize, name)

    def _map(self, obs: np.ndarray, rule: Any) -> np.ndarray:
        """``obs`` with each normalised entry's part replaced by ``rule(part, its statistics)``."""
        vec_normalize = self.vec_normalize
        if not vec_normalize.norm_obs:
            return obs
        obs = np.array(obs, dtype=np.float32, copy=True)
        for key in vec_normalize.norm_obs_keys:
            part = obs[..., self.layout.slices[key]]
            shape = vec_normalize.obs_rms[key].mean.shape
            mapped = rule(part.reshape((*part.shape[:-1], *shape)), vec_normalize.obs_rms[key])
            obs[..., self.layout.slices[key]] = np.reshape(mapped, part.shape)
        return obs

    def normalize_obs(self, obs: np.ndarray) -> np.ndarray:
        """Flat observation(s) normalised as the ``VecNormalize`` normalises the Dict's entries.

        :param obs: flat observation(s), with the skill if the model has one
        """
        return self._map(obs, self.vec_normalize._normalize_obs)

    def unnormalize_obs(self, obs: np.ndarray) -> np.ndarray:
        """The inverse of :meth:`normalize_obs`.

        :param obs: normalised flat observation(s)
        """
        return self._map(obs, self.vec_normalize._unnormalize_obs)

    def get_original_obs(self) -> np.ndarray:
        """The envs' last observations before normalisation, flat, with the envs' current skills if the model adds
        one."""
        flat = self.layout.flatten(self.vec_normalize.get_original_obs(), batch=True)  # type: ignore[arg-type]
        if self.top.observation_space.shape[0] == flat.shape[-1]:
            return flat
        skills = np.stack(self.top.get_attr("skill")).astype(np.float32)
        return np.concatenate([flat, skills], axis=-1)


def vec_normalize_of(env: VecEnv | None) -> VecNormalize | FlatVecNormalize | None:
    """What a model on ``env`` uses as SB3's ``_vec_normalize_env``: SB3's ``unwrap_vec_normalize(env)``, seen
    through :class:`FlatVecNormalize` when that ``VecNormalize`` is of Dict observations flattened above it.

    :param env: the model's VecEnv, or None
    """
    vec_normalize = unwrap_vec_normalize(env) if env is not None else None
    flat = find_vec_flat_state_dict(env) if env is not None else None
    if vec_normalize is None or flat is None or not isinstance(vec_normalize.observation_space, spaces.Dict):
        return vec_normalize
    return FlatVecNormalize(vec_normalize, flat, env)


def check_finite_step(step: int, observation: Any, reward: Any, infos: list[dict[str, Any]]) -> None:
    """``ValueError`` naming ``step`` if the env returned a non-finite (NaN or inf) observation, reward or final
    observation (one NaN in a replay buffer turns every network's weights to NaN).

    :param step: the step that returned them (the model's ``num_timesteps``)
    :param observation: the new observations
    :param reward: the rewards
    :param infos: the infos (``terminal_observation`` of an ended episode)
    """
    final = [info["terminal_observation"] for info in infos if "terminal_observation" in info]
    for name, values in (("observation", observation), ("reward", reward), ("final observation", final)):
        if not np.all(np.isfinite(values)):
            raise ValueError(
                f"the env returned a non-finite {name} at step {step} ({values!r}): nothing was stored; "
                "check the env (or wrap it to clip or replace such values)"
            )
