"""Which fine-tunings a paired report counts, and how much a second pre-training moves a score.

URLB's protocol pairs fine-tuning seed s with the pre-training of seed s. A study of the CIC code's protocol
fine-tunes several seeds from one shared pre-training (its seeds 1 and 2 come from the pre-training of seed 0):
such runs are no draw of a second pre-training and are never counted beside the paired ones
(:func:`gather_results`). :func:`pretraining_differences` gives, per method and task, the difference between two
paired draws.
"""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from sb3_cic.report.scores import pairing_kind
from sb3_cic.study.layout import parse_label

#: the pre-training kinds (:func:`~sb3_cic.report.scores.pairing_kind`) that a paired report counts
COUNTED_KINDS: tuple[str, ...] = ("paired", "from_scratch")


@dataclass
class Gathered:
    """The fine-tunings of several studies that a paired report counts, and what it read.

    :param results: the counted results (final snapshots, the seeds asked for, paired or from scratch)
    :param runs_read: ``{study: lines}``, how many runs of which kind each study counted
        (:meth:`~sb3_cic.study.results.StudyResults.describe`)
    :param kinds: ``{study: {pre-training kind: runs}}`` of its final-snapshot fine-tunings, before the seeds were chosen
    :param left_out: the runs of the seeds asked for that are neither paired nor from scratch: each one's study,
        label, task, seed and pre-training seed
    :param repeated: the runs found in two folders with the same evaluations (:func:`same_run`), counted once (from
        the first folder): each one's label, task, seed and the two folders
    """

    results: list[dict[str, Any]] = field(default_factory=list)
    runs_read: dict[str, list[str]] = field(default_factory=dict)
    kinds: dict[str, dict[str, int]] = field(default_factory=dict)
    left_out: list[dict[str, Any]] = field(default_factory=list)
    repeated: list[dict[str, Any]] = field(default_factory=list)


def same_run(a: dict[str, Any], b: dict[str, Any]) -> bool:
    """Whether two fine-tuning results are one run made twice: the same pre-training seed, the same final return and
    the same evaluation at every step (``eval.csv``: e.g. DDPG from scratch at one seed and settings, in two studies)."""
    (steps_a, returns_a), (steps_b, returns_b) = a["curve"], b["curve"]
    return (a["pretrain_seed"] == b["pretrain_seed"] and a["final_return"] == b["final_return"]
            and np.array_equal(steps_a, steps_b) and np.array_equal(returns_a, returns_b))


def gather_results(studies: Sequence[str | Path], seeds: Sequence[int] | None = None) -> Gathered:
    """The fine-tuning results of several study folders that a paired report counts: final snapshots only (no
    ``label@step``), ``seeds`` only, and only runs fine-tuned from the pre-training of their own seed or from scratch
    (:data:`COUNTED_KINDS`); each study's runs of each kind are counted and the others named in ``left_out``. Each
    study's results are those it counts (:func:`sb3_cic.study.results.study_results`: the runs of its record, each
    checked; a run folder that disagrees is a one-line warning and not counted).

    :param studies: study folders
    :param seeds: fine-tuning seeds to keep (None: all)
    :raises ValueError: a folder without results, one (label, task, seed) in two folders with other evaluations (with
        the same: one run made twice, counted once and named in ``repeated``), or studies made with other settings
        (:func:`check_same_settings`)
    """
    from sb3_cic.study.results import study_results

    out, origin, settings = Gathered(), {}, {}
    for study in studies:
        counted = study_results(study)
        settings[str(study)] = counted.settings
        out.runs_read[str(study)] = counted.describe()
        if not counted.results:
            raise ValueError(f"no fine-tuning results under {Path(study) / 'finetune'}")
        finals = [r for r in counted.results if parse_label(r["label"])[1] is None]  # not from an intermediate snapshot
        out.kinds[str(study)] = dict(Counter(pairing_kind(r) for r in finals))
        for result in finals:
            if seeds is not None and result["seed"] not in seeds:
                continue
            if pairing_kind(result) not in COUNTED_KINDS:
                out.left_out.append({"study": str(study), **{key: result[key] for key in ("label", "task", "seed", "pretrain_seed")}})
                continue
            key = (result["label"], result["task"], result["seed"])
            if key in origin:
                if not same_run(origin[key], result):
                    raise ValueError(f"{key} is in both {origin[key]['study']} and {study} with other evaluations: "
                                     "give each run once")
                out.repeated.append({"label": key[0], "task": key[1], "seed": key[2],
                                     "studies": [origin[key]["study"], str(study)]})
                continue
            origin[key] = result
            result["study"] = str(study)
            out.results.append(result)
    check_same_settings(settings)
    return out


#: settings of a study that change no result it reports (the intermediate snapshots a pre-training saves)
RESULT_NEUTRAL_SETTINGS: tuple[str, ...] = ("snapshots",)


def check_same_settings(settings: dict[str, dict[str, Any] | None]) -> None:
    """``ValueError`` (one line) if the studies were made with other settings: their runs would be mixed in one
    table and one aggregate (1,000-step fine-tunings beside 2,000-step ones). A setting is compared between the
    studies that record it (a study of runs from scratch records no pre-training setting; the oldest studies record
    none); :data:`RESULT_NEUTRAL_SETTINGS` are not compared.

    :param settings: ``{study: its recorded settings}`` (None: none recorded)
    """
    recorded = {study: values for study, values in settings.items() if values}
    keys = sorted({key for values in recorded.values() for key in values} - set(RESULT_NEUTRAL_SETTINGS))
    differ = {}
    for key in keys:
        values = {study: values[key] for study, values in recorded.items() if key in values}
        if len({json.dumps(value, sort_keys=True) for value in values.values()}) > 1:
            differ[key] = values
    if differ:
        raise ValueError(f"the studies were made with other settings ({differ}): their runs would be mixed in one "
                         "report; report each study alone, or give studies of the same settings")


def pretraining_differences(results: list[dict[str, Any]]) -> dict[str, Any] | None:
    """Per method and task, the final return of the second seed minus the first's (two paired pre-trainings and their
    fine-tunings; from scratch, two runs), and per method the mean absolute difference of the normalised scores.

    :param results: counted results (:func:`gather_results`)
    :return: ``{"seeds": [first, second], "returns": {label: {task: difference}}, "normalised": {label: mean |diff|}}``,
        None with fewer than two seeds
    """
    seeds = sorted({r["seed"] for r in results})
    if len(seeds) < 2:
        return None
    first, second = seeds[:2]
    by_run = {(r["label"], r["task"], r["seed"]): r for r in results}
    returns: dict[str, dict[str, float]] = {}
    normalised: dict[str, list[float]] = {}
    for (label, task, seed), result in sorted(by_run.items()):
        other = by_run.get((label, task, first))
        if seed != second or other is None:
            continue
        returns.setdefault(label, {})[task] = float(result["final_return"] - other["final_return"])
        if result["final_normalized_score"] is not None and other["final_normalized_score"] is not None:
            normalised.setdefault(label, []).append(abs(result["final_normalized_score"] - other["final_normalized_score"]))
    return {"seeds": [first, second], "returns": returns,
            "normalised": {label: float(sum(v) / len(v)) for label, v in normalised.items()}}
