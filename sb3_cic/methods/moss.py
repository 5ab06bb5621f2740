"""A Mixture Of SurpriseS (MOSS) as an SB3 algorithm."""

from __future__ import annotations

from typing import Any, ClassVar

from sb3_cic.callbacks import FixedSkillCallback, SkillGridSweepCallback
from sb3_cic.methods.cic import CIC
from sb3_cic.rewards.moss import MOSSReward
from sb3_cic.skills import MixtureSkillPrior


class MOSS(CIC):
    """A Mixture Of SurpriseS (Zhao et al., 2022, https://arxiv.org/abs/2210.06702; code: LeapLabTHU/MOSS).

    :class:`~sb3_cic.methods.cic.CIC` with a mode in each skill: the first part of every episode *explores*
    (maximises CIC's particle entropy), the next *controls* (minimises it: the reward of a control skill's
    transitions is negated, :class:`~sb3_cic.rewards.moss.MOSSReward`). The mode alternates over ``partitions``
    equal parts of the episode and decides which half of the 32-d skill is drawn from U[0, 1] and which is zero
    (:class:`~sb3_cic.skills.MixtureSkillPrior`).

    The defaults are those of MOSS's code (its configuration files; ``docs/methods.md`` lists each with where it
    comes from): a 32-d skill resampled every 50 steps, ``skill_mode="half"``, 2 partitions, the CIC code's loss
    (``cic_variant="code"``), k = 16, the distances normalised as ``(d - mean) / var``, each ``g1(s)`` measured
    against the batch's ``g1(s')``.

    Fine-tuning (:meth:`load_pretrained` then ``learn``) chooses the skill as MOSS's ``grid_search`` (the default,
    ``finetune_skill_choice="sweep"``): constant skills ``c * 1``, ``c`` evenly spaced in [-1, 0], one per 50 steps of
    the 4,000-step random-action phase (80 candidates), the best fixed. Those lie in the control region of the
    ``"sign"`` mode and outside the ``"half"`` mode's skills (MOSS's code pairs them so by default). ``"fixed"``
    is MOSS's ``constant``: ``0.5 * 1``, the README's jaco example. Deviation: the sweep acts with exploration
    noise, as this package's CIC sweep; MOSS's acts greedily.

    :param policy: policy (``"MlpPolicy"``)
    :param env: environment id, environment or VecEnv (wrapped with the skill wrapper if needed)
    :param partitions: parts of an episode, alternately explore and control (2: the first half explores)
    :param skill_mode: "half" (MOSS's default) or "sign" (its jaco example): how a skill carries its mode
    :param episode_length: steps of an episode, for the parts (URLB's 1,000)
    :param minus_mean: normalise the kNN distances as ``(d - mean) / var`` (True, MOSS) instead of ``d / var``
    :param knn_source: "state" (MOSS) or "next_state" (CIC): the embeddings measured against the batch's ``g1(s')``
    :param kwargs: arguments of :class:`~sb3_cic.methods.cic.CIC` (``skill_dim``, ``knn_k``, ``cic_variant``...)
    """

    skill_prior_class = MixtureSkillPrior
    reward_module_class = MOSSReward
    reward_module_args: ClassVar[dict[str, str]] = {
        **CIC.reward_module_args,
        "minus_mean": "minus_mean",
        "knn_source": "knn_source",
        "skill_mode": "skill_mode",
    }
    skill_prior_args: ClassVar[dict[str, str]] = {
        "partitions": "partitions",
        "skill_mode": "skill_mode",
        "episode_length": "episode_length",
    }
    finetune_skill_choices: ClassVar[dict[str, Any]] = {
        "sweep": (SkillGridSweepCallback, {"window": 50}),
        "fixed": (FixedSkillCallback, {"value": 0.5}),
    }
    finetune_critic: ClassVar[str] = "trunk"
