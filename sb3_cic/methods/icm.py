"""Intrinsic Curiosity Module (ICM) as an SB3 algorithm."""

from __future__ import annotations

from typing import Any, ClassVar

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
    :param icm_hidden_dim: hidden width of the forward and inverse models (default: the policy's)
    :param icm_lr: learning rate of the models (default: ICMReward's)
    :param icm_scale: factor of the forward error inside the log (default: ICMReward's)
    :param kwargs: arguments of :class:`URLBDDPG` (``batch_size``, ``policy_kwargs``...)
    """

    # the method ---------------------------------------------------------------------------------
    skill_prior_class = None
    reward_module_class = ICMReward
    reward_module_args: ClassVar[dict[str, str]] = {
        "icm_hidden_dim": "hidden_dim",
        "icm_lr": "lr",
        "icm_scale": "scale",
    }
    finetune_skill_choices: ClassVar[dict[str, Any]] = {}
    finetune_critic: ClassVar[str] = "trunk"
