"""CIC's reward module: the contrastive skill discriminator and the particle-entropy reward."""

from __future__ import annotations

from typing import ClassVar

import math

import torch as th
import torch.nn.functional as F
from stable_baselines3.common.type_aliases import ReplayBufferSamples

from sb3_cic.common.arguments import FLAG, NON_NEGATIVE, POSITIVE, POSITIVE_INT, Flag, Range
from sb3_cic.policies import orthogonal_init
from sb3_cic.rewards.base import RewardModule, mlp
from sb3_cic.rewards.particle import ParticleEntropy


#: the CIC loss and reward variants (see :class:`CICReward`)
CIC_VARIANTS = ("paper", "code")
#: the default number of neighbours of each variant: the paper's k, the reference code's
KNN_K = {"paper": 12, "code": 16}


def check_variant(variant: str) -> None:
    """``ValueError`` unless ``variant`` is one of :data:`CIC_VARIANTS`."""
    if variant not in CIC_VARIANTS:
        raise ValueError(f"the CIC variant must be one of {CIC_VARIANTS}, got {variant!r}")


class CICReward(RewardModule):
    """Contrastive Intrinsic Control (Laskin et al., 2022).

    * ``state_net`` g1: state -> h -> h -> e, applied to s and s';
      ``pred_net``: [g1(s), g1(s')] -> h -> h -> e (the key);
      ``skill_net`` g2: skill -> h -> h -> e (the query);
      the embedding size ``e`` is ``skill_dim`` as in the CIC code unless ``embed_dim`` is given.
    * Loss, ``variant="paper"`` (Listing 2): cross-entropy of the logits ``normalize(q) normalize(k)^T / T``
      with the diagonal as positives. ``variant="code"`` (rll-research/cic): exp(1/T), the largest possible
      positive term, is subtracted from each row's denominator:
      ``log(max(sum_j exp(l_ij) - exp(1/T), 1e-6) + 1e-6) - l_ii``, averaged over the batch.
    * Reward: particle entropy (k nearest neighbours in the batch) of ``g1(s')``, divided by the running
      mean of the distances (``variant="code"``: by their running variance, as the CIC code does).
    * Initialisation: orthogonal weights and zero biases, as the CIC code's networks.

    :meth:`update_and_reward` computes ``g1(s)`` and ``g1(s')`` once for both the loss and the reward
    (the reward uses the networks as they were when the batch was sampled).

    :param state_dim: state size
    :param action_dim: action size
    :param skill_dim: skill size (64)
    :param hidden_dim: hidden width of the three networks (1024)
    :param embed_dim: output size of the three networks (default: ``skill_dim``; with ``skill_dim`` 1
        the normalised embeddings would be +-1 and carry no information, so give more, e.g. 16)
    :param lr: Adam learning rate (1e-4)
    :param temperature: contrastive temperature (0.5)
    :param knn_k: neighbours of the entropy estimator (default: the variant's, :data:`KNN_K`)
    :param knn_clip: clip of the entropy estimator (0.0005)
    :param knn_avg: average the k distances
    :param knn_rms: divide by the running mean (variant "code": variance) of the distances
    :param variant: "paper" (the paper's loss and reward) or "code" (the reference code's, see above)
    """

    parameter_ranges: ClassVar[dict[str, Range | Flag]] = {
        "embed_dim": POSITIVE_INT, "temperature": POSITIVE, "knn_k": POSITIVE_INT, "knn_clip": NON_NEGATIVE,
        "knn_avg": FLAG, "knn_rms": FLAG,
    }

    def __init__(
        self,
        state_dim: int,
        action_dim: int,
        skill_dim: int = 64,
        hidden_dim: int = 1024,
        embed_dim: int | None = None,
        lr: float = 1e-4,
        temperature: float = 0.5,
        knn_k: int | None = None,
        knn_clip: float = 0.0005,
        knn_avg: bool = True,
        knn_rms: bool = True,
        variant: str = "paper",
    ) -> None:
        check_variant(variant)
        super().__init__(state_dim, action_dim, skill_dim, lr)
        self.temperature = temperature
        self.variant = variant
        embed_dim = embed_dim or skill_dim
        self.state_net = mlp(state_dim, hidden_dim, embed_dim)
        self.pred_net = mlp(2 * embed_dim, hidden_dim, embed_dim)
        self.skill_net = mlp(skill_dim, hidden_dim, embed_dim)
        self.apply(orthogonal_init)  # orthogonal weights, zero biases, as the CIC code
        divide_by = "mean" if variant == "paper" else "var"
        knn_k = self.default_knn_k(variant) if knn_k is None else knn_k
        self.particle = ParticleEntropy(k=knn_k, avg=knn_avg, rms=knn_rms, clip=knn_clip, divide_by=divide_by)
        self.make_optimizer()

    @staticmethod
    def default_knn_k(variant: str) -> int:
        """The number of neighbours of ``variant`` (:data:`KNN_K`); ``ValueError`` for an unknown variant.

        :param variant: "paper" or "code"
        """
        check_variant(variant)
        return KNN_K[variant]

    def logits(self, query: th.Tensor, key: th.Tensor) -> th.Tensor:
        """The discriminator's ``(B, B)`` logits: cosine similarities of queries and keys over the temperature."""
        return F.normalize(query, dim=1) @ F.normalize(key, dim=1).T / self.temperature

    def contrastive_loss(self, query: th.Tensor, key: th.Tensor, variant: str | None = None) -> tuple[th.Tensor, th.Tensor]:
        """The contrastive loss of :meth:`logits` (diagonal positives); also top-1 accuracy.

        :param variant: "paper" or "code" (default: the module's)
        """
        return self.loss_of_logits(self.logits(query, key), variant)

    def loss_of_logits(self, logits: th.Tensor, variant: str | None = None) -> tuple[th.Tensor, th.Tensor]:
        """:meth:`contrastive_loss` and top-1 accuracy of already computed :meth:`logits`."""
        labels = th.arange(logits.shape[0], device=logits.device)
        accuracy = (logits.argmax(dim=1) == labels).float().mean()
        if (variant or self.variant) == "paper":
            return F.cross_entropy(logits, labels), accuracy
        negatives = (logits.exp().sum(dim=1) - math.exp(1.0 / self.temperature)).clamp_min(1e-6)
        return (th.log(negatives + 1e-6) - logits.diagonal()).mean(), accuracy

    def query_key(self, batch: ReplayBufferSamples) -> tuple[th.Tensor, th.Tensor, tuple[th.Tensor, th.Tensor]]:
        """The queries ``g2(z)``, the keys ``pred([g1(s), g1(s')])`` and the embeddings ``(g1(s), g1(s'))`` of a batch."""
        state, skill = self.split(batch.observations)
        next_state = batch.next_observations[:, : self.state_dim]
        embedding, next_embedding = self.state_net(th.cat([state, next_state], dim=0)).chunk(2, dim=0)
        key = self.pred_net(th.cat([embedding, next_embedding], dim=1))
        return self.skill_net(skill), key, (embedding, next_embedding)

    def _loss(self, batch: ReplayBufferSamples) -> tuple[th.Tensor, th.Tensor, tuple[th.Tensor, th.Tensor]]:
        query, key, embeddings = self.query_key(batch)
        loss, accuracy = self.contrastive_loss(query, key)
        return loss, accuracy, embeddings

    def particle_reward(self, batch: ReplayBufferSamples, embeddings: tuple[th.Tensor, th.Tensor] | None = None) -> th.Tensor:
        """The particle reward of a batch: the entropy estimate of each ``g1(s')`` among the batch's.

        :param batch: the batch
        :param embeddings: ``(g1(s), g1(s'))`` when already computed (:meth:`query_key`), else computed here
        """
        if embeddings is None:
            return self.particle(self.state_net(batch.next_observations[:, : self.state_dim]))
        return self.particle(embeddings[1])

    def update(self, batch: ReplayBufferSamples) -> dict[str, th.Tensor]:
        loss, accuracy, _ = self._loss(batch)
        self.optimizer_step(loss)
        return {"contrastive_loss": loss.detach(), "disc_accuracy": accuracy}

    def reward(self, batch: ReplayBufferSamples) -> th.Tensor:
        return self.particle_reward(batch)

    def update_and_reward(self, batch: ReplayBufferSamples) -> tuple[th.Tensor, dict[str, th.Tensor]]:
        loss, accuracy, embeddings = self._loss(batch)
        with th.no_grad():
            reward = self.particle_reward(batch, (embeddings[0].detach(), embeddings[1].detach()))
        self.optimizer_step(loss)
        return reward, {"contrastive_loss": loss.detach(), "disc_accuracy": accuracy}
