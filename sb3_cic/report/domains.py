"""Per URLB domain: the fine-tuning learning curves of normalised scores, and our mean normalised score beside
Table 6's (the numbers of two figures of the whole-benchmark report)."""

from __future__ import annotations

from typing import Any

import numpy as np

from sb3_cic.constants import EXPERT_SCORES, PUBLISHED_RETURNS
from sb3_cic.report.scores import published_method


def _run_curves(results: list[dict[str, Any]], label: str, tasks: tuple[str, ...]) -> tuple[np.ndarray, list[np.ndarray]]:
    """The evaluation steps of ``label`` on ``tasks`` and, per seed that ran all of them on those steps, its mean
    normalised score over the tasks at each step."""
    curves: dict[int, dict[str, tuple[np.ndarray, np.ndarray]]] = {}
    for result in results:
        if result["label"] == label and result["task"] in tasks:
            curves.setdefault(result["seed"], {})[result["task"]] = result["curve"]
    full = [runs for _, runs in sorted(curves.items()) if set(runs) == set(tasks)]
    if not full:
        return np.zeros(0), []
    steps = full[0][tasks[0]][0]
    means = [
        np.mean([runs[task][1] / EXPERT_SCORES[task] for task in tasks], axis=0)
        for runs in full if all(np.array_equal(runs[task][0], steps) for task in tasks)
    ]
    return steps, means


def domain_curves(results: list[dict[str, Any]], domains: dict[str, tuple[str, ...]]) -> dict[str, dict[str, dict[str, Any]]]:
    """Per domain and method, the mean normalised score over the domain's tasks against fine-tuning steps: the mean
    over the runs (a run: one seed on every task of the domain) and their spread (lowest and highest run).

    :param results: fine-tuning results with their ``curve``
    :param domains: ``{domain: its tasks}``
    :return: ``{domain: {label: {"steps", "mean", "low", "high", "runs"}}}`` (lists; a method without a full run is absent)
    """
    out: dict[str, dict[str, dict[str, Any]]] = {}
    labels = sorted({r["label"] for r in results})
    for domain, tasks in domains.items():
        for label in labels:
            steps, runs = _run_curves(results, label, tasks)
            if runs:
                values = np.stack(runs)
                out.setdefault(domain, {})[label] = {
                    "steps": steps.tolist(), "mean": values.mean(axis=0).tolist(), "low": values.min(axis=0).tolist(),
                    "high": values.max(axis=0).tolist(), "runs": len(runs),
                }
    return out


def versus_published(
    returns: dict[str, dict[str, list[float]]], domains: dict[str, tuple[str, ...]]
) -> list[dict[str, Any]]:
    """Per label of a Table 6 method (or of a variant of one, :func:`~sb3_cic.report.scores.published_method`) and
    domain it ran in full: its mean normalised score over the domain's tasks (each task's mean over runs) beside
    Table 6's.

    :param returns: ``{label: {task: [final return per run]}}``
    :param domains: ``{domain: its tasks}``
    :return: ``[{"method", "domain", "published", "ours"}]``
    """
    rows = []
    for label in sorted(returns):
        table = PUBLISHED_RETURNS.get(published_method(label))
        for domain, tasks in domains.items():
            if table is None or not all(returns[label].get(task) for task in tasks):
                continue
            ours = np.mean([np.mean(returns[label][task]) / EXPERT_SCORES[task] for task in tasks])
            published = np.mean([table[task][0] / EXPERT_SCORES[task] for task in tasks])
            rows.append({"method": label, "domain": domain, "published": float(published), "ours": float(ours)})
    return rows
