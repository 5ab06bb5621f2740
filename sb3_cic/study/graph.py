"""The job graph of a study: its runs (pre-trainings, fine-tunings) and their dependencies, checked against
the study folder before anything runs, and the status of each run read back from its folder."""

from __future__ import annotations

import json
import os
import socket
from collections import Counter
from dataclasses import astuple, dataclass
from pathlib import Path
from typing import Any, Sequence

from envs.tasks import DOMAIN_TASKS
from sb3_cic import zoo
from sb3_cic.constants import EXPERT_SCORES
from sb3_cic.study.checkpoint import RunFolder, write_json
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

#: the URLB domains (those of the expert-scored tasks): ``--domains all``
URLB_DOMAINS: tuple[str, ...] = tuple(sorted({task.split("_")[0] for task in EXPERT_SCORES}))
#: the states :func:`run_state` tells apart
STATES: tuple[str, ...] = ("done", "running", "failed", "pending")


def all_methods() -> list[str]:
    """``--methods all``: the ten unsupervised methods (URLB's nine and MOSS) and ``ddpg`` (one name per class);
    the baselines of :data:`~sb3_cic.zoo.BASELINES_BY_NAME_ONLY` (``fixed``) only by name."""
    names: dict[type, str] = {}
    for name, cls in zoo.algorithms().items():
        if name not in zoo.BASELINES_BY_NAME_ONLY:
            names.setdefault(cls, name)
    return list(names.values())


@dataclass(frozen=True)
class Run:
    """One run of a study: a pre-training (``task`` None) or a fine-tuning of ``method`` on ``domain``.

    :param method: rl-zoo name of the method (``cic``...; ``ddpg`` fine-tunes from scratch)
    :param domain: URLB domain
    :param task: URLB task name (``walker_flip``), None for a pre-training
    :param seed: the run's seed (a pre-training's: the study's pre-training seed)
    :param snapshot: pre-training step of the snapshot a fine-tuning starts from (None: the final one)
    """

    method: str
    domain: str
    task: str | None
    seed: int
    snapshot: int | None = None

    @property
    def kind(self) -> str:
        """``pretrain`` or ``finetune``."""
        return "pretrain" if self.task is None else "finetune"

    @property
    def from_scratch(self) -> bool:
        """A fine-tuning without pre-training (``ddpg``)."""
        return not zoo.has_reward_module(zoo.get_algo(self.method))

    def folder(self, study: str | Path) -> Path:
        """The run's folder in ``study`` (:mod:`sb3_cic.study.layout`: ``cic@100000`` for a fine-tuning from the
        snapshot at 100,000 steps)."""
        if self.task is None:
            return pretrain_dir(study, self.method, self.domain)
        return finetune_dir(study, self.label, self.task, self.seed)

    @property
    def label(self) -> str:
        """The method's name in the study's folders and reports (``cic``, ``cic@100000``)."""
        return run_label(self.method, self.snapshot)

    def dependency(self, pretrain_seed: int) -> Run | None:
        """The pre-training a fine-tuning starts from (None for a pre-training or a run from scratch)."""
        if self.task is None or self.from_scratch:
            return None
        return Run(self.method, self.domain, None, pretrain_seed)

    def __str__(self) -> str:
        return f"pretrain {self.method} {self.domain}" if self.task is None else f"{self.label} {self.task} seed {self.seed}"


def build_graph(
    methods: Sequence[str],
    domains: Sequence[str],
    tasks: Sequence[str] | None,
    seeds: Sequence[int],
    pretrain_seed: int = 0,
    from_snapshot: int | None = None,
) -> list[Run]:
    """The runs of a study command, each pre-training before the fine-tunings that depend on it.

    ``ValueError`` for an unknown method, domain or task, a task of none of the domains, or bad seeds.

    :param methods: rl-zoo names, or ``["all"]``
    :param domains: URLB domains, or ``["all"]``
    :param tasks: tasks (``flip`` or ``walker_flip``: a short name applies to every domain that has it); None:
        each domain's tasks
    :param seeds: fine-tuning seeds
    :param pretrain_seed: seed of the pre-trainings
    :param from_snapshot: fine-tune from the snapshot at this pre-training step (None: the final one); runs
        from scratch ignore it
    """
    methods = all_methods() if list(methods) == ["all"] else [m.lower() for m in methods]
    domains = list(URLB_DOMAINS) if list(domains) == ["all"] else list(domains)
    for method in methods:
        zoo.get_algo(method)  # a ValueError names the known ones
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
            finetunes = [Run(method, domain, name, seed) for name in names for seed in seeds]
            if finetunes[0].dependency(pretrain_seed) is not None:
                runs.append(Run(method, domain, None, pretrain_seed))
                finetunes = [Run(method, domain, name, seed, from_snapshot) for name in names for seed in seeds]
            runs.extend(finetunes)
    return runs


def settings_use(runs: Sequence[Run]) -> dict[str, Any]:
    """What a command's runs use, as :func:`~sb3_cic.protocol.check_study_settings` takes it: whether they pre-train
    (``pretrained``) and the yaml of each method (``configs``: the default ``zoo_configs/<method>.yml``).

    :param runs: the command's runs (:func:`build_graph`)
    """
    return {"pretrained": any(run.task is None for run in runs), "configs": {run.method: None for run in runs}}


def check_study(study: str | Path, runs: Sequence[Run], pretrain_seed: int) -> list[Run]:
    """Check the study folder's runs against a command, before anything runs; return the runs still to do.

    ``ValueError`` when an unfinished run has a corrupt checkpoint or has lost one, or when a finished
    pre-training lacks the snapshot its fine-tunings need (the settings of ``study.json``: see
    :func:`~sb3_cic.protocol.check_study_settings`). Writes nothing.

    :param study: study folder
    :param runs: the command's runs (:func:`build_graph`)
    :param pretrain_seed: the command's pre-training seed
    """
    todo = []
    for run in runs:
        folder = RunFolder(run.folder(study))
        if folder.done:
            if run.task is None:  # the snapshots its fine-tunings start from
                final = json.loads(folder.result.read_text())["steps"]
                needed = {final if r.snapshot is None else r.snapshot for r in runs if r.dependency(pretrain_seed) == run}
                for step in sorted(needed or {final}):
                    check_snapshot(snapshot_file(folder.path, step))
            continue
        folder.read_meta()  # a ValueError for a corrupt or missing checkpoint
        todo.append(run)
    return todo


def record_runs(study: str | Path, runs: Sequence[Run]) -> None:
    """Add ``runs`` to the runs listed in ``study.json`` (which :func:`~sb3_cic.protocol.record_study_settings`
    wrote), for ``sb3-cic status``.

    :param study: study folder
    :param runs: the runs of a command
    """
    path = study_file(study)
    data = json.loads(path.read_text())
    listed = {astuple(Run(*run)) for run in data.get("runs", [])}  # rows of 4 (before snapshot) or 5
    listed |= {astuple(run) for run in runs}
    data["runs"] = sorted(listed, key=lambda r: (r[0], r[1], r[2] or "", r[3], r[4] or 0))
    write_json(path, data)


def study_runs(study: str | Path) -> list[Run]:
    """The runs listed in ``study.json`` (:func:`record_runs`); ``ValueError`` if the folder is no study.

    :param study: study folder
    """
    path = study_file(study)
    if not path.is_file():
        raise ValueError(f"{study} is not a study folder (no study.json)")
    return [Run(*run) for run in json.loads(path.read_text()).get("runs", [])]


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def run_state(folder: RunFolder) -> tuple[str, dict[str, Any]]:
    """The state of a run (one of :data:`STATES`) and what its folder says: ``checkpoint_step``, ``error``...

    :param folder: the run's folder

    ``running``: its ``progress.json`` names a live process (on this host) or another host; a run whose process
    is gone is ``pending`` (it resumes from its checkpoint when started again).
    """
    if folder.done:
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
    if progress:
        here = progress.get("host") == socket.gethostname()
        if not here or _alive(int(progress.get("pid", -1))):
            return "running", {**info, "host": progress.get("host"), "pid": progress.get("pid")}
    return "pending", info


def status_report(study: str | Path) -> tuple[str, bool]:
    """The text of ``sb3-cic status`` and whether every run of the study is done.

    :param study: study folder
    """
    runs = study_runs(study)
    counts: dict[tuple[str, str], Counter] = {}
    unfinished, failed = [], []
    for run in runs:
        folder = RunFolder(run.folder(study))
        state, info = run_state(folder)
        counts.setdefault((run.method, run.domain), Counter())[state] += 1
        if state != "done":
            where = f" on {info['host']} (pid {info['pid']})" if state == "running" else ""
            unfinished.append(f"  {run}: {state}{where}, last checkpoint at step {info['checkpoint_step']}")
        if state == "failed":
            failed.append(f"  {run}: {info['error']}\n    traceback: {info['traceback']}")
    total = Counter()
    for counter in counts.values():
        total.update(counter)
    counted = f"{len(runs)} run{'' if len(runs) == 1 else 's'}"
    lines = [f"{study}: {counted}, " + ", ".join(f"{total[s]} {s}" for s in STATES), ""]
    lines.append(f"| method | domain | {' | '.join(STATES)} |")
    lines.append("|---|---|" + "---:|" * len(STATES))
    for (method, domain), counter in sorted(counts.items()):
        lines.append(f"| {method} | {domain} | " + " | ".join(str(counter[s]) for s in STATES) + " |")
    if unfinished:
        lines += ["", "Unfinished runs:", *unfinished]
    if failed:
        lines += ["", "Failed runs:", *failed]
    return "\n".join(lines), total["done"] == len(runs)
