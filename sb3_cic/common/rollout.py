"""The acting loop of the URLB agents: SB3's ``collect_rollouts`` with less work per env step.

With ``speed_options.lean_loop`` (the default), :class:`LeanRolloutMixin` runs SB3's loop step for step (the
same callbacks at the same points, the same statistics and return values) and computes three parts of a step
with less work around what they compute: the action, the env step and the stored transition. Each part falls
back to SB3's own form where it does not apply; the whole loop falls back to SB3's ``collect_rollouts`` for
several envs, VecNormalize or gSDE (and with ``lean_loop`` off).
"""

from __future__ import annotations

import math
import operator
from copy import deepcopy
from typing import Any, Callable

import numpy as np
import torch as th
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback, ConvertCallback
from stable_baselines3.common.noise import ActionNoise, NormalActionNoise
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import RolloutReturn, TrainFreq, TrainFrequencyUnit
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv
from torch import nn
from torch.nn.modules import module as torch_module

from sb3_cic.common.env_util import check_finite_step
from sb3_cic.common.fast_update import GraphedActor
from sb3_cic.policies import URLBActor
from sb3_cic.speed import LeanSequential, speed_options

Sampler = Callable[[int, Any], tuple[np.ndarray, np.ndarray]]
Stepper = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]]
Storer = Callable[..., None]


class LeanRolloutMixin:
    """SB3's ``collect_rollouts`` at less cost per env step, for :class:`~sb3_cic.ddpg.URLBDDPG`.

    Mixed in before SB3's algorithm (``class URLBDDPG(MethodMixin, SkillMixin, LeanRolloutMixin, DDPG)``), whose
    ``_sample_action`` and ``_store_transition`` its lean parts reproduce (a subclass's own: those are called). With
    ``speed_options.lean_loop`` and one env, no VecNormalize and no gSDE, :meth:`collect_rollouts` is SB3's
    loop: the same actions, env steps, callbacks (``update_locals`` gets the names of SB3's loop: ``actions``,
    ``buffer_actions``, ``new_obs``, ``rewards``, ``dones``, ``infos``...; a few more), ``_update_info_buffer``,
    stored transitions, progress, ``_on_step``, action-noise resets, episode counts, log dumps and return
    values. Less work per step:

    * the action, where URLBDDPG's ``_sample_action`` acts with :func:`~sb3_cic.speed.lean_action`: the actor's
      layers as plain function calls (:class:`ActorCall`) on the pending observation (shared with torch on the
      CPU; with ``compile_update`` on CUDA, the actor replayed as one CUDA graph,
      :class:`~sb3_cic.common.fast_update.GraphedActor`), SB3's rescaling round trip on the action bounds read once (:func:`unit_rescale` on [-1, 1] bounds)
      and SB3's gaussian noise drawn with scalar arguments (:func:`normal_noise`); a model or policy class with
      its own ``_sample_action``, ``scale_action`` or ``unscale_action``: those are called;
    * the env step, on a plain ``DummyVecEnv`` of one env: that env's ``step`` (its wrappers, Monitor included)
      and ``reset`` called as ``DummyVecEnv.step_wait`` calls them, returning what it returns (fresh arrays,
      the ``TimeLimit.truncated`` and ``terminal_observation`` infos, the infos copied, by :func:`copy_info`)
      without its scratch buffers; any other VecEnv, or one whose ``step`` was replaced: its ``step``;
    * the transition, for URLBDDPG's ``_store_transition``: the finiteness check
      (:func:`~sb3_cic.common.env_util.check_finite_step` runs, and raises, only when a cheaper test fails)
      and SB3's ``ReplayBuffer.add`` as the stores it makes (a buffer with its own ``add``: ``add``);
    * the callback of ``learn(callback=None)`` (SB3's ``ConvertCallback`` of None, which reads nothing and
      returns True) is not called at each step;
    * the policy is switched to evaluation mode at the start of a rollout only when it is not in it
      (``policy.training``), as URLBDDPG's ``train`` under ``lean_acting`` leaves the training mode alone while
      it is set.
    """

    # what the loop reads of SB3's OffPolicyAlgorithm and of URLBDDPG
    policy: Any
    num_timesteps: int
    _episode_num: int
    _total_timesteps: int
    _last_obs: Any
    _last_original_obs: Any
    _vec_normalize_env: Any
    use_sde: bool
    warmup_with_policy: bool
    compile_update: Any

    def collect_rollouts(  # type: ignore[override]
        self,
        env: VecEnv,
        callback: BaseCallback,
        train_freq: TrainFreq,
        replay_buffer: ReplayBuffer,
        action_noise: ActionNoise | None = None,
        learning_starts: int = 0,
        log_interval: int | None = None,
    ) -> RolloutReturn:
        """SB3's ``collect_rollouts``: the same arguments, steps and return value (see the class docstring)."""
        if not speed_options.lean_loop or env.num_envs != 1 or self.use_sde or self._vec_normalize_env is not None:
            return super().collect_rollouts(  # type: ignore[misc]
                env, callback, train_freq, replay_buffer, action_noise, learning_starts, log_interval
            )
        # Switch to eval mode (this affects batch norm / dropout), unless the policy is in it
        if self.policy.training:
            self.policy.set_training_mode(False)

        num_collected_steps, num_collected_episodes = 0, 0

        assert isinstance(env, VecEnv), "You must pass a VecEnv"
        assert train_freq.frequency > 0, "Should at least collect one step or episode."

        sample_action, step_env, store_transition = self._lean_parts(env, replay_buffer, action_noise)
        by_steps = train_freq.unit == TrainFrequencyUnit.STEP
        calls_back = not (type(callback) is ConvertCallback and callback.callback is None)

        callback.on_rollout_start()
        continue_training = True
        while (num_collected_steps if by_steps else num_collected_episodes) < train_freq.frequency:
            # Select action randomly or according to policy
            actions, buffer_actions = sample_action(learning_starts, action_noise)

            # Rescale and perform action
            new_obs, rewards, dones, infos = step_env(actions)

            self.num_timesteps += 1
            num_collected_steps += 1

            # Give access to local variables (SB3's stand-in for no callback reads none: it is not called)
            if calls_back:
                callback.update_locals(locals())
                # Only stop training if return value is False, not when it is None.
                if not callback.on_step():
                    return RolloutReturn(num_collected_steps, num_collected_episodes, continue_training=False)

            # Retrieve reward and episode length if using Monitor wrapper
            self._update_info_buffer(infos, dones)  # type: ignore[attr-defined]

            # Store data in replay buffer (normalized action and unnormalized observation)
            store_transition(replay_buffer, buffer_actions, new_obs, rewards, dones, infos)

            self._update_current_progress_remaining(self.num_timesteps, self._total_timesteps)  # type: ignore[attr-defined]

            self._on_step()  # type: ignore[attr-defined]

            for idx, done in enumerate(dones):
                if done:
                    # Update stats
                    num_collected_episodes += 1
                    self._episode_num += 1

                    if action_noise is not None:
                        kwargs = dict(indices=[idx]) if env.num_envs > 1 else {}
                        action_noise.reset(**kwargs)

                    # Log training infos
                    if log_interval is not None and self._episode_num % log_interval == 0:
                        self.dump_logs()  # type: ignore[attr-defined]
        callback.on_rollout_end()

        return RolloutReturn(num_collected_steps, num_collected_episodes, continue_training)

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_lean_rollout"]  # type: ignore[misc]

    # the three parts ----------------------------------------------------------------------------
    def _lean_parts(self, env: VecEnv, replay_buffer: ReplayBuffer, action_noise: Any) -> tuple[Sampler, Stepper, Storer]:
        """The action, env-step and transition functions of a rollout, built again when the env, the buffer, the
        noise or the policy is another."""
        gym_env = _single_env(env)
        key = (env, gym_env, replay_buffer, action_noise, self.policy)
        cached = self.__dict__.get("_lean_rollout")
        if cached is None or any(a is not b for a, b in zip(cached[0], key)):
            parts = (self._lean_sampler(action_noise), _env_stepper(env, gym_env), self._lean_storer(replay_buffer))
            cached = self.__dict__["_lean_rollout"] = (key, parts)
        return cached[1]

    def _lean_sampler(self, action_noise: Any) -> Sampler:
        """URLBDDPG's ``_sample_action`` for one env, lean where it acts with :func:`~sb3_cic.speed.lean_action`."""
        sample = self._sample_action  # type: ignore[attr-defined]
        if not _reproduced_method(type(self), "_sample_action"):
            return lambda learning_starts, noise: sample(learning_starts, noise, 1)
        policy = self.policy
        rescale = _rescaler(policy)
        draw = normal_noise(action_noise)
        shape = (-1, *policy.action_space.shape)
        actor_call = [ActorCall(policy.actor)]
        # compile_update on CUDA: the actor as a CUDA graph (GraphedActor), captured at the first action
        graphed: list[GraphedActor | None] = [None] if self.compile_update and policy.device.type == "cuda" else []

        def lean(learning_starts: int, noise: Any) -> tuple[np.ndarray, np.ndarray]:
            obs = self._last_obs
            acting = self.num_timesteps >= (0 if self.warmup_with_policy else learning_starts)
            if not (acting and speed_options.lean_acting and type(obs) is np.ndarray):
                return sample(learning_starts, noise, 1)
            call = actor_call[0]
            if call.actor is not policy.actor:  # a new actor
                call = actor_call[0] = ActorCall(policy.actor)
            plain_obs = obs.dtype == np.float32 and obs.flags.c_contiguous
            if call.on_cpu() and plain_obs:
                mu = call(th.from_numpy(obs)).numpy()  # th.as_tensor(obs).float(), without its conversions
            elif graphed and plain_obs and call.plain():
                graph = graphed[0]
                if graph is None or not graph.current(policy.actor, obs.shape):
                    graph = graphed[0] = GraphedActor(policy.actor, obs.shape)
                mu = graph(obs)
            else:
                mu = call(th.as_tensor(obs, device=policy.device).float()).cpu().numpy()
            return rescale(mu.reshape(shape), draw if noise is action_noise else noise)

        return lean

    def _lean_storer(self, replay_buffer: ReplayBuffer) -> Storer:
        """URLBDDPG's ``_store_transition`` for one env without VecNormalize, with a cheaper finiteness check and,
        on SB3's ``ReplayBuffer.add``, its stores made directly."""
        fallback = self._store_transition  # type: ignore[attr-defined]
        if not _reproduced_method(type(self), "_store_transition"):
            return fallback
        direct = type(replay_buffer).add is ReplayBuffer.add and not replay_buffer.optimize_memory_usage
        action_shape = (replay_buffer.n_envs, replay_buffer.action_dim)

        def store(
            buffer: ReplayBuffer, buffer_action: np.ndarray, new_obs: np.ndarray, reward: np.ndarray,
            dones: np.ndarray, infos: list[dict[str, Any]],
        ) -> None:
            if type(new_obs) is not np.ndarray:  # (URLB's observations are flat arrays)
                return fallback(buffer, buffer_action, new_obs, reward, dones, infos)
            info = infos[0]
            final = info.get("terminal_observation", _MISSING)
            if not (_finite(new_obs) and _finite(reward) and (final is _MISSING or _finite(final))):
                check_finite_step(self.num_timesteps, new_obs, reward, infos)  # the exact check, and its error
            self._last_original_obs = obs = self._last_obs
            next_obs = new_obs
            if dones[0] and final is not _MISSING and final is not None:
                next_obs = new_obs.copy()
                next_obs[0] = final
            if not (direct and buffer is replay_buffer):
                buffer.add(obs, new_obs.copy() if next_obs is new_obs else next_obs, buffer_action, reward, dones, infos)
            else:  # ReplayBuffer.add's stores (they copy)
                pos = buffer.pos
                buffer.observations[pos] = obs
                buffer.next_observations[pos] = next_obs
                buffer.actions[pos] = buffer_action.reshape(action_shape)
                buffer.rewards[pos] = reward
                buffer.dones[pos] = dones
                if buffer.handle_timeout_termination:
                    buffer.timeouts[pos] = info.get("TimeLimit.truncated", False)
                buffer.pos += 1
                if buffer.pos == buffer.buffer_size:
                    buffer.full = True
                    buffer.pos = 0
            self._last_obs = new_obs

        return store


# ------------------------------------------------------------------------------------------------
# the parts' helpers
#: the types of the values that ``deepcopy`` returns as they are (and numpy's scalars)
_ATOMIC = frozenset({float, int, bool, str, type(None)})
#: a key that an info dict does not hold
_MISSING = object()
#: the layers that :class:`~sb3_cic.speed.LeanSequential` runs as plain function calls
_LEAN_LAYERS = (nn.Linear, nn.LayerNorm, nn.Tanh, nn.ReLU)


class ActorCall:
    """``actor(obs)`` under ``no_grad`` for a :class:`~sb3_cic.policies.URLBActor` whose two
    :class:`~sb3_cic.speed.LeanSequential` hold only linear, LayerNorm, tanh and ReLU layers: the functions those
    call, in order, on the parameters read beforehand (``lean_forward``'s kernels on the same inputs: the same
    output, bit for bit).

    A parameter read through its module (``nn.Module.__getattr__``) and the module calls cost more than the
    kernels of a forward pass for one observation at hidden 256. At every call it checks, as ``LeanSequential``
    and ``nn.Module.__call__`` do, that ``lean_forward`` is on and that no module has hooks or is compiled (and
    no global hooks, no tracing), else it calls ``actor``; modules or parameters replaced since it read them are
    read again.

    :param actor: the policy's actor
    """

    def __init__(self, actor: nn.Module) -> None:
        self.actor = actor
        self._ops: list[tuple[int, Any, Any, nn.Module]] | None = None
        self._read()

    def _read(self) -> None:
        actor, self._ops = self.actor, None
        if type(actor).forward is not URLBActor.forward:
            return
        sequences = [actor._modules.get("trunk"), actor._modules.get("policy")]
        if not all(seq is not None and type(seq).forward is LeanSequential.forward for seq in sequences):
            return
        containers = [seq._modules for seq in sequences if seq is not None]
        layers = [layer for modules in containers for layer in modules.values() if layer is not None]
        if not all(type(layer) in _LEAN_LAYERS for layer in layers) or len(layers) != sum(map(len, containers)):
            return
        self._modules = [actor, *(seq for seq in sequences if seq is not None), *layers]
        if any(m._compiled_call_impl is not None for m in self._modules):
            return
        self._hooks = [
            hooks for m in self._modules
            for hooks in (m._forward_hooks, m._forward_pre_hooks, m._backward_hooks, m._backward_pre_hooks)
        ]
        # (dict, key, value) of every module and parameter the ops read and of each module's compiled call (None),
        # and the sequences' lengths
        links: list[tuple[dict[str, Any], str, Any]] = [(actor._modules, "trunk", sequences[0])]
        links.append((actor._modules, "policy", sequences[1]))
        links += [(modules, key, m) for modules in containers for key, m in modules.items()]
        for layer in layers:
            links += [(layer._parameters, name, value) for name, value in layer._parameters.items()]
        links += [(m.__dict__, "_compiled_call_impl", None) for m in self._modules]
        self._dicts, self._keys, self._values = zip(*links)
        self._containers, self._lengths = containers, [len(modules) for modules in containers]
        self._ops = [_op(layer) for layer in layers]
        self._first = next(iter(layers[0]._parameters.values()), None) if layers else None
        if self._first is None:
            self._ops = None

    def _current(self) -> bool:
        """Whether the modules and parameters are those :meth:`_read` read, and none is compiled."""
        return list(map(len, self._containers)) == self._lengths and all(
            map(operator.is_, map(dict.get, self._dicts, self._keys), self._values)
        )

    def plain(self) -> bool:
        """Whether a call runs the layers' functions (the actor and its modules as read, no hooks, no tracing): what a
        :class:`~sb3_cic.common.fast_update.GraphedActor` may capture."""
        if self._ops is not None and not self._current():
            self._read()
        return self._ops is not None and self._plain()

    def on_cpu(self) -> bool:
        """Whether the actor's layers run as plain calls on the CPU (its first weight is there)."""
        return self._ops is not None and self._first.device.type == "cpu"

    def _plain(self) -> bool:
        """Whether calling the modules would only call their ``forward`` (and ``lean_forward`` is on)."""
        return (
            speed_options.lean_forward
            and not any(self._hooks)
            and not (
                torch_module._global_forward_hooks or torch_module._global_forward_pre_hooks
                or torch_module._global_backward_hooks or torch_module._global_backward_pre_hooks
                or th._C._get_tracing_state()
            )
        )

    def __call__(self, obs: th.Tensor) -> th.Tensor:
        """The actor's output for ``obs``, without gradient."""
        enabled = th.is_grad_enabled()
        th._C._set_grad_enabled(False)
        try:
            if self._ops is not None and not self._current():
                self._read()  # modules or parameters replaced, or a module compiled (then not read)
            if self._ops is None or not self._plain():
                return self.actor(obs)
            x, linear = obs, th._C._nn.linear
            for kind, weight, bias, layer in self._ops:
                if kind == _LINEAR:
                    x = linear(x, weight, bias)
                elif kind == _TANH:
                    x = th.tanh(x)
                elif kind == _RELU:
                    x = th.relu_(x) if layer.inplace else th.relu(x)
                else:
                    x = th.layer_norm(x, layer.normalized_shape, weight, bias, layer.eps)
            return x
        finally:
            th._C._set_grad_enabled(enabled)


_LINEAR, _LAYER_NORM, _TANH, _RELU = range(4)


def _op(layer: nn.Module) -> tuple[int, Any, Any, nn.Module]:
    """What :class:`~sb3_cic.speed.LeanSequential` calls for ``layer``: ``(kind, weight, bias, layer)`` (its
    parameters read now, its settings at each call)."""
    params = layer._parameters
    if type(layer) is nn.Linear:
        return _LINEAR, params["weight"], params["bias"], layer
    if type(layer) is nn.LayerNorm:
        return _LAYER_NORM, params["weight"], params["bias"], layer
    return (_RELU if type(layer) is nn.ReLU else _TANH), None, None, layer


def copy_info(info: dict[str, Any]) -> dict[str, Any]:
    """``deepcopy(info)`` in a plain loop for an info dict of immutable values and numeric arrays.

    Any other value (a nested dict, a list, an object array), a key that is not a string, or one array under two
    keys: ``deepcopy`` itself.

    :param info: one env's info dict
    """
    out: dict[str, Any] = {}
    arrays: set[int] = set()
    for key, value in info.items():
        if type(key) is not str:
            return deepcopy(info)
        if type(value) in _ATOMIC or isinstance(value, (np.number, np.bool_)):
            out[key] = value
        elif type(value) is np.ndarray and value.dtype.kind in "biufc" and id(value) not in arrays:
            arrays.add(id(value))
            out[key] = value.copy()
        else:
            return deepcopy(info)
    return out


def normal_noise(noise: Any) -> Any:
    """``noise``, or for SB3's ``NormalActionNoise`` with one mean and one std for every entry, a function that
    makes its draw with them as scalars.

    ``np.random.normal(mu, sigma)`` with array arguments costs several times its draw (broadcasting); with scalar
    arguments numpy draws the same values from the same generator (the same ``loc + scale * gauss`` per entry, in
    order). The function checks at each call that the noise holds the same arrays (objects and bytes) and dtype,
    and calls ``noise`` otherwise.

    :param noise: an action noise, or None
    """
    if type(noise) is not NormalActionNoise:
        return noise
    mu, sigma, dtype = noise._mu, noise._sigma, noise._dtype
    if not (type(mu) is np.ndarray and type(sigma) is np.ndarray and mu.shape == sigma.shape and mu.size):
        return noise
    if mu.dtype != np.float64 or sigma.dtype != np.float64:
        return noise
    loc, scale = float(mu.flat[0]), float(sigma.flat[0])
    if not (math.isfinite(loc) and math.isfinite(scale) and scale >= 0):
        return noise
    if np.full_like(mu, loc).tobytes() != mu.tobytes() or np.full_like(sigma, scale).tobytes() != sigma.tobytes():
        return noise
    shape, saved = mu.shape, (mu.tobytes(), sigma.tobytes())

    def draw() -> np.ndarray:
        if noise._mu is not mu or noise._sigma is not sigma or noise._dtype is not dtype:
            return noise()
        if (mu.tobytes(), sigma.tobytes()) != saved:
            return noise()
        return np.random.normal(loc, scale, shape).astype(dtype)

    return draw


def unit_rescale(x: np.ndarray) -> np.ndarray:
    """SB3's ``unscale_action(x)`` and ``scale_action(x)`` for bounds of exactly -1 and 1: ``(x + 1) - 1``.

    Both formulas reduce to it in floating point: with ``y = fl(x + 1)``, ``0.5 * y * 2`` and ``y / 2 * 2`` are
    exact (``y`` is 0 or at least ``ulp(1) / 2``, far from the subnormals: ``x + 1`` is exact where it is small),
    and ``-1 + y`` is ``y - 1``; the same operations in the same format, so the same bits (checked against SB3's
    formulas on edge values and a million float32 in ``tests/test_rollout.py``, and once on all 2**32 float32).

    :param x: a float32 or float64 array
    """
    return (x + 1.0) - 1.0


def _rescaler(policy: Any) -> Callable[[np.ndarray, Any], tuple[np.ndarray, np.ndarray]]:
    """``(mu, noise) -> (action, buffer_action)``: :func:`~sb3_cic.speed.lean_action` after the actor, with SB3's
    ``scale_action``/``unscale_action`` formulas on the bounds read once (:func:`unit_rescale` for [-1, 1]
    float32 bounds and float32 values; the policy's methods if it has its own)."""
    cls = type(policy)
    scale: Callable[[np.ndarray], np.ndarray]
    unscale: Callable[[np.ndarray], np.ndarray]
    if cls.scale_action is not BasePolicy.scale_action or cls.unscale_action is not BasePolicy.unscale_action:
        scale, unscale = policy.scale_action, policy.unscale_action
        unit = False
    else:
        low, high = policy.action_space.low, policy.action_space.high
        span = high - low
        unit = low.dtype == high.dtype == np.float32 and bool(np.all(low == -1.0) and np.all(high == 1.0))

        def scale(action: np.ndarray) -> np.ndarray:
            return 2.0 * ((action - low) / span) - 1.0

        def unscale(scaled_action: np.ndarray) -> np.ndarray:
            return low + (0.5 * (scaled_action + 1.0) * span)

    def rescale(mu: np.ndarray, noise: Any) -> tuple[np.ndarray, np.ndarray]:
        noisy = None if noise is None else noise()
        if unit and mu.dtype == np.float32:
            scaled_action = unit_rescale(unit_rescale(mu))
        else:
            scaled_action = scale(unscale(mu))
        if noisy is not None:  # np.clip(scaled_action + noise, -1, 1), without np.clip's wrappers
            scaled_action = np.minimum(np.maximum(scaled_action + noisy, -1), 1)
        if unit and scaled_action.dtype == np.float32:
            return unit_rescale(scaled_action), scaled_action
        return unscale(scaled_action), scaled_action

    return rescale


def _single_env(env: VecEnv) -> Any:
    """The gymnasium env of a plain ``DummyVecEnv`` of one env whose step methods are its class's (else None)."""
    if type(env) is not DummyVecEnv or env.num_envs != 1 or env.keys != [None]:
        return None
    own = env.__dict__
    if "step" in own or "step_async" in own or "step_wait" in own:  # replaced on the instance
        return None
    return env.envs[0]


def _env_stepper(env: VecEnv, gym_env: Any) -> Stepper:
    """``env.step``, or for a plain ``DummyVecEnv`` of one env, what ``DummyVecEnv.step`` returns for it.

    Its ``actions`` and ``reset_infos`` are set as it sets them; its scratch buffers (``buf_obs``, ``buf_rews``,
    ``buf_dones``, ``buf_infos``, which it copies what it returns from) are not used.
    """
    if gym_env is None:
        return env.step
    dummy: DummyVecEnv = env  # type: ignore[assignment]
    obs_shape, obs_dtype = dummy.buf_obs[None].shape, dummy.buf_obs[None].dtype

    def step(actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        dummy.actions = actions
        obs, reward, terminated, truncated, info = gym_env.step(actions[0])
        rewards = np.empty(1, np.float32)
        rewards[0] = reward
        dones = np.empty(1, bool)
        dones[0] = terminated or truncated
        info["TimeLimit.truncated"] = truncated and not terminated
        new_obs = np.empty(obs_shape, obs_dtype)
        if dones[0]:
            info["terminal_observation"] = obs
            obs, dummy.reset_infos[0] = gym_env.reset()
            new_obs[0] = obs
            return new_obs, rewards, dones, deepcopy([info])
        new_obs[0] = obs
        return new_obs, rewards, dones, [copy_info(info)]

    return step


def _finite(values: Any) -> bool:
    """True if ``values`` is a float array whose entries are all finite (False: the exact check decides).

    A sum of squares of finite floats is finite unless it overflows; an inf or NaN entry makes it inf or NaN.
    """
    if type(values) is not np.ndarray or values.dtype.kind != "f":
        return False
    if values.size == 1:
        return math.isfinite(values.flat[0])
    flat = values.reshape(-1)
    return math.isfinite(flat.dot(flat))


_REPRODUCED: dict[tuple[type, str], bool] = {}


def _reproduced_method(cls: type, name: str) -> bool:
    """Whether ``cls``'s method ``name`` is the one of the class that mixes :class:`LeanRolloutMixin` in (URLBDDPG,
    whose methods the lean parts reproduce), not a subclass's own."""
    key = (cls, name)
    if key not in _REPRODUCED:
        owner = next(c for c in cls.__mro__ if LeanRolloutMixin in c.__bases__)
        _REPRODUCED[key] = name in owner.__dict__ and getattr(cls, name) is owner.__dict__[name]
    return _REPRODUCED[key]
