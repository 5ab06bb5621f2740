"""What a study folder records of its settings: ``study.json``'s settings, pairing and yaml of each method
(:func:`check_study_settings`, :func:`record_study_settings`, :func:`conf_file_record`), each run folder's
``settings.json`` (:func:`run_record`) with the settings of the process that ran it (:func:`run_settings`), and the
identity a run's checkpoint records (:func:`run_identity`).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import torch as th
import yaml

from sb3_cic import zoo
from sb3_cic.study.checkpoint import write_json
from sb3_cic.study.layout import study_file
from sb3_cic.study.record import Pairing, changed_entries, rebuild_study_record, study_record
from sb3_cic.study.settings import Settings


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


