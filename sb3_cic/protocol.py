"""The runs of the URLB protocol: one pre-training (:func:`pretrain`) and one fine-tuning (:func:`finetune`).

A run is a :class:`~sb3_cic.study.run.Run` of a study folder, laid out as :mod:`sb3_cic.study.layout` says; the
study's driver (:mod:`sb3_cic.study.driver`) checks and records the study, then runs its runs in this process
(``sb3-cic protocol``) or as Ray tasks (``sb3-cic study``). Every run checkpoints itself at an episode boundary
every ``checkpoint_every`` steps and, started again, resumes from its last checkpoint
(:mod:`sb3_cic.study.checkpoint`). DDPG ("from scratch") has no pre-training. A run whose ``result.json`` exists
is not run again; an unfinished one resumes. Hyperparameters come from ``zoo_configs/<method>.yml`` or the
method's ``--conf-file`` (read with rl_zoo3, see :func:`sb3_cic.zoo.zoo_hyperparams`), with the small-scale
options of :class:`~sb3_cic.study.settings.Settings` on top.
Evaluation: :class:`~sb3_cic.callbacks.URLBEvalCallback` (deterministic episodes at step 0 and every
``eval_freq`` steps, plus one at the end if the schedule misses it; with the grid sweep, step 0 is evaluated
with the sweep's first candidate, as no skill is chosen yet); the final return is that of
the last evaluation, the normalised score ``return / expert`` (:data:`sb3_cic.constants.EXPERT_SCORES`).
"""

from __future__ import annotations

import csv
import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Callable

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.utils import set_random_seed

from sb3_cic import zoo
from sb3_cic.callbacks import SkillGridSweepCallback, SkillSelectionCallback, URLBEvalCallback
from sb3_cic.common.fast_update import enable_tf32
from sb3_cic.common.progress import close_progress, progress_callback
from sb3_cic.common.resumable import RunCheckpointCallback, RunPaused
from sb3_cic.constants import EXPERT_SCORES
from sb3_cic.finetune import finetune_callbacks
from sb3_cic.study.checkpoint import RunFolder
from sb3_cic.study.layout import pretrain_dir, snapshot_file, task_env_id, task_name
from sb3_cic.study.record import Pairing, check_resume_settings, check_run_settings, pause_requested, write_run_settings
from sb3_cic.study.run import Run
from sb3_cic.study.run_result import FinetuneResult
from sb3_cic.study.settings import Settings
from sb3_cic.study.settings_record import run_identity, run_record
from sb3_cic.study.snapshots import SnapshotCallback, check_pretraining, file_sha256, snapshot_steps


@dataclass
class RunStart:
    """A run about to train: its folder, the settings it records and the checkpoint it resumes from.

    :param folder: the run folder
    :param record: what the folder records of the run (:func:`~sb3_cic.study.settings_record.run_record`)
    :param checkpoint: the checkpoint's meta (None: the run starts at step 0)
    """

    folder: RunFolder
    record: dict[str, Any]
    checkpoint: dict[str, Any] | None

    @property
    def step(self) -> int:
        """The step the run starts from."""
        return self.checkpoint["step"] if self.checkpoint else 0


def open_run(study: str | Path, run: Run, settings: Settings, config: str | Path | None, pairing: Pairing | None) -> RunStart:
    """The run folder of ``run`` with what it records; a ``ValueError`` if the folder records other settings
    (:func:`~sb3_cic.study.record.check_run_settings`). Writes nothing: :func:`start_run` does, once the run's
    inputs are checked.

    :param study: study folder
    :param run: the run
    :param settings: the study's settings
    :param config: the method's yaml (None: the default ``zoo_configs/<method>.yml``)
    :param pairing: the pairing of its pre-training (None: from scratch)
    """
    record = run_record(run.row(), settings, run.task is not None and run.from_scratch, pairing, config)
    folder = RunFolder(run.folder(study), identity=run_identity(record))
    check_run_settings(folder.path, record)
    return RunStart(folder, record, None)


def start_run(start: RunStart, settings: Settings) -> RunStart:
    """Read the checkpoint the run resumes from (a ``ValueError`` for a corrupt or missing one, another run's, or one
    made with other run settings), write the run's ``settings.json`` and set this process's threads and TF32.

    :param start: :func:`open_run`'s
    :param settings: the study's settings
    """
    checkpoint = start.folder.read_meta()
    if checkpoint:
        check_resume_settings(start.folder.path, start.record)
    write_run_settings(start.folder.path, start.record, overwrite=not checkpoint)
    if settings.num_threads:
        th.set_num_threads(settings.num_threads)
    if settings.tf32:
        enable_tf32()
    return RunStart(start.folder, start.record, checkpoint)


def done_result(start: RunStart) -> dict[str, Any] | None:
    """The ``result.json`` of a finished run (what a run killed just after writing it left is deleted); None when
    the run is not finished."""
    if not start.folder.done:
        return None
    start.folder.clean()
    return json.loads(start.folder.result.read_text())


def model_kwargs(study: str | Path, settings: Settings) -> dict[str, Any]:
    """The arguments every run's model is made (or loaded) with: device, verbosity, the study's TensorBoard folder."""
    return {"device": settings.device, "verbose": settings.verbose, "tensorboard_log": str(Path(study) / "tensorboard")}


def pretrain(study: str | Path, run: Run, settings: Settings, config: str | Path | None = None) -> dict[str, Any]:
    """Pre-train ``run.method`` on ``URLB/<domain>-v0`` once (skipped if its ``result.json`` exists; an unfinished
    run resumes from its checkpoint, written every ``settings.pretrain_checkpoint_every`` steps).

    :param study: study folder
    :param run: the pre-training (``task`` None; ``shared``: a shared-pre-training study's one pre-training)
    :param settings: the study's settings
    :param config: the method's yaml (None: the default ``zoo_configs/<method>.yml``)
    :return: the pre-training ``result.json`` content
    """
    cls = zoo.get_algo(run.method)
    start = open_run(study, run, settings, config, Pairing("shared", run.seed) if run.shared else Pairing("paired"))
    done = done_result(start)
    if done is not None:
        return done
    start = start_run(start, settings)
    env_id = f"URLB/{run.domain}-v0"
    hyperparams, _, n_timesteps, _ = zoo.zoo_hyperparams(run.method, env_id, config, settings.overrides(finetune=False))
    hyperparams.pop("env_wrapper", None)
    steps = int(settings.pretrain_steps or n_timesteps)
    set_random_seed(run.seed)
    if start.checkpoint:
        model = start.folder.load_model(cls, env_id, **model_kwargs(study, settings))
    else:
        model = cls(env=env_id, seed=run.seed, **model_kwargs(study, settings), **hyperparams)
    snapshots = SnapshotCallback(start.folder.path, snapshot_steps(settings, steps), settings.verbose)
    wall = train(model, start, steps, [snapshots], settings.pretrain_checkpoint_every, settings,
                 f"pretrain_{run.method}_{run.domain}", f"pretrain {run.method} {run.domain} seed {run.seed}",
                 pause_check(study))
    result = {
        "method": run.method,
        "domain": run.domain,
        "env_id": env_id,
        "seed": run.seed,
        "steps": steps,
        "snapshots": snapshots.saved,
        "snapshot_sha256": {str(step): file_sha256(start.folder.path / name) for step, name in snapshots.saved.items()},
        "resumed_from_step": start.step,
        "run_settings": start.record["run_settings"],
        "wall_time_s": {"pretrain": wall},
        "hyperparams": _describe(hyperparams),
    }
    start.folder.finish(result)
    return result


def pause_check(study: str | Path) -> Callable[[], bool]:
    """Whether the command driving ``study`` was asked to pause (:func:`~sb3_cic.study.record.request_pause`), asked
    by a run once an episode."""
    return lambda: pause_requested(study) is not None


def train(
    model: Any, start: RunStart, steps: int, callbacks: list[Any], checkpoint_every: int, settings: Settings,
    tb_log_name: str, label: str = "run", pause: Callable[[], bool] | None = None,
) -> float:
    """Train ``model`` to ``steps`` with ``callbacks`` and checkpoints, resuming from ``start.checkpoint`` (one line
    says so); return the run's training seconds (before and after a resume). Progress (``settings.progress_bar``)
    is a bar on a terminal, a line a minute elsewhere (:func:`~sb3_cic.common.progress.progress_callback`).

    :param label: the run, for the resume and progress lines (``"pretrain cic walker seed 0"``)
    :param pause: asked at each episode's end: when True, the run checkpoints there and raises
        :class:`~sb3_cic.common.resumable.RunPaused` (:meth:`~sb3_cic.study.checkpoint.RunFolder.pause` recorded)
    """
    folder, checkpoint = start.folder, start.checkpoint
    folder.start(start.step)
    if checkpoint:
        print(f"{label}: resumed from its checkpoint at step {checkpoint['step']:,} of {steps:,}", flush=True)
        folder.restore(model, callbacks)  # last: the random states as the checkpoint saved them
    checkpointer = RunCheckpointCallback(folder, checkpoint_every, callbacks, checkpoint["elapsed_s"] if checkpoint else 0.0,
                                         pause)
    progress = progress_callback(label, steps, settings.progress_bar)
    try:
        model.learn(
            steps - model.num_timesteps,
            callback=[*callbacks, checkpointer, *([progress] if progress is not None else [])],
            tb_log_name=tb_log_name,
            reset_num_timesteps=not checkpoint,
        )
    except RunPaused as paused:
        folder.pause(paused.step)
        model.logger.close()  # its TensorBoard events written out: the process may live on (a Ray worker)
        kept = "its checkpoint" if paused.step else "nothing done to keep"
        print(f"{label}: paused at step {paused.step:,} of {steps:,} ({kept})", flush=True)
        raise
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


@dataclass
class Origin:
    """Where a fine-tuning starts: the pre-training it loads (all None: from scratch).

    :param folder: the pre-training folder
    :param result: its ``result.json``
    :param snapshot: the step of the snapshot it loads
    :param snapshot_sha256: the snapshot's sha256 (:func:`check_pretraining`)
    """

    folder: Path | None = None
    result: dict[str, Any] | None = None
    snapshot: int | None = None
    snapshot_sha256: str | None = None
    #: the pairing of the pre-training (None: from scratch)
    pairing: Pairing | None = None


def origin_of(study: str | Path, run: Run) -> Origin:
    """The pre-training a fine-tuning ``run`` starts from, read from its folder; a ``FileNotFoundError`` when it is
    not done, a ``ValueError`` when it saved no snapshot at ``run.snapshot`` (None: its final one)."""
    if run.from_scratch:
        return Origin()
    folder = pretrain_dir(study, run.method, run.domain, None if run.shared else run.seed)
    pre_file = folder / "result.json"
    if not pre_file.exists():
        raise FileNotFoundError(f"pre-train {run.method} on {run.domain} first ({pre_file} is missing)")
    pre = json.loads(pre_file.read_text())
    snapshot = int(pre["steps"]) if run.snapshot is None else int(run.snapshot)
    if str(snapshot) not in {str(k) for k in pre["snapshots"]}:
        raise ValueError(f"no snapshot at {snapshot} steps; saved: {sorted(int(k) for k in pre['snapshots'])}")
    return Origin(folder, pre, snapshot, pairing=Pairing("shared", int(pre["seed"])) if run.shared else Pairing("paired"))


def finetune(study: str | Path, run: Run, settings: Settings, config: str | Path | None = None) -> dict[str, Any]:
    """One fine-tuning run (or a from-scratch run for DDPG), skipped if its ``result.json`` exists; an unfinished
    run resumes from its checkpoint (written every ``settings.finetune_checkpoint_every`` steps).

    :param study: study folder (the run's pre-training must be done unless it runs from scratch)
    :param run: the fine-tuning (``snapshot`` None: from the pre-training's final snapshot; ``shared``: from the
        study's one shared pre-training, else from the pre-training of its own seed)
    :param settings: the study's settings
    :param config: the method's yaml (None: the default ``zoo_configs/<method>.yml``)
    :return: the run's ``result.json`` content
    """
    origin = origin_of(study, run)
    start = open_run(study, run, settings, config, origin.pairing)
    done = done_result(start)
    if done is not None:
        return done
    if origin.folder is not None:
        origin.snapshot_sha256 = check_pretraining(origin.folder, origin.result, origin.snapshot,
                                                   None if run.shared else run.seed)
    start = start_run(start, settings)
    model, callbacks, hyperparams, steps = build_finetune_model(study, run, settings, config, start, origin)
    name = task_name(run.domain, run.task)
    expert = EXPERT_SCORES.get(name)
    evaluation = evaluation_callback(task_env_id(run.domain, run.task), name if expert else None, run.seed,
                                     settings.eval_episodes, settings.eval_freq)
    try:
        wall = train(model, start, steps, [*callbacks, evaluation], settings.finetune_checkpoint_every, settings,
                     f"finetune_{run.label}_{name}_seed{run.seed}", f"{run.label} {name} seed {run.seed}",
                     pause_check(study))
    except RunPaused:
        evaluation.eval_env.close()
        raise
    if not evaluation.history or evaluation.history[-1][0] != model.num_timesteps:
        begin = time.perf_counter()
        evaluation._evaluate()  # the final evaluation
        wall += time.perf_counter() - begin
    evaluation.eval_env.close()
    return write_finetune_files(run, start, origin, model, callbacks, evaluation, steps, wall, hyperparams)


def build_finetune_model(
    study: str | Path, run: Run, settings: Settings, config: str | Path | None, start: RunStart, origin: Origin
) -> tuple[Any, list[Any], dict[str, Any], int]:
    """The model of a fine-tuning (loaded from its checkpoint, its pre-training's snapshot, or made from scratch),
    its callbacks (the yaml's but its ``URLBEvalCallback``, with the skill selection; the grid sweep lasts
    ``learning_starts`` steps), its hyperparameters and its steps.

    :param study: study folder
    :param run: the fine-tuning
    :param settings: the study's settings
    :param config: the method's yaml (None: the default)
    :param start: the run about to train (:func:`start_run`)
    :param origin: the pre-training it starts from (:func:`origin_of`)
    """
    cls = zoo.get_algo(run.method)
    env_id = task_env_id(run.domain, run.task)
    overrides = settings.overrides(finetune=not run.from_scratch)
    config = config or zoo.default_config(run.method)
    # the yaml's callbacks minus its URLBEvalCallback (ours is in finetune), the sweep as long as learning_starts
    overrides = zoo.zoo_overrides(config, env_id, overrides, drop_eval=True)
    hyperparams, callbacks, n_timesteps, _ = zoo.zoo_hyperparams(run.method, env_id, config, overrides)
    hyperparams.pop("env_wrapper", None)
    if run.skill_choice is not None:  # the run's choice instead of the yaml's (its selection callback added below)
        hyperparams["finetune_skill_choice"] = run.skill_choice
        callbacks = [callback for callback in callbacks if not isinstance(callback, SkillSelectionCallback)]
    steps = int(settings.finetune_steps or n_timesteps)
    common = model_kwargs(study, settings)
    set_random_seed(run.seed)
    if start.checkpoint:
        model = start.folder.load_model(cls, env_id, **common)
    elif origin.folder is None:
        model = cls(env=env_id, seed=run.seed, **common, **hyperparams)
    else:
        kwargs = {k: v for k, v in hyperparams.items() if k not in ("policy", "policy_kwargs")}
        model = cls.load_pretrained(snapshot_file(origin.folder, origin.snapshot), env_id, seed=run.seed, **common, **kwargs)
    callbacks = finetune_callbacks(model, callbacks)  # what learn() would add; kept here to record the sweep
    for callback in callbacks:  # the sweep lasts learning_starts steps (also when the yaml sets neither)
        if isinstance(callback, SkillGridSweepCallback):
            callback.sweep_steps = model.learning_starts
    return model, callbacks, hyperparams, steps


def write_finetune_files(
    run: Run, start: RunStart, origin: Origin, model: Any, callbacks: list[Any], evaluation: URLBEvalCallback,
    steps: int, wall: float, hyperparams: dict[str, Any],
) -> dict[str, Any]:
    """Write a finished fine-tuning's ``eval.csv`` (its evaluations) and ``result.json`` (:class:`~sb3_cic.study.run_result.FinetuneResult`);
    return the latter's content.

    :param run: the fine-tuning
    :param start: the run as it started (:func:`start_run`)
    :param origin: the pre-training it started from
    :param model: the trained model
    :param callbacks: its callbacks (the grid sweep's results are recorded)
    :param evaluation: its evaluation, with the final one
    :param steps: its steps
    :param wall: its training seconds
    :param hyperparams: its hyperparameters
    """
    with open(start.folder.path / "eval.csv", "w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(["timestep", "mean_return", "normalized_score"])
        for step, ret, score in evaluation.history:
            writer.writerow([step, ret, "" if math.isnan(score) else score])
    _, final_return, final_score = evaluation.history[-1]
    name = task_name(run.domain, run.task)
    skill = getattr(model, "finetune_skill", None)
    sweep = next((c.results for c in callbacks if isinstance(c, SkillGridSweepCallback)), None)
    pre = origin.result
    result = FinetuneResult(
        method=run.method,
        label=run.label,
        domain=run.domain,
        task=name,
        env_id=task_env_id(run.domain, run.task),
        seed=run.seed,
        from_scratch=run.from_scratch,
        snapshot_steps=origin.snapshot,
        finetune_steps=steps,
        final_return=float(final_return),
        final_normalized_score=None if math.isnan(final_score) else float(final_score),
        expert_score=EXPERT_SCORES.get(name),
        n_evaluations=len(evaluation.history),
        finetune_skill=None if skill is None else [float(v) for v in np.asarray(skill)],
        skill_sweep=None if sweep is None else [[float(np.mean(z)), float(ret)] for z, ret in sweep],
        finetune_skill_choice=None if skill is None else model.finetune_skill_choice,
        cic_variant=getattr(model, "cic_variant", None),
        resumed_from_step=start.step,
        pretrain_seed=None if pre is None else int(pre["seed"]),
        snapshot_sha256=origin.snapshot_sha256,
        run_settings=start.record["run_settings"],
        wall_time_s={"finetune": wall, "pretrain": None if pre is None else pre["wall_time_s"]["pretrain"]},
        hyperparams=_describe({**hyperparams, "policy_kwargs": model.policy_kwargs}),
    )
    start.folder.finish(asdict(result))
    return asdict(result)




def _describe(hyperparams: dict[str, Any]) -> dict[str, str]:
    return {key: str(value) for key, value in sorted(hyperparams.items())}
