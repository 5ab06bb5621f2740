"""The job graph of a study: its runs (pre-trainings, fine-tunings) and their dependencies, checked against
the study folder before anything runs, and the status of each run read back from its folder."""

from __future__ import annotations

import functools
import json
import os
import socket
from collections import Counter
from pathlib import Path
from typing import Any, Sequence

from sb3_cic.envs.tasks import DOMAIN_TASKS
from sb3_cic import zoo
from sb3_cic.constants import EXPERT_SCORES
from sb3_cic.study.run_result import read_run_result
from sb3_cic.study.checkpoint import RunFolder, process_start_time, write_json
from sb3_cic.study.record import Pairing, StudyLock, pause_requested, study_record
from sb3_cic.study.run import Run
from sb3_cic.study.layout import (
    check_snapshot,
    snapshot_file,
    study_file,
    task_env_id,
    task_name,
)

#: the URLB domains (those of the expert-scored tasks): ``--domains all``
URLB_DOMAINS: tuple[str, ...] = tuple(sorted({task.split("_")[0] for task in EXPERT_SCORES}))
#: the states :func:`run_state` tells apart (``damaged``: a result that cannot be read or does not hold together)
STATES: tuple[str, ...] = ("done", "running", "failed", "pending", "damaged")


def all_methods() -> list[str]:
    """``--methods all``: the ten unsupervised methods (URLB's nine and MOSS) and ``ddpg`` (one name per class);
    the baselines of :data:`~sb3_cic.zoo.BASELINES_BY_NAME_ONLY` (``fixed``) only by name."""
    names: dict[type, str] = {}
    for name, cls in zoo.algorithms().items():
        if name not in zoo.BASELINES_BY_NAME_ONLY:
            names.setdefault(cls, name)
    return list(names.values())


def build_graph(
    methods: Sequence[str],
    domains: Sequence[str],
    tasks: Sequence[str] | None,
    seeds: Sequence[int],
    pairing: Pairing | int = Pairing("paired"),
    from_snapshot: int | None = None,
) -> list[Run]:
    """The runs of a study command, each pre-training before the fine-tunings that depend on it.

    ``ValueError`` for an unknown method, domain or task, a task of none of the domains, or bad seeds.

    :param methods: rl-zoo names, or ``["all"]``; ``<name>+<choice>`` fine-tunes with the method's skill choice
        ``<choice>`` (``cic+fixed``: the skill fixed at 0.5; labels of one method share its pre-trainings)
    :param domains: URLB domains, or ``["all"]``
    :param tasks: tasks (``flip`` or ``walker_flip``: a short name applies to every domain that has it); None:
        each domain's tasks
    :param seeds: fine-tuning seeds
    :param pairing: which pre-training each fine-tuning starts from (paired: one per seed; an int: shared
        pre-training with that seed)
    :param from_snapshot: fine-tune from the snapshot at this pre-training step (None: the final one); runs
        from scratch ignore it
    """
    pairing = Pairing("shared", pairing) if isinstance(pairing, int) else pairing
    methods = all_methods() if list(methods) == ["all"] else [m.lower() for m in methods]
    domains = list(URLB_DOMAINS) if list(domains) == ["all"] else list(domains)
    choices = {method: skill_choice_of(method) for method in methods}
    for domain in domains:
        if domain not in DOMAIN_TASKS:
            raise ValueError(f"unknown domain {domain!r}; known: {sorted(DOMAIN_TASKS)}")
    if not methods or not domains or not seeds:
        raise ValueError("a study needs at least one method, one domain and one seed")
    if any(not isinstance(s, int) or s < 0 for s in seeds) or len(set(seeds)) != len(seeds):
        raise ValueError(f"seeds must be distinct ints >= 0, got {list(seeds)}")
    if len(set(methods)) != len(methods) or len(set(domains)) != len(domains):
        raise ValueError(f"methods and domains must be distinct, got {methods} and {domains}")
    task_names: dict[str, list[str]] = {domain: [] for domain in domains}
    for task in tasks or ():
        owners = [d for d in domains if task.startswith(f"{d}_") or task in DOMAIN_TASKS[d]]
        if not owners:
            known = {d: DOMAIN_TASKS[d] for d in domains}
            raise ValueError(f"unknown task {task!r} of the domains {domains}; known: {known}")
        for domain in owners:
            task_env_id(domain, task)  # a ValueError for an unknown task of a known domain
            task_names[domain].append(task_name(domain, task))
    runs: list[Run] = []
    for method in methods:
        for domain in domains:
            names = task_names[domain] if tasks else [task_name(domain, t) for t in DOMAIN_TASKS[domain]]
            if not names:
                continue
            base, choice = choices[method]
            rows = [[base, domain, name, seed, from_snapshot, choice] for name in names for seed in seeds]
            finetunes = [Run.of_row(row, pairing) for row in rows]
            if finetunes[0].from_scratch:
                finetunes = [Run(base, domain, name, seed) for name in names for seed in seeds]
            else:  # a pre-training once, when several labels of its method fine-tune from it
                pretrainings = (Run.of_row([base, domain, None, s, None], pairing)
                                for s in sorted({pairing.pretrain_seed(seed) for seed in seeds}))
                runs.extend(run for run in pretrainings if run not in runs)
            runs.extend(finetunes)
    return runs


def skill_choice_of(method: str) -> tuple[str, str | None]:
    """``(rl-zoo name, skill choice)`` of a ``--methods`` entry: ``cic`` -> ``("cic", None)``, ``cic+fixed`` ->
    ``("cic", "fixed")``; ``ValueError`` for an unknown method or a choice the method does not have."""
    name, plus, choice = method.partition("+")
    known = getattr(zoo.get_algo(name), "finetune_skill_choices", {})  # get_algo: a ValueError names the known ones
    if plus and choice not in known:
        raise ValueError(f"{method}: {name} fine-tunes with one of the skill choices {sorted(known)}" if known
                         else f"{method}: {name} fine-tunes without a skill to choose")
    return name, choice or None


def settings_use(runs: Sequence[Run], configs: dict[str, str | None] | None = None) -> dict[str, Any]:
    """What a command's runs use, as :func:`~sb3_cic.study.settings_record.check_study_settings` takes it: whether they
    pre-train (``pretrained``) and the yaml of each method (``configs``).

    :param runs: the command's runs (:func:`build_graph`)
    :param configs: the yaml of each method (missing or None: the default ``zoo_configs/<method>.yml``)
    """
    configs = configs or {}
    return {"pretrained": any(run.task is None for run in runs), "configs": {run.method: configs.get(run.method) for run in runs}}


def check_study(study: str | Path, runs: Sequence[Run]) -> list[Run]:
    """Check the study folder's runs against a command, before anything runs; return the runs still to do.

    ``ValueError`` (one line) when a finished run's ``result.json`` or ``eval.csv`` is damaged or disagree
    (:func:`~sb3_cic.study.run_result.read_run_result`), when an unfinished run has a corrupt checkpoint or has lost one,
    or when a pre-training lacks a snapshot that a fine-tuning still to do needs (the settings: see
    :func:`~sb3_cic.study.settings_record.check_study_settings` and :func:`~sb3_cic.study.record.check_run_settings`). Writes
    nothing.

    :param study: study folder
    :param runs: the command's runs (:func:`build_graph`)
    """
    from sb3_cic.study.results import read_done_run

    record = study_record(study) if Path(study).is_dir() else None
    todo = []
    for run in runs:
        folder = RunFolder(run.folder(study), identity={"run": run.row()})
        if folder.done:
            read_done_run(study, run, record)
            continue
        folder.read_meta()  # a ValueError for a corrupt or missing checkpoint, or one of another run
        todo.append(run)
    for run in runs:  # the snapshots the fine-tunings still to do start from
        if run.task is None and run not in todo:
            final = read_run_result(run.folder(study), finetune=False)["steps"]
            needed = {final if r.snapshot is None else r.snapshot for r in todo if r.dependency() == run}
            for step in sorted(needed):
                check_snapshot(snapshot_file(run.folder(study), step))
    return todo


def record_runs(study: str | Path, runs: Sequence[Run]) -> None:
    """Add ``runs`` to the runs listed in ``study.json`` (which :func:`~sb3_cic.study.settings_record.record_study_settings`
    wrote), for ``sb3-cic status``.

    :param study: study folder
    :param runs: the runs of a command
    """
    path = study_file(study)
    data = json.loads(path.read_text())
    listed = {tuple(Run.of_row(run, None).row()) for run in data.get("runs", [])}  # rows of 4 (before snapshot) to 6
    listed |= {tuple(run.row()) for run in runs}
    data["runs"] = [list(r) for r in sorted(listed, key=lambda r: (r[0], r[1], r[2] or "", r[3], r[4] or 0))]
    write_json(path, data)


def study_runs(study: str | Path) -> tuple[list[Run], Pairing | None]:
    """The runs listed in ``study.json`` (:func:`record_runs`; a lost ``study.json``: rebuilt from the run folders)
    and the study's pairing; ``ValueError`` if the folder is no study or its ``study.json`` is damaged.

    :param study: study folder
    """
    data = study_record(study)
    if data is None:
        raise ValueError(f"{study} is not a study folder (no study.json)")
    pairing = Pairing.from_record(data)
    return [Run.of_row(row, pairing) for row in data.get("runs", [])], pairing


def alive(pid: int, start_time: int | None = None) -> bool:
    """Whether the process ``pid`` of this host runs (a zombie, ended but not yet reaped, does not) and, given its
    ``start_time`` (:func:`~sb3_cic.study.checkpoint.process_start_time`), is the same process: a pid that the
    system gave to another process since is not."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass
    if start_time is not None and process_start_time(pid) not in (None, start_time):
        return False
    try:
        with open(f"/proc/{pid}/stat") as file:
            return file.read().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return True


#: the largest pid Linux gives (``/proc/sys/kernel/pid_max`` is at most 2**22)
PID_MAX = 2**22


def recorded_pid(progress: dict[str, Any]) -> int | None:
    """The pid a run's ``progress.json`` records; None where it is no pid (absent, no int, not in 1..PID_MAX: a
    damaged or edited file names no process, and ``-1`` or ``0`` would name many to ``kill``)."""
    pid = progress.get("pid")
    return pid if type(pid) is int and 0 < pid <= PID_MAX else None


def recorded_process_alive(progress: dict[str, Any]) -> bool:
    """Whether the process of this host that a run's ``progress.json`` names still runs, proven by its start time
    (:func:`alive`). A process recorded without its start time (by older code) is not proven, and so not taken for
    the run's, except on a host that cannot read start times at all (no ``/proc``), where the pid is all there is.

    :param progress: the run's ``progress.json``
    """
    pid, start = recorded_pid(progress), progress.get("start_time")
    if pid is None:
        return False
    if type(start) is not int:
        return start is None and process_start_time(os.getpid()) is None and alive(pid)
    return alive(pid, start) and process_start_time(pid) == start


def run_state(folder: RunFolder, kind: str = "finetune", check: Any = None) -> tuple[str, dict[str, Any]]:
    """The state of a run (one of :data:`STATES`) and what its folder says: ``checkpoint_step``, ``error``...

    :param folder: the run's folder
    :param kind: ``finetune`` or ``pretrain`` (what its ``result.json`` must hold)
    :param check: reads a done run's result, checked (a ``ValueError`` if it disagrees; None:
        :func:`~sb3_cic.study.run_result.read_run_result` alone)

    ``running``: its ``progress.json`` names a live process (on this host, the same process: its start time is the
    one recorded, :func:`recorded_process_alive`) or a process of another host; a run whose process is gone, or
    that names none (paused), is ``pending`` (it resumes from its checkpoint when started again).
    """
    if folder.done:
        try:
            if check is not None:
                check()
            else:
                read_run_result(folder.path, finetune=kind == "finetune")
        except ValueError as error:
            return "damaged", {"checkpoint_step": "none", "error": str(error)}
        return "done", {}
    progress = folder.read_progress() or {}
    try:
        meta = folder.read_meta()
        info: dict[str, Any] = {"checkpoint_step": meta["step"] if meta else 0}
    except ValueError as error:  # corrupt or lost: the next start of the run refuses it
        info = {"checkpoint_step": f"unusable ({error})"}
    if folder.error.exists():
        lines = folder.error.read_text().strip().splitlines()
        return "failed", {**info, "error": lines[-1] if lines else "", "traceback": str(folder.error)}
    if progress and recorded_pid(progress) is not None:  # one that names no process (a paused run's): pending
        here = progress.get("host") == socket.gethostname()
        if not here or recorded_process_alive(progress):
            return "running", {**info, "host": progress.get("host"), "pid": progress.get("pid")}
    return "pending", info


def time_left(unfinished: Sequence[tuple[Run, Any]], done: dict[Run, dict[str, Any]]) -> str | None:
    """The line of ``sb3-cic status`` on the time its unfinished runs still need, None without unfinished runs.

    Each unfinished run is expected to take the mean wall time of the study's done runs of its kind, method and
    domain (where there are none: of its kind and domain), times the share of its steps after its last checkpoint;
    a run with no done run to go by is counted apart. The sum is in hours of one run on one worker: divide by the
    workers that run them.

    :param unfinished: each unfinished run and its last checkpoint's step (not an int: none usable, step 0)
    :param done: the ``result.json`` of each done run
    """
    if not unfinished:
        return None
    times: dict[tuple[str, ...], list[tuple[float, int]]] = {}
    for run, result in done.items():
        steps = result.get("steps" if run.kind == "pretrain" else "finetune_steps")
        walls = result.get("wall_time_s")
        wall = walls.get(run.kind) if isinstance(walls, dict) else None
        if isinstance(steps, int) and steps > 0 and isinstance(wall, (int, float)):
            for key in ((run.kind, run.method, run.domain), (run.kind, run.domain)):
                times.setdefault(key, []).append((float(wall), steps))
    seconds, unknown = 0.0, 0
    for run, step in unfinished:
        known = times.get((run.kind, run.method, run.domain)) or times.get((run.kind, run.domain))
        if not known:
            unknown += 1
            continue
        step = step if isinstance(step, int) else 0
        seconds += sum(wall * max(0.0, 1 - step / steps) for wall, steps in known) / len(known)
    counted = len(unfinished) - unknown
    if not counted:
        return "Time left: not known yet (no done run of the unfinished runs' kind and domain to go by)"
    line = (f"Time left: about {seconds / 3600:.1f} run-hours for {counted} of the {len(unfinished)} unfinished runs "
            "(one run on one worker: divide by the workers)")
    if unknown:
        line += f", and {unknown} with no done run of their kind and domain to go by"
    return (line + "\n  each run: the mean wall time of the done runs of its kind, method and domain (else of its kind "
            "and domain), less its last checkpoint's share")


def status_report(study: str | Path) -> tuple[str, bool]:
    """The text of ``sb3-cic status`` and whether every run of the study is done.

    :param study: study folder
    """
    from sb3_cic.study.results import read_done_run, study_results

    runs, pairing = study_runs(study)
    record = study_record(study)
    counts: dict[tuple[str, str], Counter] = {}
    unfinished, failed, damaged = [], [], []
    done: dict[Run, dict[str, Any]] = {}
    left: list[tuple[Run, Any]] = []

    def check(run: Run) -> None:
        done[run] = read_done_run(study, run, record)

    for run in runs:
        folder = RunFolder(run.folder(study), identity={"run": run.row()})
        state, info = run_state(folder, run.kind, functools.partial(check, run))
        counts.setdefault((run.method, run.domain), Counter())[state] += 1
        if state not in ("done", "damaged"):
            where = f" on {info['host']} (pid {info['pid']})" if state == "running" else ""
            unfinished.append(f"  {run}: {state}{where}, last checkpoint at step {info['checkpoint_step']}")
            left.append((run, info["checkpoint_step"]))
        if state == "failed":
            failed.append(f"  {run}: {info['error']}\n    traceback: {info['traceback']}")
        if state == "damaged":
            damaged.append(f"  {run}: {info['error']}")
    total = Counter()
    for counter in counts.values():
        total.update(counter)
    if not runs:
        return f"{study}: no runs recorded yet (its study.json lists none): start them with sb3-cic study or protocol", False
    counted = f"{len(runs)} run{'' if len(runs) == 1 else 's'}"
    lines = [f"{study}: {counted}, " + ", ".join(f"{total[s]} {s}" for s in STATES)]
    lines.append(f"pre-training: {pairing.describe() if pairing else 'none yet (runs from scratch only)'}")
    holder, pause = StudyLock.holder(study), pause_requested(study)
    lines.append(f"driven now by {holder}" if holder else "no command drives it now")
    if holder and pause:
        lines.append(f"asked to pause ({pause}; sb3-cic pause): its runs stop at their next episode end, checkpointed")
    lines.append("")
    lines.append(f"| method | domain | {' | '.join(STATES)} |")
    lines.append("|---|---|" + "---:|" * len(STATES))
    for (method, domain), counter in sorted(counts.items()):
        lines.append(f"| {method} | {domain} | " + " | ".join(str(counter[s]) for s in STATES) + " |")
    if unfinished:
        lines += ["", "Unfinished runs:", *unfinished, "", time_left(left, done)]
    if failed:
        lines += ["", "Failed runs:", *failed]
    if damaged:
        lines += ["", "Damaged runs (not counted as done):", *damaged]
    listed = {run.folder(study) for run in runs}
    strays = [line for line in study_results(study, warn=False).refused if not any(f"{f}/" in line for f in listed)]
    if strays:
        lines += ["", "Run folders the study does not count (not of its record):", *(f"  {line}" for line in strays)]
    return "\n".join(lines), total["done"] == len(runs)
