"""The engine: a study's job graph as Ray tasks.

Each run is one Ray task with its resources (``num_cpus``, ``num_gpus``: ``0.25`` puts four runs on a GPU)
and ``max_retries`` (Ray starts it again when its worker dies; the run resumes from its checkpoint). A
fine-tuning task takes its pre-training task's result as an argument, so Ray releases it as soon as the
pre-training is done. A run that raises is recorded in its folder (``error.txt``, where the folder can be
written) and returns a failed status: the other runs go on. No queue or retry loop of our own: that is Ray's work.

One command drives a study folder at a time (:class:`~sb3_cic.study.record.StudyLock`). Interrupted (Ctrl-C,
SIGTERM: :class:`KeyboardInterrupt`), the command stops its runs before it ends (:func:`stop_runs`): no process of
it writes in the folder afterwards, and the same command resumes the study.
"""

from __future__ import annotations

import dataclasses
import math
import os
import signal
import socket
import time
import traceback
from pathlib import Path
from typing import Any, Sequence

from tqdm.auto import tqdm

from sb3_cic import protocol
from sb3_cic.common.arguments import check_argument
from sb3_cic.protocol import Settings, check_study_settings, record_study_settings, run_record
from sb3_cic.study.checkpoint import RunFolder, process_start_time
from sb3_cic.study.graph import Run, alive, build_graph, check_study, record_runs, recorded_pid, settings_use
from sb3_cic.study.record import Pairing, StudyLock, check_resume_settings, check_run_settings, resolve_pairing


def execute(study: str, run: Run, settings: Settings, dependency: dict[str, Any] | None = None) -> dict[str, Any]:
    """Run ``run`` in this process (the body of a Ray task); record a failure in its folder instead of raising.

    :param study: study folder (absolute: workers may have another working directory)
    :param run: the run
    :param settings: the study's settings
    :param dependency: the status its pre-training's task returned (a failed one fails this run too)
    :return: ``{"run": str(run), "state": "done" | "failed", "error": ...}``
    """
    try:
        if dependency is not None and dependency["state"] != "done":
            raise RuntimeError(f"its pre-training failed: {dependency['error']}")
        if run.task is None:
            protocol.pretrain(study, run.method, run.domain, settings, seed=run.seed, paired=not run.shared)
        else:
            protocol.finetune(study, run.method, run.domain, run.task, run.seed, settings, snapshot=run.snapshot,
                              from_scratch=run.from_scratch, paired=not run.shared)
    except Exception as error:  # recorded; the study goes on
        return failed(study, run, f"{type(error).__name__}: {error}", traceback.format_exc())
    return {"run": str(run), "state": "done", "error": None}


def failed(study: str | Path, run: Run, error: str, details: str) -> dict[str, Any]:
    """Record ``run`` as failed in its folder (``error.txt``) where the folder can be written; return its status.

    :param study: study folder
    :param run: the run
    :param error: one line: what failed
    :param details: the traceback
    """
    try:
        RunFolder(run.folder(study)).fail(details)
    except OSError as write_error:  # the folder cannot be written: the status says it, the study goes on
        error += f" (not recorded in its folder: {type(write_error).__name__}: {write_error})"
    return {"run": str(run), "state": "failed", "error": error}


def run_graph(
    study: str | Path,
    runs: Sequence[Run],
    settings: Settings,
    cpus_per_run: float = 1,
    gpus_per_run: float = 0,
    max_retries: int = 3,
    progress_bar: bool = True,
) -> list[dict[str, Any]]:
    """Run ``runs`` (pre-trainings before their fine-tunings, as :func:`~sb3_cic.study.graph.build_graph` orders
    them) as Ray tasks on the Ray instance this process is connected to; return each run's status.

    Interrupted (:class:`KeyboardInterrupt`), it cancels the runs' tasks, killing their workers, and raises.

    :param study: study folder (on a cluster: storage that every node sees)
    :param runs: the runs still to do
    :param settings: the study's settings (``num_threads`` None: ``cpus_per_run`` torch threads per run)
    :param cpus_per_run: CPUs of a run's task
    :param gpus_per_run: GPUs of a run's task (a fraction shares a GPU)
    :param max_retries: times Ray starts a run again after its worker died
    :param progress_bar: show a progress bar over the runs
    """
    import ray

    study = str(Path(study).resolve())
    if settings.num_threads is None:
        settings = dataclasses.replace(settings, num_threads=max(1, int(cpus_per_run)))
    settings = dataclasses.replace(settings, progress_bar=False)
    task = ray.remote(execute).options(num_cpus=cpus_per_run, num_gpus=gpus_per_run, max_retries=max_retries)
    refs: dict[Run, Any] = {}
    for run in runs:
        dependency = run.dependency()
        refs[run] = task.remote(study, run, settings, refs.get(dependency) if dependency else None)
    names = {ref: run for run, ref in refs.items()}
    statuses = []
    pending = list(refs.values())
    try:
        with tqdm(total=len(pending), desc="runs", unit="run", disable=not progress_bar) as bar:
            while pending:
                ready, pending = ray.wait(pending, num_returns=1)
                for ref in ready:
                    run = names[ref]
                    try:
                        status = ray.get(ref)
                    except ray.exceptions.RayError as error:  # its worker died more than max_retries times
                        status = failed(study, run, f"{type(error).__name__}: {error}", f"Ray gave up on the run:\n{error}\n")
                    statuses.append(status)
                    bar.update(1)
                    bar.set_postfix(failed=sum(s["state"] != "done" for s in statuses), refresh=False)
                    if status["state"] != "done":
                        bar.write(f"failed: {status['run']}: {status['error']}")
    except KeyboardInterrupt:
        for ref in pending:
            ray.cancel(ref, force=True, recursive=True)
        raise
    return statuses


def stop_runs(study: str | Path, runs: Sequence[Run], since: float, grace_s: float = 10.0) -> None:
    """Make sure that no process of this host still runs one of ``runs`` for a command started at ``since``: each
    run folder's ``progress.json`` names the process that runs it (its pid and start time, updated at each
    checkpoint); one still alive after ``grace_s`` seconds (Ray stops its workers when it shuts down) is killed, by
    its pid, and only when it is proven to be that process: its start time is the one recorded
    (:func:`~sb3_cic.study.checkpoint.process_start_time`). A pid the system gave to another process since (the
    worker died) is left alone, as is one whose start time was not recorded.

    :param study: study folder
    :param runs: the runs the command started
    :param since: when the command started (``time.time()``): older ``progress.json`` are another command's
    :param grace_s: seconds given to the processes to end
    """
    here = socket.gethostname()
    processes = set()
    for run in runs:
        progress = RunFolder(run.folder(study)).read_progress() or {}
        if progress.get("host") == here and progress.get("updated", 0) >= since and progress.get("pid") != os.getpid():
            pid, start = recorded_pid(progress), progress.get("start_time")
            if pid is not None and type(start) is int:
                processes.add((pid, start))
    deadline = time.monotonic() + grace_s
    while any(alive(pid, start) for pid, start in processes) and time.monotonic() < deadline:
        time.sleep(0.1)
    for pid, start in processes:
        if alive(pid, start) and process_start_time(pid) == start:  # proven: the process the run folder names
            os.kill(pid, signal.SIGKILL)


def start_ray(
    address: str | None = None, workers: int = 1, cpus_per_run: float = 1, gpus_per_run: float = 0, log_to_driver: bool = False
) -> None:
    """Connect to a Ray cluster (``address``: ``auto``, ``ray://host:10001``...) or start a local instance that
    runs ``workers`` runs at a time.

    A cluster confined to one machine (nodes started with ``--node-ip-address 127.0.0.1``): Ray turns a loopback
    ``address`` into the machine's network address, where such nodes do not listen, unless the environment has
    ``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0`` (Ray's switch for local-only clusters).

    :param address: a running cluster's address; None: a local instance on this machine
    :param workers: runs at a time of the local instance
    :param cpus_per_run: CPUs per run (the local instance has ``workers * cpus_per_run``)
    :param gpus_per_run: GPUs per run (the local instance has ``workers * gpus_per_run``, rounded up)
    :param log_to_driver: show the workers' output here

    The process's SIGTERM handler is kept (``ray.init`` installs its own, which ends the process with no word: a
    SIGTERM while ``ray.init`` runs is :class:`~sb3_cic.study.cli.Interrupted` instead). A local instance runs its workers at
    this process's niceness: Ray's default (15) leaves a study's runs a few percent of a CPU that any other
    program keeps busy; ``RAY_worker_niceness`` in the environment still decides where it is set.
    """
    import ray

    from sb3_cic.study.cli import Interrupted

    sigterm = signal.getsignal(signal.SIGTERM)
    unset = not address and "RAY_worker_niceness" not in os.environ
    if unset:  # the raylet, started here, passes it to the workers it starts
        os.environ["RAY_worker_niceness"] = str(os.nice(0))
    try:
        if address:
            ray.init(address=address, log_to_driver=log_to_driver)
        else:
            ray.init(num_cpus=math.ceil(workers * cpus_per_run), num_gpus=math.ceil(workers * gpus_per_run),
                     include_dashboard=False, log_to_driver=log_to_driver)
    except SystemExit as exit_:  # Ray's SIGTERM handler, in place while ray.init runs, exits with no word
        if exit_.code != signal.SIGTERM:
            raise
        raise Interrupted(signal.SIGTERM) from None
    finally:
        if unset:
            del os.environ["RAY_worker_niceness"]
        if sigterm is not None:  # Ray's driver aborts on SIGTERM with a stack dump: the command's own handler stays
            signal.signal(signal.SIGTERM, sigterm)


def run_study(
    study: str | Path,
    methods: Sequence[str],
    domains: Sequence[str],
    tasks: Sequence[str] | None,
    seeds: Sequence[int],
    settings: Settings,
    pretrain_seed: int | None = None,
    address: str | None = None,
    workers: int = 1,
    cpus_per_run: float = 1,
    gpus_per_run: float = 0,
    max_retries: int = 3,
    progress_bar: bool = True,
    from_snapshot: int | None = None,
    pairing: str | None = None,
) -> tuple[list[Run], list[dict[str, Any]]]:
    """``sb3-cic study``: build the job graph, check it against the study folder, run what is left on Ray.

    Every bad input (unknown method, domain or task, a folder or a run folder made with other settings, another
    pairing, a damaged ``study.json``, ``result.json`` or ``eval.csv``, a corrupt or lost checkpoint, a missing
    snapshot, bad resources, another command driving the folder) is a ``ValueError`` before anything is written or
    run. Without ``address`` and without a Ray instance in this process, a local one is started (and stopped).
    Interrupted (:class:`KeyboardInterrupt`; SIGTERM while Ray starts, :func:`start_ray`) or failed once runs may
    have started, the runs are stopped (:func:`stop_runs`) before it raises.

    :param study: study folder
    :param methods: rl-zoo names or ``["all"]``
    :param domains: URLB domains or ``["all"]``
    :param tasks: tasks (None: each domain's)
    :param seeds: fine-tuning seeds
    :param settings: scale, evaluation and checkpoint settings
    :param pretrain_seed: seed of shared pre-training (given alone: ``pairing="shared"``)
    :param address: address of a running Ray cluster
    :param workers: runs at a time of a local Ray instance
    :param cpus_per_run: CPUs of each run
    :param gpus_per_run: GPUs of each run (a fraction shares a GPU)
    :param max_retries: times Ray starts a run again after its worker died
    :param progress_bar: show a progress bar over the runs
    :param from_snapshot: fine-tune from the pre-training's snapshot at this step (one of ``settings.snapshots``;
        None: the final one); the runs are ``cic@<step>`` in the study's folders and reports
    :param pairing: ``paired``, ``shared`` or None: the study's (a new study: ``paired``;
        :func:`~sb3_cic.study.record.resolve_pairing`)
    :return: the command's runs and the statuses of those that ran now
    """
    import ray

    if not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be an int >= 1, got {workers!r}")
    if not cpus_per_run > 0 or not gpus_per_run >= 0:
        raise ValueError(f"cpus_per_run must be > 0 and gpus_per_run >= 0, got {cpus_per_run!r} and {gpus_per_run!r}")
    check_argument("max_retries", max_retries)  # no -1 (Ray's "no limit"): a run that kills its worker would never end
    if from_snapshot is not None and (from_snapshot not in settings.snapshots or from_snapshot == settings.pretrain_steps):
        raise ValueError(f"fine-tuning from the snapshot at {from_snapshot} steps needs it among the intermediate "
                         f"snapshots (--snapshots {' '.join(map(str, settings.snapshots))}); the final one is the default")
    chosen = resolve_pairing(study, pairing, pretrain_seed)
    runs = build_graph(methods, domains, tasks, seeds, chosen, from_snapshot)
    protocol.check_learning_starts(runs, settings)
    check_study_settings(study, settings, chosen, **settings_use(runs))
    check_runs_settings(study, runs, settings, chosen)
    todo = check_study(study, runs)
    check_resumes(study, todo, settings, chosen, cpus_per_run)
    with StudyLock(study):
        record_study_settings(study, settings, chosen, **settings_use(runs))
        record_runs(study, runs)
        for run in runs:  # a done run killed just after writing its result.json: what it left is deleted
            RunFolder(run.folder(study)).clean()
        if not todo:
            return runs, []
        announce_resumed(study, todo)
        started, since = not ray.is_initialized(), time.time()
        try:
            if started:
                start_ray(address, workers, cpus_per_run, gpus_per_run, log_to_driver=settings.verbose > 0)
            return runs, run_graph(study, todo, settings, cpus_per_run, gpus_per_run, max_retries, progress_bar)
        except BaseException:  # interrupted, or whatever error an interruption became (Ray's own, a half-made import)
            if started:
                ray.shutdown()
            stop_runs(study, todo, since)
            raise
        finally:
            if started and ray.is_initialized():
                ray.shutdown()


def announce_resumed(study: str | Path, runs: Sequence[Run]) -> None:
    """Print one line for each of ``runs`` that will resume from a checkpoint (its ``progress.json`` records one),
    with the step.

    :param study: study folder
    :param runs: the runs about to run
    """
    for run in runs:
        step = (RunFolder(run.folder(study)).read_progress() or {}).get("checkpoint_step")
        if type(step) is int and step > 0:
            print(f"{run}: resumes from its checkpoint at step {step:,}", flush=True)


def check_runs_settings(study: str | Path, runs: Sequence[Run], settings: Settings, pairing: Pairing) -> None:
    """``ValueError`` (one line) if a run folder of ``runs`` records other settings than the command's
    (:func:`~sb3_cic.study.record.check_run_settings`; the default yaml of each method).

    :param study: study folder
    :param runs: the command's runs
    :param settings: the command's settings
    :param pairing: the command's pairing
    """
    for run in runs:
        check_run_settings(run.folder(study), run_record(run.row(), settings, run.from_scratch, pairing))


def check_resumes(study: str | Path, runs: Sequence[Run], settings: Settings, pairing: Pairing, cpus_per_run: float) -> None:
    """``ValueError`` (one line) if a run of ``runs`` that will resume from its checkpoint was started with other run
    settings (threads, compile, TF32, device) than its Ray task will have
    (:func:`~sb3_cic.study.record.check_resume_settings`; ``num_threads`` None: ``cpus_per_run``, as :func:`run_graph`).

    :param study: study folder
    :param runs: the runs still to do
    :param settings: the command's settings
    :param pairing: the command's pairing
    :param cpus_per_run: CPUs of a run's task
    """
    if settings.num_threads is None:
        settings = dataclasses.replace(settings, num_threads=max(1, int(cpus_per_run)))
    for run in runs:
        if RunFolder(run.folder(study)).checkpoint.exists():
            check_resume_settings(run.folder(study), run_record(run.row(), settings, run.from_scratch, pairing))
