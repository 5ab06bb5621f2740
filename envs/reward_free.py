"""Any env as a reward-free pre-training env, as URLB's ``URLB/<domain>-v0`` ids are."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np


class RewardFree(gym.Wrapper):
    """Reward 0 at every step; the env's own reward goes to ``info["task_reward"]`` (recorded, never learnt from).

    The same interface as :class:`~sb3_cic.envs.dmc.DMCEnv` with ``reward_free=True``: a method pre-trains on its intrinsic
    reward alone (its relabel hook would replace the stored reward anyway; with this wrapper nothing extrinsic is
    even stored), and a callback reads the extrinsic return from the infos. Episode ends pass through unchanged:
    Gymnasium's ``Hopper-v5`` still *terminates* when the hopper falls, the leak that the CIC paper's Appendix I
    is about.

    :param env: the env
    """

    def step(self, action: np.ndarray) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        observation, reward, terminated, truncated, info = self.env.step(action)
        info["task_reward"] = float(reward)
        return observation, 0.0, terminated, truncated, info
