"""The URLB protocol: pre-train a method once on a domain, fine-tune it on the domain's tasks over seeds.

One study lives in one folder, laid out as :mod:`sb3_cic.study.layout` says (``study.json``, ``pretrain/``,
``finetune/``, ``tensorboard/``; a command with other settings than ``study.json``'s is refused). Every run
checkpoints itself at an episode boundary every ``checkpoint_every`` steps and, started again, resumes from
its last checkpoint (:mod:`sb3_cic.study.checkpoint`). DDPG ("from scratch") has no pre-training. A run whose ``result.json`` exists is
not run again; an unfinished one resumes. Hyperparameters come from ``zoo_configs/<method>.yml`` (read with rl_zoo3, see
:func:`sb3_cic.zoo.zoo_hyperparams`), with the small-scale options of :class:`Settings` on top.
Evaluation: :class:`~sb3_cic.callbacks.URLBEvalCallback` (deterministic episodes at step 0 and every
``eval_freq`` steps, plus one at the end if the schedule misses it; with the grid sweep, step 0 is evaluated
with the sweep's first candidate, as no skill is chosen yet); the final return is that of
the last evaluation, the normalised score ``return / expert`` (:data:`sb3_cic.constants.EXPERT_SCORES`).
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Sequence

import gymnasium as gym
import numpy as np
import torch as th
import yaml
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.utils import set_random_seed

from sb3_cic.envs.tasks import DOMAIN_TASKS
from sb3_cic import zoo
from sb3_cic.callbacks import SkillGridSweepCallback, URLBEvalCallback
from sb3_cic.common.fast_update import enable_tf32
from sb3_cic.common.progress import close_progress, progress_callback
from sb3_cic.common.resumable import ResumableCallback
from sb3_cic.common.arguments import RANGES, check_argument
from sb3_cic.constants import DEFAULT_SNAPSHOTS, EXPERT_SCORES
from sb3_cic.finetune import finetune_callbacks
from sb3_cic.parsers import add_pairing_arguments, add_settings_arguments, build_parser, settings_values  # noqa: F401  (protocol's command line)
from sb3_cic.study.checkpoint import RunCheckpointCallback, RunFolder, write_json
from sb3_cic.study.graph import build_graph, record_runs
from sb3_cic.study.record import (
    Pairing,
    StudyLock,
    changed_entries,
    check_resume_settings,
    check_run_settings,
    rebuild_study_record,
    resolve_pairing,
    study_record,
    write_run_settings,
)
from sb3_cic.study.layout import (
    check_snapshot,
    finetune_dir,
    pretrain_dir,
    run_label,
    snapshot_file,
    study_file,
    task_env_id,
    task_name,
)



@dataclass
class Settings:
    """Scale and evaluation settings of a protocol run (None: the yaml's value).

    :param hidden_dim: hidden width of actor, critic (and the reward networks that follow it)
    :param batch_size: minibatch size
    :param learning_starts: random steps before learning; the fine-tuning skill sweep lasts as long
    :param buffer_size: replay capacity
    :param pretrain_steps: pre-training steps (yaml: 2M)
    :param finetune_steps: fine-tuning steps (yaml: 100k)
    :param eval_freq: steps between evaluations (10,000)
    :param eval_episodes: episodes per evaluation (10)
    :param snapshots: pre-training steps at which a snapshot is saved (the final step always is)
    :param device: torch device
    :param num_threads: torch threads (None: torch's default)
    :param compile_update: compile each run's update step (``compile_update=True``; the same math to float rounding)
    :param tf32: TF32 matrix products on CUDA (:func:`~sb3_cic.common.fast_update.enable_tf32`)
    :param progress_bar: show progress: SB3's progress bar on a terminal, a line a minute elsewhere
    :param verbose: verbosity of the algorithms
    :param pretrain_checkpoint_every: steps between the checkpoints of a pre-training (0: none)
    :param finetune_checkpoint_every: steps between the checkpoints of a fine-tuning (0: none)
    """

    hidden_dim: int | None = None
    batch_size: int | None = None
    learning_starts: int | None = None
    buffer_size: int | None = None
    pretrain_steps: int | None = None
    finetune_steps: int | None = None
    eval_freq: int = 10_000
    eval_episodes: int = 10
    snapshots: tuple[int, ...] = DEFAULT_SNAPSHOTS
    device: str = "auto"
    num_threads: int | None = None
    compile_update: bool = False
    tf32: bool = False
    progress_bar: bool = False
    verbose: int = 0
    pretrain_checkpoint_every: int = 50_000
    finetune_checkpoint_every: int = 20_000

    #: the settings that make a study's results (recorded in ``study.json``); the others only say how it runs
    STUDY_KEYS: ClassVar[tuple[str, ...]] = (
        "hidden_dim", "batch_size", "learning_starts", "buffer_size", "pretrain_steps", "finetune_steps",
        "eval_freq", "eval_episodes", "snapshots",
    )
    #: the study settings only a pre-training (and the fine-tunings from it) uses; a run from scratch does not
    PRETRAIN_KEYS: ClassVar[tuple[str, ...]] = ("pretrain_steps", "snapshots")

    def __post_init__(self) -> None:
        """A ``ValueError`` naming the first setting out of its range (:data:`~sb3_cic.common.arguments.RANGES`)."""
        for key, value in asdict(self).items():
            for item in value if key == "snapshots" else [value]:
                if item is not None and key in RANGES:
                    check_argument(key, item)

    def study_settings(self, pretrained: bool = True) -> dict[str, Any]:
        """The settings recorded in ``study.json`` (:attr:`STUDY_KEYS`), as JSON values.

        :param pretrained: whether the runs pre-train (False: runs from scratch, without :attr:`PRETRAIN_KEYS`)
        """
        return {key: list(value) if isinstance(value, tuple) else value for key, value in asdict(self).items()
                if key in self.STUDY_KEYS and (pretrained or key not in self.PRETRAIN_KEYS)}

    def overrides(self, finetune: bool) -> dict[str, Any]:
        """Hyperparameter overrides for rl-zoo's reading of the yaml."""
        out: dict[str, Any] = {}
        for key in ("batch_size", "learning_starts", "buffer_size"):
            if getattr(self, key) is not None:
                out[key] = getattr(self, key)
        if self.hidden_dim is not None and not finetune:  # a fine-tuned model keeps its saved width
            out["policy_kwargs"] = {"hidden_dim": self.hidden_dim}
        if self.compile_update:
            out["compile_update"] = True
        return out


@dataclass
class FinetuneResult:
    """What ``result.json`` of a fine-tuning run holds."""

    method: str
    label: str
    domain: str
    task: str
    env_id: str
    seed: int
    from_scratch: bool
    snapshot_steps: int | None
    finetune_steps: int
    final_return: float
    final_normalized_score: float | None
    expert_score: float | None
    n_evaluations: int
    finetune_skill: list[float] | None
    #: the grid sweep's (candidate c, window return) pairs, when the skill was chosen by a sweep
    skill_sweep: list[list[float]] | None
    #: the step of the checkpoint the run resumed from (0: it ran uninterrupted)
    resumed_from_step: int = 0
    #: the seed of the pre-training it started from (None: from scratch)
    pretrain_seed: int | None = None
    #: the sha256 of the snapshot it started from (None: from scratch)
    snapshot_sha256: str | None = None
    #: the settings of the process that can change its numbers (:func:`run_settings`)
    run_settings: dict[str, Any] = field(default_factory=dict)
    wall_time_s: dict[str, float | None] = field(default_factory=dict)
    hyperparams: dict[str, str] = field(default_factory=dict)


def conf_file_record(method: str, config: str | Path | None = None) -> dict[str, Any]:
    """What ``study.json`` records of the yaml a method's runs read: the file as given (None: the default
    ``zoo_configs/<method>.yml``), the sha256 of its content and a sha256 of each entry as yaml reads it (anchors
    merged, comments dropped), which :func:`check_study_settings` compares: a new comment or a new environment's
    entry changes no run (:func:`~sb3_cic.study.record.changed_entries`).

    :param method: rl-zoo name of the method
    :param config: the ``--conf-file`` (None: the default)
    """
    path = Path(config) if config is not None else zoo.default_config(method)
    if not path.is_file():
        raise ValueError(f"no yaml file {path} (--conf-file)")
    table = yaml.safe_load(path.read_text()) or {}
    if not isinstance(table, dict):
        raise ValueError(f"{path} is not an rl-zoo yaml (a mapping of environment ids to hyperparameters)")
    entries = {str(key): hashlib.sha256(json.dumps(value, sort_keys=True, default=str).encode()).hexdigest()
               for key, value in table.items()}
    return {"file": None if config is None else str(config), "sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
            "entries": entries}


def check_study_settings(
    study: str | Path,
    settings: Settings,
    pairing: Pairing | int,
    pretrained: bool = True,
    configs: dict[str, str | Path | None] | None = None,
) -> dict[str, Any]:
    """The content of ``<study>/study.json`` (but its runs) once a command with these settings is recorded;
    ``ValueError`` if the folder holds other values of the settings the command's runs use.

    ``study.json`` holds the settings the study's runs used so far: the pre-training ones
    (:attr:`Settings.PRETRAIN_KEYS`, the pairing and its ``pretrain_seed``) once a run pre-trains, each method's yaml
    (:func:`conf_file_record`) once it ran. A command is checked against the recorded values of the settings its
    runs use, and adds those not recorded yet. A damaged ``study.json`` is refused; a lost one is rebuilt from the
    run folders (:func:`~sb3_cic.study.record.study_record`). Writes nothing (see :func:`record_study_settings`).

    :param study: study folder
    :param settings: the command's settings
    :param pairing: the command's pairing (an int: shared pre-training with that seed)
    :param pretrained: whether the command's runs pre-train (False: only runs from scratch, as DDPG's)
    :param configs: the yaml of each method of the command (None: the default ``zoo_configs/<method>.yml``);
        None: not checked
    """
    pairing = Pairing("shared", pairing) if isinstance(pairing, int) else pairing
    wanted: dict[str, Any] = {"settings": settings.study_settings(pretrained)}
    if pretrained:
        wanted.update(pairing.record())
    if configs:
        wanted["conf_files"] = {method: conf_file_record(method, config) for method, config in configs.items()}
    recorded = study_record(study)
    if recorded is None:  # a new study
        return wanted
    recorded = {key: recorded[key] for key in ("settings", "pretrain_seed", "pairing", "conf_files") if key in recorded}
    old_settings, old_confs = dict(recorded.get("settings", {})), dict(recorded.get("conf_files", {}))
    diff = {key: (old_settings[key], value) for key, value in wanted["settings"].items()
            if key in old_settings and old_settings[key] != value}
    old_pairing = Pairing.from_record(recorded)
    if pretrained and old_pairing is not None and old_pairing != pairing:
        if old_pairing.mode == pairing.mode:
            diff["pretrain_seed"] = (old_pairing.seed, pairing.seed)
        else:
            diff["pairing"] = (old_pairing.describe(), pairing.describe())
    for method, conf in wanted.get("conf_files", {}).items():
        changed = changed_entries(old_confs.get(method), conf, f"{study}/study.json ({method})")
        if changed:
            diff[f"conf_file of {method} (entries {', '.join(changed)})"] = (old_confs[method]["file"], conf["file"])
    if diff:
        raise ValueError(
            f"{study} was made with other settings; (study, command): {diff}. "
            "Use the study's settings or another folder"
        )
    merged = {**recorded, "settings": {**old_settings, **wanted["settings"]}}
    if pretrained and old_pairing is None:  # (a study made before pairing existed keeps its record as it is)
        merged.update(pairing.record())
    if old_confs or "conf_files" in wanted:
        merged["conf_files"] = {**old_confs, **wanted.get("conf_files", {})}
    return merged


def record_study_settings(
    study: str | Path,
    settings: Settings,
    pairing: Pairing | int,
    pretrained: bool = True,
    configs: dict[str, str | Path | None] | None = None,
) -> None:
    """Check (:func:`check_study_settings`, same arguments), then write into ``<study>/study.json`` the settings
    it does not record yet (its runs are kept; a lost ``study.json`` is written anew from the run folders)."""
    wanted = check_study_settings(study, settings, pairing, pretrained, configs)
    path = study_file(study)
    data = json.loads(path.read_text()) if path.exists() else (rebuild_study_record(study) or {})
    if {**data, **wanted} != data or not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        write_json(path, {**data, **wanted})


def run_record(
    row: list[Any], settings: Settings, from_scratch: bool, pairing: Pairing | None, config: str | Path | None = None
) -> dict[str, Any]:
    """What a run folder records of the settings it is made with (``settings.json``,
    :func:`~sb3_cic.study.record.check_run_settings`): the run, the study settings it uses, its yaml, its pairing.

    :param row: the run as ``study.json`` lists it: ``[method, domain, task or None, seed, snapshot or None]``
    :param settings: the command's settings
    :param from_scratch: a run without pre-training (its record has no pre-training settings)
    :param pairing: the pairing of its pre-training (None: from scratch)
    :param config: the ``--conf-file`` (None: the default)
    """
    return {
        "run": list(row),
        "settings": settings.study_settings(pretrained=not from_scratch),
        "conf_file": conf_file_record(row[0], config),
        "pairing": None if from_scratch or pairing is None else pairing.record(),
        "run_settings": run_settings(settings),
    }


def run_settings(settings: Settings) -> dict[str, Any]:
    """The settings of the process that runs a run which can change its numbers though no study setting changes:
    torch's threads (the order of float sums), ``compile_update`` (float rounding), TF32 and the device. Recorded in
    each run folder (``settings.json``, ``result.json``); a run resumes only with the same
    (:func:`~sb3_cic.study.record.check_resume_settings`).

    :param settings: the command's settings (``num_threads`` None: torch's threads in this process)
    """
    from stable_baselines3.common.utils import get_device

    return {"num_threads": int(settings.num_threads or th.get_num_threads()), "compile_update": bool(settings.compile_update),
            "tf32": bool(settings.tf32), "device": get_device(settings.device).type}


def run_identity(record: dict[str, Any]) -> dict[str, Any]:
    """What a run's checkpoint records of the run it belongs to (:class:`~sb3_cic.study.checkpoint.RunFolder`): its
    row (method, domain, task, seed, snapshot) and the sha256 of its study settings and pairing.

    :param record: :func:`run_record`
    """
    digest = hashlib.sha256(json.dumps({"settings": record["settings"], "pairing": record["pairing"]}, sort_keys=True).encode())
    return {"run": list(record["run"]), "settings_sha256": digest.hexdigest()}


def file_sha256(path: str | Path) -> str:
    """The sha256 of a file's content (a snapshot's: what ties a fine-tuning to the pre-training it loaded)."""
    digest = hashlib.sha256()
    with open(path, "rb") as file:
        for block in iter(lambda: file.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def snapshot_steps(settings: Settings, steps: int) -> list[int]:
    """The steps at which a pre-training of ``steps`` steps saves a snapshot: the earlier of ``settings.snapshots``
    and the final step.

    :param settings: the run's settings
    :param steps: the pre-training's steps
    """
    return sorted({s for s in settings.snapshots if s < steps} | {steps})


def _check_run_inputs(
    study: str | Path,
    method: str,
    domain: str,
    tasks: Sequence[str],
    settings: Settings,
    snapshot: int | None,
    from_scratch: bool,
    config: str | Path | None,
) -> None:
    """``ValueError`` before anything is written if the runs of :func:`run_protocol` would stop on their input:
    a missing yaml or one without an entry for one of their envs, or a snapshot the pre-training does not save."""
    if config is not None and not Path(config).is_file():
        raise ValueError(f"no yaml file {config} (--conf-file)")
    overrides = settings.overrides(finetune=not from_scratch)
    for task in tasks:  # rl-zoo's ValueError for a missing entry
        hyperparams, _, n_timesteps, _ = zoo.zoo_hyperparams(method, task_env_id(domain, task), config, overrides)
        _check_learning_starts(settings, hyperparams, int(settings.finetune_steps or n_timesteps), "fine-tuning")
    if from_scratch:
        return
    env_id = f"URLB/{domain}-v0"
    hyperparams, _, n_timesteps, _ = zoo.zoo_hyperparams(method, env_id, config, settings.overrides(finetune=False))
    _check_learning_starts(settings, hyperparams, int(settings.pretrain_steps or n_timesteps), "pre-training")
    if snapshot is not None:
        pre_file = pretrain_dir(study, method, domain) / "result.json"
        if pre_file.exists():
            saved = sorted(int(k) for k in json.loads(pre_file.read_text())["snapshots"])
        else:
            saved = snapshot_steps(settings, int(settings.pretrain_steps or n_timesteps))
        if int(snapshot) not in saved:
            raise ValueError(f"no snapshot at {snapshot} steps: the pre-training saves {saved} (--snapshots)")


def _check_learning_starts(settings: Settings, hyperparams: dict[str, Any], steps: int, phase: str) -> None:
    """``ValueError`` when a ``learning_starts`` given in ``settings`` leaves a run of ``steps`` steps no update.

    :param settings: the command's settings
    :param hyperparams: the run's hyperparameters (the yaml's with the settings on top)
    :param steps: the run's steps
    :param phase: "pre-training" or "fine-tuning", for the message
    """
    learning_starts = hyperparams.get("learning_starts")
    if settings.learning_starts is not None and learning_starts is not None and learning_starts >= steps:
        raise ValueError(
            f"learning_starts {learning_starts} is not below the {phase}'s {steps} steps: it would never update "
            "(--learning-starts)"
        )


def check_learning_starts(runs: Sequence[Any], settings: Settings) -> None:
    """``ValueError`` before anything is written when the ``learning_starts`` of ``settings`` leaves one of ``runs``
    (:class:`~sb3_cic.study.run.Run`, the study's) no update; nothing to check when it is the yaml's.

    :param runs: the command's runs
    :param settings: the command's settings
    """
    if settings.learning_starts is None:
        return
    for method, domain, task in sorted({(run.method, run.domain, run.task) for run in runs}, key=str):
        from_scratch = not zoo.has_reward_module(zoo.get_algo(method))
        if task is None:
            env_id, steps, phase = f"URLB/{domain}-v0", settings.pretrain_steps, "pre-training"
        else:
            env_id, steps, phase = task_env_id(domain, task), settings.finetune_steps, "fine-tuning"
        overrides = settings.overrides(finetune=task is not None and not from_scratch)
        hyperparams, _, n_timesteps, _ = zoo.zoo_hyperparams(method, env_id, None, overrides)
        _check_learning_starts(settings, hyperparams, int(steps or n_timesteps), phase)


def _describe(hyperparams: dict[str, Any]) -> dict[str, str]:
    return {key: str(value) for key, value in sorted(hyperparams.items())}


def _set_threads(settings: Settings) -> None:
    if settings.num_threads:
        th.set_num_threads(settings.num_threads)
    if settings.tf32:
        enable_tf32()


class SnapshotCallback(ResumableCallback):
    """Save the model as ``snapshot_<steps>.zip`` when training reaches each of ``steps``.

    :param save_path: folder of the snapshots
    :param steps: the steps to save at
    :param verbose: verbosity
    """

    def __init__(self, save_path: str | Path, steps: Sequence[int], verbose: int = 0) -> None:
        super().__init__(verbose)
        self.save_path = Path(save_path)
        self.pending = sorted(set(int(s) for s in steps))
        self.saved: dict[int, str] = {}

    def _on_step(self) -> bool:
        while self.pending and self.num_timesteps >= self.pending[0]:
            step = self.pending.pop(0)
            path = snapshot_file(self.save_path, step)
            self.model.save(path)
            self.saved[step] = path.name
            if self.verbose:
                print(f"Saved snapshot {path}")
        return True

    def get_checkpoint_state(self) -> dict[str, Any]:
        return {"pending": list(self.pending), "saved": dict(self.saved)}

    def set_checkpoint_state(self, state: dict[str, Any]) -> None:
        self.pending, self.saved = list(state["pending"]), dict(state["saved"])


def pretrain(
    study: str | Path,
    method: str,
    domain: str,
    settings: Settings | None = None,
    seed: int = 0,
    config: str | Path | None = None,
    paired: bool = False,
) -> dict[str, Any]:
    """Pre-train ``method`` on ``URLB/<domain>-v0`` once (skipped if its ``result.json`` exists; an unfinished
    run resumes from its checkpoint, written every ``settings.pretrain_checkpoint_every`` steps).

    :param study: study folder
    :param method: rl-zoo name of an unsupervised method (``cic``...)
    :param domain: URLB domain
    :param settings: scale settings
    :param seed: pre-training seed
    :param config: yaml file (default ``zoo_configs/<method>.yml``)
    :param paired: one of a paired study's pre-trainings (one per seed, :func:`~sb3_cic.study.layout.pretrain_dir`);
        False: a shared-pre-training study's one pre-training
    :return: the pre-training ``result.json`` content
    """
    settings = settings or Settings()
    cls = zoo.get_algo(method)
    pairing = Pairing("paired") if paired else Pairing("shared", seed)
    record = run_record([method, domain, None, seed, None], settings, False, pairing, config)
    folder = RunFolder(pretrain_dir(study, method, domain, seed if paired else None), identity=run_identity(record))
    check_run_settings(folder.path, record)
    if folder.done:
        folder.clean()  # what a run killed just after writing result.json left
        return json.loads(folder.result.read_text())
    checkpoint = folder.read_meta()  # a ValueError for a corrupt or missing checkpoint (or another run's), before any work
    if checkpoint:
        check_resume_settings(folder.path, record)
    write_run_settings(folder.path, record, overwrite=not checkpoint)
    _set_threads(settings)
    env_id = f"URLB/{domain}-v0"
    hyperparams, _, n_timesteps, _ = zoo.zoo_hyperparams(method, env_id, config, settings.overrides(finetune=False))
    hyperparams.pop("env_wrapper", None)
    steps = int(settings.pretrain_steps or n_timesteps)
    common = {"device": settings.device, "verbose": settings.verbose, "tensorboard_log": str(Path(study) / "tensorboard")}
    set_random_seed(seed)
    if checkpoint:
        model = folder.load_model(cls, env_id, **common)
    else:
        model = cls(env=env_id, seed=seed, **common, **hyperparams)
    snapshots = SnapshotCallback(folder.path, snapshot_steps(settings, steps), settings.verbose)
    wall = _train(model, folder, checkpoint, steps, [snapshots], settings.pretrain_checkpoint_every, settings,
                  f"pretrain_{method}_{domain}", f"pretrain {method} {domain} seed {seed}")
    result = {
        "method": method,
        "domain": domain,
        "env_id": env_id,
        "seed": seed,
        "steps": steps,
        "snapshots": snapshots.saved,
        "snapshot_sha256": {str(step): file_sha256(folder.path / name) for step, name in snapshots.saved.items()},
        "resumed_from_step": checkpoint["step"] if checkpoint else 0,
        "run_settings": record["run_settings"],
        "wall_time_s": {"pretrain": wall},
        "hyperparams": _describe(hyperparams),
    }
    folder.finish(result)
    return result


def _train(
    model: Any,
    folder: RunFolder,
    checkpoint: dict[str, Any] | None,
    steps: int,
    callbacks: list[Any],
    checkpoint_every: int,
    settings: Settings,
    tb_log_name: str,
    label: str = "run",
) -> float:
    """Train ``model`` to ``steps`` with ``callbacks`` and checkpoints, resuming from ``checkpoint`` (one line says
    so); return the run's training seconds (before and after a resume). Progress (``settings.progress_bar``) is a
    bar on a terminal, a line a minute elsewhere (:func:`~sb3_cic.common.progress.progress_callback`).

    :param label: the run, for the resume and progress lines (``"pretrain cic walker seed 0"``)
    """
    folder.start(checkpoint["step"] if checkpoint else 0)
    if checkpoint:
        print(f"{label}: resumed from its checkpoint at step {checkpoint['step']:,} of {steps:,}", flush=True)
        folder.restore(model, callbacks)  # last: the random states as the checkpoint saved them
    checkpointer = RunCheckpointCallback(folder, checkpoint_every, callbacks, checkpoint["elapsed_s"] if checkpoint else 0.0)
    progress = progress_callback(label, steps, settings.progress_bar)
    try:
        model.learn(
            steps - model.num_timesteps,
            callback=[*callbacks, checkpointer, *([progress] if progress is not None else [])],
            tb_log_name=tb_log_name,
            reset_num_timesteps=not checkpoint,
        )
    finally:
        close_progress(progress)
    return checkpointer.elapsed()


def evaluation_callback(env_id: str, task: str | None, seed: int, n_eval_episodes: int, eval_freq: int) -> URLBEvalCallback:
    """The evaluation of a fine-tuning run: a Monitor-wrapped ``env_id`` seeded ``10_000 + seed``, silent.

    :param task: URLB task name for the normalised score (None: none)
    """
    eval_env = Monitor(gym.make(env_id))
    eval_env.reset(seed=10_000 + seed)
    return URLBEvalCallback(eval_env, task=task, n_eval_episodes=n_eval_episodes, eval_freq=eval_freq, verbose=0)


def finetune(
    study: str | Path,
    method: str,
    domain: str,
    task: str,
    seed: int,
    settings: Settings | None = None,
    snapshot: int | None = None,
    from_scratch: bool | None = None,
    config: str | Path | None = None,
    paired: bool = False,
) -> dict[str, Any]:
    """One fine-tuning run (or a from-scratch run for DDPG), skipped if its ``result.json`` exists; an unfinished
    run resumes from its checkpoint (written every ``settings.finetune_checkpoint_every`` steps).

    :param study: study folder (the pre-training must be done unless ``from_scratch``)
    :param method: rl-zoo name of the method
    :param domain: URLB domain
    :param task: task (``flip`` or ``walker_flip``)
    :param seed: seed of the run
    :param settings: scale and evaluation settings
    :param snapshot: pre-training step of the snapshot to start from (None: the final one)
    :param from_scratch: no pre-training (default: True for ``ddpg``)
    :param config: yaml file (default ``zoo_configs/<method>.yml``)
    :param paired: start from the pre-training of seed ``seed`` (a paired study); False: from the study's one
        shared pre-training
    :return: the run's ``result.json`` content
    """
    settings = settings or Settings()
    cls = zoo.get_algo(method)
    from_scratch = (not zoo.has_reward_module(cls)) if from_scratch is None else from_scratch
    name, env_id = task_name(domain, task), task_env_id(domain, task)
    pre: dict[str, Any] | None = None
    label, pairing = method, None
    pre_dir = pretrain_dir(study, method, domain, seed if paired else None)
    if not from_scratch:
        pre_file = pre_dir / "result.json"
        if not pre_file.exists():
            raise FileNotFoundError(f"pre-train {method} on {domain} first ({pre_file} is missing)")
        pre = json.loads(pre_file.read_text())
        snapshot = int(pre["steps"]) if snapshot is None else int(snapshot)
        if str(snapshot) not in {str(k) for k in pre["snapshots"]}:
            raise ValueError(f"no snapshot at {snapshot} steps; saved: {sorted(int(k) for k in pre['snapshots'])}")
        label = run_label(method, None if snapshot == int(pre["steps"]) else snapshot)
        pairing = Pairing("paired") if paired else Pairing("shared", int(pre["seed"]))
    record = run_record([method, domain, name, seed, None if label == method else snapshot], settings, from_scratch,
                        pairing, config)
    folder = RunFolder(finetune_dir(study, label, name, seed), identity=run_identity(record))
    check_run_settings(folder.path, record)
    if folder.done:
        folder.clean()  # what a run killed just after writing result.json left
        return json.loads(folder.result.read_text())
    snapshot_path = snapshot_file(pre_dir, snapshot)
    snapshot_sha256 = None if from_scratch else check_pretraining(pre_dir, pre, snapshot, seed if paired else None)
    checkpoint = folder.read_meta()  # a ValueError for a corrupt or missing checkpoint (or another run's), before any work
    if checkpoint:
        check_resume_settings(folder.path, record)
    write_run_settings(folder.path, record, overwrite=not checkpoint)
    _set_threads(settings)

    overrides = settings.overrides(finetune=not from_scratch)
    config = config or zoo.default_config(method)
    # the yaml's callbacks minus its URLBEvalCallback (ours is below), the sweep as long as learning_starts
    overrides = zoo.zoo_overrides(config, env_id, overrides, drop_eval=True)
    hyperparams, callbacks, n_timesteps, _ = zoo.zoo_hyperparams(method, env_id, config, overrides)
    hyperparams.pop("env_wrapper", None)
    steps = int(settings.finetune_steps or n_timesteps)
    common = {"device": settings.device, "verbose": settings.verbose, "tensorboard_log": str(Path(study) / "tensorboard")}
    set_random_seed(seed)
    if checkpoint:
        model = folder.load_model(cls, env_id, **common)
    elif from_scratch:
        model = cls(env=env_id, seed=seed, **common, **hyperparams)
    else:
        kwargs = {k: v for k, v in hyperparams.items() if k not in ("policy", "policy_kwargs")}
        model = cls.load_pretrained(snapshot_path, env_id, seed=seed, **common, **kwargs)
    callbacks = finetune_callbacks(model, callbacks)  # what learn() would add; kept here to record the sweep
    for callback in callbacks:  # the sweep lasts learning_starts steps (also when the yaml sets neither)
        if isinstance(callback, SkillGridSweepCallback):
            callback.sweep_steps = model.learning_starts

    expert = EXPERT_SCORES.get(name)
    evaluation = evaluation_callback(env_id, name if expert else None, seed, settings.eval_episodes, settings.eval_freq)
    wall = _train(model, folder, checkpoint, steps, [*callbacks, evaluation], settings.finetune_checkpoint_every, settings,
                  f"finetune_{label}_{name}_seed{seed}", f"{label} {name} seed {seed}")
    if not evaluation.history or evaluation.history[-1][0] != model.num_timesteps:
        start = time.perf_counter()
        evaluation._evaluate()  # the final evaluation
        wall += time.perf_counter() - start
    evaluation.eval_env.close()

    with open(folder.path / "eval.csv", "w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(["timestep", "mean_return", "normalized_score"])
        for step, ret, score in evaluation.history:
            writer.writerow([step, ret, "" if math.isnan(score) else score])
    final_step, final_return, final_score = evaluation.history[-1]
    skill = getattr(model, "finetune_skill", None)
    sweep = next((c.results for c in callbacks if isinstance(c, SkillGridSweepCallback)), None)
    result = FinetuneResult(
        method=method,
        label=label,
        domain=domain,
        task=name,
        env_id=env_id,
        seed=seed,
        from_scratch=from_scratch,
        snapshot_steps=snapshot,
        finetune_steps=steps,
        final_return=float(final_return),
        final_normalized_score=None if math.isnan(final_score) else float(final_score),
        expert_score=expert,
        n_evaluations=len(evaluation.history),
        finetune_skill=None if skill is None else [float(v) for v in np.asarray(skill)],
        skill_sweep=None if sweep is None else [[float(np.mean(z)), float(ret)] for z, ret in sweep],
        resumed_from_step=checkpoint["step"] if checkpoint else 0,
        pretrain_seed=None if pre is None else int(pre["seed"]),
        snapshot_sha256=snapshot_sha256,
        run_settings=record["run_settings"],
        wall_time_s={"finetune": wall, "pretrain": None if pre is None else pre["wall_time_s"]["pretrain"]},
        hyperparams=_describe({**hyperparams, "policy_kwargs": model.policy_kwargs}),
    )
    folder.finish(asdict(result))
    return asdict(result)


def check_pretraining(folder: Path, pre: dict[str, Any], step: int, seed: int | None) -> str:
    """The sha256 of the snapshot at ``step`` of the pre-training in ``folder`` (its ``result.json``: ``pre``), which
    a fine-tuning is about to load; a one-line ``ValueError`` when the snapshot is unreadable, when its content is
    not the one the pre-training recorded (a snapshot copied over it), or when the pre-training is not of ``seed``.

    :param folder: the pre-training folder
    :param pre: its ``result.json``
    :param step: the snapshot's step
    :param seed: the pre-training seed the fine-tuning must start from (None: the study's shared one, not checked)
    """
    path = snapshot_file(folder, step)
    check_snapshot(path)
    if seed is not None and int(pre["seed"]) != seed:
        raise ValueError(f"{folder / 'result.json'} is the pre-training of seed {pre['seed']}, not of seed {seed}: it was "
                         f"copied; delete {folder} to pre-train seed {seed} again")
    digest = file_sha256(path)
    recorded = (pre.get("snapshot_sha256") or {}).get(str(step))
    if recorded is not None and recorded != digest:
        raise ValueError(f"the snapshot {path} is not the one its pre-training saved (sha256 {digest[:12]}..., "
                         f"{folder / 'result.json'} records {recorded[:12]}...): it was replaced; restore it, or delete "
                         f"{folder} to pre-train again")
    return digest


def run_protocol(
    study: str | Path,
    method: str,
    domain: str,
    tasks: Sequence[str] | None = None,
    seeds: Sequence[int] = tuple(range(10)),
    settings: Settings | None = None,
    snapshot: int | None = None,
    from_scratch: bool | None = None,
    pretrain_seed: int | None = None,
    config: str | Path | None = None,
    pairing: str | None = None,
) -> list[dict[str, Any]]:
    """Run the URLB protocol for one method and domain: pre-train, fine-tune on tasks x seeds.

    Paired (URLB's, the default of a new study): one pre-training per seed, fine-tuning seed s from pre-training
    seed s. Shared (the CIC code's): one pre-training, of seed ``pretrain_seed``, for every fine-tuning seed. A
    study keeps its pairing (:func:`~sb3_cic.study.record.resolve_pairing`). Finished runs (``result.json`` present)
    are not run again, so an interrupted study resumes. One command drives a study folder at a time
    (:class:`~sb3_cic.study.record.StudyLock`).

    :param study: study folder
    :param method: rl-zoo name of the method (``ddpg`` trains from scratch)
    :param domain: URLB domain
    :param tasks: tasks (``flip`` or ``walker_flip``; default: all of the domain)
    :param seeds: fine-tuning seeds
    :param settings: scale and evaluation settings
    :param snapshot: snapshot to fine-tune from (default: the final one)
    :param from_scratch: no pre-training (default: True for ``ddpg``)
    :param pretrain_seed: seed of shared pre-training (given alone: ``pairing="shared"``)
    :param config: yaml file (default ``zoo_configs/<method>.yml``)
    :param pairing: ``paired``, ``shared`` or None (the study's; a new study: ``paired``)
    :return: the fine-tuning results
    """
    settings = settings or Settings()
    method = method.lower()
    cls = zoo.get_algo(method)
    from_scratch = (not zoo.has_reward_module(cls)) if from_scratch is None else from_scratch
    if domain not in DOMAIN_TASKS:
        raise ValueError(f"unknown domain {domain!r}; known: {sorted(DOMAIN_TASKS)}")
    for task in tasks or ():
        task_env_id(domain, task)  # a ValueError for an unknown task
    chosen = resolve_pairing(study, pairing, pretrain_seed)
    _check_run_inputs(study, method, domain, tasks or DOMAIN_TASKS[domain], settings, snapshot, from_scratch, config)
    check_study_settings(study, settings, chosen, pretrained=not from_scratch, configs={method: config})
    with StudyLock(study):
        record_study_settings(study, settings, chosen, pretrained=not from_scratch, configs={method: config})
        if snapshot is None and from_scratch != zoo.has_reward_module(cls):  # the study's layout: listed for ``status``
            record_runs(study, build_graph([method], [domain], tasks, seeds, chosen))
        if not from_scratch:
            for seed in sorted({chosen.pretrain_seed(s) for s in seeds}):
                pretrain(study, method, domain, settings, seed=seed, config=config, paired=chosen.paired)
        results = []
        for task in tasks or DOMAIN_TASKS[domain]:
            for seed in seeds:
                results.append(finetune(study, method, domain, task, seed, settings, snapshot, from_scratch, config,
                                        paired=chosen.paired))
    return results


def settings_from_args(args: argparse.Namespace) -> Settings:
    """The :class:`Settings` of the options of :func:`~sb3_cic.parsers.add_settings_arguments` (a ``ValueError``
    naming the options that do not go together, see :func:`~sb3_cic.parsers.settings_values`)."""
    return Settings(**settings_values(args))


def main(argv: Sequence[str] | None = None) -> list[dict[str, Any]]:
    """``sb3-cic protocol``."""
    args = build_parser().parse_args(argv)
    settings = settings_from_args(args)
    results = run_protocol(
        args.study,
        args.method,
        args.domain,
        tasks=args.tasks,
        seeds=args.seeds,
        settings=settings,
        snapshot=args.snapshot,
        from_scratch=args.from_scratch,
        pretrain_seed=args.pretrain_seed,
        config=args.conf_file,
        pairing=args.pairing,
    )
    print(f"{len(results)} fine-tuning runs in {Path(args.study) / 'finetune'}; report: sb3-cic report {args.study}")
    return results
