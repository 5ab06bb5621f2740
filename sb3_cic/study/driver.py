"""The study driver: the runs of one command (``sb3-cic protocol`` or ``sb3-cic study``), checked against the study
folder, recorded, then run by an executor.

One chain for both commands (:func:`plan_study`): the job graph (:func:`~sb3_cic.study.graph.build_graph`), the
runs' inputs (each method's yaml and its entries, ``learning_starts``, the snapshot fine-tunings start from:
:func:`check_run_inputs`), the study's settings and each run folder's (:mod:`sb3_cic.study.settings`,
:mod:`sb3_cic.study.record`), the finished runs' results and the unfinished runs' checkpoints
(:func:`~sb3_cic.study.graph.check_study`): every bad input is a ``ValueError`` before anything is written or
run. :func:`drive` then records the command in ``study.json`` under the study's lock and hands the runs to an
executor: :class:`InProcess` (``sb3-cic protocol``: one run after the other in this process) or
:class:`~sb3_cic.study.engine.RayExecutor` (``sb3-cic study``: each run a Ray task).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, Sequence

from sb3_cic import zoo
from sb3_cic.common.resumable import RunPaused
from sb3_cic.protocol import finetune, pretrain
from sb3_cic.study.checkpoint import RunFolder
from sb3_cic.study.graph import build_graph, check_study, record_runs, settings_use, skill_choice_of
from sb3_cic.study.layout import task_env_id
from sb3_cic.study.record import (
    Pairing,
    StudyLock,
    check_resume_settings,
    check_run_settings,
    clear_pause,
    pause_requested,
    resolve_pairing,
)
from sb3_cic.study.run import Run
from sb3_cic.study.settings import Settings
from sb3_cic.study.settings_record import check_study_settings, record_study_settings, run_record
from sb3_cic.study.snapshots import snapshot_steps


@dataclass
class StudyPlan:
    """The checked runs of one command (:func:`plan_study`).

    :param study: study folder
    :param runs: the command's runs, each pre-training before its fine-tunings
    :param todo: those not finished yet
    :param pairing: the study's pairing
    :param settings: the command's settings
    :param conf_files: the yaml of each method (None: the default ``zoo_configs/<method>.yml``)
    """

    study: str | Path
    runs: list[Run]
    todo: list[Run]
    pairing: Pairing
    settings: Settings
    conf_files: dict[str, str | None] = field(default_factory=dict)

    def config(self, run: Run) -> str | None:
        """The yaml of ``run``'s method (None: the default)."""
        return self.conf_files.get(run.method)


class Executor(Protocol):
    """What runs a study's runs: :class:`InProcess` or :class:`~sb3_cic.study.engine.RayExecutor`."""

    def run_settings(self, settings: Settings) -> Settings:
        """The settings each run runs with (the threads of a Ray task...), as the resume check must see them."""

    def run(self, plan: StudyPlan) -> list[dict[str, Any]]:
        """Run the plan's runs; return what the command reports of them."""


class InProcess:
    """Run the runs one after the other in this process (``sb3-cic protocol``); a run that fails raises."""

    def run_settings(self, settings: Settings) -> Settings:
        """The settings as given (``num_threads`` None: torch's threads in this process)."""
        return settings

    def run(self, plan: StudyPlan) -> list[dict[str, Any]]:
        """Run every run of the plan (a finished one returns its result); return the fine-tunings' results. Asked to
        pause (:func:`~sb3_cic.study.record.request_pause`), the running run checkpoints at its episode's end and
        :class:`~sb3_cic.common.resumable.RunPaused` ends the command."""
        results = []
        for run in plan.runs:
            if pause_requested(plan.study) is not None:
                raise RunPaused()
            if run.task is None:
                pretrain(plan.study, run, plan.settings, plan.config(run))
            else:
                results.append(finetune(plan.study, run, plan.settings, plan.config(run)))
        return results


def plan_study(
    study: str | Path,
    methods: Sequence[str],
    domains: Sequence[str],
    tasks: Sequence[str] | None,
    seeds: Sequence[int],
    settings: Settings,
    executor: Executor,
    pairing: str | None = None,
    pretrain_seed: int | None = None,
    from_snapshot: int | None = None,
    conf_files: dict[str, str | Path | None] | None = None,
) -> StudyPlan:
    """The runs of a command, checked against the study folder before anything is written or run: a one-line
    ``ValueError`` for an unknown method, domain or task, bad seeds, a missing yaml or entry, a ``learning_starts``
    that leaves a run no update, a snapshot the pre-training does not save, a folder or a run folder made with
    other settings (another yaml, pairing...), a damaged ``study.json``, ``result.json`` or ``eval.csv``, a corrupt
    or lost checkpoint, a checkpoint made with other run settings than the executor's.

    :param study: study folder
    :param methods: rl-zoo names or ``["all"]``
    :param domains: URLB domains or ``["all"]``
    :param tasks: tasks (None: each domain's)
    :param seeds: fine-tuning seeds
    :param settings: the command's settings
    :param executor: what will run the runs (its :meth:`Executor.run_settings` for the resume check)
    :param pairing: ``paired``, ``shared`` or None: the study's (:func:`~sb3_cic.study.record.resolve_pairing`)
    :param pretrain_seed: seed of shared pre-training (given alone: ``pairing="shared"``)
    :param from_snapshot: fine-tune from the pre-training's snapshot at this step (None, or the final step: the
        final one); the runs are ``<method>@<step>``
    :param conf_files: the yaml of each method (missing or None: the default ``zoo_configs/<method>.yml``)
    """
    chosen = resolve_pairing(study, pairing, pretrain_seed)
    runs = build_graph(methods, domains, tasks, seeds, chosen, from_snapshot)
    configs = check_conf_files(runs, conf_files or {})
    runs = check_run_inputs(study, runs, settings, configs, from_snapshot)
    check_study_settings(study, settings, chosen, **settings_use(runs, configs))
    for run in runs:
        check_run_settings(run.folder(study), _record(run, settings, chosen, configs))
    todo = check_study(study, runs)
    resumed = executor.run_settings(settings)
    for run in todo:
        if RunFolder(run.folder(study)).checkpoint.exists():
            check_resume_settings(run.folder(study), _record(run, resumed, chosen, configs))
    return StudyPlan(study, runs, todo, chosen, settings, configs)


def drive(plan: StudyPlan, executor: Executor) -> list[dict[str, Any]]:
    """Record the plan's command in ``study.json`` (its settings, yaml, pairing and runs) under the study's lock
    (:class:`~sb3_cic.study.record.StudyLock`: one command drives a folder at a time), delete what a finished run
    killed just after writing its ``result.json`` left, and run the plan with ``executor``; return what it returns.
    A pause request (:func:`~sb3_cic.study.record.request_pause`) left from an earlier command is forgotten as the
    command starts, this command's as it ends."""
    with StudyLock(plan.study):
        clear_pause(plan.study)
        try:
            record_study_settings(plan.study, plan.settings, plan.pairing, **settings_use(plan.runs, plan.conf_files))
            record_runs(plan.study, plan.runs)
            for run in plan.runs:
                RunFolder(run.folder(plan.study)).clean()
            return executor.run(plan)
        finally:
            clear_pause(plan.study)


def _record(run: Run, settings: Settings, pairing: Pairing, configs: dict[str, str | None]) -> dict[str, Any]:
    return run_record(run.row(), settings, run.from_scratch, pairing, configs.get(run.method))


def check_conf_files(runs: Sequence[Run], conf_files: dict[str, str | Path | None]) -> dict[str, str | None]:
    """The yaml of each method of ``runs`` (None: the default), as ``study.json`` records it; a ``ValueError`` for a
    file that does not exist or a method that none of the runs has.

    :param runs: the command's runs
    :param conf_files: ``{method: yaml}`` of the command
    """
    methods = sorted({run.method for run in runs})
    for method, path in conf_files.items():
        if method not in methods:
            raise ValueError(f"--conf-file for {method}, which is not among the methods {methods}")
        if path is not None and not Path(path).is_file():
            raise ValueError(f"no yaml file {path} (--conf-file)")
    return {method: None if conf_files.get(method) is None else str(conf_files[method]) for method in methods}


def check_run_inputs(
    study: str | Path, runs: Sequence[Run], settings: Settings, configs: dict[str, str | None], from_snapshot: int | None
) -> list[Run]:
    """``ValueError`` before anything is written when a run would stop on its input: its yaml has no entry for its
    environment (rl-zoo's message), a ``learning_starts`` of ``settings`` leaves it no update, or the pre-training
    saves no snapshot at ``from_snapshot``. Returns ``runs``, those from the pre-training's final snapshot without
    a snapshot step (``cic``, not ``cic@<final step>``).

    :param study: study folder
    :param runs: the command's runs
    :param settings: the command's settings
    :param configs: the yaml of each method (None: the default)
    :param from_snapshot: the snapshot step the fine-tunings start from (None: the final one)
    """
    final: dict[Run, int] = {}  # each pre-training's steps
    for method, domain, task in sorted({(run.method, run.domain, run.task) for run in runs}, key=str):
        phase = "pre-training" if task is None else "fine-tuning"
        env_id = f"URLB/{domain}-v0" if task is None else task_env_id(domain, task)
        overrides = settings.overrides(finetune=task is not None and zoo.has_reward_module(zoo.get_algo(method)))
        hyperparams, _, n_timesteps, _ = zoo.zoo_hyperparams(method, env_id, configs.get(method), overrides)
        steps = int((settings.pretrain_steps if task is None else settings.finetune_steps) or n_timesteps)
        learning_starts = hyperparams.get("learning_starts")
        if settings.learning_starts is not None and learning_starts is not None and learning_starts >= steps:
            raise ValueError(f"learning_starts {learning_starts} is not below the {phase}'s {steps} steps: it would "
                             "never update (--learning-starts)")
        if task is None:
            final.update({run: steps for run in runs if (run.method, run.domain, run.task) == (method, domain, None)})
    if from_snapshot is None:
        return list(runs)
    for pretraining, steps in final.items():
        saved = _saved_snapshots(RunFolder(pretraining.folder(study))) or snapshot_steps(settings, steps)
        if from_snapshot not in saved:
            raise ValueError(f"no snapshot at {from_snapshot} steps: the pre-training saves {saved} (--snapshots)")
        final[pretraining] = saved[-1]
    return [dataclasses.replace(run, snapshot=None) if run.snapshot is not None and final.get(run.dependency()) == run.snapshot
            else run for run in runs]


def _saved_snapshots(folder: RunFolder) -> list[int] | None:
    """The snapshot steps a finished pre-training saved (None: not finished, or its ``result.json`` is damaged,
    which :func:`~sb3_cic.study.graph.check_study` refuses)."""
    if not folder.done:
        return None
    try:
        return sorted(int(step) for step in json.loads(folder.result.read_text())["snapshots"])
    except (ValueError, KeyError, TypeError, AttributeError):
        return None


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
    """``sb3-cic protocol``: the URLB protocol for one method and domain in this process: pre-train, fine-tune on
    tasks x seeds (:func:`plan_study`, :func:`drive` with :class:`InProcess`).

    Paired (URLB's, the default of a new study): one pre-training per seed, fine-tuning seed s from pre-training
    seed s. Shared (the CIC code's): one pre-training, of seed ``pretrain_seed``, for every fine-tuning seed. A
    study keeps its pairing (:func:`~sb3_cic.study.record.resolve_pairing`). Finished runs (``result.json`` present)
    are not run again, so an interrupted study resumes.

    :param study: study folder
    :param method: rl-zoo name of the method (``ddpg`` trains from scratch; ``cic+fixed``: with the method's
        fine-tuning skill choice ``fixed``, :func:`~sb3_cic.study.graph.build_graph`)
    :param domain: URLB domain
    :param tasks: tasks (``flip`` or ``walker_flip``; default: all of the domain)
    :param seeds: fine-tuning seeds
    :param settings: scale and evaluation settings
    :param snapshot: snapshot to fine-tune from (default: the final one)
    :param from_scratch: no pre-training: True only for a method without one (``ddpg``), the default there
    :param pretrain_seed: seed of shared pre-training (given alone: ``pairing="shared"``)
    :param config: yaml file (default ``zoo_configs/<method>.yml``)
    :param pairing: ``paired``, ``shared`` or None (the study's; a new study: ``paired``)
    :return: the fine-tuning results
    """
    method = method.lower()
    name, _ = skill_choice_of(method)
    pretrains = zoo.has_reward_module(zoo.get_algo(name))
    if from_scratch is not None and from_scratch == pretrains:
        raise ValueError(f"--from-scratch: {method} pre-trains (its runs from scratch would take the folders of its "
                         "fine-tunings); the runs from scratch are ddpg's" if pretrains
                         else f"{method} has no pre-training: its runs are from scratch")
    executor = InProcess()
    plan = plan_study(study, [method], [domain], tasks, seeds, settings or Settings(), executor, pairing=pairing,
                      pretrain_seed=pretrain_seed, from_snapshot=snapshot, conf_files={name: config})
    return drive(plan, executor)
