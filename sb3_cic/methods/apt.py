"""Active Pre-Training (APT) as an SB3 algorithm."""

from __future__ import annotations

from typing import Any

from stable_baselines3.common.type_aliases import GymEnv

from sb3_cic.ddpg import URLBDDPG
from sb3_cic.rewards.apt import APTReward


class APT(URLBDDPG):
    """Active Pre-Training (Liu & Abbeel, 2021, https://arxiv.org/abs/2103.04551), URLB's state-based version.

    Reference implementation: https://github.com/rll-research/url_benchmark (``agent/icm_apt.py``).
    A data-based method without skills: URLB DDPG (:class:`URLBDDPG`) with the particle-entropy
    reward of :class:`~sb3_cic.rewards.apt.APTReward` in a representation trained by ICM losses.
    Fine-tuning keeps the actor and the critic trunk (URLB).

    Deliberate deviation from the reference code: the entropy is estimated on the representation of
    the next state ``s'`` (the code uses ``s``).

    :param policy: policy (``"MlpPolicy"``)
    :param env: environment id, environment or VecEnv
    :param apt_hidden_dim: hidden width of the forward and inverse models (default: the policy's, 1024)
    :param apt_rep_dim: size of the representation (512)
    :param apt_lr: learning rate of the representation and models (1e-4)
    :param knn_k: neighbours of the particle estimator (12)
    :param knn_clip: clip of the particle estimator (0)
    :param knn_avg: average the k distances (True)
    :param knn_rms: divide by the running mean of the distances (False)
    :param kwargs: arguments of :class:`URLBDDPG` (``batch_size``, ``policy_kwargs``...)
    """

    def __init__(
        self,
        policy: str | type,
        env: GymEnv | str,
        apt_hidden_dim: int | None = None,
        apt_rep_dim: int = 512,
        apt_lr: float = 1e-4,
        knn_k: int = 12,
        knn_clip: float = 0.0,
        knn_avg: bool = True,
        knn_rms: bool = False,
        **kwargs: Any,
    ) -> None:
        self.apt_hidden_dim = apt_hidden_dim
        self.apt_rep_dim = apt_rep_dim
        self.apt_lr = apt_lr
        self.knn_k = knn_k
        self.knn_clip = knn_clip
        self.knn_avg = knn_avg
        self.knn_rms = knn_rms
        super().__init__(policy, env, **kwargs)

    def _make_reward_module(self) -> APTReward:
        return APTReward(
            self.state_dim,
            self.action_dim,
            hidden_dim=self.apt_hidden_dim or self.hidden_dim,
            rep_dim=self.apt_rep_dim,
            lr=self.apt_lr,
            knn_k=self.knn_k,
            knn_clip=self.knn_clip,
            knn_avg=self.knn_avg,
            knn_rms=self.knn_rms,
        )
