"""Which results a study counts: the runs its record lists, each checked against its place in the study.

A result is what its folder proves. The reports (``sb3-cic report``, ``sb3-cic benchmark-report``) and
``sb3-cic status`` read the fine-tunings that ``study.json`` lists, and a run folder the record does not list only
when the run's own ``settings.json`` proves that it was made with the study's settings (runs are copied between
studies on purpose); never a folder because its name matches a pattern. Each run's ``result.json`` is checked
(:func:`~sb3_cic.study.run_result.read_run_result`) against what its place says (:func:`expected_fields`): method, label,
task, seed, the pre-training seed of the study's pairing, the study's steps, the hash of the snapshot its
pre-training saved. A run that disagrees is named in one line (a warning) and not counted.

Runs made before runs recorded their settings (no ``settings.json``; every committed study) are read on what their
``result.json`` records: a field that is absent is "not recorded", a field that is present must agree. A folder
with neither ``study.json`` nor runs that record their settings (the oldest studies) is read run by run, each
checked against its place only: nothing says which settings it was made with, and the report says so.
"""

from __future__ import annotations

import json
import warnings
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sb3_cic import zoo
from sb3_cic.envs.tasks import DOMAIN_TASKS
from sb3_cic.study.run_result import read_run_result
from sb3_cic.study.record import Pairing, read_study_record, rebuild_study_record, run_settings_of
from sb3_cic.study.layout import parse_label, study_file

#: how a counted run came to be read (the report counts each)
KINDS: dict[str, str] = {
    "listed": "listed in study.json",
    "listed_legacy": "listed in study.json, made before runs recorded their settings",
    "copied": "not listed, its settings.json equal to the study's (copied in)",
    "unlisted_legacy": "not listed, made before runs recorded their settings (checked on its result.json)",
    "no_record": "in a folder without study.json (checked on its place only)",
}


def domain_of(task: str) -> str:
    """The URLB domain of a task name (``walker_flip`` -> ``walker``, ``point_mass_reach`` -> ``point_mass``);
    ``ValueError`` for none."""
    for domain, tasks in DOMAIN_TASKS.items():
        if task.startswith(f"{domain}_") and task[len(domain) + 1 :] in tasks:
            return domain
    raise ValueError(f"{task!r} is no task of a known domain")


def place_of(folder: Path) -> tuple[str, str, str, int, int | None, str | None]:
    """``(method, label, task, seed, snapshot, skill choice)`` of a fine-tuning folder
    ``finetune/<label>/<task>/seed_<k>``; ``ValueError`` for a folder the study's layout does not make."""
    label, task, name = folder.parts[-3:]
    if not name.startswith("seed_") or not name[5:].isdigit() or str(int(name[5:])) != name[5:]:
        raise ValueError(f"{folder} is no run folder of a study (seed_<k>)")
    try:
        method, snapshot, skill_choice = parse_label(label)
    except ValueError as error:
        raise ValueError(f"{folder} is no run folder of a study ({error})") from None
    zoo.get_algo(method)  # a ValueError for an unknown method
    domain_of(task)
    return method, label, task, int(name[5:]), snapshot, skill_choice


def snapshot_hash(study: Path, method: str, domain: str, pretrain_seed: int, pairing: Pairing, step: int | None) -> str | None:
    """The sha256 that a pre-training's ``result.json`` records of its snapshot at ``step`` (None: the final one);
    None when it records none (made before snapshots were hashed) or is not done."""
    from sb3_cic.study.layout import pretrain_dir

    folder = pretrain_dir(study, method, domain, pretrain_seed if pairing.paired else None)
    try:
        pre = json.loads((folder / "result.json").read_text())
        step = int(pre["steps"]) if step is None else step
        return pre.get("snapshot_sha256", {}).get(str(step))
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None


def expected_fields(
    study: str | Path, folder: Path, settings: dict[str, Any] | None, pairing: Pairing | None
) -> dict[str, Any]:
    """What the ``result.json`` of the fine-tuning in ``folder`` must record, from its place in the study and the
    study's settings (:func:`~sb3_cic.study.run_result.read_run_result` checks each field the run records).

    :param study: study folder
    :param folder: the run folder (``finetune/<label>/<task>/seed_<k>``)
    :param settings: the study's recorded settings (None: none recorded)
    :param pairing: the study's pairing (None: none recorded)
    """
    method, label, task, seed, snapshot, skill_choice = place_of(folder)
    from_scratch = not zoo.has_reward_module(zoo.get_algo(method))
    expected: dict[str, Any] = {"method": method, "label": label, "domain": domain_of(task), "task": task, "seed": seed,
                                "from_scratch": from_scratch}
    settings = settings or {}
    if settings.get("finetune_steps") is not None:
        expected["finetune_steps"] = settings["finetune_steps"]
    if from_scratch:
        expected["pretrain_seed"] = None
        return expected
    if skill_choice is not None:
        expected["finetune_skill_choice"] = skill_choice
    if snapshot is not None:
        expected["snapshot_steps"] = snapshot
    elif settings.get("pretrain_steps") is not None:
        expected["snapshot_steps"] = settings["pretrain_steps"]
    if pairing is not None:
        expected["pretrain_seed"] = pairing.pretrain_seed(seed)
        digest = snapshot_hash(Path(study), method, expected["domain"], expected["pretrain_seed"], pairing, snapshot)
        if digest is not None:
            expected["snapshot_sha256"] = digest
    return expected


def _settings_agree(study_settings: dict[str, Any], study_pairing: Pairing | None, record: dict[str, Any]) -> str | None:
    """None when a run's ``settings.json`` ``record`` was made with the study's settings; else what differs."""
    diff = {key: (value, study_settings.get(key)) for key, value in record["settings"].items()
            if study_settings.get(key) != value}
    if record.get("pairing") and study_pairing is not None and Pairing.from_record(record["pairing"]) != study_pairing:
        diff["pairing"] = (record["pairing"], study_pairing.record())
    return None if not diff else f"(run, study): {diff}"


@dataclass
class StudyResults:
    """The fine-tuning results a study counts, how each came to be read, and the run folders refused.

    :param results: the results (:func:`~sb3_cic.study.run_result.read_run_result`, with ``curve`` and ``pretrain_seed``)
    :param kinds: ``{kind of :data:`KINDS`: runs}``
    :param refused: one line per run folder not counted (what disagrees, in which file)
    :param unrecorded: ``{field: runs that do not record it}`` (made before it was recorded)
    :param settings: the study's recorded settings (None: none recorded)
    """

    results: list[dict[str, Any]] = field(default_factory=list)
    kinds: Counter = field(default_factory=Counter)
    refused: list[str] = field(default_factory=list)
    unrecorded: Counter = field(default_factory=Counter)
    settings: dict[str, Any] | None = None

    def describe(self) -> list[str]:
        """Lines for a report: how many runs of which kind were read, refused, and what some do not record."""
        lines = [f"{n} run{'' if n == 1 else 's'} {KINDS[kind]}" for kind, n in sorted(self.kinds.items())]
        lines += [f"{n} run{'' if n == 1 else 's'} that do not record {name} (made before it was recorded)"
                  for name, n in sorted(self.unrecorded.items())]
        mixed = Counter(json.dumps(r["run_settings"], sort_keys=True) for r in self.results if "run_settings" in r)
        if len(mixed) > 1:
            lines.append("the runs mix run settings (they can change results): "
                         + "; ".join(f"{n} with {value}" for value, n in sorted(mixed.items())))
        lines += [f"refused (not counted): {line}" for line in self.refused]
        return lines


#: fields a run made by older code may lack (counted by :attr:`StudyResults.unrecorded`)
RECORDED_LATER: tuple[str, ...] = ("pretrain_seed", "snapshot_sha256", "run_settings")


def study_results(study: str | Path, warn: bool = True) -> StudyResults:
    """The fine-tuning results a study counts (see the module docstring); ``ValueError`` (one line) for a damaged
    ``study.json``, and for a folder that is no study (neither ``study.json`` nor run folders).

    :param study: study folder
    :param warn: each refused run folder is also a warning (one line that names the file)
    """
    from sb3_cic.study.run import Run
    from sb3_cic.study.layout import run_folders

    study = Path(study)
    out = StudyResults()
    if study_file(study).exists():
        record: dict[str, Any] | None = read_study_record(study)
    else:
        try:
            record = rebuild_study_record(study)
        except ValueError:  # runs that do not record their settings: the oldest studies
            record = None
    candidates = [f for f in run_folders(study) if f.parent.parent.parent.name == "finetune" and (f / "result.json").exists()]
    if record is None and not candidates:
        raise ValueError(f"{study} is not a study folder (no study.json and no fine-tuning results)")
    settings = out.settings = None if record is None else record.get("settings", {})
    pairing = None if record is None else Pairing.from_record(record)
    listed: set[Path] = set()
    for row in [] if record is None else record.get("runs", []):
        run = Run.of_row(row, pairing)
        if run.task is not None:
            listed.add(run.folder(study))
            if (run.folder(study) / "result.json").exists() and run.folder(study) not in candidates:
                candidates.append(run.folder(study))
    for folder in sorted(candidates):
        try:
            expected = expected_fields(study, folder, settings, pairing)
            own = run_settings_of(folder)
            if own is not None:
                check_own_settings(study, folder, expected, own, None if record is None else (settings or {}), pairing)
            if record is None:
                kind = "no_record"
            elif folder in listed:
                kind = "listed" if own is not None else "listed_legacy"
            else:
                kind = "copied" if own is not None else "unlisted_legacy"
            result = read_run_result(folder, expected=expected)
        except ValueError as error:
            out.refused.append(str(error))
            if warn:
                warnings.warn(str(error), stacklevel=2)
            continue
        for name in RECORDED_LATER:
            if name not in result and not (name == "snapshot_sha256" and result.get("from_scratch")):
                out.unrecorded[name] += 1
        if "pretrain_seed" not in result:
            result["pretrain_seed"] = expected.get("pretrain_seed", _legacy_pretrain_seed(study, expected))
        out.kinds[kind] += 1
        out.results.append(result)
    return out


def check_own_settings(
    study: Path, folder: Path, expected: dict[str, Any], own: dict[str, Any], settings: dict[str, Any] | None,
    pairing: Pairing | None,
) -> None:
    """``ValueError`` (one line) when a run folder's ``settings.json`` (``own``) records another run than its place in
    the study (it was moved or copied), or other settings than the study's (``settings``; None: none recorded).

    :param study: study folder
    :param folder: the run folder
    :param expected: what its place says (:func:`expected_fields`)
    :param own: its ``settings.json``
    :param settings: the study's recorded settings (None: no ``study.json``, nothing to compare)
    :param pairing: the study's pairing
    """
    from sb3_cic.study.run import Run

    _, snapshot, skill_choice = parse_label(expected["label"])
    row = Run(expected["method"], expected["domain"], expected["task"], expected["seed"], snapshot,
              skill_choice=skill_choice).row()
    if list(own["run"]) != row:
        raise ValueError(f"{folder / 'settings.json'} records the run {own['run']} but its place in the study is "
                         f"{row}: it was moved or copied; move it back or delete it")
    diff = None if settings is None else _settings_agree(settings, pairing, own)
    if diff:
        raise ValueError(f"{folder / 'settings.json'} records other settings than {study_file(study)} "
                         f"{diff}: a run of another study, or one of the two files was changed; "
                         "delete the run folder or report it in its own study")


def _legacy_pretrain_seed(study: Path, expected: dict[str, Any]) -> int | None:
    """The pre-training seed of a fine-tuning of a folder without a study record whose ``result.json`` predates
    ``pretrain_seed``: its one (shared) pre-training's seed (None: from scratch, or nothing says)."""
    if expected["from_scratch"]:
        return None
    try:
        value = json.loads((study / "pretrain" / f"{expected['method']}_{expected['domain']}" / "result.json").read_text())["seed"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return value if isinstance(value, int) else None


def read_done_run(study: str | Path, run: Any, record: dict[str, Any] | None) -> dict[str, Any]:
    """The checked ``result.json`` of a done run of the study's record (:class:`~sb3_cic.study.run.Run`): its
    fields against its place and the study's settings (:func:`expected_fields`), its ``settings.json`` against its
    place; a one-line ``ValueError`` naming the file that disagrees.

    :param study: study folder
    :param run: the run
    :param record: the study's record (None: none)
    """
    settings = (record or {}).get("settings", {})
    pairing = None if record is None else Pairing.from_record(record)
    folder = run.folder(study)
    own = run_settings_of(folder)
    if own is not None and list(own["run"]) != run.row():
        raise ValueError(f"{folder / 'settings.json'} records the run {own['run']} but its place in the study is "
                         f"{run.row()}: it was moved or copied; move it back or delete it")
    if run.task is not None:
        return read_run_result(folder, expected=expected_fields(study, folder, settings, pairing))
    expected = {"method": run.method, "domain": run.domain, "seed": run.seed}
    if settings.get("pretrain_steps") is not None:
        expected["steps"] = settings["pretrain_steps"]
    return read_run_result(folder, finetune=False, expected=expected)
