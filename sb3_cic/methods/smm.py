"""State Marginal Matching (SMM) as an SB3 algorithm."""

from __future__ import annotations

from typing import Any, ClassVar

from stable_baselines3.common.type_aliases import GymEnv

from sb3_cic.callbacks import SkillGridSweepCallback
from sb3_cic.ddpg import URLBDDPG
from sb3_cic.rewards.smm import SMMReward
from sb3_cic.skills import OneHotSkillPrior


class SMM(URLBDDPG):
    """State Marginal Matching (Lee et al., 2019, https://arxiv.org/abs/1906.05274), URLB's version.

    Reference implementation: https://github.com/rll-research/url_benchmark (``agent/smm.py``).
    A competence-based method: one-hot skills (4) fixed for a whole episode and the reward of
    :class:`~sb3_cic.rewards.smm.SMMReward` (VAE density, ``log K`` and the discriminator's ``log q(z|s')``).

    Deliberate deviations from the reference code: the reward adds ``+log q(z|s')`` as in the SMM
    objective (the code adds ``-log q(z|s)``, a sign slip); the VAE reconstructs the state only and
    all terms are computed on ``s'``; the VAE's ``log var`` is clamped to ``[-10, 10]`` (without it, one of three
    quadruped pre-training seeds overflowed to NaN within a hundred updates). Fine-tuning (our choice, like DIAYN): during the first ``learning_starts`` (4,000) steps each skill is fixed
    in turn for ``learning_starts // 4`` steps, acting with the pre-trained policy, and the skill
    with the highest extrinsic return is kept (:class:`~sb3_cic.callbacks.SkillGridSweepCallback`). The
    reference has a one-episode-per-skill search, but it only runs while ``reward_free`` (in
    pre-training), so its fine-tuning keeps a random skill per episode.

    :param policy: policy (``"MlpPolicy"``)
    :param env: environment id, environment or VecEnv (wrapped with the skill wrapper if needed)
    :param skill_dim: number of skills (4)
    :param smm_hidden_dim: hidden width of the discriminator (default: the policy's)
    :param vae_hidden_dim: hidden width of the VAE (default: SMMReward's)
    :param code_dim: VAE latent size (default: SMMReward's)
    :param vae_lr: learning rate of the VAE (default: SMMReward's)
    :param disc_lr: learning rate of the discriminator (default: SMMReward's)
    :param vae_beta: weight of the VAE's KL term (default: SMMReward's)
    :param skill_resample_every: skill resampling period (None: once per episode)
    :param kwargs: arguments of :class:`URLBDDPG` (``batch_size``, ``policy_kwargs``...)
    """

    # the method ---------------------------------------------------------------------------------
    skill_prior_class = OneHotSkillPrior
    reward_module_class = SMMReward
    reward_module_args: ClassVar[dict[str, str]] = {
        "smm_hidden_dim": "hidden_dim",
        "vae_hidden_dim": "vae_hidden_dim",
        "code_dim": "code_dim",
        "vae_lr": "vae_lr",
        "disc_lr": "disc_lr",
        "vae_beta": "vae_beta",
    }
    finetune_skill_choices: ClassVar[dict[str, Any]] = {"sweep": (SkillGridSweepCallback, {"window": None})}
    finetune_critic: ClassVar[str] = "trunk"

    def __init__(
        self, policy: str | type, env: GymEnv | str, skill_dim: int = 4, skill_resample_every: int | None = None, **kwargs: Any
    ) -> None:
        super().__init__(policy, env, skill_dim=skill_dim, skill_resample_every=skill_resample_every, **kwargs)
