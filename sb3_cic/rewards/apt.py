"""APT's reward module: an ICM-trained representation and the particle entropy of next states in it."""

from __future__ import annotations

from typing import ClassVar

import torch as th
from stable_baselines3.common.type_aliases import ReplayBufferSamples
from torch import nn

from sb3_cic.common.arguments import FLAG, NON_NEGATIVE, POSITIVE_INT, Flag, Range
from sb3_cic.policies import orthogonal_init
from sb3_cic.rewards.base import RewardModule, mlp
from sb3_cic.rewards.particle import ParticleEntropy
from sb3_cic.speed import LeanSequential


class APTReward(RewardModule):
    """Active Pre-Training (Liu & Abbeel, 2021), state-based as in URLB (``agent/icm_apt.py``).

    * ``trunk``: ``state -> rep_dim -> LayerNorm -> Tanh`` (the representation ``rep``).
    * ICM losses in that space: ``forward_net`` ``[rep(s), a] -> h -> rep_dim`` and ``inverse_net``
      ``[rep(s), rep(s')] -> h -> action_dim -> tanh``; loss ``mean ||f - rep(s')|| + mean ||g - a||``.
    * Reward: particle entropy (k nearest neighbours within the batch) of ``rep(s')`` with
      ``k = 12``, averaged, no running normalisation, clip 0 (the reference scores ``rep(s)``).

    :param state_dim: state size
    :param action_dim: action size
    :param hidden_dim: hidden width of the forward and inverse models (1024)
    :param rep_dim: size of the representation (512)
    :param lr: Adam learning rate (1e-4)
    :param knn_k: neighbours of the entropy estimator (12)
    :param knn_clip: clip of the entropy estimator (0)
    :param knn_avg: average the k distances
    :param knn_rms: divide by the running mean of the distances
    """

    parameter_ranges: ClassVar[dict[str, Range | Flag]] = {
        "rep_dim": POSITIVE_INT, "knn_k": POSITIVE_INT, "knn_clip": NON_NEGATIVE, "knn_avg": FLAG, "knn_rms": FLAG,
    }

    def __init__(
        self,
        state_dim: int,
        action_dim: int,
        hidden_dim: int = 1024,
        rep_dim: int = 512,
        lr: float = 1e-4,
        knn_k: int = 12,
        knn_clip: float = 0.0,
        knn_avg: bool = True,
        knn_rms: bool = False,
    ) -> None:
        super().__init__(state_dim, action_dim, 0, lr)
        self.trunk = LeanSequential(nn.Linear(state_dim, rep_dim), nn.LayerNorm(rep_dim), nn.Tanh())
        self.forward_net = mlp(rep_dim + action_dim, hidden_dim, rep_dim, n_hidden=1)
        self.inverse_net = LeanSequential(*mlp(2 * rep_dim, hidden_dim, action_dim, n_hidden=1), nn.Tanh())
        self.apply(orthogonal_init)
        self.particle = ParticleEntropy(k=knn_k, avg=knn_avg, rms=knn_rms, clip=knn_clip)
        self.make_optimizer()

    def _loss(self, batch: ReplayBufferSamples) -> tuple[th.Tensor, th.Tensor, th.Tensor, th.Tensor]:
        state, next_state = self.split(batch.observations)[0], self.split(batch.next_observations)[0]
        rep, next_rep = self.trunk(th.cat([state, next_state], dim=0)).chunk(2, dim=0)
        next_hat = self.forward_net(th.cat([rep, batch.actions], dim=1))
        action_hat = self.inverse_net(th.cat([rep, next_rep], dim=1))
        forward_error = th.linalg.vector_norm(next_hat - next_rep, dim=1).mean()
        inverse_error = th.linalg.vector_norm(action_hat - batch.actions, dim=1).mean()
        return forward_error + inverse_error, forward_error, inverse_error, next_rep

    def _step(self, loss: th.Tensor, forward_error: th.Tensor, inverse_error: th.Tensor) -> dict[str, th.Tensor]:
        self.optimizer_step(loss)
        return {"icm_loss": loss.detach(), "forward_error": forward_error.detach(), "inverse_error": inverse_error.detach()}

    def update(self, batch: ReplayBufferSamples) -> dict[str, th.Tensor]:
        return self._step(*self._loss(batch)[:3])

    def reward(self, batch: ReplayBufferSamples) -> th.Tensor:
        return self.particle(self.trunk(self.split(batch.next_observations)[0]))

    def update_and_reward(self, batch: ReplayBufferSamples) -> tuple[th.Tensor, dict[str, th.Tensor]]:
        loss, forward_error, inverse_error, next_rep = self._loss(batch)
        with th.no_grad():
            reward = self.particle(next_rep.detach())
        return reward, self._step(loss, forward_error, inverse_error)
