"""The Fixed baseline's reward module: a constant intrinsic reward, no networks."""

from __future__ import annotations

from typing import ClassVar

import torch as th
from stable_baselines3.common.type_aliases import ReplayBufferSamples

from sb3_cic.common.arguments import FINITE, Flag, Range
from sb3_cic.rewards.base import RewardModule


class ConstantReward(RewardModule):
    """A constant reward at every step: the CIC paper's *Fixed* baseline (Appendix I).

    With a reward of 1 per step and no other signal, an agent gains by making its episodes last: in an env
    that ends episodes early (Gym's locomotion when the agent falls) it learns to stay healthy; in one with
    fixed-length episodes (DMC) every policy earns the same return.

    * Reward: ``value`` for every sampled transition. As every intrinsic reward here (URLB's convention), it is the
      reward of a whole n-step transition ``(s_t, s_{t+k})``, not a sum over its k steps: staying alive forever is
      worth ``value / (1 - gamma^n)`` instead of ``value / (1 - gamma)``, and any longer episode still earns more.
    * No networks and no loss: :meth:`update` returns no metrics. Its optimiser holds one empty parameter group,
      so that the model saves and loads it like every module's.

    :param state_dim: state size
    :param action_dim: action size
    :param value: the reward of every step (1)
    """

    parameter_ranges: ClassVar[dict[str, Range | Flag]] = {"value": FINITE}

    def __init__(self, state_dim: int, action_dim: int, value: float = 1.0) -> None:
        super().__init__(state_dim, action_dim, 0)
        self.value = float(value)
        self.make_optimizer([{"params": []}])

    def update(self, batch: ReplayBufferSamples) -> dict[str, th.Tensor]:
        return {}

    def reward(self, batch: ReplayBufferSamples) -> th.Tensor:
        return th.full_like(batch.rewards, self.value)
