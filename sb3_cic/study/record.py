"""What a study folder records, and how every command checks it before it trusts it.

* the **pairing** of fine-tunings with pre-trainings (:class:`Pairing`): URLB's (fine-tuning seed s from
  pre-training seed s, the default of new studies) or the CIC code's shared pre-training (every fine-tuning seed
  from one pre-training seed: every study made before pairing existed, whose ``study.json`` has a
  ``pretrain_seed`` and no ``pairing``);
* ``study.json`` (:func:`read_study_record`): its content checked, a damaged one named in one line; a lost one
  rebuilt from the run folders' ``settings.json`` (:func:`rebuild_study_record`), or refused in one line when a run
  folder does not record its settings;
* each run folder's ``settings.json`` (:func:`check_run_settings`): the settings the run was made with, checked
  against every command that meets the run;
* the lock (:class:`StudyLock`): one command drives a study folder at a time;
* a pause request (:func:`request_pause`): the command that drives the study stops its runs at their next episode
  end, each checkpointed there.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import socket
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from sb3_cic.study.checkpoint import write_json
from sb3_cic.study.layout import lock_file, pause_file, run_folders, study_file

#: the pairings of a study: ``paired`` (URLB's) and ``shared`` (the CIC code's)
PAIRINGS: tuple[str, ...] = ("paired", "shared")
#: the file of a run folder that records the settings it was made with
RUN_SETTINGS = "settings.json"


@dataclass(frozen=True)
class Pairing:
    """Which pre-training each fine-tuning of a study starts from.

    :param mode: ``paired``: fine-tuning seed s from pre-training seed s (URLB's ``finetune.py``); ``shared``: every
        fine-tuning seed from the pre-training of seed ``seed`` (the CIC code release)
    :param seed: the pre-training seed of a ``shared`` study (None for ``paired``)
    """

    mode: str
    seed: int | None = None

    def __post_init__(self) -> None:
        if self.mode not in PAIRINGS:
            raise ValueError(f"unknown pairing {self.mode!r}; known: {list(PAIRINGS)}")
        if (self.mode == "shared") != (isinstance(self.seed, int) and not isinstance(self.seed, bool) and self.seed >= 0):
            raise ValueError(f"a shared pairing needs a pre-training seed >= 0 and a paired one none, got {self.seed!r}")

    @property
    def paired(self) -> bool:
        """Whether fine-tuning seed s starts from pre-training seed s."""
        return self.mode == "paired"

    def pretrain_seed(self, seed: int) -> int:
        """The pre-training seed of fine-tuning seed ``seed``."""
        return seed if self.paired else int(self.seed)  # type: ignore[arg-type]

    def describe(self) -> str:
        """``paired (fine-tuning seed s from pre-training seed s)`` or ``shared (pre-training seed 0 for every
        fine-tuning seed)``."""
        if self.paired:
            return "paired (fine-tuning seed s from pre-training seed s, as URLB)"
        return f"shared (pre-training seed {self.seed} for every fine-tuning seed, as the CIC code)"

    def record(self) -> dict[str, Any]:
        """What ``study.json`` records of it."""
        return {"pairing": self.mode, **({} if self.paired else {"pretrain_seed": self.seed})}

    @classmethod
    def from_record(cls, data: dict[str, Any]) -> Pairing | None:
        """The pairing ``study.json`` records (one made before pairing existed: shared, with its ``pretrain_seed``);
        None when no run of the study pre-trained yet."""
        if "pairing" in data:
            return cls(data["pairing"], data.get("pretrain_seed"))
        if "pretrain_seed" in data:
            return cls("shared", data["pretrain_seed"])
        return None


def resolve_pairing(study: str | Path, pairing: str | None = None, pretrain_seed: int | None = None) -> Pairing:
    """The pairing of a command: the one asked for, else the study's, else ``paired`` (a new study).

    ``--pretrain-seed N`` alone asks for shared pre-training with seed N. A pairing other than the study's is a
    ``ValueError`` in one line: the two modes are not mixed in one folder by accident.

    :param study: study folder
    :param pairing: ``paired``, ``shared`` or None (the study's)
    :param pretrain_seed: the seed of shared pre-training (None: the study's, or 0)
    """
    if pairing == "paired" and pretrain_seed is not None:
        raise ValueError("--pretrain-seed is the one seed of shared pre-training; paired pre-training has one per "
                         "fine-tuning seed: use --pairing shared --pretrain-seed N, or leave --pretrain-seed out")
    recorded = Pairing.from_record(read_study_record(study)) if study_file(study).exists() else None
    if pairing is None and pretrain_seed is None:
        return recorded or Pairing("paired")
    if pairing is None or pairing == "shared":
        seed = pretrain_seed if pretrain_seed is not None else (recorded.seed if recorded and not recorded.paired else 0)
        wanted = Pairing("shared", seed)
    else:
        wanted = Pairing(pairing)
    if recorded is not None and recorded.mode != wanted.mode:  # (another shared seed: check_study_settings says so)
        hint = "--pairing paired" if recorded.paired else f"--pairing shared --pretrain-seed {recorded.seed}"
        raise ValueError(f"{study} pre-trains {recorded.describe()}; this command asks for {wanted.describe()}: "
                         f"give {hint} (or neither option) to go on with it, or use another folder")
    return wanted


# study.json ----------------------------------------------------------------------------------------------
def _check_study_data(data: Any) -> None:
    """``ValueError`` (the reason) unless ``data`` has the form of a ``study.json``."""
    if not isinstance(data, dict):
        raise ValueError(f"a {type(data).__name__}, not an object")
    if not isinstance(data.get("settings", {}), dict):
        raise ValueError("'settings' is not an object")
    if "pretrain_seed" in data and (not isinstance(data["pretrain_seed"], int) or data["pretrain_seed"] < 0):
        raise ValueError(f"'pretrain_seed' {data['pretrain_seed']!r} is not an int >= 0")
    if "pairing" in data:
        Pairing.from_record(data)
    confs = data.get("conf_files", {})
    if not isinstance(confs, dict) or not all(isinstance(c, dict) and isinstance(c.get("sha256"), str) for c in confs.values()):
        raise ValueError("'conf_files' is not an object of {file, sha256}")
    runs = data.get("runs", [])
    if not isinstance(runs, list):
        raise ValueError("'runs' is not a list")
    for row in runs:
        if not (isinstance(row, list) and 4 <= len(row) <= 6 and isinstance(row[0], str) and isinstance(row[1], str)
                and (row[2] is None or isinstance(row[2], str)) and isinstance(row[3], int)
                and (len(row) == 4 or row[4] is None or isinstance(row[4], int))
                and (len(row) < 6 or isinstance(row[5], str))):
            raise ValueError(f"the run {row!r} is not [method, domain, task or null, seed, snapshot or null"
                             "(, skill choice)]")


def read_study_record(study: str | Path) -> dict[str, Any]:
    """The content of ``<study>/study.json``, checked: a damaged file is a one-line ``ValueError`` naming it.

    :param study: study folder (its ``study.json`` must exist)
    """
    path = study_file(study)
    try:
        data = json.loads(path.read_text())
        _check_study_data(data)
    except (UnicodeDecodeError, ValueError) as error:
        raise ValueError(f"{path} is damaged ({error}); restore it from a copy, or delete it to rebuild it from "
                         "the run folders") from None
    return data


def run_settings_of(folder: str | Path) -> dict[str, Any] | None:
    """The ``settings.json`` of a run folder (None for a run made before runs recorded their settings); a damaged
    one is a one-line ``ValueError``.

    :param folder: the run folder
    """
    path = Path(folder) / RUN_SETTINGS
    if not path.exists():
        return None
    try:
        data = json.loads(path.read_text())
        if not isinstance(data, dict) or not isinstance(data.get("settings"), dict) or not isinstance(data.get("run"), list):
            raise ValueError("not an object with 'settings' and 'run'")
    except (UnicodeDecodeError, ValueError) as error:
        raise ValueError(f"{path} is damaged ({error}); delete the run folder {path.parent} to run the run again") from None
    return data


def changed_entries(recorded: dict[str, Any] | None, current: dict[str, Any], where: str) -> list[str]:
    """The entries (environment ids) of a method's yaml whose content differs between what a study or run recorded
    (:func:`sb3_cic.study.settings_record.conf_file_record`) and the yaml a command reads now; entries only one of them has are
    not compared (a new environment changes no run), nor are comments.

    A record made before entries were recorded holds only the sha256 of the whole file. When that file was the
    package's default yaml and changed since, it cannot be told whether an entry did: a warning says so and nothing
    is refused (a package upgrade rewrites its yamls' comments). A ``--conf-file`` that changed is refused.

    :param recorded: the recorded ``conf_file`` (None: nothing recorded, nothing compared)
    :param current: the command's ``conf_file``
    :param where: the file the record is read from, for the warning
    """
    if not recorded:
        return []
    if "entries" in recorded:
        old = recorded["entries"]
        return sorted(key for key, digest in current["entries"].items() if old.get(key, digest) != digest)
    if recorded.get("sha256") == current["sha256"]:
        return []
    if recorded.get("file") is None and current["file"] is None:
        warnings.warn(f"{where} records the sha256 of the whole default yaml (made before its entries were recorded) "
                      "and the yaml changed since; whether an entry changed cannot be told. The runs of this command "
                      "use the yaml as it is now; compare its entries with the hyperparams of a run's result.json",
                      stacklevel=2)
        return []
    return ["(the whole file)"]


def check_run_settings(folder: str | Path, record: dict[str, Any]) -> None:
    """``ValueError`` (one line) if the run folder records other settings than ``record``, what a command would make
    it with (its settings and its yaml's sha256: ``settings.json``). A folder that records none is not checked.

    :param folder: the run folder
    :param record: what :func:`sb3_cic.study.settings_record.run_record` returns for the command's run
    """
    recorded = run_settings_of(folder)
    if recorded is None:
        return
    diff = {key: (recorded["settings"].get(key), value) for key, value in record["settings"].items()
            if recorded["settings"].get(key) != value}
    changed = changed_entries(recorded.get("conf_file"), record["conf_file"], f"{folder}/{RUN_SETTINGS}")
    if changed:
        diff[f"conf_file (entries {', '.join(changed)})"] = (recorded["conf_file"]["file"], record["conf_file"]["file"])
    if diff:
        raise ValueError(f"the run {folder} was made with other settings; (run, command): {diff}. "
                         "Use the run's settings or another folder")


def check_resume_settings(folder: str | Path, record: dict[str, Any]) -> None:
    """``ValueError`` (one line) if a run about to resume from its checkpoint was started with other run settings
    (threads, ``compile_update``, TF32, device: :func:`sb3_cic.study.settings_record.run_settings`) than the command's: the two
    halves of one run would be made differently. A run folder that records none is not checked.

    :param folder: the run folder
    :param record: what :func:`sb3_cic.study.settings_record.run_record` returns for the command's run
    """
    recorded = (run_settings_of(folder) or {}).get("run_settings")
    if not recorded:
        return
    diff = {key: (recorded.get(key), value) for key, value in record["run_settings"].items()
            if key in recorded and recorded[key] != value}
    if diff:
        raise ValueError(f"the run {folder} was started with other run settings, which change its numbers; (run, "
                         f"command): {diff}. Resume it with the run's (--num-threads, --compile, --tf32, --device), or "
                         f"delete its checkpoint.zip and progress.json to run it again from step 0")


def write_run_settings(folder: str | Path, record: dict[str, Any], overwrite: bool = False) -> None:
    """Record in the run folder the settings it is made with (once: a resumed run keeps its record).

    :param folder: the run folder
    :param record: :func:`sb3_cic.study.settings_record.run_record`
    :param overwrite: write it anew (a run that starts from step 0: its record is that of the process that runs it)
    """
    path = Path(folder) / RUN_SETTINGS
    if overwrite or not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        write_json(path, record)


def rebuild_study_record(study: str | Path) -> dict[str, Any] | None:
    """The ``study.json`` of a study that lost it, from its run folders' ``settings.json`` (None: no run folder,
    a new study); a one-line ``ValueError`` when a run folder records no settings or two disagree.

    :param study: study folder
    """
    marks = (RUN_SETTINGS, "result.json", "checkpoint.zip", "progress.json")  # what a run writes, settings first
    folders = [f for f in run_folders(study) if any((f / mark).exists() for mark in marks)]
    if not folders:
        return None
    data: dict[str, Any] = {"settings": {}, "conf_files": {}, "runs": []}
    for folder in folders:
        record = run_settings_of(folder)
        if record is None:
            raise ValueError(f"{study_file(study)} is missing and the run {folder} does not record its settings (made "
                             "before runs did): restore study.json from a copy, or use another folder")
        for key, value in record["settings"].items():
            if data["settings"].setdefault(key, value) != value:
                raise ValueError(f"{study_file(study)} is missing and its runs disagree on {key} "
                                 f"({data['settings'][key]!r}, {value!r} in {folder}): restore study.json from a copy")
        method = record["run"][0]
        data["conf_files"].setdefault(method, record["conf_file"])
        if record.get("pairing"):
            pairing = Pairing.from_record(record["pairing"])
            if Pairing.from_record(data) not in (None, pairing):
                raise ValueError(f"{study_file(study)} is missing and its runs disagree on the pairing ({folder}): "
                                 "restore study.json from a copy")
            data.update(record["pairing"])
        data["runs"].append(record["run"])
    data["runs"].sort(key=lambda r: (r[0], r[1], r[2] or "", r[3], r[4] or 0))
    return data


def study_record(study: str | Path) -> dict[str, Any] | None:
    """``study.json`` checked (:func:`read_study_record`), or rebuilt from the run folders when it is lost
    (:func:`rebuild_study_record`; not written); None for a folder with neither.

    :param study: study folder
    """
    return read_study_record(study) if study_file(study).exists() else rebuild_study_record(study)


# the lock ------------------------------------------------------------------------------------------------
#: what the lock of a command that reads pause requests says of it (a command of an older version does not)
PAUSABLE = "pausable: sb3-cic pause"


def _holder_said(file: IO[str]) -> str:
    """Who holds the lock, as its open lock ``file`` says (written by :class:`StudyLock`)."""
    file.seek(0)
    return file.read().strip() or "another process"


class StudyLock:
    """One driver per study folder: an exclusive ``flock`` on ``<study>/study.lock``, held while the command runs.

    The kernel releases the lock when its process ends, however it ends (a killed driver leaves no stuck lock).
    The file says who holds it (host, pid, start, and that it reads pause requests: :data:`PAUSABLE`), for the message
    of the command it refuses and for ``sb3-cic pause``. A folder the lock made and in which nothing else was
    written (the command was stopped at once) is removed when it is released.

    :param study: study folder
    """

    def __init__(self, study: str | Path) -> None:
        self.path = lock_file(study)
        self._file: IO[str] | None = None
        self._created = False

    @staticmethod
    def holder(study: str | Path) -> str | None:
        """Who drives ``study`` now (what its lock file says: host, pid, start), or None when no command holds its
        lock. Only probes: creates nothing, and a lock it takes for the probe is released at once.

        :param study: study folder
        """
        try:
            file = open(lock_file(study))
        except OSError:  # no lock file (never driven) or unreadable: nothing to say
            return None
        with file:
            try:
                fcntl.flock(file, fcntl.LOCK_SH | fcntl.LOCK_NB)
            except OSError:
                return _holder_said(file)
            fcntl.flock(file, fcntl.LOCK_UN)
        return None

    def __enter__(self) -> StudyLock:
        self._created = not self.path.parent.exists()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        file = open(self.path, "a+")
        try:
            try:
                fcntl.flock(file, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:  # once more: `sb3-cic status` probes the lock for an instant (:meth:`holder`)
                time.sleep(0.2)
                fcntl.flock(file, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = _holder_said(file)
            file.close()
            raise ValueError(f"another command drives {self.path.parent} ({holder}); wait for it to end or stop it "
                             "(a stopped command leaves no lock behind), then run this one again") from None
        file.seek(0)
        file.truncate()
        file.write(f"pid {os.getpid()} on {socket.gethostname()}, since {time.strftime('%Y-%m-%d %H:%M:%S')} "
                   f"({PAUSABLE})\n")
        file.flush()
        self._file = file
        return self

    def __exit__(self, *exc: Any) -> None:
        if self._file is None:
            return
        if self._created and [p.name for p in self.path.parent.iterdir()] == [self.path.name]:
            # a command stopped before it wrote anything (Ctrl-C at once) leaves no folder behind that is no study
            with contextlib.suppress(OSError):
                self.path.unlink(missing_ok=True)
                self.path.parent.rmdir()
        fcntl.flock(self._file, fcntl.LOCK_UN)
        self._file.close()
        self._file = None


# the pause -----------------------------------------------------------------------------------------------
def request_pause(study: str | Path) -> str:
    """Ask the command that drives ``study`` to pause (``sb3-cic pause``): each of its running runs checkpoints at
    its next episode end and stops, no other run starts, and the command ends (a run without checkpoints,
    ``--checkpoint-every 0``, runs to its end). Returns who drives it; a ``ValueError`` when no command does.

    :param study: study folder
    """
    holder = StudyLock.holder(study)
    if holder is None:
        raise ValueError(f"no command drives {study}: there is nothing to pause (sb3-cic status {study})")
    if PAUSABLE not in holder:
        raise ValueError(f"the command that drives {study} ({holder}) is of a version that does not read pause "
                         "requests: stop it with Ctrl-C or SIGTERM instead (each run keeps its last checkpoint)")
    write_json(pause_file(study), {"requested": time.strftime("%Y-%m-%d %H:%M:%S"), "by": f"pid {os.getpid()} on "
                                   f"{socket.gethostname()}", "driver": holder})
    return holder


def pause_requested(study: str | Path) -> str | None:
    """When the command driving ``study`` was asked to pause (None: it was not). Read by each run once an episode.

    :param study: study folder
    """
    try:
        request = json.loads(pause_file(study).read_text())
    except FileNotFoundError:
        return None
    except (OSError, ValueError):  # unreadable or damaged: a request all the same
        return "at an unknown time"
    return str(request.get("requested", "at an unknown time")) if isinstance(request, dict) else "at an unknown time"


def clear_pause(study: str | Path) -> None:
    """Forget a pause request: the command that drives ``study`` does when it starts (a request for an earlier
    command is not for it) and when it ends.

    :param study: study folder
    """
    pause_file(study).unlink(missing_ok=True)
