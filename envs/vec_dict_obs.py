"""The VecEnv form of :class:`~sb3_cic.envs.dict_obs.FlatStateDict` (apart: it imports Stable-Baselines3, which
``import sb3_cic.envs`` does not)."""

from __future__ import annotations

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper
from stable_baselines3.common.vec_env.base_vec_env import VecEnvObs, VecEnvStepReturn

from sb3_cic.envs.dict_obs import StateDictLayout


class VecFlatStateDict(VecEnvWrapper):
    """:class:`~sb3_cic.envs.dict_obs.FlatStateDict` for a VecEnv of Dict observations
    (``make_vec_env("dm_control/...")``, and a ``VecFrameStack`` or ``VecNormalize`` over it): the observations and
    each ``terminal_observation`` flattened, the actions mapped to the envs' bounds, by the same
    :class:`~sb3_cic.envs.dict_obs.StateDictLayout`.

    :param venv: a VecEnv whose observation space is a Dict of state entries
    """

    def __init__(self, venv: VecEnv) -> None:
        if not isinstance(venv.observation_space, spaces.Dict):
            raise ValueError(f"VecFlatStateDict needs a Dict observation space, got {venv.observation_space}")
        self.layout = StateDictLayout(venv.observation_space, venv.action_space)
        super().__init__(venv, observation_space=self.layout.observation_space, action_space=self.layout.action_space)

    def reset(self) -> VecEnvObs:
        return self.layout.flatten(self.venv.reset(), batch=True)  # type: ignore[arg-type]

    def step_async(self, actions: np.ndarray) -> None:
        self.venv.step_async(self.layout.env_action(actions))

    def step_wait(self) -> VecEnvStepReturn:
        observations, rewards, dones, infos = self.venv.step_wait()
        for info in infos:
            if isinstance(info.get("terminal_observation"), dict):
                info["terminal_observation"] = self.layout.flatten(info["terminal_observation"], batch=False)
        return self.layout.flatten(observations, batch=True), rewards, dones, infos  # type: ignore[arg-type]
