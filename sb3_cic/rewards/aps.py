"""APS's reward module: successor features phi, particle entropy plus the successor-feature reward."""

from __future__ import annotations

from typing import ClassVar

import torch as th
import torch.nn.functional as F
from stable_baselines3.common.type_aliases import ReplayBufferSamples

from sb3_cic.common.arguments import FLAG, NON_NEGATIVE, POSITIVE_INT, Flag, Range
from sb3_cic.policies import orthogonal_init
from sb3_cic.rewards.base import RewardModule, mlp
from sb3_cic.rewards.particle import ParticleEntropy


class APSReward(RewardModule):
    """Active Pre-training with Successor features (Liu & Abbeel, 2021), as in URLB (``agent/aps.py``).

    * ``phi_net``: ``state -> h -> h -> skill_dim`` (10); ``phi = normalize(phi_net)``.
    * Loss: ``-mean(w . phi(s'))``, ``w`` the task vector (the skill, a unit vector).
    * Reward: particle entropy of ``phi_net(s')`` (k = 12, averaged, running mean, clip 1e-4) plus
      ``w . phi(s')``. As in the reference, the entropy term uses the features before normalisation.

    :param state_dim: state size
    :param action_dim: action size
    :param skill_dim: size of phi and of the task vector (10)
    :param hidden_dim: hidden width (1024)
    :param lr: Adam learning rate (1e-4)
    :param knn_k: neighbours of the entropy estimator (12)
    :param knn_clip: clip of the entropy estimator (1e-4)
    :param knn_avg: average the k distances
    :param knn_rms: divide by the running mean of the distances
    """

    parameter_ranges: ClassVar[dict[str, Range | Flag]] = {"knn_k": POSITIVE_INT, "knn_clip": NON_NEGATIVE, "knn_avg": FLAG, "knn_rms": FLAG}

    def __init__(
        self,
        state_dim: int,
        action_dim: int,
        skill_dim: int = 10,
        hidden_dim: int = 1024,
        lr: float = 1e-4,
        knn_k: int = 12,
        knn_clip: float = 1e-4,
        knn_avg: bool = True,
        knn_rms: bool = True,
    ) -> None:
        super().__init__(state_dim, action_dim, skill_dim, lr)
        self.phi_net = mlp(state_dim, hidden_dim, skill_dim)
        self.apply(orthogonal_init)
        self.particle = ParticleEntropy(k=knn_k, avg=knn_avg, rms=knn_rms, clip=knn_clip)
        self.make_optimizer()

    def phi(self, state: th.Tensor) -> th.Tensor:
        """Normalised successor features ``phi(state)``, ``(batch, skill_dim)``."""
        return F.normalize(self.phi_net(state), dim=1)

    def _features(self, batch: ReplayBufferSamples) -> tuple[th.Tensor, th.Tensor]:
        next_state, task = self.split(batch.next_observations)
        return self.phi_net(next_state), task

    def _reward(self, features: th.Tensor, task: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        entropy = self.particle(features)
        sf = (F.normalize(features, dim=1) * task).sum(dim=1, keepdim=True)
        return entropy, sf

    def _step(self, features: th.Tensor, task: th.Tensor) -> dict[str, th.Tensor]:
        loss = -(F.normalize(features, dim=1) * task).sum(dim=1).mean()
        self.optimizer_step(loss)
        return {"aps_loss": loss.detach()}

    def update(self, batch: ReplayBufferSamples) -> dict[str, th.Tensor]:
        return self._step(*self._features(batch))

    def reward(self, batch: ReplayBufferSamples) -> th.Tensor:
        return sum(self._reward(*self._features(batch)))  # type: ignore[return-value]

    def update_and_reward(self, batch: ReplayBufferSamples) -> tuple[th.Tensor, dict[str, th.Tensor]]:
        features, task = self._features(batch)
        with th.no_grad():
            entropy, sf = self._reward(features.detach(), task)
        metrics = self._step(features, task)
        metrics.update(entropy_reward=entropy.mean(), sf_reward=sf.mean())
        return entropy + sf, metrics
