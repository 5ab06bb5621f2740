"""The score report of one study, built as a plain object (:class:`StudyReport`) from the fine-tunings it counts.

:func:`build_study_report` reads ``<study>/finetune/<label>/<task>/seed_<k>/result.json`` and ``eval.csv`` (the runs
the study counts: :func:`sb3_cic.study.results.study_results`) and computes:

* per-task mean and standard error (over seeds) of the final return and normalised score, and of the area under
  the learning curve (:func:`~sb3_cic.report.scores.curve_area`); wall times;
* how each method's runs pair with pre-trainings (:func:`~sb3_cic.report.scores.pairings`);
* per method the IQM, median, mean and optimality gap of normalised scores over the runs x tasks matrix with
  stratified-bootstrap 95% intervals (rliable, Agarwal et al., 2021), once per task set
  (:func:`~sb3_cic.report.scores.comparisons`);
* against the published numbers (:func:`~sb3_cic.report.scores.published_comparison`).

The runs of a method are the seeds it has on every one of its tasks (rliable needs a full matrix). Methods that ran
different tasks are compared once per task set. Aggregates need normalised scores, i.e. tasks with an expert score.
:mod:`sb3_cic.report.markdown` and :mod:`sb3_cic.report.figures` write it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sb3_cic.report.scores import aggregate_scores, comparisons, pairings, per_task, published_comparison, score_matrices


@dataclass
class Comparison:
    """The aggregates of the methods that ran every task of one task set.

    :param tasks: the tasks
    :param matrices: per method, its ``(runs, tasks)`` normalised scores
    :param seeds_of: per method, the seeds of its rows
    :param aggregates: ``{method: {metric: {"point", "low", "high"}}}``
    """

    tasks: list[str]
    matrices: dict[str, np.ndarray]
    seeds_of: dict[str, list[int]]
    aggregates: dict[str, dict[str, dict[str, float]]]


@dataclass
class StudyReport:
    """The numbers of one study's report.

    :param study: the study folder's name
    :param reps: bootstrap replications of the intervals
    :param runs_read: how many runs of which kind were read (:meth:`~sb3_cic.study.results.StudyResults.describe`)
    :param read: the study's counted results (:class:`~sb3_cic.study.results.StudyResults`)
    :param rows: per (method, task) (:func:`~sb3_cic.report.scores.per_task`)
    :param pairing: per method, its runs' pre-trainings (:func:`~sb3_cic.report.scores.pairings`)
    :param comparisons: the aggregates per task set, largest first
    :param published: against the published returns (None: no listed method)
    """

    study: str
    reps: int
    runs_read: list[str]
    read: Any
    rows: list[dict[str, Any]]
    pairing: dict[str, dict[str, Any]]
    comparisons: list[Comparison]
    published: dict[str, Any] | None

    @property
    def results(self) -> list[dict[str, Any]]:
        """The fine-tuning results the report is made of (with their curves)."""
        return self.read.results

    def to_json(self) -> dict[str, Any]:
        """The ``report.json`` content."""
        return {
            "study": self.study,
            "reps": self.reps,
            "runs_read": {"kinds": dict(self.read.kinds), "refused": self.read.refused, "unrecorded": dict(self.read.unrecorded)},
            "pairing": self.pairing,
            "per_task": self.rows,
            "comparisons": [
                {
                    "tasks": group.tasks,
                    "aggregates": group.aggregates,
                    "matrices": {label: {"seeds": group.seeds_of[label], "scores": m.tolist()} for label, m in group.matrices.items()},
                }
                for group in self.comparisons
            ],
            "published": self.published,
        }


def build_study_report(study: str | Path, reps: int = 2000, seed: int = 0) -> StudyReport:
    """The report of the study folder ``study``.

    :param study: study folder
    :param reps: bootstrap replications of the intervals
    :param seed: seed of the bootstrap
    :raises FileNotFoundError: no such folder, or no fine-tuning results
    """
    from sb3_cic.study.results import study_results

    study = Path(study)
    if not study.is_dir():
        raise FileNotFoundError(f"no such study folder: {study}")
    read = study_results(study)
    results = read.results
    if not results:
        raise FileNotFoundError(f"no fine-tuning results of the study {study} (under {study / 'finetune'})"
                                + (f"; {len(read.refused)} refused" if read.refused else ""))
    groups = []
    for tasks, labels in comparisons(results):
        matrices, _, seeds_of = score_matrices([r for r in results if r["label"] in labels], tasks)
        groups.append(Comparison(tasks, matrices, seeds_of, aggregate_scores(matrices, reps=reps, seed=seed)))
    return StudyReport(
        study=study.name,
        reps=reps,
        runs_read=read.describe(),
        read=read,
        rows=per_task(results),
        pairing=pairings(results),
        comparisons=groups,
        published=published_comparison(results, reps=reps, seed=seed),
    )
