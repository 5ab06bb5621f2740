"""Active Pre-Training (APT) as an SB3 algorithm."""

from __future__ import annotations

from typing import Any, ClassVar

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
    :param apt_hidden_dim: hidden width of the forward and inverse models (default: the policy's)
    :param apt_rep_dim: size of the representation (default: APTReward's)
    :param apt_lr: learning rate of the representation and models (default: APTReward's)
    :param knn_k: neighbours of the particle estimator (default: APTReward's)
    :param knn_clip: clip of the particle estimator (default: APTReward's)
    :param knn_avg: average the k distances (default: APTReward's)
    :param knn_rms: divide by the running mean of the distances (default: APTReward's)
    :param kwargs: arguments of :class:`URLBDDPG` (``batch_size``, ``policy_kwargs``...)
    """

    # the method ---------------------------------------------------------------------------------
    skill_prior_class = None
    reward_module_class = APTReward
    reward_module_args: ClassVar[dict[str, str]] = {
        "apt_hidden_dim": "hidden_dim",
        "apt_rep_dim": "rep_dim",
        "apt_lr": "lr",
        "knn_k": "knn_k",
        "knn_clip": "knn_clip",
        "knn_avg": "knn_avg",
        "knn_rms": "knn_rms",
    }
    finetune_skill_choices: ClassVar[dict[str, Any]] = {}
    finetune_critic: ClassVar[str] = "trunk"
