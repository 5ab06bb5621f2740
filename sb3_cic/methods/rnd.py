"""Random Network Distillation (RND) as an SB3 algorithm."""

from __future__ import annotations

from typing import Any

from stable_baselines3.common.type_aliases import GymEnv

from sb3_cic.ddpg import URLBDDPG
from sb3_cic.rewards.rnd import RNDReward


class RND(URLBDDPG):
    """Random Network Distillation (Burda et al., 2019, https://arxiv.org/abs/1810.12894), URLB's version.

    Reference implementation: https://github.com/rll-research/url_benchmark (``agent/rnd.py``).
    A knowledge-based method without skills: URLB DDPG (:class:`URLBDDPG`) with the normalised
    prediction-error reward of :class:`~sb3_cic.rewards.rnd.RNDReward`. Fine-tuning keeps the actor
    and the critic trunk (URLB).

    Deliberate deviation from the reference code: the reward scores the next state ``s'`` of the
    transition (the code scores ``s``).

    :param policy: policy (``"MlpPolicy"``)
    :param env: environment id, environment or VecEnv
    :param rnd_hidden_dim: hidden width of predictor and target (default: the policy's, 1024)
    :param rnd_rep_dim: output size of predictor and target (512)
    :param rnd_lr: learning rate of the predictor (1e-4)
    :param rnd_scale: reward scale (1)
    :param kwargs: arguments of :class:`URLBDDPG` (``batch_size``, ``policy_kwargs``...)
    """

    def __init__(
        self,
        policy: str | type,
        env: GymEnv | str,
        rnd_hidden_dim: int | None = None,
        rnd_rep_dim: int = 512,
        rnd_lr: float = 1e-4,
        rnd_scale: float = 1.0,
        **kwargs: Any,
    ) -> None:
        self.rnd_hidden_dim = rnd_hidden_dim
        self.rnd_rep_dim = rnd_rep_dim
        self.rnd_lr = rnd_lr
        self.rnd_scale = rnd_scale
        super().__init__(policy, env, **kwargs)

    def _make_reward_module(self) -> RNDReward:
        return RNDReward(
            self.state_dim,
            self.action_dim,
            hidden_dim=self.rnd_hidden_dim or self.hidden_dim,
            rep_dim=self.rnd_rep_dim,
            lr=self.rnd_lr,
            scale=self.rnd_scale,
        )
