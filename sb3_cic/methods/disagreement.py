"""Disagreement (ensemble-variance exploration) as an SB3 algorithm."""

from __future__ import annotations

from typing import Any, ClassVar

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
    :param disagreement_hidden_dim: hidden width of each forward model (default: the policy's)
    :param disagreement_lr: learning rate of the ensemble (default: DisagreementReward's)
    :param n_models: ensemble size (default: DisagreementReward's)
    :param kwargs: arguments of :class:`URLBDDPG` (``batch_size``, ``policy_kwargs``...)
    """

    # the method ---------------------------------------------------------------------------------
    skill_prior_class = None
    reward_module_class = DisagreementReward
    reward_module_args: ClassVar[dict[str, str]] = {
        "disagreement_hidden_dim": "hidden_dim",
        "disagreement_lr": "lr",
        "n_models": "n_models",
    }
    finetune_skill_choices: ClassVar[dict[str, Any]] = {}
    finetune_critic: ClassVar[str] = "trunk"
