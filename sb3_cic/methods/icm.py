"""Intrinsic Curiosity Module (ICM) as an SB3 algorithm."""

from __future__ import annotations

from typing import Any

from stable_baselines3.common.type_aliases import GymEnv

from sb3_cic.ddpg import URLBDDPG
from sb3_cic.rewards.icm import ICMReward


class ICM(URLBDDPG):
    """Curiosity-driven exploration (Pathak et al., 2017, https://arxiv.org/abs/1705.05363), URLB's version.

    Reference implementation: https://github.com/rll-research/url_benchmark (``agent/icm.py``).
    A knowledge-based method without skills: URLB DDPG (:class:`URLBDDPG`) with the forward-model
    error reward of :class:`~sb3_cic.rewards.icm.ICMReward`. Fine-tuning keeps the actor and the
    critic trunk (URLB).

    :param policy: policy (``"MlpPolicy"``)
    :param env: environment id, environment or VecEnv
    :param icm_hidden_dim: hidden width of the forward and inverse models (default: the policy's, 1024)
    :param icm_lr: learning rate of the models (1e-4)
    :param icm_scale: factor of the forward error inside the log (1)
    :param kwargs: arguments of :class:`URLBDDPG` (``batch_size``, ``policy_kwargs``...)
    """

    def __init__(
        self,
        policy: str | type,
        env: GymEnv | str,
        icm_hidden_dim: int | None = None,
        icm_lr: float = 1e-4,
        icm_scale: float = 1.0,
        **kwargs: Any,
    ) -> None:
        self.icm_hidden_dim = icm_hidden_dim
        self.icm_lr = icm_lr
        self.icm_scale = icm_scale
        super().__init__(policy, env, **kwargs)

    def _make_reward_module(self) -> ICMReward:
        return ICMReward(
            self.state_dim,
            self.action_dim,
            hidden_dim=self.icm_hidden_dim or self.hidden_dim,
            lr=self.icm_lr,
            scale=self.icm_scale,
        )
