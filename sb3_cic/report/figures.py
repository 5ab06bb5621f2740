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
