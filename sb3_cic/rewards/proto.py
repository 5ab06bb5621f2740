"""ProtoRL's reward module: prototypical representation (SwAV-style) and a kNN novelty reward."""

from __future__ import annotations

from typing import ClassVar

import copy

import torch as th
import torch.nn.functional as F
from stable_baselines3.common.type_aliases import ReplayBufferSamples
from torch import nn

from sb3_cic.common.arguments import FRACTION, POSITIVE, POSITIVE_INT, Flag, Range
from sb3_cic.policies import orthogonal_init
from sb3_cic.rewards.base import RewardModule, mlp
from sb3_cic.rewards.particle import knn_distances


def sinkhorn_knopp(logits: th.Tensor, n_iters: int = 3) -> th.Tensor:
    """Soft, balanced assignment of samples to prototypes (Sinkhorn-Knopp on ``exp(logits)``).

    Alternately rescales the ``(K, B)`` matrix ``exp(logits).T`` so that every prototype holds mass
    ``1 / K`` and every sample ``1 / B``; the result is rescaled so that each sample's row sums to 1.

    :param logits: ``(B, K)`` scores already divided by the temperature
    :param n_iters: number of row/column normalisation rounds (3)
    :return: ``(B, K)`` assignment probabilities
    """
    q = th.exp(logits - logits.max()).T
    q = q / q.sum()
    n_protos, n_samples = q.shape
    for _ in range(n_iters):
        q = q / (q.sum(dim=1, keepdim=True) * n_protos)
        q = q / (q.sum(dim=0, keepdim=True) * n_samples)
    return (q / q.sum(dim=0, keepdim=True)).T


class ProtoReward(RewardModule):
    """Proto-RL (Yarats et al., 2021) on states, as in URLB (``agent/proto.py``).

    * ``predictor``: a linear encoder ``state -> pred_dim`` (128); ``projector``:
      ``pred_dim -> proj_dim -> pred_dim`` (512 hidden); ``protos``: ``num_protos`` (512) prototypes,
      L2-normalised before each use; ``predictor_target``: EMA (``target_tau`` 0.05) of the predictor.
    * Loss (swapped prediction): cross-entropy between ``sinkhorn(protos(normalize(target(s'))) / T)``
      (3 iterations) and ``softmax(protos(normalize(projector(predictor(s)))) / T)``, ``T = 0.1``.
    * Reward: each prototype samples one candidate of the batch (``softmax`` over the batch of its
      scores); the ``num_protos`` candidates enter a FIFO queue of ``queue_size`` (2048) embeddings (a
      buffer, saved); the reward of a transition is the distance from ``normalize(predictor(s'))``
      to its ``topk``-th (3rd) nearest queue entry. As in the reference, the embedding is the online
      predictor's and the queue starts as zeros.

    :param state_dim: state size
    :param action_dim: action size
    :param pred_dim: embedding size (128)
    :param proj_dim: hidden width of the projector (512)
    :param num_protos: number of prototypes (512)
    :param queue_size: candidate queue length (2048)
    :param topk: the reward is the distance to the topk-th nearest candidate (3)
    :param temperature: softmax temperature (0.1)
    :param sinkhorn_iters: Sinkhorn-Knopp iterations (3)
    :param target_tau: EMA coefficient of the target predictor (0.05)
    :param lr: Adam learning rate (1e-4)
    """

    parameter_ranges: ClassVar[dict[str, Range | Flag]] = {
        "pred_dim": POSITIVE_INT, "proj_dim": POSITIVE_INT, "num_protos": POSITIVE_INT, "queue_size": POSITIVE_INT,
        "topk": POSITIVE_INT, "temperature": POSITIVE, "sinkhorn_iters": POSITIVE_INT, "target_tau": FRACTION,
    }

    def __init__(
        self,
        state_dim: int,
        action_dim: int,
        pred_dim: int = 128,
        proj_dim: int = 512,
        num_protos: int = 512,
        queue_size: int = 2048,
        topk: int = 3,
        temperature: float = 0.1,
        sinkhorn_iters: int = 3,
        target_tau: float = 0.05,
        lr: float = 1e-4,
    ) -> None:
        super().__init__(state_dim, action_dim, 0, lr)
        if not topk <= queue_size or not num_protos <= queue_size:
            raise ValueError(f"need topk ({topk}) and num_protos ({num_protos}) <= queue_size ({queue_size})")
        self.topk, self.temperature, self.sinkhorn_iters, self.target_tau = topk, temperature, sinkhorn_iters, target_tau
        self.predictor = nn.Linear(state_dim, pred_dim)
        self.projector = mlp(pred_dim, proj_dim, pred_dim, n_hidden=1)
        self.protos = nn.Linear(pred_dim, num_protos, bias=False)
        self.apply(orthogonal_init)
        self.predictor_target = copy.deepcopy(self.predictor).requires_grad_(False)
        self.register_buffer("queue", th.zeros(queue_size, pred_dim))
        # the write position as a float64 (exact up to 2**53): every state_dict entry is floating point,
        # as SB3's get_parameters/set_parameters tools assume
        self.register_buffer("queue_ptr", th.zeros((), dtype=th.float64))
        self.make_optimizer()

    @th.no_grad()
    def normalize_protos(self) -> None:
        """L2-normalise every prototype in place."""
        self.protos.weight.copy_(F.normalize(self.protos.weight, dim=1))

    def embed(self, state: th.Tensor) -> th.Tensor:
        """The reward's embedding ``normalize(predictor(state))``."""
        return F.normalize(self.predictor(state), dim=1)

    @th.no_grad()
    def enqueue(self, embeddings: th.Tensor) -> None:
        """Write ``embeddings`` into the FIFO queue (overwriting the oldest entries)."""
        size = self.queue.shape[0]
        index = (self.queue_ptr.long() + th.arange(embeddings.shape[0], device=self.queue.device)) % size
        self.queue[index] = embeddings
        # through a view: torch.compile drops an in-place update of a 0-d float64 tensor
        self.queue_ptr.view(1).copy_((self.queue_ptr + embeddings.shape[0]) % size)

    def loss(self, batch: ReplayBufferSamples) -> th.Tensor:
        """Swapped-prediction loss of the batch (prototypes are normalised first)."""
        self.normalize_protos()
        state, next_state = self.split(batch.observations)[0], self.split(batch.next_observations)[0]
        online = F.normalize(self.projector(self.predictor(state)), dim=1)
        log_p = F.log_softmax(self.protos(online) / self.temperature, dim=1)
        with th.no_grad():
            target = F.normalize(self.predictor_target(next_state), dim=1)
            q = sinkhorn_knopp(self.protos(target) / self.temperature, self.sinkhorn_iters)
        return -(q * log_p).sum(dim=1).mean()

    def update(self, batch: ReplayBufferSamples) -> dict[str, th.Tensor]:
        loss = self.loss(batch)
        self.optimizer_step(loss)
        with th.no_grad():
            for target, online in zip(self.predictor_target.parameters(), self.predictor.parameters()):
                target.lerp_(online, self.target_tau)
        return {"proto_loss": loss.detach()}

    @th.no_grad()
    def reward(self, batch: ReplayBufferSamples) -> th.Tensor:
        self.normalize_protos()
        z = self.embed(self.split(batch.next_observations)[0])
        probs = F.softmax(self.protos(z).T, dim=1)  # (num_protos, batch): each prototype's choice
        self.enqueue(z[th.multinomial(probs, 1).squeeze(1)])
        return knn_distances(z, self.queue, self.topk)[:, -1:]
