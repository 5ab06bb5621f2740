"""Disagreement (ensemble-variance exploration) as an SB3 algorithm."""

from __future__ import annotations

from typing import Any

from stable_baselines3.common.type_aliases import GymEnv

from sb3_cic.ddpg import URLBDDPG
from sb3_cic.rewards.disagreement import DisagreementReward


class Disagreement(URLBDDPG):
    """Self-supervised exploration via disagreement (Pathak et al., 2019, https://arxiv.org/abs/1906.04161).

    Reference implementation: https://github.com/rll-research/url_benchmark (``agent/disagreement.py``).
    A knowledge-based method without skills: URLB DDPG (:class:`URLBDDPG`) with the ensemble-variance
    reward of :class:`~sb3_cic.rewards.disagreement.DisagreementReward` (5 forward models).
    Fine-tuning keeps the actor and the critic trunk (URLB).

    :param policy: policy (``"MlpPolicy"``)
    :param env: environment id, environment or VecEnv
    :param disagreement_hidden_dim: hidden width of each forward model (default: the policy's, 1024)
    :param disagreement_lr: learning rate of the ensemble (1e-4)
    :param n_models: ensemble size (5)
    :param kwargs: arguments of :class:`URLBDDPG` (``batch_size``, ``policy_kwargs``...)
    """

    def __init__(
        self,
        policy: str | type,
        env: GymEnv | str,
        disagreement_hidden_dim: int | None = None,
        disagreement_lr: float = 1e-4,
        n_models: int = 5,
        **kwargs: Any,
    ) -> None:
        self.disagreement_hidden_dim = disagreement_hidden_dim
        self.disagreement_lr = disagreement_lr
        self.n_models = n_models
        super().__init__(policy, env, **kwargs)

    def _make_reward_module(self) -> DisagreementReward:
        return DisagreementReward(
            self.state_dim,
            self.action_dim,
            hidden_dim=self.disagreement_hidden_dim or self.hidden_dim,
            n_models=self.n_models,
            lr=self.disagreement_lr,
        )
