"""RND's reward module: a predictor regressing a frozen random network, reward = prediction error."""

from __future__ import annotations

from typing import ClassVar

import torch as th
from stable_baselines3.common.type_aliases import ReplayBufferSamples
from torch import nn

from sb3_cic.common.arguments import NON_NEGATIVE, POSITIVE_INT, Flag, Range
from sb3_cic.policies import orthogonal_init
from sb3_cic.rewards.base import RewardModule, mlp
from sb3_cic.rewards.particle import RunningMeanStd


class RNDReward(RewardModule):
    """Random Network Distillation (Burda et al., 2019), as in URLB (``agent/rnd.py``).

    * The state is normalised by ``BatchNorm1d(affine=False)`` (batch statistics in training mode,
      the module's default) and clipped to ``+-clip``. Its integer ``num_batches_tracked`` counter is
      not kept (the running statistics use momentum 0.1, not a cumulative average), so every
      ``state_dict`` entry is floating point, as SB3's ``get_parameters``/``set_parameters`` tools assume.
    * ``predictor`` and a frozen random ``target``: ``state -> h -> h -> rep_dim``.
    * Loss: the mean over the batch of ``e = mean_j (target_j - predictor_j)^2``.
    * Reward: ``scale * e / (sqrt(running var of e) + 1e-8)``; each reward call updates the running
      statistics (:class:`~sb3_cic.rewards.particle.RunningMeanStd`) first.
    * No fused ``update_and_reward``: the reward and the update each normalise the batch, as the reference's
      ``compute_intr_reward`` and ``update_rnd`` do, so the BatchNorm running statistics move twice per update
      there as here (a fused path that normalised once left them 2.2e-2 away).

    Like every module here it scores the transition's next state ``s'`` (the reference: ``s``).

    :param state_dim: state size
    :param action_dim: action size
    :param hidden_dim: hidden width (1024)
    :param rep_dim: output size of predictor and target (512)
    :param lr: Adam learning rate (1e-4)
    :param clip: clip of the normalised state (5)
    :param scale: reward scale (1)
    """

    parameter_ranges: ClassVar[dict[str, Range | Flag]] = {"rep_dim": POSITIVE_INT, "scale": NON_NEGATIVE}

    def __init__(
        self,
        state_dim: int,
        action_dim: int,
        hidden_dim: int = 1024,
        rep_dim: int = 512,
        lr: float = 1e-4,
        clip: float = 5.0,
        scale: float = 1.0,
    ) -> None:
        super().__init__(state_dim, action_dim, 0, lr)
        self.clip, self.scale = clip, scale
        self.normalize = nn.BatchNorm1d(state_dim, affine=False)
        self.normalize.register_buffer("num_batches_tracked", None)
        self.predictor = mlp(state_dim, hidden_dim, rep_dim)
        self.target = mlp(state_dim, hidden_dim, rep_dim)
        self.apply(orthogonal_init)
        self.target.requires_grad_(False)
        self.error_rms = RunningMeanStd()
        self.make_optimizer()

    def prediction_error(self, state: th.Tensor) -> th.Tensor:
        """``mean_j (target_j - predictor_j)^2`` of the normalised, clipped state, ``(batch, 1)``."""
        x = self.normalize(state).clamp(-self.clip, self.clip)
        return (self.target(x) - self.predictor(x)).pow(2).mean(dim=1, keepdim=True)

    def update(self, batch: ReplayBufferSamples) -> dict[str, th.Tensor]:
        loss = self.prediction_error(self.split(batch.next_observations)[0]).mean()
        self.optimizer_step(loss)
        return {"rnd_loss": loss.detach(), "error_running_std": self.error_rms.var.sqrt().squeeze()}

    def reward(self, batch: ReplayBufferSamples) -> th.Tensor:
        error = self.prediction_error(self.split(batch.next_observations)[0])
        self.error_rms.update(error)
        return self.scale * error / (self.error_rms.var.sqrt() + 1e-8)
