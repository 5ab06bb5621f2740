"""A run's own files: what a fine-tuning's ``result.json`` holds (:class:`FinetuneResult`), and the ``result.json``
of a done run and a fine-tuning's ``eval.csv`` read and checked.

The study's records (:mod:`sb3_cic.study.results`, :mod:`sb3_cic.study.graph`) and the reports
(:mod:`sb3_cic.report`) read a run through :func:`read_run_result`.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np


@dataclass
class FinetuneResult:
    """What ``result.json`` of a fine-tuning run holds."""

    method: str
    label: str
    domain: str
    task: str
    env_id: str
    seed: int
    from_scratch: bool
    snapshot_steps: int | None
    finetune_steps: int
    final_return: float
    final_normalized_score: float | None
    expert_score: float | None
    n_evaluations: int
    finetune_skill: list[float] | None
    #: the grid sweep's (candidate c, window return) pairs, when the skill was chosen by a sweep
    skill_sweep: list[list[float]] | None
    #: how the skill was chosen (the model's ``finetune_skill_choice``: ``sweep``, ``fixed``...; None: no skill)
    finetune_skill_choice: str | None = None
    #: the CIC variant of the pre-training (``paper`` or ``code``; None: a method without one)
    cic_variant: str | None = None
    #: the step of the checkpoint the run resumed from (0: it ran uninterrupted)
    resumed_from_step: int = 0
    #: the seed of the pre-training it started from (None: from scratch)
    pretrain_seed: int | None = None
    #: the sha256 of the snapshot it started from (None: from scratch)
    snapshot_sha256: str | None = None
    #: the settings of the process that can change its numbers (:func:`run_settings`)
    run_settings: dict[str, Any] = field(default_factory=dict)
    wall_time_s: dict[str, float | None] = field(default_factory=dict)
    hyperparams: dict[str, str] = field(default_factory=dict)


#: what a fine-tuning's ``result.json`` must hold, and of which type
FINETUNE_FIELDS: dict[str, type | tuple[type, ...]] = {
    "method": str, "label": str, "domain": str, "task": str, "seed": int, "final_return": (int, float),
    "final_normalized_score": (int, float, type(None)), "wall_time_s": dict,
}
#: what a pre-training's ``result.json`` must hold
PRETRAIN_FIELDS: dict[str, type | tuple[type, ...]] = {"method": str, "domain": str, "seed": int, "steps": int, "snapshots": dict}


def _damaged(path: Path, reason: Any) -> ValueError:
    return ValueError(f"{path} is damaged ({reason}); delete the run folder {path.parent} to run the run again")


def read_eval_csv(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """The ``(timesteps, returns)`` of a fine-tuning's ``eval.csv``; a one-line ``ValueError`` naming the file if it
    is missing or damaged (no evaluation, a value that is no number, steps that do not increase)."""
    path = Path(path)
    if not path.is_file():
        raise _damaged(path, "missing")
    try:
        with open(path, newline="") as file:
            reader = csv.DictReader(file)
            if not {"timestep", "mean_return"} <= set(reader.fieldnames or ()):
                raise ValueError(f"no timestep and mean_return columns: {reader.fieldnames}")
            rows = [(int(row["timestep"]), float(row["mean_return"])) for row in reader]
    except (ValueError, TypeError, csv.Error) as error:
        raise _damaged(path, error) from None
    steps, returns = np.asarray([r[0] for r in rows], dtype=np.int64), np.asarray([r[1] for r in rows], dtype=float)
    if not rows or not np.all(np.isfinite(returns)) or np.any(np.diff(steps) <= 0):
        raise _damaged(path, "no evaluation, a non-finite return or steps that do not increase")
    return steps, returns


def read_run_result(folder: str | Path, finetune: bool = True, expected: dict[str, Any] | None = None) -> dict[str, Any]:
    """The ``result.json`` of a done run, checked; a fine-tuning's with its ``eval.csv`` as ``curve``
    (``(timesteps, returns)`` arrays), whose last evaluation must be its ``final_return``.

    Nothing derived is trusted: a fine-tuning's ``final_normalized_score`` (and ``expert_score``) must be what its
    ``final_return`` and the task's expert score (:data:`~sb3_cic.constants.EXPERT_SCORES`) give, and each field of
    ``expected`` (what the run's place in its study and the study's settings say: method, label, task, seed,
    pretrain_seed, steps...; :func:`sb3_cic.study.results.expected_fields`) must be the run's. A field the run does
    not record (a run made before it was recorded) is not checked; a field it records must agree.

    A damaged file (unreadable, a field missing or of another type, a ``final_return`` that its ``eval.csv`` does
    not have, a field that disagrees) is a one-line ``ValueError`` that names it and says what to do.

    :param folder: the run folder
    :param finetune: a fine-tuning (False: a pre-training)
    :param expected: ``{field: value}`` the run's ``result.json`` must hold where it records the field (None: none)
    """
    from sb3_cic.constants import EXPERT_SCORES

    path = Path(folder) / "result.json"
    try:
        result = json.loads(path.read_text())
    except ValueError as error:  # (UnicodeDecodeError and JSONDecodeError are ValueErrors)
        raise _damaged(path, error) from None
    fields = FINETUNE_FIELDS if finetune else PRETRAIN_FIELDS
    if not isinstance(result, dict):
        raise _damaged(path, f"a {type(result).__name__}, not an object")
    wrong = [key for key, kind in fields.items() if not isinstance(result.get(key, ...), kind)]
    if wrong:
        raise _damaged(path, f"missing or wrong fields {wrong}")
    for key, value in (expected or {}).items():
        if key in result and result[key] != value:
            raise ValueError(f"{path} says {key} {result[key]!r} but its place in the study says {value!r}: it is not "
                             f"this study's run (copied or edited); delete the run folder {path.parent} to run the run again")
    if not finetune:
        return result
    steps, returns = curve = read_eval_csv(Path(folder) / "eval.csv")
    if not math.isclose(result["final_return"], returns[-1], rel_tol=1e-9, abs_tol=1e-9):
        raise ValueError(f"{path} says final_return {result['final_return']} but the last evaluation of its eval.csv "
                         f"(step {steps[-1]}) is {returns[-1]}: one of the two was changed; delete the run folder "
                         f"{path.parent} to run the run again")
    expert = EXPERT_SCORES.get(result["task"])
    score = None if expert is None else result["final_return"] / expert
    recorded = result["final_normalized_score"]
    if (score is None) != (recorded is None) or (score is not None and not math.isclose(recorded, score, rel_tol=1e-9, abs_tol=1e-12)) \
            or result.get("expert_score", expert) != expert:
        raise ValueError(f"{path} says final_normalized_score {recorded} (expert score {result.get('expert_score')}) but "
                         f"its final_return {result['final_return']} and the expert score {expert} of {result['task']} give "
                         f"{score}: one of them was changed; delete the run folder {path.parent} to run the run again")
    return {**result, "curve": curve}
