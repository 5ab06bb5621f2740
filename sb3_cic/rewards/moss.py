"""MOSS's reward module: CIC's discriminator and particle reward, the reward's sign set by the skill's mode."""

from __future__ import annotations

from typing import Any, ClassVar

import torch as th
from stable_baselines3.common.type_aliases import ReplayBufferSamples

from sb3_cic.common.arguments import FLAG, Flag, Range
from sb3_cic.rewards.cic import CICReward
from sb3_cic.skills import check_skill_mode, control_mask

#: the embeddings MOSS's particle reward measures against the batch's ``g1(s')`` (see :class:`MOSSReward`)
KNN_SOURCES = ("state", "next_state")


class MOSSReward(CICReward):
    """A Mixture Of SurpriseS (Zhao et al., 2022, https://arxiv.org/abs/2210.06702; code: LeapLabTHU/MOSS).

    :class:`~sb3_cic.rewards.cic.CICReward` (the same networks, loss and update), with the reward of each
    transition whose skill is a *control* skill (:func:`~sb3_cic.skills.control_mask`) negated: explore skills
    maximise the particle entropy, control skills minimise it. The statistics and the k nearest neighbours are
    those of the whole batch, both modes together, as MOSS's code computes them.

    Where MOSS's defaults differ from CIC's (``docs/methods.md``): the reference CIC code's loss and k = 16
    (``variant="code"``); each ``g1(s)`` measured against the batch's ``g1(s')`` (``knn_source="state"``; CIC:
    ``g1(s')`` against ``g1(s')``); the distances normalised as ``(d - mean) / var`` (``minus_mean``; the CIC code:
    ``d / var``); a 32-d skill.

    :param state_dim: state size
    :param action_dim: action size
    :param skill_dim: skill size (32)
    :param variant: CIC's loss variant ("code", MOSS's; see :class:`~sb3_cic.rewards.cic.CICReward`)
    :param minus_mean: subtract the running mean of the distances before dividing (MOSS: True)
    :param knn_source: "state" (MOSS: ``g1(s)`` against the batch's ``g1(s')``) or "next_state" (CIC)
    :param skill_mode: how a skill carries its mode, "half" or "sign" (:class:`~sb3_cic.skills.MixtureSkillPrior`)
    :param kwargs: the other parameters of :class:`~sb3_cic.rewards.cic.CICReward`, with its defaults
        (``hidden_dim``, ``embed_dim``, ``lr``, ``temperature``, ``knn_k``: the variant's, ``knn_clip``...)
    """

    parameter_ranges: ClassVar[dict[str, Range | Flag]] = {"minus_mean": FLAG}

    def __init__(
        self,
        state_dim: int,
        action_dim: int,
        skill_dim: int = 32,
        variant: str = "code",
        minus_mean: bool = True,
        knn_source: str = "state",
        skill_mode: str = "half",
        **kwargs: Any,
    ) -> None:
        if knn_source not in KNN_SOURCES:
            raise ValueError(f"knn_source must be one of {KNN_SOURCES}, got {knn_source!r}")
        check_skill_mode(skill_mode)
        super().__init__(state_dim, action_dim, skill_dim=skill_dim, variant=variant, **kwargs)
        self.particle.center = minus_mean
        self.knn_source = knn_source
        self.skill_mode = skill_mode

    def particle_reward(self, batch: ReplayBufferSamples, embeddings: tuple[th.Tensor, th.Tensor] | None = None) -> th.Tensor:
        """CIC's particle reward of the batch (of ``knn_source`` against the ``g1(s')``), negated for control skills."""
        if embeddings is None:
            next_state = batch.next_observations[:, : self.state_dim]
            if self.knn_source == "state":
                embeddings = self.state_net(th.cat([self.split(batch.observations)[0], next_state])).chunk(2)
            else:
                embeddings = (None, self.state_net(next_state))  # type: ignore[assignment]
        source = embeddings[0] if self.knn_source == "state" else embeddings[1]
        reward = self.particle(source, embeddings[1])
        return th.where(control_mask(self.split(batch.observations)[1], self.skill_mode), -reward, reward)
