"""ICM's reward module: forward and inverse dynamics models, curiosity = forward prediction error."""

from __future__ import annotations

from typing import ClassVar

import torch as th
from stable_baselines3.common.type_aliases import ReplayBufferSamples
from torch import nn

from sb3_cic.common.arguments import NON_NEGATIVE, Flag, Range
from sb3_cic.policies import orthogonal_init
from sb3_cic.rewards.base import RewardModule, mlp
from sb3_cic.speed import LeanSequential


class ICMReward(RewardModule):
    """Intrinsic Curiosity Module (Pathak et al., 2017), as in URLB (``agent/icm.py``), on states.

    * ``forward_net``: ``[s, a] -> h -> state_dim``; ``inverse_net``: ``[s, s'] -> h -> action_dim -> tanh``.
    * Loss: ``mean ||f(s, a) - s'|| + mean ||g(s, s') - a||`` (per-sample L2 norms).
    * Reward: ``log(1 + scale * ||f(s, a) - s'||)``.

    :param state_dim: state size
    :param action_dim: action size
    :param hidden_dim: hidden width of both models (1024)
    :param lr: Adam learning rate (1e-4)
    :param scale: factor of the forward error inside the log (1)
    """

    parameter_ranges: ClassVar[dict[str, Range | Flag]] = {"scale": NON_NEGATIVE}

    def __init__(self, state_dim: int, action_dim: int, hidden_dim: int = 1024, lr: float = 1e-4, scale: float = 1.0) -> None:
        super().__init__(state_dim, action_dim, 0, lr)
        self.scale = scale
        self.forward_net = mlp(state_dim + action_dim, hidden_dim, state_dim, n_hidden=1)
        self.inverse_net = LeanSequential(*mlp(2 * state_dim, hidden_dim, action_dim, n_hidden=1), nn.Tanh())
        self.apply(orthogonal_init)
        self.make_optimizer()

    def errors(self, batch: ReplayBufferSamples) -> tuple[th.Tensor, th.Tensor]:
        """Forward and inverse L2 prediction errors, each ``(batch, 1)``."""
        state, next_state = self.split(batch.observations)[0], self.split(batch.next_observations)[0]
        next_hat = self.forward_net(th.cat([state, batch.actions], dim=1))
        action_hat = self.inverse_net(th.cat([state, next_state], dim=1))
        forward_error = th.linalg.vector_norm(next_hat - next_state, dim=1, keepdim=True)
        inverse_error = th.linalg.vector_norm(action_hat - batch.actions, dim=1, keepdim=True)
        return forward_error, inverse_error

    def _step(self, forward_error: th.Tensor, inverse_error: th.Tensor) -> dict[str, th.Tensor]:
        loss = forward_error.mean() + inverse_error.mean()
        self.optimizer_step(loss)
        return {
            "icm_loss": loss.detach(),
            "forward_error": forward_error.detach().mean(),
            "inverse_error": inverse_error.detach().mean(),
        }

    def update(self, batch: ReplayBufferSamples) -> dict[str, th.Tensor]:
        return self._step(*self.errors(batch))

    def reward(self, batch: ReplayBufferSamples) -> th.Tensor:
        return th.log1p(self.scale * self.errors(batch)[0])

    def update_and_reward(self, batch: ReplayBufferSamples) -> tuple[th.Tensor, dict[str, th.Tensor]]:
        forward_error, inverse_error = self.errors(batch)
        reward = th.log1p(self.scale * forward_error.detach())
        return reward, self._step(forward_error, inverse_error)
