"""DIAYN's reward module: a skill discriminator, reward = log q(z | s') - log p(z)."""

from __future__ import annotations

from typing import ClassVar

import math

import torch as th
import torch.nn.functional as F
from stable_baselines3.common.type_aliases import ReplayBufferSamples

from sb3_cic.common.arguments import NON_NEGATIVE, Flag, Range
from sb3_cic.policies import orthogonal_init
from sb3_cic.rewards.base import RewardModule, mlp


class DIAYNReward(RewardModule):
    """Diversity Is All You Need (Eysenbach et al., 2019), as in URLB (``agent/diayn.py``).

    * ``discriminator``: ``s' -> h -> h -> skill_dim`` logits over the one-hot skills.
    * Loss: cross-entropy with the skill's index.
    * Reward: ``scale * (log_softmax(q(s'))[z] + log skill_dim)``.

    :param state_dim: state size
    :param action_dim: action size
    :param skill_dim: number of one-hot skills (16)
    :param hidden_dim: hidden width (1024)
    :param lr: Adam learning rate (1e-4)
    :param scale: reward scale (1)
    """

    parameter_ranges: ClassVar[dict[str, Range | Flag]] = {"scale": NON_NEGATIVE}

    def __init__(
        self, state_dim: int, action_dim: int, skill_dim: int = 16, hidden_dim: int = 1024, lr: float = 1e-4, scale: float = 1.0
    ) -> None:
        super().__init__(state_dim, action_dim, skill_dim, lr)
        self.scale = scale
        self.discriminator = mlp(state_dim, hidden_dim, skill_dim)
        self.apply(orthogonal_init)
        self.make_optimizer()

    def log_q(self, batch: ReplayBufferSamples) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        """``log q(z|s')`` of the true skill ``(batch, 1)``, all log-probabilities and the skill indices."""
        next_state, skill = self.split(batch.next_observations)
        index = skill.argmax(dim=1, keepdim=True)
        log_probs = F.log_softmax(self.discriminator(next_state), dim=1)
        return log_probs.gather(1, index), log_probs, index

    def _reward(self, log_q: th.Tensor) -> th.Tensor:
        return self.scale * (log_q + math.log(self.skill_dim))

    def _step(self, log_q: th.Tensor, log_probs: th.Tensor, index: th.Tensor) -> dict[str, th.Tensor]:
        loss = -log_q.mean()
        self.optimizer_step(loss)
        accuracy = (log_probs.detach().argmax(dim=1, keepdim=True) == index).float().mean()
        return {"diayn_loss": loss.detach(), "disc_accuracy": accuracy}

    def update(self, batch: ReplayBufferSamples) -> dict[str, th.Tensor]:
        return self._step(*self.log_q(batch))

    def reward(self, batch: ReplayBufferSamples) -> th.Tensor:
        return self._reward(self.log_q(batch)[0])

    def update_and_reward(self, batch: ReplayBufferSamples) -> tuple[th.Tensor, dict[str, th.Tensor]]:
        log_q, log_probs, index = self.log_q(batch)
        reward = self._reward(log_q.detach())
        return reward, self._step(log_q, log_probs, index)
