"""Diversity Is All You Need (DIAYN) as an SB3 algorithm."""

from __future__ import annotations

from typing import Any

from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.type_aliases import GymEnv

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
    :param diayn_hidden_dim: hidden width of the discriminator (default: the policy's, 1024)
    :param diayn_lr: learning rate of the discriminator (1e-4)
    :param diayn_scale: reward scale (1)
    :param skill_resample_every: skill resampling period (50)
    :param kwargs: arguments of :class:`URLBDDPG` (``batch_size``, ``policy_kwargs``...)
    """

    def __init__(
        self,
        policy: str | type,
        env: GymEnv | str,
        skill_dim: int = 16,
        diayn_hidden_dim: int | None = None,
        diayn_lr: float = 1e-4,
        diayn_scale: float = 1.0,
        skill_resample_every: int | None = 50,
        **kwargs: Any,
    ) -> None:
        self.diayn_hidden_dim = diayn_hidden_dim
        self.diayn_lr = diayn_lr
        self.diayn_scale = diayn_scale
        prior = OneHotSkillPrior(skill_dim)
        super().__init__(policy, env, skill_prior=prior, skill_resample_every=skill_resample_every, **kwargs)

    def _make_reward_module(self) -> DIAYNReward:
        return DIAYNReward(
            self.state_dim,
            self.action_dim,
            skill_dim=self.skill_dim,
            hidden_dim=self.diayn_hidden_dim or self.hidden_dim,
            lr=self.diayn_lr,
            scale=self.diayn_scale,
        )

    def make_finetune_callback(self) -> BaseCallback:
        return SkillGridSweepCallback(sweep_steps=self.learning_starts, window=None, verbose=self.verbose)
