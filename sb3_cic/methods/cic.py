"""Contrastive Intrinsic Control (CIC) as an SB3 algorithm."""

from __future__ import annotations

from typing import Any

from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.type_aliases import GymEnv

from sb3_cic.callbacks import FixedSkillCallback, SkillGridSweepCallback
from sb3_cic.ddpg import URLBDDPG
from sb3_cic.rewards.cic import CICReward, check_variant
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
    :param skill_dim: skill size (64)
    :param cic_hidden_dim: hidden width of state_net, pred_net, skill_net (default: the policy's, 1024)
    :param cic_embed_dim: output size of those networks (default: ``skill_dim``, as the CIC code;
        give e.g. 16 with ``skill_dim`` 1, whose normalised 1-d embeddings carry no information)
    :param cic_lr: learning rate of the discriminator (1e-4)
    :param temperature: contrastive temperature (0.5)
    :param knn_k: neighbours of the particle estimator (default 12; 16 with ``cic_variant="code"``)
    :param knn_clip: clip of the particle estimator (0.0005)
    :param finetune_skill_choice: "sweep" (paper) or "fixed" (0.5, reference code)
    :param cic_variant: "paper" or "code" (the reference code's loss, reward normalisation and k; see above)
    :param kwargs: arguments of :class:`URLBDDPG` (``batch_size``, ``policy_kwargs``...)
    """

    def __init__(
        self,
        policy: str | type,
        env: GymEnv | str,
        skill_dim: int = 64,
        cic_hidden_dim: int | None = None,
        cic_embed_dim: int | None = None,
        cic_lr: float = 1e-4,
        temperature: float = 0.5,
        knn_k: int | None = None,
        knn_clip: float = 0.0005,
        finetune_skill_choice: str = "sweep",
        skill_resample_every: int | None = 50,
        cic_variant: str = "paper",
        **kwargs: Any,
    ) -> None:
        if finetune_skill_choice not in ("sweep", "fixed"):
            raise ValueError(f"finetune_skill_choice must be 'sweep' or 'fixed', got {finetune_skill_choice!r}")
        check_variant(cic_variant)  # before the default k is chosen from it
        self.cic_variant = cic_variant
        self.cic_hidden_dim = cic_hidden_dim
        self.cic_embed_dim = cic_embed_dim
        self.cic_lr = cic_lr
        self.temperature = temperature
        self.knn_k = knn_k if knn_k is not None else (12 if cic_variant == "paper" else 16)
        self.knn_clip = knn_clip
        self.finetune_skill_choice = finetune_skill_choice
        prior = UniformSkillPrior(skill_dim)
        super().__init__(policy, env, skill_prior=prior, skill_resample_every=skill_resample_every, **kwargs)

    def _make_reward_module(self) -> CICReward:
        return CICReward(
            self.state_dim,
            self.action_dim,
            skill_dim=self.skill_dim,
            hidden_dim=self.cic_hidden_dim or self.hidden_dim,
            embed_dim=self.cic_embed_dim,
            lr=self.cic_lr,
            temperature=self.temperature,
            knn_k=self.knn_k,
            knn_clip=self.knn_clip,
            variant=self.cic_variant,
        )

    def make_finetune_callback(self) -> BaseCallback:
        if self.finetune_skill_choice == "fixed":
            return FixedSkillCallback(0.5, verbose=self.verbose)
        return SkillGridSweepCallback(sweep_steps=self.learning_starts, window=100, verbose=self.verbose)
