"""What a run checkpoint saves of a training beyond SB3's ``save``, and the callback that takes it: the random states
(:func:`rng_state`), the callbacks' state (:class:`ResumableCallback`, :func:`callback_state`), each env layer's and
VecEnv wrapper's state (:func:`env_state`, :func:`vec_env_state`), and :class:`RunCheckpointCallback`, which
checkpoints a run at an episode boundary (and, asked to pause, checkpoints at the next one and raises
:class:`RunPaused`). The checkpoint file and the run folder that holds it are the study's
(:mod:`sb3_cic.study.checkpoint`)."""

from __future__ import annotations

import random
import time
from pathlib import Path
from typing import Any, Callable, Protocol, Sequence

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecEnvWrapper


class RunPaused(Exception):
    """A run stopped on a pause request (:class:`RunCheckpointCallback`), its progress saved: started again, it
    resumes from its checkpoint. Not a failure.

    :param step: the step of its last checkpoint (None: the run stopped before it started)
    """

    def __init__(self, step: int | None = None) -> None:
        super().__init__(f"paused at step {step}" if step is not None else "paused before it started")
        self.step = step


class ResumableCallback(BaseCallback):
    """A callback whose state a checkpoint saves (its ``n_calls`` and :meth:`get_checkpoint_state`).

    After :meth:`set_checkpoint_state` the callback is :attr:`resumed`: its ``_on_training_start`` must
    continue, not start over (no step-0 evaluation, no new skill sweep...).

    :param verbose: verbosity
    """

    #: set when the state came from a checkpoint
    resumed: bool = False

    def get_checkpoint_state(self) -> dict[str, Any]:
        """The callback's state beyond ``n_calls`` (none by default)."""
        return {}

    def set_checkpoint_state(self, state: dict[str, Any]) -> None:
        """Restore what :meth:`get_checkpoint_state` returned.

        :param state: the saved state
        """


def has_method(obj: Any, name: str) -> bool:
    """Whether ``obj``'s class defines a method ``name`` (gymnasium wrappers do not forward attributes).

    :param obj: an env, a wrapper or a VecEnv wrapper
    :param name: the method's name
    """
    return callable(getattr(type(obj), name, None))


def env_layers(env: gym.Env) -> list[gym.Env]:
    """``env`` and every env it wraps, outermost first.

    :param env: a gymnasium env and its wrappers
    """
    layers = [env]
    while isinstance(env, gym.Wrapper):
        env = env.env
        layers.append(env)
    return layers


def env_state(env: gym.Env) -> list[Any]:
    """The checkpoint state of each layer of ``env`` (its ``get_checkpoint_state``, None for a layer without).

    Taken just after a reset: :class:`~sb3_cic.envs.dmc.DMCEnv` saves the random state its episode started from.

    :param env: a gymnasium env and its wrappers
    """
    return [layer.get_checkpoint_state() if has_method(layer, "get_checkpoint_state") else None for layer in env_layers(env)]


def set_env_state(env: gym.Env, state: list[Any]) -> list[Any]:
    """Reset ``env`` (the wrappers' bookkeeping), then restore each layer's state; return what the layers returned.

    :param env: an env built as the one :func:`env_state` read
    :param state: what :func:`env_state` returned
    """
    layers = env_layers(env)
    if len(layers) != len(state):
        raise ValueError(f"the env has {len(layers)} layers, the checkpoint {len(state)}: not the same env")
    env.reset()
    return [layer.set_checkpoint_state(saved) for layer, saved in zip(layers, state) if saved is not None]


# random states -------------------------------------------------------------------------------
def rng_state(model: BaseAlgorithm) -> dict[str, Any]:
    """The random states a run draws from: Python, numpy (action noise, replay sampling), torch and the model's spaces.

    :param model: the model (its action space draws the warm-up's random actions)
    """
    return {
        "python": random.getstate(),
        "numpy": np.random.get_state(),
        "torch": th.get_rng_state(),
        "cuda": th.cuda.get_rng_state_all() if th.cuda.is_available() and th.cuda.is_initialized() else None,
        "action_space": model.action_space.np_random.bit_generator.state,
        "observation_space": model.observation_space.np_random.bit_generator.state,
    }


def set_rng_state(model: BaseAlgorithm, state: dict[str, Any]) -> None:
    """Restore what :func:`rng_state` returned.

    :param model: the model
    :param state: the saved random states
    """
    random.setstate(state["python"])
    np.random.set_state(state["numpy"])
    th.set_rng_state(state["torch"])
    if state["cuda"] is not None and th.cuda.is_available():
        th.cuda.set_rng_state_all(state["cuda"])
    model.action_space.np_random.bit_generator.state = state["action_space"]
    model.observation_space.np_random.bit_generator.state = state["observation_space"]


# environments --------------------------------------------------------------------------------
def _vec_layers(venv: VecEnv) -> tuple[list[VecEnvWrapper], DummyVecEnv]:
    wrappers = []
    while isinstance(venv, VecEnvWrapper):
        wrappers.append(venv)
        venv = venv.venv
    if not isinstance(venv, DummyVecEnv):
        raise ValueError(f"checkpoints need the envs in this process (a DummyVecEnv), got {type(venv).__name__}")
    return wrappers, venv


def vec_env_state(venv: VecEnv | None) -> dict[str, Any]:
    """The checkpoint state of a VecEnv (of its VecEnv wrappers and of each env), taken at an episode boundary.

    :param venv: the model's training env (a DummyVecEnv, possibly wrapped)
    """
    assert venv is not None
    wrappers, dummy = _vec_layers(venv)
    return {
        "wrappers": [w.get_checkpoint_state() if has_method(w, "get_checkpoint_state") else None for w in wrappers],
        "envs": [env_state(env) for env in dummy.envs],
    }


def set_vec_env_state(venv: VecEnv | None, state: dict[str, Any], last_obs: np.ndarray | None = None) -> None:
    """Restore what :func:`vec_env_state` returned.

    :param venv: the VecEnv, built as the one that was saved
    :param state: the saved state
    :param last_obs: the model's saved last observation: each env's restored observation must start with it
        (a ``RuntimeError`` says the episode start could not be reproduced)
    """
    assert venv is not None
    wrappers, dummy = _vec_layers(venv)
    for i, (env, saved) in enumerate(zip(dummy.envs, state["envs"], strict=True)):
        observations = [obs for obs in set_env_state(env, saved) if isinstance(obs, np.ndarray)]
        if last_obs is not None and observations:
            obs = observations[0]
            if not np.array_equal(np.asarray(last_obs[i][: obs.size], dtype=np.float32), obs.astype(np.float32)):
                raise RuntimeError("the checkpoint's episode start could not be reproduced: the env is not the saved one")
    for wrapper, saved in zip(wrappers, state["wrappers"], strict=True):
        if saved is not None:
            wrapper.set_checkpoint_state(saved)


# callbacks -----------------------------------------------------------------------------------
def callback_state(callback: BaseCallback) -> dict[str, Any]:
    """The state of ``callback`` a checkpoint saves: ``n_calls``, plus the own state of a
    :class:`ResumableCallback`.

    :param callback: any SB3 callback
    """
    own = callback.get_checkpoint_state() if isinstance(callback, ResumableCallback) else {}
    return {"class": type(callback).__name__, "n_calls": callback.n_calls, "state": own}


def set_callback_state(callback: BaseCallback, state: dict[str, Any]) -> None:
    """Restore what :func:`callback_state` returned (the callback must be of the same class).

    :param callback: the run's callback
    :param state: its saved state
    """
    if type(callback).__name__ != state["class"]:
        raise ValueError(f"the checkpoint saved a {state['class']}, the run has a {type(callback).__name__}")
    callback.n_calls = state["n_calls"]
    if isinstance(callback, ResumableCallback):
        callback.set_checkpoint_state(state["state"])
        callback.resumed = True


class CheckpointFolder(Protocol):
    """Where :class:`RunCheckpointCallback` writes: a run folder (:class:`~sb3_cic.study.checkpoint.RunFolder`)."""

    #: the checkpoint file
    checkpoint: Path

    def save_checkpoint(self, model: BaseAlgorithm, callbacks: Sequence[BaseCallback], meta: dict[str, Any]) -> int:
        """Write the checkpoint of ``model`` and ``callbacks`` with ``meta``; return its size in bytes."""


class RunCheckpointCallback(BaseCallback):
    """Checkpoint the run every ``every`` steps, at the first episode boundary after that many steps, and when
    ``pause_requested()`` says so at an episode boundary: then the run checkpoints there (unless it has not stepped
    since its start or last checkpoint) and stops, raising :class:`RunPaused` out of ``learn``. A run without
    checkpoints (``every`` 0) ignores the pause: it could not resume.

    The checkpoint is taken when a rollout starts (the previous rollout's updates done) right after an
    episode ended, so a resumed run goes on exactly as the uninterrupted one would. The callback sees the episode
    ends itself (each step's ``dones``): SB3's off-policy algorithms leave ``_last_episode_starts`` as ``learn`` set
    it, all True, which would take a period that ends mid-episode for an episode boundary (a checkpoint whose episode
    start cannot be reproduced).

    :param folder: the run's folder
    :param every: steps between checkpoints (0: none)
    :param callbacks: the run's other callbacks, whose state is saved
    :param elapsed_s: training time of the run before this ``learn`` call (a resumed run's)
    :param pause_requested: asked once per episode, at its end: whether to checkpoint and stop (None: never)
    :param verbose: verbosity
    """

    def __init__(
        self,
        folder: CheckpointFolder,
        every: int,
        callbacks: Sequence[BaseCallback],
        elapsed_s: float = 0.0,
        pause_requested: Callable[[], bool] | None = None,
        verbose: int = 0,
    ) -> None:
        super().__init__(verbose)
        if not isinstance(every, (int, np.integer)) or every < 0:
            raise ValueError(f"the checkpoint period must be an int >= 0, got {every!r}")
        self.folder = folder
        self.every = int(every)
        self.callbacks = list(callbacks)
        self.elapsed_s = elapsed_s
        self.pause_requested = pause_requested
        #: (step, seconds, bytes) of each checkpoint written
        self.written: list[tuple[int, float, int]] = []

    def _init_callback(self) -> None:
        if self.every:  # a ValueError now rather than at the first checkpoint
            _, dummy = _vec_layers(self.model.get_env())
            for env in dummy.envs:
                if not any(has_method(layer, "get_checkpoint_state") for layer in env_layers(env)):
                    raise ValueError(
                        f"{env} cannot checkpoint its episode start (no get_checkpoint_state, as URLB's DMCEnv has): "
                        "use checkpoint_every=0"
                    )
        self._last = self.num_timesteps
        self._start = time.perf_counter()
        self._episode_start = True  # ``learn`` starts at an episode start: a reset, or the checkpoint's restored one

    def elapsed(self) -> float:
        """Training seconds of the run so far (including the time before a resume)."""
        return self.elapsed_s + time.perf_counter() - self._start

    def _on_rollout_start(self) -> None:
        if not self.every or not self._episode_start:
            return
        pause = self.pause_requested is not None and self.pause_requested()
        if self.num_timesteps - self._last >= self.every or (pause and self.num_timesteps > self._last):
            self._checkpoint()
        if pause:
            raise RunPaused(self._last)

    def _checkpoint(self) -> None:
        start = time.perf_counter()
        size = self.folder.save_checkpoint(self.model, self.callbacks, {"elapsed_s": self.elapsed()})
        self.written.append((self.num_timesteps, time.perf_counter() - start, size))
        self._last = self.num_timesteps
        if self.verbose:
            print(f"Checkpoint at step {self.num_timesteps}: {self.folder.checkpoint} ({size / 1e6:.1f} MB)")

    def _on_step(self) -> bool:
        self._episode_start = bool(np.all(self.locals["dones"]))
        return True
