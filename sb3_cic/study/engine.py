"""The engine: a study's job graph as Ray tasks (:class:`RayExecutor`, the executor of ``sb3-cic study`` for the
driver, :mod:`sb3_cic.study.driver`).

Each run is one Ray task with its resources (``num_cpus``, ``num_gpus``: ``0.25`` puts four runs on a GPU)
and ``max_retries`` (Ray starts it again when its worker dies; the run resumes from its checkpoint). A
fine-tuning task takes its pre-training task's result as an argument, so Ray releases it as soon as the
pre-training is done. A run that raises is recorded in its folder (``error.txt``, where the folder can be
written) and returns a failed status: the other runs go on. No queue or retry loop of our own: that is Ray's work.

One command drives a study folder at a time (:class:`~sb3_cic.study.record.StudyLock`). Interrupted (Ctrl-C,
SIGTERM: :class:`KeyboardInterrupt`), the command stops its runs before it ends (:func:`stop_runs`): no process of
it writes in the folder afterwards, and the same command resumes the study. Paused (``sb3-cic pause``,
:func:`~sb3_cic.study.record.request_pause`), its running runs checkpoint at their episode's end and return a
paused status, and the runs not started return one at once.
"""

from __future__ import annotations

import contextlib
import dataclasses
from dataclasses import dataclass
import math
import os
import signal
import socket
import tempfile
import time
import traceback
from pathlib import Path
from typing import Any, Iterator, Sequence

from tqdm.auto import tqdm

from sb3_cic.command_line import Interrupted
from sb3_cic.common.arguments import NON_NEGATIVE_INT, check_argument
from sb3_cic.common.resumable import RunPaused
from sb3_cic.protocol import finetune, pretrain
from sb3_cic.study.checkpoint import RunFolder, process_start_time
from sb3_cic.study.driver import StudyPlan, drive, plan_study
from sb3_cic.study.graph import alive, recorded_pid
from sb3_cic.study.record import pause_requested
from sb3_cic.study.run import Run
from sb3_cic.study.settings import Settings


def execute(
    study: str, run: Run, settings: Settings, dependency: dict[str, Any] | None = None, config: str | None = None
) -> dict[str, Any]:
    """Run ``run`` in this process (the body of a Ray task); record a failure in its folder instead of raising.

    :param study: study folder (absolute: workers may have another working directory)
    :param run: the run
    :param settings: the study's settings
    :param dependency: the status its pre-training's task returned (a failed one fails this run too)
    :param config: the yaml of the run's method (None: the default)
    :return: ``{"run": str(run), "state": "done" | "failed" | "paused", "error": ...}`` (paused: the command was
        asked to pause, :func:`~sb3_cic.study.record.request_pause`; the run stopped at its checkpoint, or did not
        start, as a fine-tuning of a paused pre-training)
    """
    try:
        if pause_requested(study) is not None or (dependency is not None and dependency["state"] == "paused"):
            raise RunPaused()
        if dependency is not None and dependency["state"] != "done":
            raise RuntimeError(f"its pre-training failed: {dependency['error']}")
        (pretrain if run.task is None else finetune)(study, run, settings, config)
    except RunPaused as paused:
        return {"run": str(run), "state": "paused", "error": None, "step": paused.step}
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


def run_graph(plan: StudyPlan, executor: RayExecutor) -> list[dict[str, Any]]:
    """Run the plan's runs still to do (pre-trainings before their fine-tunings, as
    :func:`~sb3_cic.study.graph.build_graph` orders them) as Ray tasks on the Ray instance this process is connected
    to, with the executor's resources; return each run's status.

    Interrupted (:class:`KeyboardInterrupt`), it cancels the runs' tasks, killing their workers, and raises.

    :param plan: the checked runs (:func:`~sb3_cic.study.driver.plan_study`; the study folder, on a cluster, on
        storage that every node sees)
    :param executor: the resources of a run's task
    """
    import ray

    study = str(Path(plan.study).resolve())
    settings = executor.run_settings(plan.settings)
    task = ray.remote(execute).options(num_cpus=executor.cpus_per_run, num_gpus=executor.gpus_per_run,
                                       max_retries=executor.max_retries)
    refs: dict[Run, Any] = {}
    for run in plan.todo:
        dependency = run.dependency()
        config = plan.config(run)  # absolute, as the study folder: a worker may have another working directory
        refs[run] = task.remote(study, run, settings, refs.get(dependency) if dependency else None,
                                None if config is None else str(Path(config).resolve()))
    names = {ref: run for run, ref in refs.items()}
    statuses = []
    pending = list(refs.values())
    try:
        with tqdm(total=len(pending), desc="runs", unit="run", disable=not executor.progress_bar) as bar:
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
                    bar.set_postfix(failed=sum(s["state"] == "failed" for s in statuses), refresh=False)
                    if status["state"] == "failed":
                        bar.write(f"failed: {status['run']}: {status['error']}")
                    elif status["state"] == "paused" and status["step"] is not None:
                        bar.write(f"paused: {status['run']} at step {status['step']:,}")
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
    SIGTERM while ``ray.init`` runs is :class:`~sb3_cic.command_line.Interrupted` instead). A local instance's
    workers (:func:`_local_workers`) run at this process's niceness and import the package this process imported.
    """
    import ray

    sigterm = signal.getsignal(signal.SIGTERM)
    try:
        if address:
            ray.init(address=address, log_to_driver=log_to_driver)
        else:
            with _local_workers():
                ray.init(num_cpus=math.ceil(workers * cpus_per_run), num_gpus=math.ceil(workers * gpus_per_run),
                         include_dashboard=False, log_to_driver=log_to_driver)
    except SystemExit as exit_:  # Ray's SIGTERM handler, in place while ray.init runs, exits with no word
        if exit_.code != signal.SIGTERM:
            raise
        raise Interrupted(signal.SIGTERM) from None
    finally:
        if sigterm is not None:  # Ray's driver aborts on SIGTERM with a stack dump: the command's own handler stays
            signal.signal(signal.SIGTERM, sigterm)


@contextlib.contextmanager
def _local_workers() -> Iterator[None]:
    """While a local Ray instance starts, what its raylet passes on to the workers it starts:

    * this process's niceness: ``RAY_worker_niceness`` is what the raylet adds to its own (this process's), 0 here;
      Ray's default (15) leaves a study's runs a few percent of a CPU that any other program keeps busy; set in the
      environment, it still decides;
    * this package: Ray puts the driver's working directory first on its workers' ``sys.path`` and starts them there,
      so a study driven from inside another source checkout would run that checkout's ``sb3_cic``. The working
      directory is the temporary folder while Ray starts (the runs' paths are absolute), and where this process
      imported ``sb3_cic`` from its working directory (``python -m`` in a checkout), ``PYTHONPATH`` begins with it.
    """
    import sb3_cic

    saved = {name: os.environ.get(name) for name in ("RAY_worker_niceness", "PYTHONPATH")}
    here = os.getcwd()
    os.environ.setdefault("RAY_worker_niceness", "0")
    if Path(sb3_cic.__file__).resolve().parent.parent == Path(here).resolve():
        os.environ["PYTHONPATH"] = os.pathsep.join(p for p in (here, saved["PYTHONPATH"]) if p)
    os.chdir(tempfile.gettempdir())
    try:
        yield
    finally:
        os.chdir(here)
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


@dataclass
class RayExecutor:
    """Run a study's runs as Ray tasks (``sb3-cic study``): each run one task with its resources and ``max_retries``;
    a run that fails is recorded in its folder and the others go on (:func:`run_graph`). Without ``address`` and
    without a Ray instance in this process, a local one is started (and stopped). Interrupted
    (:class:`KeyboardInterrupt`; SIGTERM while Ray starts) or failed once runs may have started, the runs are stopped
    (:func:`stop_runs`) before it raises.

    :param address: address of a running Ray cluster
    :param workers: runs at a time of a local Ray instance
    :param cpus_per_run: CPUs of each run
    :param gpus_per_run: GPUs of each run (a fraction shares a GPU)
    :param max_retries: times Ray starts a run again after its worker died
    :param progress_bar: show a progress bar over the runs
    """

    address: str | None = None
    workers: int = 1
    cpus_per_run: float = 1
    gpus_per_run: float = 0
    max_retries: int = 3
    progress_bar: bool = True

    def __post_init__(self) -> None:
        """A ``ValueError`` for bad resources."""
        if not isinstance(self.workers, int) or self.workers < 1:
            raise ValueError(f"workers must be an int >= 1, got {self.workers!r}")
        if not self.cpus_per_run > 0 or not self.gpus_per_run >= 0:
            raise ValueError(f"cpus_per_run must be > 0 and gpus_per_run >= 0, got {self.cpus_per_run!r} and "
                             f"{self.gpus_per_run!r}")
        check_argument("max_retries", self.max_retries, NON_NEGATIVE_INT)  # no -1 (Ray's "no limit"): a run that kills its worker never ends

    def run_settings(self, settings: Settings) -> Settings:
        """The settings of a run's task: ``num_threads`` None is ``cpus_per_run`` torch threads, no progress bar."""
        if settings.num_threads is None:
            settings = dataclasses.replace(settings, num_threads=max(1, int(self.cpus_per_run)))
        return dataclasses.replace(settings, progress_bar=False)

    def run(self, plan: StudyPlan) -> list[dict[str, Any]]:
        """Run the plan's runs still to do on Ray; return their statuses."""
        import ray

        if not plan.todo:
            return []
        announce_resumed(plan.study, plan.todo)
        started, since = not ray.is_initialized(), time.time()
        try:
            if started:
                start_ray(self.address, self.workers, self.cpus_per_run, self.gpus_per_run,
                          log_to_driver=plan.settings.verbose > 0)
            return run_graph(plan, self)
        except BaseException:  # interrupted, or whatever error an interruption became (Ray's own, a half-made import)
            if started:
                ray.shutdown()
            stop_runs(plan.study, plan.todo, since)
            raise
        finally:
            if started and ray.is_initialized():
                ray.shutdown()


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
    conf_files: dict[str, str | Path | None] | None = None,
) -> tuple[list[Run], list[dict[str, Any]]]:
    """``sb3-cic study``: the study's runs, checked (:func:`~sb3_cic.study.driver.plan_study`: every bad input, bad
    resources too, is a ``ValueError`` before anything is written or run), recorded and run on Ray
    (:class:`RayExecutor`, :func:`~sb3_cic.study.driver.drive`). Interrupted (:class:`KeyboardInterrupt`; SIGTERM while Ray
    starts, :func:`start_ray`) or failed once runs may have started, the runs are stopped (:func:`stop_runs`) before it
    raises.

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
    :param from_snapshot: fine-tune from the pre-training's snapshot at this step (one it saves; None or the final
        step: the final one); the runs are ``cic@<step>`` in the study's folders and reports
    :param pairing: ``paired``, ``shared`` or None: the study's (a new study: ``paired``;
        :func:`~sb3_cic.study.record.resolve_pairing`)
    :param conf_files: the yaml of each method (``--conf-file``; None: the default ``zoo_configs/<method>.yml``)
    :return: the command's runs and the statuses of those that ran now
    """
    executor = RayExecutor(address, workers, cpus_per_run, gpus_per_run, max_retries, progress_bar)
    plan = plan_study(study, methods, domains, tasks, seeds, settings, executor, pairing=pairing,
                      pretrain_seed=pretrain_seed, from_snapshot=from_snapshot, conf_files=conf_files)
    return plan.runs, drive(plan, executor)


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
