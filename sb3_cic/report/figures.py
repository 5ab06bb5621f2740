"""The figures of the reports, drawn from the numbers that :mod:`sb3_cic.report.scores` and the report builders
compute (rliable's own plotting where it has one)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from sb3_cic.report.scores import METRICS


def _pyplot() -> Any:
    """matplotlib's pyplot on the Agg backend (no display)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_aggregates(aggregates: dict[str, dict[str, dict[str, float]]], path: Path) -> None:
    """rliable's interval plot of the aggregates."""
    plt = _pyplot()
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
    plt = _pyplot()

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



#: the learning curves of a study report
LEARNING_CURVES = "learning_curves.png"


def aggregates_name(index: int) -> str:
    """The file of the ``index``-th aggregates figure of a report: ``aggregates.png``, then ``aggregates_1.png``..."""
    return "aggregates.png" if index == 0 else f"aggregates_{index}.png"

#: the figures of the whole-benchmark report, beside ``aggregates.png`` and ``learning_curves.png``
DOMAINS, VERSUS_PUBLISHED = "domains.png", "versus_published.png"


def _interval_arrays(aggregates: dict[str, Any], labels: list[str], names: list[str], key: Any) -> tuple[dict, dict]:
    """rliable's point and interval estimates of ``labels``: ``key(aggregates, label, name)`` gives each statistic."""
    points = {m: np.array([key(aggregates, m, n)["point"] for n in names]) for m in labels}
    intervals = {m: np.array([[key(aggregates, m, n)["low"] for n in names], [key(aggregates, m, n)["high"] for n in names]])
                 for m in labels}
    return points, intervals


def plot_aggregates_beside_published(
    aggregates: dict[str, dict[str, dict[str, float]]], published: dict[str, dict[str, tuple[float | None, str]]], path: Path
) -> None:
    """rliable's interval plot of the 12-task aggregates, the methods sorted by IQM (the best on top), each published
    value (Table 5's, or the median and mean from Table 6) marked beside ours with a black diamond."""
    plt = _pyplot()
    from rliable import plot_utils

    labels = sorted(aggregates, key=lambda label: aggregates[label]["IQM"]["point"])
    points, intervals = _interval_arrays(aggregates, labels, list(METRICS), lambda agg, m, n: agg[m][n])
    row_height = max(0.37, 1.6 / len(labels))
    fig, axes = plot_utils.plot_interval_estimates(
        points, intervals, metric_names=list(METRICS), algorithms=labels, xlabel="Normalized score (diamond: published)",
        row_height=row_height, xlabel_y_coordinate=-0.5 / (row_height * len(labels)),
    )
    for ax, metric in zip(np.atleast_1d(axes), METRICS):
        for y, label in enumerate(labels):
            value = published.get(label, {}).get(metric, (None, ""))[0]
            if value is not None:
                ax.plot([value], [y], marker="D", color="k", markersize=6, linestyle="none")
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)


def plot_domains(domains: dict[str, dict[str, dict[str, dict[str, float]]]], path: Path) -> None:
    """The paper's Figure 8 view: each method's IQM with its interval, one panel per domain (rliable's interval plot;
    the methods with every domain, sorted by their mean IQM, the best on top)."""
    plt = _pyplot()
    from rliable import plot_utils

    names = list(domains)
    labels = sorted(set.intersection(*(set(agg) for agg in domains.values())))
    labels.sort(key=lambda label: np.mean([domains[d][label]["IQM"]["point"] for d in names]))
    points, intervals = _interval_arrays(domains, labels, names, lambda agg, m, n: agg[n][m]["IQM"])
    row_height = max(0.37, 1.6 / len(labels))
    fig, _ = plot_utils.plot_interval_estimates(
        points, intervals, metric_names=names, algorithms=labels, xlabel="IQM of normalized scores",
        row_height=row_height, xlabel_y_coordinate=-0.5 / (row_height * len(labels)),
    )
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)


def plot_domain_curves(curves: dict[str, dict[str, dict[str, Any]]], path: Path) -> None:
    """Per domain, the mean normalised score over its tasks against fine-tuning steps, one line per method (the
    mean over its runs), the spread over the runs (lowest to highest) shaded."""
    plt = _pyplot()
    labels = sorted({label for by_label in curves.values() for label in by_label})
    fig, axes = plt.subplots(1, len(curves), figsize=(4.5 * len(curves), 3.5), squeeze=False)
    for ax, (domain, by_label) in zip(axes.flat, curves.items()):
        for label, curve in sorted(by_label.items()):
            color, linestyle = line_style(labels.index(label))
            ax.plot(curve["steps"], curve["mean"], color=color, linestyle=linestyle, label=label)
            ax.fill_between(curve["steps"], curve["low"], curve["high"], color=color, alpha=0.2)
        ax.set_title(domain)
        ax.set_xlabel("fine-tuning steps")
        ax.set_ylabel("mean normalised score")
        ax.grid(alpha=0.3)
    handles = {text: handle for ax in axes.flat for handle, text in zip(*ax.get_legend_handles_labels())}
    fig.tight_layout()
    fig.legend(handles.values(), handles.keys(), loc="upper center", bbox_to_anchor=(0.5, 0.0), ncol=min(6, len(handles)))
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)


def plot_versus_published(rows: list[dict[str, Any]], path: Path) -> None:
    """Ours against published: one point per method and domain (x: Table 6's mean normalised score, y: ours; a
    colour per method, a marker per domain), the diagonal drawn."""
    plt = _pyplot()
    labels = sorted({row["method"] for row in rows})
    domains = list(dict.fromkeys(row["domain"] for row in rows))
    markers = dict(zip(domains, "osD^v"))
    fig, ax = plt.subplots(figsize=(5.5, 5))
    for row in rows:
        color, _ = line_style(labels.index(row["method"]))
        ax.plot(row["published"], row["ours"], marker=markers[row["domain"]], color=color, linestyle="none", markersize=8)
    top = max([1.0] + [max(row["published"], row["ours"]) for row in rows])
    ax.plot([0, top], [0, top], color="k", linewidth=1, alpha=0.5)
    method_handles = [plt.Line2D([], [], color=line_style(i)[0], marker="o", linestyle="none") for i in range(len(labels))]
    domain_handles = [plt.Line2D([], [], color="k", markerfacecolor="none", marker=markers[d], linestyle="none") for d in domains]
    ax.legend(method_handles + domain_handles, labels + domains, loc="center left", bbox_to_anchor=(1.02, 0.5))
    ax.set_xlabel("Table 6: mean normalised score")
    ax.set_ylabel("ours: mean normalised score")
    ax.set_xlim(0, top)
    ax.set_ylim(0, top)
    ax.grid(alpha=0.3)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)
