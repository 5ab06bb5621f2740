"""Making an env ready for a URLB agent, and reading its Gymnasium id."""

from __future__ import annotations

import re
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from stable_baselines3.common.type_aliases import GymEnv
from stable_baselines3.common.vec_env import VecEnv, unwrap_vec_normalize

from envs.dict_obs import FlatStateDict
from envs.reward_free import RewardFree
from envs.skill_wrapper import SkillObservationWrapper, VecSkillObservation
from sb3_cic.skills import SkillPrior

#: the ids of URLB's reward-free pre-training envs (``URLB/walker-v0``): a domain, no task
REWARD_FREE_ID = re.compile(r"URLB/[A-Za-z0-9_]+-v0")


def find_skill_wrapper(env: gym.Env) -> SkillObservationWrapper | None:
    """The :class:`~envs.SkillObservationWrapper` among the wrappers of ``env``, or None.

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
    :class:`~envs.reward_free.RewardFree`, whose reward is 0.

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

    A Dict observation of state vectors (shimmy's ``dm_control/...`` ids) needs ``multi_input`` (the model's
    ``"MultiInputPolicy"``; without it a ``ValueError`` says so, as SB3's): the env is wrapped with
    :class:`~envs.dict_obs.FlatStateDict` (entries in the Dict's key order, actions in [-1, 1]).
    Checks that actions are continuous and observations flat states, and adds the skill when the agent
    has a skill prior and the env does not carry it yet: an env is wrapped with
    :class:`~envs.SkillObservationWrapper`, a VecEnv of plain envs with :class:`~envs.VecSkillObservation`.
    A wrapper with another skill size is a ``ValueError``, and so is a VecNormalize below the skill
    (its statistics would have the state's size).

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
                "MultiInputPolicy flattens a Dict of 1-D or scalar Boxes in its key order (envs.FlatStateDict)"
            )
        if isinstance(env, VecEnv):
            raise ValueError(
                "a VecEnv of Dict observations: wrap each env with envs.FlatStateDict first "
                "(make_vec_env(..., wrapper_class=FlatStateDict))"
            )
        env = FlatStateDict(env)
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
            if unwrap_vec_normalize(env) is not None:
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
