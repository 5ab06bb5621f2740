"""Resumable runs: a run folder's bookkeeping files and its checkpoint.

A run folder holds, besides what the run produces (``result.json``, ``eval.csv``, snapshots):

* ``checkpoint.zip`` while the run is unfinished: the run's whole state at an episode boundary,
  written to ``checkpoint.tmp`` and renamed (a kill during a write leaves the previous checkpoint);
  deleted once ``result.json`` is written (a run killed in between is done: :meth:`RunFolder.clean` deletes
  what it left when the run is next seen);
* ``progress.json`` while the run is unfinished: who runs it (host, pid and the process's start time, so that a pid
  the system gave to another process since is not taken for it: :func:`process_start_time`) and its last
  checkpoint step;
* ``error.txt`` when the run raised: the traceback.

The checkpoint is a zip (stored, not compressed) of ``meta.json`` (step, elapsed time, and the run it belongs to:
its row and the hash of its settings, :attr:`RunFolder.identity`; a checkpoint of another run is refused),
``model.zip``
(SB3's ``save``: networks, optimisers, reward module, counters, last observation, action noise),
``replay_buffer.pkl`` (SB3's ``save_replay_buffer``) and ``state.pkl``: what SB3 does not save, namely the
random states (Python, numpy, torch, the model's spaces), the environments' states (each env's episode
start, the skill wrappers' schedules) and the callbacks' states
(:class:`~sb3_cic.common.resumable.ResumableCallback`).
"""

from __future__ import annotations

import io
import json
import os
import pickle
import random
import socket
import time
import zipfile
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.type_aliases import GymEnv
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecEnvWrapper

from sb3_cic.common.resumable import ResumableCallback, env_layers, env_state, has_method, set_env_state

#: version of the checkpoint's content
CHECKPOINT_FORMAT = 1


def process_start_time(pid: int) -> int | None:
    """The start time of process ``pid`` of this host (field 22 of ``/proc/<pid>/stat``, in clock ticks since boot):
    with the pid, it names one process (a pid is reused, a (pid, start time) pair is not). None where it cannot be
    read (no such process, no ``/proc``)."""
    try:
        with open(f"/proc/{pid}/stat") as file:
            return int(file.read().rsplit(")", 1)[1].split()[19])
    except (OSError, IndexError, ValueError):
        return None


def write_json(path: Path, data: dict[str, Any]) -> None:
    """Write ``data`` to ``path`` atomically (temporary file + rename).

    :param path: the file
    :param data: JSON-able content
    """
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=2, default=float))
    os.replace(tmp, path)


class RunFolder:
    """The bookkeeping files of one run's folder (see the module docstring).

    :param path: the run folder
    :param identity: the run the folder's checkpoint must belong to (``{"run": row, "settings_sha256": ...}``,
        recorded in its ``meta.json``; each entry the checkpoint records must agree): None, not checked
    """

    def __init__(self, path: str | Path, identity: dict[str, Any] | None = None) -> None:
        self.path = Path(path)
        self.identity = identity
        self.result = self.path / "result.json"
        self.checkpoint = self.path / "checkpoint.zip"
        self.checkpoint_tmp = self.path / "checkpoint.tmp"
        self.progress = self.path / "progress.json"
        self.error = self.path / "error.txt"

    @property
    def done(self) -> bool:
        """Whether the run finished (its ``result.json`` exists)."""
        return self.result.exists()

    def read_progress(self) -> dict[str, Any] | None:
        """``progress.json`` (None if absent, unreadable or no JSON object)."""
        try:
            progress = json.loads(self.progress.read_text())
        except (OSError, ValueError):
            return None
        return progress if isinstance(progress, dict) else None

    def read_meta(self) -> dict[str, Any] | None:
        """The checkpoint's ``meta.json`` (None without checkpoint); ``ValueError`` if the checkpoint is corrupt
        or if ``progress.json`` records a checkpoint that is missing."""
        if not self.checkpoint.exists():
            progress = self.read_progress() or {}
            if progress.get("checkpoint_step"):
                raise ValueError(
                    f"{self.progress} records a checkpoint at step {progress['checkpoint_step']} but {self.checkpoint} "
                    f"is missing; restore it, or delete {self.progress} to run this run again from step 0"
                )
            return None
        try:
            with zipfile.ZipFile(self.checkpoint) as archive:
                meta = json.loads(archive.read("meta.json"))
                missing = {"model.zip", "replay_buffer.pkl", "state.pkl"} - set(archive.namelist())
        except (OSError, ValueError, KeyError, zipfile.BadZipFile) as error:
            raise ValueError(
                f"corrupt checkpoint {self.checkpoint} ({error!r}); {self._restart_advice()}"
            ) from error
        if missing or meta.get("format") != CHECKPOINT_FORMAT or not isinstance(meta.get("step"), int):
            raise ValueError(f"corrupt checkpoint {self.checkpoint} (missing {sorted(missing)} or bad meta.json {meta}); "
                             f"{self._restart_advice()}")
        recorded = meta.get("run") if isinstance(meta.get("run"), dict) else {}
        other = {key: (recorded[key], value) for key, value in (self.identity or {}).items()
                 if key in recorded and recorded[key] != value}
        if other:
            raise ValueError(f"the checkpoint {self.checkpoint} belongs to another run ((checkpoint, this run): {other}): "
                             f"it was copied; {self._restart_advice()}")
        return meta

    def _restart_advice(self) -> str:
        """What to delete to run the run again from step 0 (all of it: one round of advice)."""
        names = " and ".join(str(p) for p in (self.checkpoint, self.progress) if p.exists()) or str(self.checkpoint)
        return f"delete {names} to run this run again from step 0"

    def start(self, checkpoint_step: int = 0) -> None:
        """Mark the run as running here (``progress.json``) and forget an earlier failure.

        :param checkpoint_step: the step of the checkpoint it resumes from (0: none)
        """
        self.path.mkdir(parents=True, exist_ok=True)
        self.error.unlink(missing_ok=True)
        self._write_progress(checkpoint_step)

    def _write_progress(self, checkpoint_step: int) -> None:
        write_json(
            self.progress,
            {"host": socket.gethostname(), "pid": os.getpid(), "start_time": process_start_time(os.getpid()),
             "checkpoint_step": checkpoint_step, "updated": time.time()},
        )

    def finish(self, result: dict[str, Any]) -> None:
        """Write ``result.json``, then delete the checkpoint and ``progress.json`` (:meth:`clean`).

        :param result: the run's result
        """
        write_json(self.result, result)
        self.clean()

    def clean(self) -> list[Path]:
        """Delete what a done run has no use for (checkpoint, ``progress.json``, ``error.txt``), as left by a run
        killed between writing ``result.json`` and deleting them; return what was deleted. An unfinished run is
        left as it is.
        """
        if not self.done:
            return []
        leftovers = [path for path in (self.checkpoint, self.checkpoint_tmp, self.progress, self.error) if path.exists()]
        for path in leftovers:
            path.unlink(missing_ok=True)
        return leftovers

    def fail(self, traceback: str) -> None:
        """Record the run as failed: ``error.txt`` holds the traceback (the checkpoint stays, to resume from).

        :param traceback: the formatted traceback
        """
        self.path.mkdir(parents=True, exist_ok=True)
        self.error.write_text(traceback)

    # the checkpoint ------------------------------------------------------------------------
    def save_checkpoint(self, model: BaseAlgorithm, callbacks: Sequence[BaseCallback], meta: dict[str, Any]) -> int:
        """Write the checkpoint (temporary file + rename) and record its step; return its size in bytes.

        :param model: the model, at an episode boundary of its (single) training env
        :param callbacks: the callbacks whose state is saved (any: ``n_calls``; a
            :class:`~sb3_cic.common.resumable.ResumableCallback`: its own state too)
        :param meta: extra entries of ``meta.json``
        """
        meta = {**meta, "format": CHECKPOINT_FORMAT, "step": int(model.num_timesteps)}
        if self.identity is not None:
            meta["run"] = self.identity
        state = {
            "rng": rng_state(model),
            "env": vec_env_state(model.get_env()),
            "callbacks": [callback_state(callback) for callback in callbacks],
        }
        model_bytes = io.BytesIO()
        model.save(model_bytes)
        with zipfile.ZipFile(self.checkpoint_tmp, "w", compression=zipfile.ZIP_STORED, allowZip64=True) as archive:
            archive.writestr("meta.json", json.dumps(meta, default=float))
            archive.writestr("model.zip", model_bytes.getvalue())
            with archive.open("replay_buffer.pkl", "w", force_zip64=True) as file:
                pickle.dump(model.replay_buffer, file, protocol=pickle.HIGHEST_PROTOCOL)
            with archive.open("state.pkl", "w", force_zip64=True) as file:
                pickle.dump(state, file, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(self.checkpoint_tmp, self.checkpoint)
        self._write_progress(meta["step"])
        return self.checkpoint.stat().st_size

    def load_model(self, cls: type[BaseAlgorithm], env: GymEnv, **kwargs: Any) -> BaseAlgorithm:
        """The checkpoint's model, on ``env``, with its replay buffer (random and env states: :meth:`restore`).

        :param cls: the algorithm class
        :param env: the training env (an id or env, as the run made it)
        :param kwargs: other arguments of ``cls.load`` (``device``, ``tensorboard_log``...)
        """
        with zipfile.ZipFile(self.checkpoint) as archive:
            model = cls.load(io.BytesIO(archive.read("model.zip")), env=env, force_reset=False, **kwargs)
            model.load_replay_buffer(io.BytesIO(archive.read("replay_buffer.pkl")))  # SB3's: device, relabel hook
        return model

    def restore(self, model: BaseAlgorithm, callbacks: Sequence[BaseCallback]) -> dict[str, Any]:
        """Put the envs, the callbacks and the random states back as the checkpoint saved them; return ``meta.json``.

        Call it last before ``learn``: building the run's objects may draw from the global random states.

        :param model: the model of :meth:`load_model`
        :param callbacks: the same callbacks, in the same order, as given to :meth:`save_checkpoint`
        """
        with zipfile.ZipFile(self.checkpoint) as archive:
            meta = json.loads(archive.read("meta.json"))
            with archive.open("state.pkl") as file:
                state = pickle.load(file)
        if len(state["callbacks"]) != len(callbacks):
            raise ValueError(
                f"{self.checkpoint} holds {len(state['callbacks'])} callbacks' states, the run has {len(callbacks)}"
            )
        set_vec_env_state(model.get_env(), state["env"], model._last_obs)  # type: ignore[arg-type]
        for callback, saved in zip(callbacks, state["callbacks"]):
            set_callback_state(callback, saved)
        set_rng_state(model, state["rng"])
        return meta


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
    :class:`~sb3_cic.common.resumable.ResumableCallback`.

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


class RunCheckpointCallback(BaseCallback):
    """Checkpoint the run every ``every`` steps, at the first episode boundary after that many steps.

    The checkpoint is taken when a rollout starts (the previous rollout's updates done) right after an
    episode ended, so a resumed run goes on exactly as the uninterrupted one would. The callback sees the episode
    ends itself (each step's ``dones``): SB3's off-policy algorithms leave ``_last_episode_starts`` as ``learn`` set
    it, all True, which would take a period that ends mid-episode for an episode boundary (a checkpoint whose episode
    start cannot be reproduced).

    :param folder: the run's folder
    :param every: steps between checkpoints (0: none)
    :param callbacks: the run's other callbacks, whose state is saved
    :param elapsed_s: training time of the run before this ``learn`` call (a resumed run's)
    :param verbose: verbosity
    """

    def __init__(
        self, folder: RunFolder, every: int, callbacks: Sequence[BaseCallback], elapsed_s: float = 0.0, verbose: int = 0
    ) -> None:
        super().__init__(verbose)
        if not isinstance(every, (int, np.integer)) or every < 0:
            raise ValueError(f"the checkpoint period must be an int >= 0, got {every!r}")
        self.folder = folder
        self.every = int(every)
        self.callbacks = list(callbacks)
        self.elapsed_s = elapsed_s
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
        if not self.every or self.num_timesteps - self._last < self.every:
            return
        if not self._episode_start:
            return
        start = time.perf_counter()
        size = self.folder.save_checkpoint(self.model, self.callbacks, {"elapsed_s": self.elapsed()})
        self.written.append((self.num_timesteps, time.perf_counter() - start, size))
        self._last = self.num_timesteps
        if self.verbose:
            print(f"Checkpoint at step {self.num_timesteps}: {self.folder.checkpoint} ({size / 1e6:.1f} MB)")

    def _on_step(self) -> bool:
        self._episode_start = bool(np.all(self.locals["dones"]))
        return True
