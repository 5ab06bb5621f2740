"""Diversity Is All You Need (DIAYN) as an SB3 algorithm."""

from __future__ import annotations

from typing import Any, ClassVar

from sb3_cic.callbacks import SkillGridSweepCallback
from sb3_cic.ddpg import URLBDDPG
from sb3_cic.rewards.diayn import DIAYNReward
from sb3_cic.skills import OneHotSkillPrior


class DIAYN(URLBDDPG):
    """Diversity Is All You Need (Eysenbach et al., 2019, https://arxiv.org/abs/1802.06070), URLB's version.

    Reference implementation: https://github.com/rll-research/url_benchmark (``agent/diayn.py``).
    A competence-based method: one-hot skills (16) resampled every 50 steps and the discriminator
    reward of :class:`~sb3_cic.rewards.diayn.DIAYNReward`.

    Fine-tuning (our choice; the reference keeps resampling random skills): during the first
    ``learning_starts`` (4,000) steps each skill is fixed in turn for ``learning_starts // 16`` steps,
    acting with the pre-trained policy, and the skill with the highest extrinsic return is kept
    (:class:`~sb3_cic.callbacks.SkillGridSweepCallback` with ``window=None``).

    :param policy: policy (``"MlpPolicy"``)
    :param env: environment id, environment or VecEnv (wrapped with the skill wrapper if needed)
    :param skill_dim: number of skills (16)
    :param diayn_hidden_dim: hidden width of the discriminator (default: the policy's)
    :param diayn_lr: learning rate of the discriminator (default: DIAYNReward's)
    :param diayn_scale: reward scale (default: DIAYNReward's)
    :param skill_resample_every: skill resampling period (50)
    :param kwargs: arguments of :class:`URLBDDPG` (``batch_size``, ``policy_kwargs``...)
    """

    # the method ---------------------------------------------------------------------------------
    skill_prior_class = OneHotSkillPrior
    reward_module_class = DIAYNReward
    reward_module_args: ClassVar[dict[str, str]] = {
        "diayn_hidden_dim": "hidden_dim",
        "diayn_lr": "lr",
        "diayn_scale": "scale",
    }
    finetune_skill_choices: ClassVar[dict[str, Any]] = {"sweep": (SkillGridSweepCallback, {"window": None})}
    finetune_critic: ClassVar[str] = "trunk"
