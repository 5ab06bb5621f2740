"""The intrinsic-reward interface shared by every unsupervised method."""

from __future__ import annotations

from typing import Any, ClassVar

import torch as th
from stable_baselines3.common.type_aliases import ReplayBufferSamples
from torch import nn

from sb3_cic.common.arguments import POSITIVE, POSITIVE_INT, Flag, Range
from sb3_cic.skills import SKILL_DIM
from sb3_cic.speed import FusedAdam, LeanSequential


class RewardModule(nn.Module):
    """Networks that define an intrinsic reward, with their own optimiser.

    A subclass builds its networks in ``__init__``, then calls :meth:`make_optimizer`; it implements
    :meth:`update` (one gradient step on a batch, returns metrics) and :meth:`reward` (the intrinsic
    reward of a batch, shape ``(batch, 1)``). Observations are ``[state, skill]``; :meth:`split`
    separates them. Running statistics are registered buffers, so ``state_dict`` saves them.

    :param state_dim: size of the state part of the observation
    :param action_dim: size of the action
    :param skill_dim: size of the skill part of the observation (0: no skill)
    :param lr: learning rate of the module's Adam optimiser
    """

    optimizer: th.optim.Optimizer
    #: the range of each numeric (or bool) parameter: those most modules take here, a module's own in its class
    #: (:func:`~sb3_cic.common.arguments.ranges_of` merges them); a method's argument of a parameter is checked with it
    parameter_ranges: ClassVar[dict[str, Range | Flag]] = {"skill_dim": SKILL_DIM, "hidden_dim": POSITIVE_INT, "lr": POSITIVE}

    def __init__(self, state_dim: int, action_dim: int, skill_dim: int = 0, lr: float = 1e-4) -> None:
        super().__init__()
        self.state_dim = state_dim
        self.action_dim = action_dim
        self.skill_dim = skill_dim
        self.lr = lr

    def make_optimizer(self, params: Any = None, lr: float | None = None) -> None:
        """Create ``self.optimizer`` (:class:`~sb3_cic.speed.FusedAdam`) over ``params`` (default: all trainable ones)."""
        params = [p for p in self.parameters() if p.requires_grad] if params is None else params
        self.optimizer = FusedAdam(params, lr=self.lr if lr is None else lr)

    def split(self, obs: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        """Split observations into ``(state, skill)``."""
        return obs[:, : self.state_dim], obs[:, self.state_dim :]

    def update(self, batch: ReplayBufferSamples) -> dict[str, th.Tensor]:
        """Take one gradient step on ``batch``; return detached scalar metrics."""
        raise NotImplementedError

    def reward(self, batch: ReplayBufferSamples) -> th.Tensor:
        """Intrinsic reward of each transition of ``batch``, shape ``(batch, 1)``."""
        raise NotImplementedError

    def update_and_reward(self, batch: ReplayBufferSamples) -> tuple[th.Tensor, dict[str, th.Tensor]]:
        """Relabel a sampled batch: its intrinsic reward (networks as sampled), then one update.

        Subclasses may fuse the two to share forward passes; the result must be the same (networks, running
        statistics and queues included). SMM's fused path alone differs draw for draw: its reward and loss share
        one sample of the VAE's noise, as the reference's do.
        """
        with th.no_grad():
            reward = self.reward(batch)
        metrics = self.update(batch)
        return reward, metrics

    def optimizer_step(self, loss: th.Tensor) -> None:
        """Back-propagate ``loss`` and step the module's optimiser."""
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()


def mlp(in_dim: int, hidden_dim: int, out_dim: int, n_hidden: int = 2) -> LeanSequential:
    """ReLU MLP with ``n_hidden`` hidden layers of width ``hidden_dim``."""
    layers: list[nn.Module] = []
    dim = in_dim
    for _ in range(n_hidden):
        layers += [nn.Linear(dim, hidden_dim), nn.ReLU(inplace=True)]
        dim = hidden_dim
    layers.append(nn.Linear(dim, out_dim))
    return LeanSequential(*layers)
