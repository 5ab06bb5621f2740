"""Score report of a study: per-task returns, normalised scores and rliable aggregates.

Reads ``<study>/finetune/<label>/<task>/seed_<k>/result.json`` and ``eval.csv`` (written by
:mod:`sb3_cic.protocol`) and writes into the study folder:

* ``report.md``: per-task mean and standard error (over seeds) of the final return and normalised
  score, and of the area under the learning curve (:func:`curve_area`); per method the IQM, median,
  mean and optimality gap of normalised scores over the runs x tasks matrix with stratified-bootstrap
  95% intervals (rliable, Agarwal et al., 2021); wall times;
* against the published numbers (:func:`published_comparison`): each method's mean normalised score beside the
  CIC paper's Table 6 (MOSS: its README's), and the rank correlation of the methods with its interval;
* ``report.json``: the same numbers;
* ``aggregates.png`` (rliable's ``plot_interval_estimates``; ``aggregates_1.png``, ... for the
  comparisons over smaller task sets) and ``learning_curves.png``
  (evaluation return against fine-tuning steps, mean +- s.e. over seeds, one panel per task).

The runs of a method are the seeds it has on every one of its tasks (rliable needs a full matrix).
Methods that ran different tasks are compared once per task set (:func:`comparisons`). Aggregates
need normalised scores, i.e. tasks with an expert score.
"""

from __future__ import annotations

import json
import math
from collections import defaultdict
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from sb3_cic.common.arguments import argument_parser, option_type

#: rliable aggregate metrics, in report order
METRICS: tuple[str, ...] = ("IQM", "Median", "Mean", "Optimality Gap")


def load_results(study: str | Path) -> list[dict[str, Any]]:
    """The fine-tuning results a study counts (:func:`sb3_cic.study.results.study_results`: the runs its record
    lists, or whose own settings prove they are the study's; each checked against its place), with their
    ``eval.csv`` as ``curve`` (timestep, return) arrays and each one's ``pretrain_seed`` (None: from scratch).
    A run folder that disagrees is a one-line warning and not counted."""
    from sb3_cic.study.results import study_results

    return study_results(study).results


def pairings(results: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per method label, how its runs pair with pre-trainings: the seeds fine-tuned from the pre-training of the
    same seed (``paired``), those fine-tuned from another seed's (``shared``: ``{pre-training seed: [seeds]}``) and
    those from scratch (``from_scratch``).

    :param results: fine-tuning results (:func:`load_results`)
    """
    out: dict[str, dict[str, Any]] = {}
    for result in sorted(results, key=lambda r: (r["label"], r["seed"])):
        entry = out.setdefault(result["label"], {"paired": [], "shared": {}, "from_scratch": [], "unknown": []})
        seed, pre = result["seed"], result["pretrain_seed"]
        if result.get("from_scratch"):
            kind = entry["from_scratch"]
        elif pre is None:
            kind = entry["unknown"]
        else:
            kind = entry["paired"] if pre == seed else entry["shared"].setdefault(str(pre), [])
        if seed not in kind:
            kind.append(seed)
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


def _mean_se(values: Sequence[float]) -> tuple[float, float]:
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
        ret_mean, ret_se = _mean_se([r["final_return"] for r in runs])
        scores = [r["final_normalized_score"] for r in runs]
        score_mean, score_se = _mean_se(scores) if all(s is not None for s in scores) else (float("nan"), float("nan"))
        auc_mean, auc_se = _mean_se([curve_area(r["curve"]) for r in runs])
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


def published_comparison(results: list[dict[str, Any]], reps: int = 2000, seed: int = 0) -> dict[str, Any] | None:
    """This study's methods against the CIC paper's Table 6 (:data:`~sb3_cic.constants.PUBLISHED_RETURNS`).

    Per method (a label fine-tuned from its final snapshot, ``ddpg`` from scratch) that Table 6 lists: the mean
    normalised score over the tasks it ran (each task's mean over seeds), beside Table 6's on the same tasks
    (published mean return / expert score); MOSS beside its README's (:data:`~sb3_cic.constants.MOSS_PUBLISHED_RETURNS`).
    Over the Table 6 methods that ran the same tasks, Spearman's rank correlation of the two, with a 95% percentile
    interval from ``reps`` bootstrap resamples of each (method, task)'s seeds. None without a listed method.

    :param results: fine-tuning results (:func:`load_results`)
    :param reps: bootstrap replications
    :param seed: seed of the bootstrap
    :return: ``{"tasks", "methods": [{"method", "tasks", "ours", "published", "source"}], "spearman", "low", "high",
        "ranked"}``
    """
    from scipy.stats import spearmanr

    from sb3_cic.constants import EXPERT_SCORES, MOSS_PUBLISHED_RETURNS, PUBLISHED_RETURNS

    scores: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    for result in results:
        if "@" not in result["label"] and result["final_normalized_score"] is not None:
            scores[result["label"]][result["task"]].append(result["final_normalized_score"])
    rows = []
    for label, tasks in sorted(scores.items()):
        table, source = (
            (PUBLISHED_RETURNS.get(label), "Table 6") if label in PUBLISHED_RETURNS else (MOSS_PUBLISHED_RETURNS.get(label), "MOSS")
        )
        names = sorted(tasks)
        if table is None or not all(task in table for task in names):
            continue
        published = float(np.mean([table[task][0] / EXPERT_SCORES[task] for task in names]))
        ours = float(np.mean([np.mean(tasks[task]) for task in names]))
        rows.append({"method": label, "tasks": names, "ours": ours, "published": published, "source": source})
    if not rows:
        return None
    # the rank correlation over the Table 6 methods of the most common task set
    sets = [tuple(r["tasks"]) for r in rows if r["source"] == "Table 6"]
    common = max(set(sets), key=sets.count) if sets else ()
    ranked = [r for r in rows if r["source"] == "Table 6" and tuple(r["tasks"]) == common]
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


def _fmt(value: float | None, digits: int = 3) -> str:
    return "–" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.{digits}f}"


def _pm(mean: float, se: float, digits: int) -> str:
    return _fmt(mean, digits) if math.isnan(se) else f"{_fmt(mean, digits)} ± {_fmt(se, digits)}"


def plot_aggregates(aggregates: dict[str, dict[str, dict[str, float]]], path: Path) -> None:
    """rliable's interval plot of the aggregates."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from rliable import plot_utils

    labels = sorted(aggregates)
    points = {m: np.array([aggregates[m][k]["point"] for k in METRICS]) for m in labels}
    intervals = {
        m: np.array([[aggregates[m][k]["low"] for k in METRICS], [aggregates[m][k]["high"] for k in METRICS]]) for m in labels
    }
    row_height = max(0.37, 1.6 / len(labels))  # rliable's default squeezes the x label in for few methods
    fig, _ = plot_utils.plot_interval_estimates(
        points,
        intervals,
        metric_names=list(METRICS),
        algorithms=labels,
        xlabel="Normalized score",
        row_height=row_height,
        xlabel_y_coordinate=-0.5 / (row_height * len(labels)),
    )
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)


def line_style(index: int) -> tuple[str, str]:
    """Colour and line style of the ``index``-th curve: matplotlib's ten colours, then the same colours dashed,
    dotted and dash-dotted, so that up to 40 methods are told apart."""
    return f"C{index % 10}", ("-", "--", ":", "-.")[(index // 10) % 4]


def plot_learning_curves(results: list[dict[str, Any]], path: Path) -> None:
    """Evaluation return against fine-tuning steps, mean +- s.e. over seeds, one panel per task."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tasks = sorted({r["task"] for r in results})
    labels = sorted({r["label"] for r in results})
    cols = min(4, max(1, len(tasks)))
    rows = math.ceil(len(tasks) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4 * cols, 3 * rows), squeeze=False)
    for ax, task in zip(axes.flat, tasks):
        for label in labels:
            curves = [r["curve"] for r in results if r["task"] == task and r["label"] == label and len(r["curve"][0])]
            if not curves:
                continue
            steps = curves[0][0]
            same = [c[1] for c in curves if np.array_equal(c[0], steps)]
            values = np.stack(same)
            mean = values.mean(axis=0)
            se = values.std(axis=0, ddof=1) / np.sqrt(len(same)) if len(same) > 1 else np.zeros_like(mean)
            color, linestyle = line_style(labels.index(label))
            ax.plot(steps, mean, color=color, linestyle=linestyle, label=label)
            ax.fill_between(steps, mean - se, mean + se, color=color, alpha=0.25)
        ax.set_title(task)
        ax.set_xlabel("fine-tuning steps")
        ax.set_ylabel("return")
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(tasks) :]:
        ax.axis("off")
    handles = {text: handle for ax in axes.flat for handle, text in zip(*ax.get_legend_handles_labels())}
    fig.tight_layout()
    fig.legend(handles.values(), handles.keys(), loc="upper center", bbox_to_anchor=(0.5, 0.0), ncol=min(6, len(handles)))
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)


def write_report(study: str | Path, reps: int = 2000, seed: int = 0) -> dict[str, Any]:
    """Write ``report.md``, ``report.json``, ``aggregates.png`` and ``learning_curves.png`` into ``study``.

    :param study: study folder
    :param reps: bootstrap replications of the intervals
    :param seed: seed of the bootstrap
    :return: the ``report.json`` content
    """
    study = Path(study)
    if not study.is_dir():
        raise FileNotFoundError(f"no such study folder: {study}")
    from sb3_cic.study.results import study_results

    read = study_results(study)
    results = read.results
    if not results:
        raise FileNotFoundError(f"no fine-tuning results of the study {study} (under {study / 'finetune'})"
                                + (f"; {len(read.refused)} refused" if read.refused else ""))
    rows = per_task(results)
    groups = []
    for tasks, labels in comparisons(results):
        matrices, _, seeds_of = score_matrices([r for r in results if r["label"] in labels], tasks)
        groups.append((tasks, matrices, seeds_of, aggregate_scores(matrices, reps=reps, seed=seed)))

    lines = [f"# URLB report: `{study.name}`", ""]
    lines += [
        "Final return = mean return of the last evaluation (deterministic episodes) of each run; "
        "normalised score = return / expert score. Mean ± standard error over seeds.",
        "",
        "## Runs read",
        "",
        *[f"- {line}" for line in read.describe()],
        "",
        "## Per task",
        "",
        "| method | task | seeds | final return | normalised score |",
        "|---|---|---:|---:|---:|",
    ]
    for row in rows:
        lines.append(
            f"| {row['method']} | {row['task']} | {row['n']} | {_pm(row['return_mean'], row['return_se'], 1)} "
            f"| {_pm(row['score_mean'], row['score_se'], 3)} |"
        )
    pairing = pairings(results)
    lines += [
        "",
        "## Pre-training of each run",
        "",
        "Paired: fine-tuning seed s from the pre-training of seed s (URLB's protocol); shared: from one pre-training "
        "of another seed (the CIC code's). A shared study's fine-tunings of its pre-training seed are paired by "
        "construction.",
        "",
        "| method | runs |",
        "|---|---|",
    ]
    lines += [f"| {label} | {describe_pairing(entry)} |" for label, entry in pairing.items()]
    lines += [
        "",
        "## Area under the learning curve",
        "",
        "Area under each run's evaluation curve divided by its span of steps (trapezoid rule): the mean "
        "return over fine-tuning, which credits learning sooner. Mean ± standard error over seeds.",
        "",
        "| method | task | seeds | mean return over fine-tuning |",
        "|---|---|---:|---:|",
    ]
    for row in rows:
        lines.append(f"| {row['method']} | {row['task']} | {row['n']} | {_pm(row['auc_mean'], row['auc_se'], 1)} |")
    lines += ["", f"## Aggregates (normalised scores, rliable, stratified bootstrap 95% CI, {reps} reps)", ""]
    shown = [group for group in groups if group[3]]
    if not shown:
        lines += ["No method has normalised scores on all its tasks (no expert score): no aggregates.", ""]
    for i, (tasks, _, seeds_of, aggregates) in enumerate(shown):
        figure = "aggregates.png" if i == 0 else f"aggregates_{i}.png"
        lines += [f"Over {', '.join(tasks)}:", ""]
        lines += ["| method | runs x tasks | IQM | median | mean | optimality gap |", "|---|---:|---:|---:|---:|---:|"]
        for label, agg in aggregates.items():
            cells = [f"{_fmt(agg[k]['point'])} [{_fmt(agg[k]['low'])}, {_fmt(agg[k]['high'])}]" for k in METRICS]
            lines.append(f"| {label} | {len(seeds_of[label])} x {len(tasks)} | " + " | ".join(cells) + " |")
        plot_aggregates(aggregates, study / figure)
        lines += ["", f"![aggregates]({figure})", ""]
    published = published_comparison(results, reps=reps, seed=seed)
    if published:
        lines += [
            "## Against the published numbers",
            "",
            "Mean normalised score over the tasks each method ran (each task's mean over seeds; from the final snapshot), "
            "beside the same mean of the published returns: the CIC paper's Table 6 (URLB's code, 2M pre-training "
            "steps, full size, 10 seeds) and, for MOSS, its README.",
            "",
            "| method | tasks | this study | published | source |",
            "|---|---:|---:|---:|---|",
        ]
        for row in published["methods"]:
            lines.append(
                f"| {row['method']} | {len(row['tasks'])} | {_fmt(row['ours'])} | {_fmt(row['published'])} | {row['source']} |"
            )
        if published["spearman"] is not None:
            lines += [
                "",
                f"Spearman's rank correlation over the {len(published['ranked'])} Table 6 methods on "
                f"{', '.join(published['tasks'])}: {_fmt(published['spearman'])} "
                f"[{_fmt(published['low'])}, {_fmt(published['high'])}] (95% interval, {reps} bootstrap resamples of "
                "each method's seeds per task).",
            ]
        lines.append("")
    plot_learning_curves(results, study / "learning_curves.png")
    lines += ["## Learning curves", "", "![learning curves](learning_curves.png)", "", "## Wall time", ""]
    lines += ["| method | task | pre-training (s) | fine-tuning per run (s) |", "|---|---|---:|---:|"]
    for row in rows:
        pre, fine = _fmt(row["pretrain_wall_s"], 1), _fmt(row["finetune_wall_s"], 1)
        lines.append(f"| {row['method']} | {row['task']} | {pre} | {fine} |")
    (study / "report.md").write_text("\n".join(lines) + "\n")

    report = {
        "study": study.name,
        "reps": reps,
        "runs_read": {"kinds": dict(read.kinds), "refused": read.refused, "unrecorded": dict(read.unrecorded)},
        "pairing": pairing,
        "per_task": rows,
        "comparisons": [
            {
                "tasks": tasks,
                "aggregates": aggregates,
                "matrices": {label: {"seeds": seeds_of[label], "scores": m.tolist()} for label, m in matrices.items()},
            }
            for tasks, matrices, seeds_of, aggregates in groups
        ],
        "published": published,
    }
    (study / "report.json").write_text(json.dumps(report, indent=2, default=float))
    return report


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    """``sb3-cic report <study>``."""
    parser = argument_parser(
        "sb3-cic report",
        "Score report of a URLB study folder: per-task scores, rliable aggregates and plots, written into the folder.",
    )
    parser.add_argument("study", help="study folder, written by sb3-cic study or sb3-cic protocol")
    parser.add_argument("--reps", type=option_type("reps"), default=2000, help="bootstrap replications")
    parser.add_argument("--seed", type=option_type("seed"), default=0, help="bootstrap seed")
    args = parser.parse_args(argv)
    report = write_report(args.study, reps=args.reps, seed=args.seed)
    print((Path(args.study) / "report.md").read_text())
    return report
