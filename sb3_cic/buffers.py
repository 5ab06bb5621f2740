"""Replay buffer of the URLB agents: SB3's n-step buffer, skill-consistent, with a relabel hook."""

from __future__ import annotations

from typing import Any, Callable

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import NStepReplayBuffer
from stable_baselines3.common.type_aliases import ReplayBufferSamples
from stable_baselines3.common.vec_env import VecNormalize

#: the relabel hook: a sampled batch -> the batch with its intrinsic reward, and the reward module's metrics
Relabel = Callable[[ReplayBufferSamples], tuple[ReplayBufferSamples, dict[str, th.Tensor]]]


class URLBReplayBuffer(NStepReplayBuffer):
    """:class:`~stable_baselines3.common.buffers.NStepReplayBuffer` for observations ``[state, skill]``.

    * n-step returns as SB3 computes them: discounted reward sum over ``n_steps`` (stopping at an
      episode end), bootstrap discount ``gamma ** k``, next observation ``s_{t+k}``; time-limit
      ends are truncations and bootstrap.
    * The next observation of a sampled transition carries the skill of its observation, even when
      the skill was resampled within the n steps.
    * ``relabel``: a hook installed by the algorithm in pre-training, a tensor function that the update step
      applies to each sampled batch (:meth:`sample` does not): it returns the batch with the intrinsic reward in
      place of the stored reward, and its metrics. It is never pickled.
    * Observations are stored as float32 whatever the Box's dtype (float64 for most Gymnasium MuJoCo
      envs): the one cast of the training path (SB3 casts each batch in the networks), and half the memory.

    :param buffer_size: capacity
    :param observation_space: observation space (a flat Box)
    :param action_space: action space
    :param args: see :class:`~stable_baselines3.common.buffers.NStepReplayBuffer`
    :param skill_dim: number of trailing observation entries that hold the skill (0: no skill)
    :param n_steps: n of the n-step return
    :param gamma: discount factor
    :param kwargs: see :class:`~stable_baselines3.common.buffers.NStepReplayBuffer`
    """

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        *args: Any,
        skill_dim: int = 0,
        n_steps: int = 3,
        gamma: float = 0.99,
        **kwargs: Any,
    ) -> None:
        if isinstance(observation_space, spaces.Box) and observation_space.dtype != np.float32:
            observation_space = spaces.Box(-np.inf, np.inf, observation_space.shape, np.float32)
        super().__init__(buffer_size, observation_space, action_space, *args, n_steps=n_steps, gamma=gamma, **kwargs)
        self.skill_dim = skill_dim
        self.relabel: Relabel | None = None

    def _get_samples(self, batch_inds: np.ndarray, env: VecNormalize | None = None) -> ReplayBufferSamples:
        samples = super()._get_samples(batch_inds, env)
        if self.skill_dim > 0:
            samples.next_observations[:, -self.skill_dim :] = samples.observations[:, -self.skill_dim :]
        return samples

    def transition_nbytes(self) -> int:
        """Bytes stored per transition (all arrays, one environment)."""
        arrays = (self.observations, self.next_observations, self.actions, self.rewards, self.dones, self.timeouts)
        return int(sum(a.nbytes for a in arrays) // (self.buffer_size * self.n_envs))

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["relabel"] = None  # holds the algorithm and its networks
        return state
