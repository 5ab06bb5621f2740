"""The engine: a study's job graph as Ray tasks.

Each run is one Ray task with its resources (``num_cpus``, ``num_gpus``: ``0.25`` puts four runs on a GPU)
and ``max_retries`` (Ray starts it again when its worker dies; the run resumes from its checkpoint). A
fine-tuning task takes its pre-training task's result as an argument, so Ray releases it as soon as the
pre-training is done. A run that raises is recorded in its folder (``error.txt``) and returns a failed status:
the other runs go on. No queue or retry loop of our own: that is Ray's work.
"""

from __future__ import annotations

import dataclasses
import math
import traceback
from pathlib import Path
from typing import Any, Sequence

from tqdm.auto import tqdm

from sb3_cic import protocol
from sb3_cic.common.arguments import check_argument
from sb3_cic.protocol import Settings, check_study_settings, record_study_settings
from sb3_cic.study.checkpoint import RunFolder
from sb3_cic.study.graph import Run, build_graph, check_study, record_runs, settings_use


def execute(
    study: str, run: Run, settings: Settings, pretrain_seed: int, dependency: dict[str, Any] | None = None
) -> dict[str, Any]:
    """Run ``run`` in this process (the body of a Ray task); record a failure in its folder instead of raising.

    :param study: study folder (absolute: workers may have another working directory)
    :param run: the run
    :param settings: the study's settings
    :param pretrain_seed: the study's pre-training seed
    :param dependency: the status its pre-training's task returned (a failed one fails this run too)
    :return: ``{"run": str(run), "state": "done" | "failed", "error": ...}``
    """
    folder = RunFolder(run.folder(study))
    try:
        if dependency is not None and dependency["state"] != "done":
            raise RuntimeError(f"its pre-training failed: {dependency['error']}")
        if run.task is None:
            protocol.pretrain(study, run.method, run.domain, settings, seed=pretrain_seed)
        else:
            protocol.finetune(study, run.method, run.domain, run.task, run.seed, settings, snapshot=run.snapshot,
                              from_scratch=run.from_scratch)
    except Exception as error:  # recorded; the study goes on
        folder.fail(traceback.format_exc())
        return {"run": str(run), "state": "failed", "error": f"{type(error).__name__}: {error}"}
    return {"run": str(run), "state": "done", "error": None}


def run_graph(
    study: str | Path,
    runs: Sequence[Run],
    settings: Settings,
    pretrain_seed: int = 0,
    cpus_per_run: float = 1,
    gpus_per_run: float = 0,
    max_retries: int = 3,
    progress_bar: bool = True,
) -> list[dict[str, Any]]:
    """Run ``runs`` (pre-trainings before their fine-tunings, as :func:`~sb3_cic.study.graph.build_graph` orders
    them) as Ray tasks on the Ray instance this process is connected to; return each run's status.

    :param study: study folder (on a cluster: storage that every node sees)
    :param runs: the runs still to do
    :param settings: the study's settings (``num_threads`` None: ``cpus_per_run`` torch threads per run)
    :param pretrain_seed: seed of the pre-trainings
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
        dependency = run.dependency(pretrain_seed)
        refs[run] = task.remote(study, run, settings, pretrain_seed, refs.get(dependency) if dependency else None)
    names = {ref: run for run, ref in refs.items()}
    statuses = []
    pending = list(refs.values())
    with tqdm(total=len(pending), desc="runs", unit="run", disable=not progress_bar) as bar:
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            for ref in ready:
                run = names[ref]
                try:
                    status = ray.get(ref)
                except ray.exceptions.RayError as error:  # its worker died more than max_retries times
                    RunFolder(run.folder(study)).fail(f"Ray gave up on the run:\n{error}\n")
                    status = {"run": str(run), "state": "failed", "error": f"{type(error).__name__}: {error}"}
                statuses.append(status)
                bar.update(1)
                failed = sum(s["state"] != "done" for s in statuses)
                bar.set_postfix(failed=failed, refresh=False)
                if status["state"] != "done":
                    bar.write(f"failed: {status['run']}: {status['error']}")
    return statuses


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
    """
    import ray

    if address:
        ray.init(address=address, log_to_driver=log_to_driver)
    else:
        ray.init(
            num_cpus=math.ceil(workers * cpus_per_run),
            num_gpus=math.ceil(workers * gpus_per_run),
            include_dashboard=False,
            log_to_driver=log_to_driver,
        )


def run_study(
    study: str | Path,
    methods: Sequence[str],
    domains: Sequence[str],
    tasks: Sequence[str] | None,
    seeds: Sequence[int],
    settings: Settings,
    pretrain_seed: int = 0,
    address: str | None = None,
    workers: int = 1,
    cpus_per_run: float = 1,
    gpus_per_run: float = 0,
    max_retries: int = 3,
    progress_bar: bool = True,
    from_snapshot: int | None = None,
) -> tuple[list[Run], list[dict[str, Any]]]:
    """``sb3-cic study``: build the job graph, check it against the study folder, run what is left on Ray.

    Every bad input (unknown method, domain or task, a folder made with other settings, a corrupt or lost
    checkpoint, a missing snapshot, bad resources) is a ``ValueError`` before anything is written or run.
    Without ``address`` and without a Ray instance in this process, a local one is started (and stopped).

    :param study: study folder
    :param methods: rl-zoo names or ``["all"]``
    :param domains: URLB domains or ``["all"]``
    :param tasks: tasks (None: each domain's)
    :param seeds: fine-tuning seeds
    :param settings: scale, evaluation and checkpoint settings
    :param pretrain_seed: seed of the pre-trainings
    :param address: address of a running Ray cluster
    :param workers: runs at a time of a local Ray instance
    :param cpus_per_run: CPUs of each run
    :param gpus_per_run: GPUs of each run (a fraction shares a GPU)
    :param max_retries: times Ray starts a run again after its worker died
    :param progress_bar: show a progress bar over the runs
    :param from_snapshot: fine-tune from the pre-training's snapshot at this step (one of ``settings.snapshots``;
        None: the final one); the runs are ``cic@<step>`` in the study's folders and reports
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
    runs = build_graph(methods, domains, tasks, seeds, pretrain_seed, from_snapshot)
    protocol.check_learning_starts(runs, settings)
    check_study_settings(study, settings, pretrain_seed, **settings_use(runs))
    todo = check_study(study, runs, pretrain_seed)
    record_study_settings(study, settings, pretrain_seed, **settings_use(runs))
    record_runs(study, runs)
    for run in runs:  # a done run killed just after writing its result.json: what it left is deleted
        RunFolder(run.folder(study)).clean()
    if not todo:
        return runs, []
    started = not ray.is_initialized()
    if started:
        start_ray(address, workers, cpus_per_run, gpus_per_run, log_to_driver=settings.verbose > 0)
    try:
        return runs, run_graph(study, todo, settings, pretrain_seed, cpus_per_run, gpus_per_run, max_retries, progress_bar)
    finally:
        if started:
            ray.shutdown()
