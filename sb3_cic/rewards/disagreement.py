"""Disagreement's reward module: an ensemble of forward models, reward = variance of their predictions."""

from __future__ import annotations

from typing import ClassVar

import math

import torch as th
from stable_baselines3.common.type_aliases import ReplayBufferSamples
from torch import nn

from sb3_cic.common.arguments import POSITIVE_INT, Flag, Range
from sb3_cic.rewards.base import RewardModule


class ForwardEnsemble(nn.Module):
    """``n_models`` one-hidden-layer ReLU MLPs evaluated together with batched matrix products.

    Member ``m`` computes ``relu(x @ w1[m] + b1[m]) @ w2[m] + b2[m]``. Initialisation is PyTorch's
    ``nn.Linear`` default (uniform in ``+-1/sqrt(fan_in)``), as the reference ensemble.

    :param n_models: number of members
    :param in_dim: input size
    :param hidden_dim: hidden width
    :param out_dim: output size
    """

    def __init__(self, n_models: int, in_dim: int, hidden_dim: int, out_dim: int) -> None:
        super().__init__()
        self.n_models = n_models
        self.w1 = nn.Parameter(th.empty(n_models, in_dim, hidden_dim))
        self.b1 = nn.Parameter(th.empty(n_models, 1, hidden_dim))
        self.w2 = nn.Parameter(th.empty(n_models, hidden_dim, out_dim))
        self.b2 = nn.Parameter(th.empty(n_models, 1, out_dim))
        self.reset_parameters()

    def reset_parameters(self) -> None:
        """Uniform init in ``+-1/sqrt(fan_in)`` of every weight and bias."""
        for weight, bias in ((self.w1, self.b1), (self.w2, self.b2)):
            bound = 1.0 / math.sqrt(weight.shape[1])
            nn.init.uniform_(weight, -bound, bound)
            nn.init.uniform_(bias, -bound, bound)

    def forward(self, x: th.Tensor) -> th.Tensor:
        """Predictions of every member for the batch ``x`` ``(B, in_dim)``: ``(n_models, B, out_dim)``."""
        x = x.unsqueeze(0).expand(self.n_models, -1, -1)
        return th.baddbmm(self.b2, th.baddbmm(self.b1, x, self.w1).relu(), self.w2)


class DisagreementReward(RewardModule):
    """Self-supervised exploration via disagreement (Pathak et al., 2019), as in URLB (``agent/disagreement.py``).

    * An ensemble of ``n_models`` forward models ``[s, a] -> h -> state_dim`` (:class:`ForwardEnsemble`).
    * Loss: mean over members and batch of the L2 error ``||f_m(s, a) - s'||``.
    * Reward: variance over the members' predictions (unbiased, as ``torch.var``), averaged over dimensions.

    :param state_dim: state size
    :param action_dim: action size
    :param hidden_dim: hidden width of each member (1024)
    :param n_models: ensemble size (5)
    :param lr: Adam learning rate (1e-4)
    """

    parameter_ranges: ClassVar[dict[str, Range | Flag]] = {"n_models": POSITIVE_INT}

    def __init__(self, state_dim: int, action_dim: int, hidden_dim: int = 1024, n_models: int = 5, lr: float = 1e-4) -> None:
        super().__init__(state_dim, action_dim, 0, lr)
        self.ensemble = ForwardEnsemble(n_models, state_dim + action_dim, hidden_dim, state_dim)
        self.make_optimizer()

    def predictions(self, batch: ReplayBufferSamples) -> th.Tensor:
        """Next-state predictions of every member, ``(n_models, batch, state_dim)``."""
        return self.ensemble(th.cat([self.split(batch.observations)[0], batch.actions], dim=1))

    @staticmethod
    def disagreement(predictions: th.Tensor) -> th.Tensor:
        """Variance over members, mean over dimensions, ``(batch, 1)``."""
        return predictions.var(dim=0).mean(dim=1, keepdim=True)

    def _step(self, predictions: th.Tensor, batch: ReplayBufferSamples) -> dict[str, th.Tensor]:
        next_state = self.split(batch.next_observations)[0]
        loss = th.linalg.vector_norm(predictions - next_state, dim=2).mean()
        self.optimizer_step(loss)
        return {"disagreement_loss": loss.detach()}

    def update(self, batch: ReplayBufferSamples) -> dict[str, th.Tensor]:
        return self._step(self.predictions(batch), batch)

    def reward(self, batch: ReplayBufferSamples) -> th.Tensor:
        return self.disagreement(self.predictions(batch))

    def update_and_reward(self, batch: ReplayBufferSamples) -> tuple[th.Tensor, dict[str, th.Tensor]]:
        predictions = self.predictions(batch)
        reward = self.disagreement(predictions.detach())
        return reward, self._step(predictions, batch)
