"""Contrastive Intrinsic Control (CIC) as an SB3 algorithm."""

from __future__ import annotations

from typing import Any, ClassVar

from stable_baselines3.common.type_aliases import GymEnv

from sb3_cic.callbacks import FixedSkillCallback, SkillGridSweepCallback
from sb3_cic.common.arguments import parameter_default
from sb3_cic.ddpg import URLBDDPG
from sb3_cic.rewards.cic import CICReward
from sb3_cic.skills import UniformSkillPrior


class CIC(URLBDDPG):
    """Contrastive Intrinsic Control (Laskin et al., 2022, https://arxiv.org/abs/2202.00161).

    Reference implementation: https://github.com/rll-research/cic. URLB DDPG (:class:`URLBDDPG`)
    with skills ``z ~ U[0, 1]^64`` resampled every 50 steps, and the reward of
    :class:`~sb3_cic.rewards.cic.CICReward` (contrastive discriminator + particle entropy, k = 12).

    Fine-tuning (:meth:`load_pretrained` then ``learn``) chooses the skill with the paper's grid sweep
    (:class:`~sb3_cic.callbacks.SkillGridSweepCallback`, the default) or fixes ``0.5 * 1`` like the
    reference code (``finetune_skill_choice="fixed"``).

    ``cic_variant="paper"`` (the default) follows the paper where the reference code differs: the loss is the
    paper's cross-entropy (the code subtracts exp(1/T) from the denominator), the reward divides by the running
    mean of the kNN distances (the code divides by a running variance) and k = 12 (code: 16).
    ``cic_variant="code"`` makes those three choices as the reference code does, the choices behind the
    published numbers (docs/methods.md). Either way the sweep acts with the pre-trained policy (see the callback).

    :param policy: policy (``"MlpPolicy"``)
    :param env: environment id, environment or VecEnv (wrapped with the skill wrapper if needed)
    :param skill_dim: skill size (default: UniformSkillPrior's)
    :param cic_hidden_dim: hidden width of state_net, pred_net, skill_net (default: the policy's)
    :param cic_embed_dim: output size of those networks (default: ``skill_dim``, as the CIC code;
        give e.g. 16 with ``skill_dim`` 1, whose normalised 1-d embeddings carry no information)
    :param cic_lr: learning rate of the discriminator (default: CICReward's)
    :param temperature: contrastive temperature (default: CICReward's)
    :param knn_k: neighbours of the particle estimator (default: CICReward's, which depends on ``cic_variant``)
    :param knn_clip: clip of the particle estimator (default: CICReward's)
    :param finetune_skill_choice: "sweep" (paper, the default) or "fixed" (0.5, reference code)
    :param skill_resample_every: skill resampling period (50)
    :param cic_variant: "paper" (the default) or "code" (the reference code's loss, reward normalisation and k; see above)
    :param kwargs: arguments of :class:`URLBDDPG` (``batch_size``, ``policy_kwargs``...)
    """

    # the method ---------------------------------------------------------------------------------
    skill_prior_class = UniformSkillPrior
    reward_module_class = CICReward
    reward_module_args: ClassVar[dict[str, str]] = {
        "cic_hidden_dim": "hidden_dim",
        "cic_embed_dim": "embed_dim",
        "cic_lr": "lr",
        "temperature": "temperature",
        "knn_k": "knn_k",
        "knn_clip": "knn_clip",
        "cic_variant": "variant",
    }
    finetune_skill_choices: ClassVar[dict[str, Any]] = {
        "sweep": (SkillGridSweepCallback, {"window": 100}),
        "fixed": (FixedSkillCallback, {"value": 0.5}),
    }
    finetune_critic: ClassVar[str] = "trunk"

    def __init__(self, policy: str | type, env: GymEnv | str, **kwargs: Any) -> None:
        if kwargs.get("knn_k") is None:  # the variant's (a ValueError for an unknown variant, before anything is built)
            variant = kwargs.get("cic_variant") or parameter_default(self.reward_module_class, "variant")
            kwargs["knn_k"] = CICReward.default_knn_k(variant)
        super().__init__(policy, env, **kwargs)
