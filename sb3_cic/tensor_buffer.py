"""Replay buffer held in torch tensors on the model's device.

:class:`TensorReplayBuffer` is :class:`~sb3_cic.buffers.URLBReplayBuffer` (SB3's n-step buffer with
skill-consistent next observations) with its storage and its sampling on the model's device: on a GPU,
a sampled batch is gathered there, with no host-to-device copy of the batch and no numpy in the update.
"""

from __future__ import annotations

import hashlib
import warnings
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.type_aliases import ReplayBufferSamples
from stable_baselines3.common.utils import get_device
from stable_baselines3.common.vec_env import VecNormalize

from sb3_cic.buffers import URLBReplayBuffer

try:
    import psutil
except ImportError:  # pragma: no cover
    psutil = None

#: the stored tensors, each of shape ``(buffer_size, n_envs, ...)``
STORAGE = ("observations", "next_observations", "actions", "rewards", "dones", "timeouts")


class TensorReplayBuffer(URLBReplayBuffer):
    """:class:`~sb3_cic.buffers.URLBReplayBuffer` whose storage is torch tensors on ``device``.

    * The same batches: for the same indices, :meth:`_get_samples` returns what
      :class:`~sb3_cic.buffers.URLBReplayBuffer` returns, bit for bit (n-step reward sum stopping at an
      episode end, bootstrap discount ``gamma ** k``, next observation ``s_{t+k}``, time-limit truncations
      that bootstrap, no window read across the write position, the observation's skill in the next
      observation). The n-step sum adds the steps in numpy's order, which is sequential for rows of up to
      7 steps; for longer windows numpy adds in blocks and the two agree to float32 rounding.
    * :meth:`add` takes the numpy arrays of SB3's off-policy loop and copies each into its tensor: off the
      CPU, a cast on the host as numpy's assignment casts and one host-to-device copy per array; on the CPU,
      numpy's assignment into a numpy view of the tensor (as fast as the numpy buffer's ``add``).
    * :meth:`sample` draws the indices (and the envs' indices, with several envs) with a
      :class:`torch.Generator` on the device, seeded at construction from numpy's global generator (so SB3's
      ``set_random_seed`` makes it reproducible). It does not apply the ``relabel`` hook: the algorithm does.
      VecNormalize is not supported.
    * Pickling (SB3's ``save_replay_buffer``, checkpoints) stores the tensors as numpy arrays and the
      generator's state; unpickling puts them back on the device they were saved from (on the CPU where that
      device is absent) with the generator's state, so a resumed run samples the indices of the uninterrupted
      one. Assigning :attr:`device`, as SB3's ``load_replay_buffer`` does, moves the tensors there (the
      generator keeps its state on a device of the same type, and is seeded from it on another type).
    * Memory (float32, see :meth:`memory_nbytes`): 2,000,000 transitions of a quadruped skill buffer (state
      78 + skill 64, action 12) take 2,392,000,000 bytes, of walker (state 24 + skill 64, action 6)
      1,480,000,000 bytes: either fits an 80 GB card many times over.

    :param buffer_size: capacity
    :param observation_space: observation space (a flat Box)
    :param action_space: action space
    :param device: torch device of the storage
    :param n_envs: number of parallel environments
    :param optimize_memory_usage: not supported (as in SB3's n-step buffer)
    :param handle_timeout_termination: time-limit ends are truncations that bootstrap
    :param skill_dim: number of trailing observation entries that hold the skill (0: no skill)
    :param n_steps: n of the n-step return
    :param gamma: discount factor
    """

    observations: th.Tensor  # type: ignore[assignment]
    next_observations: th.Tensor  # type: ignore[assignment]
    actions: th.Tensor  # type: ignore[assignment]
    rewards: th.Tensor  # type: ignore[assignment]
    dones: th.Tensor  # type: ignore[assignment]
    timeouts: th.Tensor  # type: ignore[assignment]

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        device: th.device | str = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
        skill_dim: int = 0,
        n_steps: int = 3,
        gamma: float = 0.99,
    ) -> None:
        # the parent with one row per env: its checks, attributes and dtypes, and no large numpy arrays
        super().__init__(
            n_envs, observation_space, action_space, device, n_envs, optimize_memory_usage, handle_timeout_termination,
            skill_dim=skill_dim, n_steps=n_steps, gamma=gamma,
        )
        self.buffer_size = max(buffer_size // n_envs, 1)
        rows = {name: getattr(self, name) for name in STORAGE}
        #: numpy dtype of each stored tensor (what :meth:`add` casts to on the host)
        self._numpy_dtypes = {name: row.dtype for name, row in rows.items()}
        _warn_if_too_large(sum(self.buffer_size * row.nbytes for row in rows.values()), self.device)
        for name, row in rows.items():
            shape = (self.buffer_size, *row.shape[1:])
            setattr(self, name, th.zeros(shape, dtype=th.from_numpy(row).dtype, device=self.device))
        self._generator = th.Generator(device=self.observations.device)
        self._generator.manual_seed(int(np.random.randint(2**31)))
        self._constants: tuple[Any, ...] | None = None
        self._bind_host_views()

    # the device ---------------------------------------------------------------------------------
    @property
    def device(self) -> th.device:
        """Where the tensors are; assigning it moves them (and the generator)."""
        return self._device

    @device.setter
    def device(self, device: th.device | str) -> None:
        self._device = get_device(device)
        if not isinstance(self.__dict__.get(STORAGE[-1]), th.Tensor):
            return  # under construction
        for name in STORAGE:
            setattr(self, name, getattr(self, name).to(self._device))
        target = self.observations.device
        if self._generator.device != target:
            self._generator = _generator_on(target, self._generator.get_state(), self._generator.device)
        self._bind_host_views()

    def _bind_host_views(self) -> None:
        """On the CPU, numpy views of the tensors, which :meth:`add` writes through (numpy's assignment is
        several times faster than torch's for one row); none on another device."""
        on_cpu = self.observations.device.type == "cpu"
        self._host_views: dict[str, np.ndarray] | None = (
            {name: getattr(self, name).numpy() for name in STORAGE} if on_cpu else None
        )

    # storing ------------------------------------------------------------------------------------
    def add(
        self,
        obs: np.ndarray,
        next_obs: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        done: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        """Store one step of the ``n_envs`` environments (the arguments of SB3's ``ReplayBuffer.add``).

        :param obs: observations
        :param next_obs: next observations (the final observation at an episode end)
        :param action: actions
        :param reward: rewards
        :param done: episode ends (terminations and truncations)
        :param infos: the envs' infos (``"TimeLimit.truncated"``: a time-limit end)
        """
        if isinstance(self.observation_space, spaces.Discrete):
            obs = obs.reshape((self.n_envs, *self.obs_shape))
            next_obs = next_obs.reshape((self.n_envs, *self.obs_shape))
        self._write("observations", obs)
        self._write("next_observations", next_obs)
        self._write("actions", action.reshape((self.n_envs, self.action_dim)))
        self._write("rewards", reward)
        self._write("dones", done)
        if self.handle_timeout_termination:
            self._write("timeouts", [info.get("TimeLimit.truncated", False) for info in infos])
        self.pos += 1
        if self.pos == self.buffer_size:
            self.full = True
            self.pos = 0

    def _write(self, name: str, value: Any) -> None:
        """Copy ``value`` into row ``pos`` of the tensor ``name``: cast on the host as numpy's assignment casts,
        then (off the CPU) one copy to the device."""
        if self._host_views is not None:
            self._host_views[name][self.pos] = value
        else:
            getattr(self, name)[self.pos].copy_(th.from_numpy(np.array(value, dtype=self._numpy_dtypes[name])))

    # sampling -----------------------------------------------------------------------------------
    def sample(self, batch_size: int, env: VecNormalize | None = None) -> ReplayBufferSamples:
        """A batch of ``batch_size`` stored transitions drawn uniformly with the buffer's generator.

        The ``relabel`` hook is not applied.

        :param batch_size: number of transitions
        :param env: VecNormalize env (not supported: must be None)
        """
        if self.size() == 0:
            raise ValueError("cannot sample from an empty replay buffer")
        batch_inds = th.randint(0, self.size(), (batch_size,), generator=self._generator, device=self.observations.device)
        return self._get_samples(batch_inds, env)

    def _get_samples(
        self,
        batch_inds: np.ndarray | th.Tensor,
        env: VecNormalize | None = None,
        env_indices: np.ndarray | th.Tensor | None = None,
    ) -> ReplayBufferSamples:
        """The n-step batch of the transitions at ``batch_inds``, as SB3's ``NStepReplayBuffer`` computes it.

        :param batch_inds: indices of the transitions (numpy or torch)
        :param env: VecNormalize env (not supported: must be None)
        :param env_indices: the env of each transition (default: drawn with the buffer's generator)
        """
        if env is not None:
            raise NotImplementedError(
                "TensorReplayBuffer does not normalise with VecNormalize: use URLBReplayBuffer (the default)"
            )
        device = self.observations.device
        inds = th.as_tensor(batch_inds, device=device).long()
        envs = self._env_indices(inds) if env_indices is None else th.as_tensor(env_indices, device=device).long()
        steps, weights, bootstrap = self._nstep_constants()
        window = (inds[:, None] + steps) % self.buffer_size  # [batch, n_steps], wrapping around the storage
        rewards, dones, timeouts = (self._gather(name, window, envs[:, None]) for name in ("rewards", "dones", "timeouts"))
        # as SB3: the newest transition (pos - 1) counts as truncated unless done, so no window reads past it
        newest = window == (self.pos - 1) % self.buffer_size
        timeouts = th.where(newest, ((timeouts != 0) | (dones == 0)).to(timeouts.dtype), timeouts)
        ends = (dones != 0) | (timeouts != 0)
        last = th.where(ends.any(dim=1), ends.to(th.uint8).argmax(dim=1), self.n_steps - 1)  # the window's last step
        discounted = rewards * weights * (steps <= last[:, None])
        returns = discounted[:, :1]
        for k in range(1, self.n_steps):  # numpy's order of the sum
            returns = returns + discounted[:, k : k + 1]
        end = last[:, None]
        observations = self._gather("observations", inds, envs)
        next_observations = self._gather("next_observations", (inds + last) % self.buffer_size, envs)
        if self.skill_dim > 0:
            next_observations[:, -self.skill_dim :] = observations[:, -self.skill_dim :]
        return ReplayBufferSamples(
            observations=observations,
            actions=self._gather("actions", inds, envs),
            next_observations=next_observations,
            dones=dones.gather(1, end) * (1.0 - timeouts.gather(1, end)),
            rewards=returns,
            discounts=bootstrap[end + 1],
        )

    def _gather(self, name: str, rows: th.Tensor, envs: th.Tensor) -> th.Tensor:
        """The entries ``[rows, envs]`` (broadcast together) of the tensor ``name``, with one ``index_select``."""
        stored = getattr(self, name)
        flat = (rows * self.n_envs + envs).reshape(-1)
        entries = stored.view(-1, *stored.shape[2:]).index_select(0, flat)
        return entries.view(*th.broadcast_shapes(rows.shape, envs.shape), *stored.shape[2:])

    def _env_indices(self, inds: th.Tensor) -> th.Tensor:
        if self.n_envs == 1:
            return th.zeros_like(inds)
        return th.randint(0, self.n_envs, inds.shape, generator=self._generator, device=inds.device)

    def _nstep_constants(self) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        """Step offsets ``[1, n]``, reward weights ``gamma ** j`` ``[1, n]`` and bootstrap discounts ``gamma ** k``
        by ``k`` in ``0..n``: computed with numpy as SB3 computes them, kept on the device."""
        key = (self.n_steps, self.gamma, self.observations.device)
        if self._constants is None or self._constants[0] != key:
            weights = self.gamma ** np.arange(self.n_steps, dtype=np.float32).reshape(1, -1)
            bootstrap = self.gamma ** np.arange(self.n_steps + 1).astype(np.float32)
            tensors = (np.arange(self.n_steps).reshape(1, -1), weights, bootstrap)
            self._constants = (key, *(th.as_tensor(x, device=key[2]) for x in tensors))
        return self._constants[1:]  # type: ignore[return-value]

    # memory -------------------------------------------------------------------------------------
    def transition_nbytes(self) -> int:
        """Bytes stored per transition (all tensors, one environment)."""
        nbytes = sum(t.numel() * t.element_size() for t in (getattr(self, name) for name in STORAGE))
        return int(nbytes // (self.buffer_size * self.n_envs))

    @staticmethod
    def memory_nbytes(n_transitions: int, obs_dim: int, action_dim: int) -> int:
        """Bytes of a buffer of ``n_transitions`` (all envs together) of flat float32 observations and actions,
        without allocating it: observation, next observation, action, reward, done, time-limit flag.

        :param n_transitions: capacity
        :param obs_dim: observation size (state + skill)
        :param action_dim: action size
        """
        return n_transitions * 4 * (2 * obs_dim + action_dim + 3)

    # pickling -----------------------------------------------------------------------------------
    def __getstate__(self) -> dict[str, Any]:
        state = super().__getstate__()  # without the relabel hook
        for name in STORAGE:
            state[name] = getattr(self, name).cpu().numpy()
        state["_generator"] = (self._generator.device, self._generator.get_state())
        state["_constants"] = state["_host_views"] = None
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        state = dict(state)
        generator_device, generator_state = state.pop("_generator")
        self.__dict__.update(state)
        self._device = get_device(self._device)  # the saved device, or the CPU where it is absent
        for name in STORAGE:
            setattr(self, name, th.from_numpy(state[name]).to(self._device))
        self._generator = _generator_on(self.observations.device, generator_state, generator_device)
        self._bind_host_views()


def _generator_on(device: th.device, state: th.Tensor, state_device: th.device) -> th.Generator:
    """A generator on ``device`` that continues ``state``, the state of a generator on ``state_device``:
    the same stream on a device of the same type; else a stream seeded from the state (deterministic)."""
    generator = th.Generator(device=device)
    if device.type == state_device.type:
        generator.set_state(state)
    else:
        digest = hashlib.sha256(state.cpu().numpy().tobytes()).digest()
        generator.manual_seed(int.from_bytes(digest[:8], "little") >> 1)
    return generator


def _warn_if_too_large(nbytes: int, device: th.device) -> None:
    """Warn (as SB3 does) when the storage exceeds the memory available on ``device``."""
    if device.type == "cuda":
        available = th.cuda.mem_get_info(device)[0]
    elif device.type == "cpu" and psutil is not None:
        available = psutil.virtual_memory().available
    else:
        return
    if nbytes > available:
        warnings.warn(
            f"The replay buffer's tensors need {nbytes / 1e9:.2f} GB on {device}, more than the {available / 1e9:.2f} GB "
            "available",
            stacklevel=3,
        )
