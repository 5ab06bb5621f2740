"""Resumable runs: a run folder's bookkeeping files and its checkpoint.

A run folder holds, besides what the run produces (``result.json``, ``eval.csv``, snapshots):

* ``checkpoint.zip`` while the run is unfinished: the run's whole state at an episode boundary,
  written to ``checkpoint.tmp`` and renamed (a kill during a write leaves the previous checkpoint);
  deleted once ``result.json`` is written (a run killed in between is done: :meth:`RunFolder.clean` deletes
  what it left when the run is next seen);
* ``progress.json`` while the run is unfinished: who runs it (host, pid and the process's start time, so that a pid
  the system gave to another process since is not taken for it: :func:`process_start_time`) and its last
  checkpoint step; a run paused (``sb3-cic pause``) names no process there (:meth:`RunFolder.pause`);
* ``error.txt`` when the run raised: the traceback.

The checkpoint is a zip (stored, not compressed) of ``meta.json`` (step, elapsed time, and the run it belongs to:
its row and the hash of its settings, :attr:`RunFolder.identity`; a checkpoint of another run is refused),
``model.zip``
(SB3's ``save``: networks, optimisers, reward module, counters, last observation, action noise),
``replay_buffer.pkl`` (SB3's ``save_replay_buffer``) and ``state.pkl``: what SB3 does not save, namely the
random states (Python, numpy, torch, the model's spaces), the environments' states (each env's episode
start, the skill wrappers' schedules) and the callbacks' states
(:class:`~sb3_cic.common.resumable.ResumableCallback`); those states and the callback that checkpoints a run
(:class:`~sb3_cic.common.resumable.RunCheckpointCallback`) are the library's (:mod:`sb3_cic.common.resumable`).
"""

from __future__ import annotations

import io
import json
import os
import pickle
import socket
import time
import zipfile
from pathlib import Path
from typing import Any, Sequence

from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.type_aliases import GymEnv

from sb3_cic.common.resumable import (
    callback_state,
    rng_state,
    set_callback_state,
    set_rng_state,
    set_vec_env_state,
    vec_env_state,
)

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

    def pause(self, checkpoint_step: int) -> None:
        """Record that the run stopped on a pause (:class:`~sb3_cic.common.resumable.RunPaused`): ``progress.json``
        keeps its last checkpoint's step and names no process (the process, a Ray worker, may live on), so the run
        is pending.

        :param checkpoint_step: the step of its last checkpoint (0: none)
        """
        write_json(self.progress, {"host": socket.gethostname(), "pid": None, "checkpoint_step": checkpoint_step,
                                   "paused": time.time()})

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
