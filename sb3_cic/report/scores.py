"""The numbers of a report, computed from the fine-tuning results a study counts: per-task means, pairings,
normalised-score matrices, rliable's aggregates and the comparison with the published returns.

Everything here returns plain numbers (dicts, lists, arrays); :mod:`sb3_cic.report.markdown` and
:mod:`sb3_cic.report.figures` write them.
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from sb3_cic.constants import METHOD_VARIANTS
from sb3_cic.study.layout import parse_label

#: rliable aggregate metrics, in report order
METRICS: tuple[str, ...] = ("IQM", "Median", "Mean", "Optimality Gap")

#: the pre-training kinds of a fine-tuning (:func:`pairing_kind`)
PAIRING_KINDS: tuple[str, ...] = ("paired", "shared", "from_scratch", "unknown")


def published_method(label: str) -> str | None:
    """The method whose published numbers ``label`` is set beside: its method, or the one a variant runs
    (``cic_code+fixed``: ``cic``; :data:`~sb3_cic.constants.METHOD_VARIANTS`), whatever its skill choice; None for a
    label fine-tuned from another snapshot than the final one (the published runs fine-tune the final one)."""
    method, snapshot, _ = parse_label(label)
    return None if snapshot is not None else METHOD_VARIANTS.get(method, method)


def load_results(study: str | Path) -> list[dict[str, Any]]:
    """The fine-tuning results a study counts (:func:`sb3_cic.study.results.study_results`: the runs its record
    lists, or whose own settings prove they are the study's; each checked against its place), with their
    ``eval.csv`` as ``curve`` (timestep, return) arrays and each one's ``pretrain_seed`` (None: from scratch).
    A run folder that disagrees is a one-line warning and not counted."""
    from sb3_cic.study.results import study_results

    return study_results(study).results


def pairing_kind(result: dict[str, Any]) -> str:
    """How a fine-tuning pairs with its pre-training: ``paired`` (from the pre-training of its own seed, URLB's
    protocol), ``shared`` (from another seed's), ``from_scratch`` or ``unknown`` (pre-trained, seed not recorded).

    :param result: a fine-tuning result (:func:`load_results`: with ``pretrain_seed``)
    """
    if result.get("from_scratch"):
        return "from_scratch"
    if result["pretrain_seed"] is None:
        return "unknown"
    return "paired" if result["pretrain_seed"] == result["seed"] else "shared"


def pairings(results: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per method label, how its runs pair with pre-trainings (:func:`pairing_kind`): the seeds of each kind, those
    fine-tuned from another seed's pre-training by that seed (``shared``: ``{pre-training seed: [seeds]}``).

    :param results: fine-tuning results (:func:`load_results`)
    """
    out: dict[str, dict[str, Any]] = {}
    for result in sorted(results, key=lambda r: (r["label"], r["seed"])):
        entry = out.setdefault(result["label"], {"paired": [], "shared": {}, "from_scratch": [], "unknown": []})
        kind = pairing_kind(result)
        seeds = entry["shared"].setdefault(str(result["pretrain_seed"]), []) if kind == "shared" else entry[kind]
        if result["seed"] not in seeds:
            seeds.append(result["seed"])
    return out


def describe_pairing(entry: dict[str, Any]) -> str:
    """One line of :func:`pairings`: ``paired: seeds 0; shared pre-training seed 0: seeds 1, 2``."""

    def seeds(values: list[int]) -> str:
        return f"seed{'s' if len(values) > 1 else ''} {', '.join(map(str, values))}"

    parts = [f"paired: {seeds(entry['paired'])}"] if entry["paired"] else []
    parts += [f"shared pre-training seed {pre}: {seeds(values)}" for pre, values in sorted(entry["shared"].items())]
    parts += [f"from scratch: {seeds(entry['from_scratch'])}"] if entry["from_scratch"] else []
    parts += [f"pre-training seed unknown: {seeds(entry['unknown'])}"] if entry["unknown"] else []
    return "; ".join(parts)


def mean_se(values: Sequence[float]) -> tuple[float, float]:
    """Mean and standard error (NaN with one value) of ``values``."""
    values = np.asarray(values, dtype=float)
    se = float(values.std(ddof=1) / np.sqrt(len(values))) if len(values) > 1 else float("nan")
    return float(values.mean()), se


def curve_area(curve: tuple[np.ndarray, np.ndarray]) -> float:
    """Area under an evaluation curve ``(steps, returns)`` over its span of steps (trapezoid rule).

    The mean return over fine-tuning: a run that learns sooner has a larger area at the same final return
    (pre-training's head start). NaN with fewer than two evaluations.
    """
    steps, returns = curve
    if len(steps) < 2 or steps[-1] == steps[0]:
        return float("nan")
    return float(np.trapezoid(returns, steps) / (steps[-1] - steps[0]))


def per_task(results: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per (method label, task): seeds, mean and s.e. of the final return, the normalised score and the curve's area."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = defaultdict(list)
    for result in results:
        groups[(result["label"], result["task"])].append(result)
    rows = []
    for (label, task), runs in sorted(groups.items()):
        runs = sorted(runs, key=lambda r: r["seed"])
        ret_mean, ret_se = mean_se([r["final_return"] for r in runs])
        scores = [r["final_normalized_score"] for r in runs]
        score_mean, score_se = mean_se(scores) if all(s is not None for s in scores) else (float("nan"), float("nan"))
        auc_mean, auc_se = mean_se([curve_area(r["curve"]) for r in runs])
        rows.append(
            {
                "method": label,
                "task": task,
                "seeds": [r["seed"] for r in runs],
                "n": len(runs),
                "return_mean": ret_mean,
                "return_se": ret_se,
                "score_mean": score_mean,
                "score_se": score_se,
                "auc_mean": auc_mean,
                "auc_se": auc_se,
                "finetune_wall_s": float(np.mean([r["wall_time_s"]["finetune"] for r in runs])),
                "pretrain_wall_s": runs[0]["wall_time_s"].get("pretrain"),
            }
        )
    return rows


def comparisons(results: list[dict[str, Any]]) -> list[tuple[list[str], list[str]]]:
    """The task sets to aggregate over, each with the method labels that ran all of its tasks.

    One comparison per distinct set of tasks some label ran, largest first, kept when at least two labels
    ran all its tasks: a label that ran fewer tasks (a fine-tuning from an early snapshot on one task, say)
    gets its own comparison with every label on its tasks, and does not shrink the others' to its tasks.
    Labels that ran the same tasks give one comparison. If no two labels share a task set, each label is
    aggregated alone over its own tasks.

    :return: ``[(tasks, labels), ...]``, sorted by decreasing number of tasks
    """
    tasks: dict[str, set[str]] = defaultdict(set)
    for result in results:
        tasks[result["label"]].add(result["task"])
    sets = sorted({frozenset(t) for t in tasks.values()}, key=lambda t: (-len(t), sorted(t)))
    groups = [(sorted(s), sorted(label for label, t in tasks.items() if s <= t)) for s in sets]
    shared = [group for group in groups if len(group[1]) > 1]
    return shared or groups


def score_matrices(
    results: list[dict[str, Any]], tasks: Sequence[str] | None = None
) -> tuple[dict[str, np.ndarray], dict[str, list[str]], dict[str, list[int]]]:
    """Per method label, the ``(runs, tasks)`` matrix of normalised scores (seeds common to all its tasks).

    Methods with a task without normalised score are left out.

    :param results: fine-tuning results
    :param tasks: only these tasks (default: all)
    """
    by_label: dict[str, dict[str, dict[int, float | None]]] = defaultdict(lambda: defaultdict(dict))
    for result in results:
        if tasks is None or result["task"] in tasks:
            by_label[result["label"]][result["task"]][result["seed"]] = result["final_normalized_score"]
    matrices, tasks_of, seeds_of = {}, {}, {}
    for label, tasks in sorted(by_label.items()):
        names = sorted(tasks)
        seeds = sorted(set.intersection(*(set(tasks[t]) for t in names)))
        if not seeds or any(tasks[t][s] is None for t in names for s in seeds):
            continue
        matrices[label] = np.array([[tasks[t][s] for t in names] for s in seeds], dtype=float)
        tasks_of[label], seeds_of[label] = names, seeds
    return matrices, tasks_of, seeds_of


def aggregate_scores(
    matrices: dict[str, np.ndarray], reps: int = 2000, seed: int = 0
) -> dict[str, dict[str, dict[str, float]]]:
    """IQM, median, mean and optimality gap with stratified-bootstrap 95% intervals (rliable).

    :param matrices: per method, a ``(runs, tasks)`` matrix of normalised scores
    :param reps: bootstrap replications
    :param seed: seed of the bootstrap
    :return: ``{method: {metric: {"point", "low", "high"}}}``
    """
    from rliable import library as rly
    from rliable import metrics

    if not matrices:
        return {}

    def aggregates(scores: np.ndarray) -> np.ndarray:
        return np.array(
            [
                metrics.aggregate_iqm(scores),
                metrics.aggregate_median(scores),
                metrics.aggregate_mean(scores),
                metrics.aggregate_optimality_gap(scores),
            ]
        )

    # rliable's StratifiedBootstrap draws its resamples from NumPy's global generator (``random_state`` only
    # reaches arch, which does not draw them), so the global state is seeded here, per method so that a method's
    # interval does not depend on the others in the report, and restored afterwards.
    points, intervals = {}, {}
    state = np.random.get_state()
    try:
        for label, scores in matrices.items():
            np.random.seed(seed)
            point, interval = rly.get_interval_estimates({label: scores}, aggregates, reps=reps)
            points[label], intervals[label] = point[label], interval[label]
    finally:
        np.random.set_state(state)
    return {
        label: {
            name: {
                "point": float(points[label][i]),
                "low": float(intervals[label][0, i]),
                "high": float(intervals[label][1, i]),
            }
            for i, name in enumerate(METRICS)
        }
        for label in matrices
    }


def _published_rows(scores: dict[str, dict[str, list[float]]]) -> list[dict[str, Any]]:
    """Per label whose published method (:func:`published_method`) has published returns on all its tasks: its mean
    normalised score beside the published one, and ``ranked``: whether it is that method's own label (one row per
    published method enters a rank correlation; a variant or skill choice of it is set beside it, not ranked)."""
    from sb3_cic.constants import EXPERT_SCORES, MOSS_PUBLISHED_RETURNS, PUBLISHED_RETURNS

    rows = []
    for label, tasks in sorted(scores.items()):
        method = published_method(label)
        table, source = (
            (PUBLISHED_RETURNS.get(method), "Table 6") if method in PUBLISHED_RETURNS else (MOSS_PUBLISHED_RETURNS.get(method), "MOSS")
        )
        names = sorted(tasks)
        if table is None or not all(task in table for task in names):
            continue
        published = float(np.mean([table[task][0] / EXPERT_SCORES[task] for task in names]))
        ours = float(np.mean([np.mean(tasks[task]) for task in names]))
        rows.append({"method": label, "tasks": names, "ours": ours, "published": published, "source": source,
                     "ranked": label == method})
    return rows


def published_comparison(results: list[dict[str, Any]], reps: int = 2000, seed: int = 0) -> dict[str, Any] | None:
    """This study's methods against the CIC paper's Table 6 (:data:`~sb3_cic.constants.PUBLISHED_RETURNS`).

    Per label fine-tuned from its final snapshot (``ddpg`` from scratch) whose method Table 6 lists: the mean
    normalised score over the tasks it ran (each task's mean over seeds), beside Table 6's on the same tasks
    (published mean return / expert score); a variant or skill choice beside its method's (``cic_code+fixed``
    beside CIC's); MOSS beside its README's (:data:`~sb3_cic.constants.MOSS_PUBLISHED_RETURNS`). Over the Table 6
    methods (each one's own label only) that ran the same tasks, Spearman's rank correlation of the two, with a 95%
    percentile interval from ``reps`` bootstrap resamples of each (method, task)'s seeds. None without a listed
    method.

    :param results: fine-tuning results (:func:`load_results`)
    :param reps: bootstrap replications
    :param seed: seed of the bootstrap
    :return: ``{"tasks", "methods": [{"method", "tasks", "ours", "published", "source", "ranked"}], "spearman",
        "low", "high", "ranked"}`` (``method``: the label)
    """
    from scipy.stats import spearmanr

    scores: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    for result in results:
        if parse_label(result["label"])[1] is None and result["final_normalized_score"] is not None:  # final snapshots
            scores[result["label"]][result["task"]].append(result["final_normalized_score"])
    rows = _published_rows(scores)
    if not rows:
        return None
    # the rank correlation over the Table 6 methods of the most common task set (a tie: the most tasks, then the
    # first in sorted order, whatever the order of a set)
    candidates = [r for r in rows if r["source"] == "Table 6" and r["ranked"]]
    sets = [tuple(r["tasks"]) for r in candidates]
    common = max(sorted(set(sets)), key=lambda t: (sets.count(t), len(t))) if sets else ()
    ranked = [r for r in candidates if tuple(r["tasks"]) == common]
    out: dict[str, Any] = {"tasks": list(common), "methods": rows, "ranked": [r["method"] for r in ranked]}
    out["spearman"] = out["low"] = out["high"] = None
    if len(ranked) >= 3:
        published = [r["published"] for r in ranked]
        out["spearman"] = float(spearmanr([r["ours"] for r in ranked], published).statistic)
        rng = np.random.default_rng(seed)
        draws = []
        for _ in range(reps):
            means = [
                np.mean([np.mean(rng.choice(scores[r["method"]][task], len(scores[r["method"]][task]))) for task in common])
                for r in ranked
            ]
            draws.append(spearmanr(means, published).statistic)
        out["low"], out["high"] = (float(q) for q in np.nanpercentile(draws, [2.5, 97.5]))
    return out
