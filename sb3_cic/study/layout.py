"""The folder layout of a study, the one place that names its folders and files.

One study lives in one folder::

    <study>/study.json                      the settings the study was made with, its pairing, and its runs
    <study>/study.lock                      held by the command that drives the study (one at a time)
    <study>/pause.json                      while that command is asked to pause (``sb3-cic pause``)
    <study>/pretrain/<method>_<domain>/snapshot_<steps>.zip, result.json, settings.json
    <study>/pretrain/<method>_<domain>_seed<s>/...      (paired studies: the pre-training of seed s > 0)
    <study>/finetune/<label>/<task>/seed_<k>/eval.csv, result.json, settings.json
    <study>/tensorboard/...

Pre-training folders (:func:`pretrain_dir`): a study with shared pre-training (every fine-tuning seed from one
pre-training seed, as the CIC code; every study made before pairing existed) has one pre-training per method and
domain, ``<method>_<domain>``, whatever its seed (its ``result.json`` records it). A paired study (URLB: fine-tuning
seed s from pre-training seed s) has one per seed: ``<method>_<domain>`` for seed 0, the same run as a shared
seed-0 pre-training, and ``<method>_<domain>_seed<s>`` for the others.

Each run folder records the settings it was made with (``settings.json``); while the run is unfinished it holds
``checkpoint.zip`` and ``progress.json`` (``error.txt`` if it raised; :class:`~sb3_cic.study.checkpoint.RunFolder`). ``<label>`` is the method name when fine-tuning from the
final snapshot, ``<method>@<steps>`` from another snapshot, ``<method>+<choice>`` with another fine-tuning skill
choice (:func:`run_label`); ``<task>`` is the URLB task name
(``walker_flip``, :func:`task_name`). The run code (:mod:`sb3_cic.protocol`) and the job graph
(:mod:`sb3_cic.study.graph`) both read the layout here.
"""

from __future__ import annotations

import zipfile
from pathlib import Path

from sb3_cic.envs.tasks import DOMAIN_TASKS


def study_file(study: str | Path) -> Path:
    """``<study>/study.json``: the study's settings and runs."""
    return Path(study) / "study.json"


def lock_file(study: str | Path) -> Path:
    """``<study>/study.lock``: locked by the command that drives the study."""
    return Path(study) / "study.lock"


def pause_file(study: str | Path) -> Path:
    """``<study>/pause.json``: the request that the command driving the study pause (``sb3-cic pause``)."""
    return Path(study) / "pause.json"


def task_name(domain: str, task: str) -> str:
    """URLB task name (``walker_flip``) of a domain and task (``flip`` or ``walker_flip``)."""
    return task if task.startswith(f"{domain}_") else f"{domain}_{task}"


def task_env_id(domain: str, task: str) -> str:
    """Gymnasium id of a task (``URLB/walker-flip-v0``); ``ValueError`` for a task the domain does not have."""
    short = task[len(domain) + 1 :] if task.startswith(f"{domain}_") else task
    if short not in DOMAIN_TASKS[domain]:
        raise ValueError(f"unknown task {task!r} of {domain}; known: {DOMAIN_TASKS[domain]}")
    return f"URLB/{domain}-{short}-v0"


def run_label(method: str, snapshot: int | None = None, skill_choice: str | None = None) -> str:
    """The method's name in the study's folders and reports: ``cic``; ``cic@100000`` for fine-tunings from the
    snapshot at 100,000 steps (None: the final one); ``cic+fixed`` for fine-tunings that choose their skill by the
    method's ``fixed`` choice (None: the yaml's ``finetune_skill_choice``)."""
    return method + ("" if snapshot is None else f"@{snapshot}") + ("" if skill_choice is None else f"+{skill_choice}")


def parse_label(label: str) -> tuple[str, int | None, str | None]:
    """``(method, snapshot, skill_choice)`` of a :func:`run_label`; ``ValueError`` for a label it does not make."""
    rest, plus, skill_choice = label.partition("+")
    method, at, step = rest.partition("@")
    snapshot = int(step) if step.isdigit() and str(int(step)) == step else None
    if not method or (at and snapshot is None) or (plus and not skill_choice.isidentifier()):
        raise ValueError(f"{label!r} is no label of a study's runs (<method>[@<step>][+<skill choice>])")
    return method, snapshot, skill_choice or None


def pretrain_dir(study: str | Path, method: str, domain: str, seed: int | None = None) -> Path:
    """Folder of the pre-training of ``method`` on ``domain``.

    :param seed: the seed of a paired study's pre-training (``<method>_<domain>`` for 0, ``<method>_<domain>_seed<s>``
        for the others); None: a shared-pre-training study's one pre-training (``<method>_<domain>``)
    """
    suffix = "" if not seed else f"_seed{seed}"
    return Path(study) / "pretrain" / f"{method}_{domain}{suffix}"


def run_folders(study: str | Path) -> list[Path]:
    """The run folders under ``study`` (pre-trainings and fine-tunings), whatever their state."""
    study = Path(study)
    return sorted(p for p in [*study.glob("pretrain/*"), *study.glob("finetune/*/*/seed_*")] if p.is_dir())


def snapshot_file(folder: str | Path, step: int) -> Path:
    """The snapshot a pre-training saved at ``step`` in its ``folder``."""
    return Path(folder) / f"snapshot_{step}.zip"


def finetune_dir(study: str | Path, label: str, task: str, seed: int) -> Path:
    """Folder of a fine-tuning run (``label``: :func:`run_label`; ``task``: the URLB task name, ``walker_flip``)."""
    return Path(study) / "finetune" / label / task / f"seed_{seed}"


def check_snapshot(path: Path) -> None:
    """``ValueError`` unless ``path`` is a readable saved model (a zip with SB3's ``data``, CRCs intact)."""
    if not path.is_file():
        raise ValueError(f"the snapshot {path} is missing (its pre-training's result.json lists it)")
    try:
        with zipfile.ZipFile(path) as archive:
            if "data" not in archive.namelist() or archive.testzip() is not None:
                raise zipfile.BadZipFile("no readable 'data' entry")
    except (OSError, zipfile.BadZipFile) as error:
        raise ValueError(f"the snapshot {path} is corrupt ({error!r}); pre-train again in a new study folder") from error
