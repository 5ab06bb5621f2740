"""The reports as markdown, written from the report objects (:class:`~sb3_cic.report.study_report.StudyReport`,
:class:`~sb3_cic.report.benchmark.BenchmarkReport`); nothing is computed here beyond the mean of the runs a cell
shows."""

from __future__ import annotations

from typing import Any

import numpy as np

from sb3_cic.constants import PUBLISHED_RETURNS
from sb3_cic.envs.tasks import URLB_TASKS
from sb3_cic.report.benchmark import ALL_12, EXACT_PERMUTATIONS_UP_TO, URLB_DOMAINS, BenchmarkReport
from sb3_cic.report.figures import DOMAINS, LEARNING_CURVES, VERSUS_PUBLISHED, aggregates_name
from sb3_cic.report.scores import METRICS, PAIRING_KINDS, describe_pairing, published_method
from sb3_cic.report.study_report import StudyReport
from sb3_cic.report.text import fmt, pm, short_name
from sb3_cic.report.verdicts import WORDS

#: how the report names each pre-training kind (:func:`~sb3_cic.report.scores.pairing_kind`)
KIND_WORDS: dict[str, str] = {
    "paired": "paired (from the pre-training of the same seed)",
    "shared": "from another seed's pre-training (not paired)",
    "from_scratch": "from scratch",
    "unknown": "pre-training seed unknown (not paired)",
}


def _study_tables(report: StudyReport) -> list[str]:
    """Runs read, per task, pre-training of each run, area under the learning curve."""
    lines = [
        "Final return = mean return of the last evaluation (deterministic episodes) of each run; "
        "normalised score = return / expert score. Mean ± standard error over seeds.",
        "",
        "## Runs read",
        "",
        *[f"- {line}" for line in report.runs_read],
        "",
        "## Per task",
        "",
        "| method | task | seeds | final return | normalised score |",
        "|---|---|---:|---:|---:|",
    ]
    for row in report.rows:
        lines.append(
            f"| {row['method']} | {row['task']} | {row['n']} | {pm(row['return_mean'], row['return_se'], 1)} "
            f"| {pm(row['score_mean'], row['score_se'], 3)} |"
        )
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
    lines += [f"| {label} | {describe_pairing(entry)} |" for label, entry in report.pairing.items()]
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
    lines += [f"| {row['method']} | {row['task']} | {row['n']} | {pm(row['auc_mean'], row['auc_se'], 1)} |" for row in report.rows]
    return lines


def _study_aggregates(report: StudyReport) -> list[str]:
    """One table and figure per task set that has aggregates (:func:`shown_comparisons`)."""
    lines = ["", f"## Aggregates (normalised scores, rliable, stratified bootstrap 95% CI, {report.reps} reps)", ""]
    shown = shown_comparisons(report)
    if not shown:
        lines += ["No method has normalised scores on all its tasks (no expert score): no aggregates.", ""]
    for i, group in enumerate(shown):
        lines += [f"Over {', '.join(group.tasks)}:", ""]
        lines += ["| method | runs x tasks | IQM | median | mean | optimality gap |", "|---|---:|---:|---:|---:|---:|"]
        for label, agg in group.aggregates.items():
            cells = [f"{fmt(agg[k]['point'])} [{fmt(agg[k]['low'])}, {fmt(agg[k]['high'])}]" for k in METRICS]
            lines.append(f"| {label} | {len(group.seeds_of[label])} x {len(group.tasks)} | " + " | ".join(cells) + " |")
        lines += ["", f"![aggregates]({aggregates_name(i)})", ""]
    return lines


def shown_comparisons(report: StudyReport) -> list[Any]:
    """The task sets of a study report that have aggregates, in the order of their figures."""
    return [group for group in report.comparisons if group.aggregates]


def _study_published(published: dict[str, Any] | None, reps: int) -> list[str]:
    """Each method's mean normalised score beside the published one, and the rank correlation."""
    if not published:
        return []
    lines = [
        "## Against the published numbers",
        "",
        "Mean normalised score over the tasks each method ran (each task's mean over seeds; from the final snapshot), "
        "beside the same mean of the published returns: the CIC paper's Table 6 (URLB's code, 2M pre-training "
        "steps, full size, 10 seeds) and, for MOSS, its README. A variant or skill choice of a method "
        "(`cic_code+fixed`) is set beside that method's published numbers and left out of the rank correlation.",
        "",
        "| method | tasks | this study | published | source |",
        "|---|---:|---:|---:|---|",
    ]
    for row in published["methods"]:
        lines.append(f"| {row['method']} | {len(row['tasks'])} | {fmt(row['ours'])} | {fmt(row['published'])} | {row['source']} |")
    if published["spearman"] is not None:
        lines += [
            "",
            f"Spearman's rank correlation over the {len(published['ranked'])} Table 6 methods on "
            f"{', '.join(published['tasks'])}: {fmt(published['spearman'])} "
            f"[{fmt(published['low'])}, {fmt(published['high'])}] (95% interval, {reps} bootstrap resamples of "
            "each method's seeds per task).",
        ]
    return lines + [""]


def render_study(report: StudyReport) -> str:
    """The ``report.md`` of one study."""
    lines = [f"# URLB report: `{report.study}`", ""]
    lines += _study_tables(report) + _study_aggregates(report) + _study_published(report.published, report.reps)
    lines += ["## Learning curves", "", f"![learning curves]({LEARNING_CURVES})", "", "## Wall time", ""]
    lines += ["| method | task | pre-training (s) | fine-tuning per run (s) |", "|---|---|---:|---:|"]
    for row in report.rows:
        lines.append(f"| {row['method']} | {row['task']} | {fmt(row['pretrain_wall_s'], 1)} | {fmt(row['finetune_wall_s'], 1)} |")
    return "\n".join(lines) + "\n"


def aggregate_table(
    aggregates: dict[str, dict[str, dict[str, float]]], published: dict[str, dict[str, tuple[float | None, str]]],
    n_runs: dict[str, int],
) -> list[str]:
    """Our four statistics beside the published ones (``{label: {metric: (value, source)}}``), one row per method,
    best IQM first."""
    lines = ["| method | runs | " + " | ".join(f"{m} ours | {m} published" for m in METRICS) + " |"]
    lines.append("|---|---:|" + "---:|---:|" * len(METRICS))
    for label, agg in sorted(aggregates.items(), key=lambda item: -item[1]["IQM"]["point"]):
        cells = []
        for metric in METRICS:
            ours, (value, source) = agg[metric], published[label][metric]
            interval = "" if ours["low"] == ours["high"] else f" [{fmt(ours['low'])}, {fmt(ours['high'])}]"
            cells.append(f"{fmt(ours['point'])}{interval}")
            cells.append(f"{fmt(value)}" + (" (T6)" if source == "Table 6" else ""))
        lines.append(f"| {label} | {n_runs[label]} | " + " | ".join(cells) + " |")
    return lines


def _per_task_beside_table6(returns: dict[str, dict[str, list[float]]]) -> list[str]:
    """Per task, each method's mean final return over its seeds beside Table 6's (the method it runs: a variant's,
    :func:`~sb3_cic.report.scores.published_method`)."""
    labels = sorted(returns)
    lines = ["| task | " + " | ".join(labels) + " |", "|---|" + "---:|" * len(labels)]
    for task in URLB_TASKS:
        cells = []
        for label in labels:
            runs = returns[label].get(task)
            mine = f"{np.mean(runs):.1f}" + (f" (n={len(runs)})" if runs and len(runs) > 1 else "") if runs else "–"
            table = PUBLISHED_RETURNS.get(published_method(label), {}).get(task)
            cells.append(mine + (f" / {table[0]:g}±{table[1]:g}" if table else ""))
        lines.append(f"| {task} | " + " | ".join(cells) + " |")
    return lines


def _agreement_table(agreement: dict[str, dict[str, Any] | None], reps: int) -> list[str]:
    """Spearman against Table 6 per task set, with its p-value and intervals."""
    lines = [
        "## Does our order of the methods agree with Table 6's?",
        "",
        "Spearman's rank correlation of the mean normalised scores. p (permutation): the share of re-orderings of our "
        f"means that agree with Table 6 at least as well (one-sided; every re-ordering up to {EXACT_PERMUTATIONS_UP_TO} "
        f"methods, else {5 * reps} random ones). Methods interval: 95% over resamples of the "
        "methods. Seeds interval: 95% over resamples of each method's seeds per task, the methods fixed (– with one seed). "
        "Methods and runs: 95% over resamples of the methods and, within each, of its runs per task, together.",
        "",
        "| tasks | methods | Spearman | p (permutation) | methods interval | seeds interval | methods and runs |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for name, row in agreement.items():
        if row is None:
            lines.append(f"| {name} | – | – | – | – | – | – |")
            continue
        seeds_interval = "–" if row["seeds_low"] is None else f"[{fmt(row['seeds_low'])}, {fmt(row['seeds_high'])}]"
        lines.append(
            f"| {name} | {len(row['methods'])} | {fmt(row['rho'])} | {fmt(row['p_permutation'])} | "
            f"[{fmt(row['methods_low'])}, {fmt(row['methods_high'])}] | {seeds_interval} | "
            f"[{fmt(row['joint_low'])}, {fmt(row['joint_high'])}] |"
        )
    return lines


def _over_the_12_tasks(report: BenchmarkReport) -> list[str]:
    """The aggregates over the 12 tasks beside Table 5, and their figure."""
    lines = ["", "## Over the 12 tasks, beside Table 5", ""]
    if not report.aggregates:
        return lines + ["No method has results on all 12 tasks yet.", ""]
    lines += [
        f"rliable, stratified bootstrap 95% intervals ({report.reps} reps; a point where each task has one run). Published: "
        "Table 5's value, or (T6) the median and mean of Table 6's per-task means (exact); – not published.",
        "",
    ]
    lines += aggregate_table(report.aggregates, report.published[ALL_12], report.runs)
    return lines + ["", f"![aggregates]({aggregates_name(0)})", ""]


def _runs_read(report: BenchmarkReport) -> list[str]:
    """What each study counted, the pre-training of its final-snapshot fine-tunings, and the runs left out."""
    lines = ["## Runs read (before the seeds were chosen)", ""]
    lines += [f"- `{short_name(study)}`: {line}" for study, described in report.gathered.runs_read.items() for line in described]
    for study, kinds in report.gathered.kinds.items():
        counts = ", ".join(f"{kinds.get(kind, 0)} {KIND_WORDS[kind]}" for kind in PAIRING_KINDS)
        lines.append(f"- `{short_name(study)}`: pre-training of its fine-tunings of the final snapshot: {counts}")
    lines += ["", f"Counted at seeds {', '.join(map(str, report.seeds))}: {len(report.results)} runs, each paired (fine-tuned "
              "from the pre-training of its own seed) or from scratch."]
    groups: dict[tuple, list[str]] = {}
    for run in report.gathered.left_out:
        groups.setdefault((short_name(run["study"]), run["label"], run["seed"], run["pretrain_seed"]), []).append(run["task"])
    if groups:
        lines += [f"Left out of every table and figure ({len(report.gathered.left_out)} runs at these seeds, not paired):", ""]
        lines += [f"- `{study}`: {label} seed {seed} from the pre-training of seed {'unknown' if pre is None else pre} "
                  f"({len(tasks)} task{'s' if len(tasks) > 1 else ''})" for (study, label, seed, pre), tasks in groups.items()]
    repeated: dict[tuple, list[str]] = {}
    for run in report.gathered.repeated:
        repeated.setdefault((run["label"], run["seed"], *map(short_name, run["studies"])), []).append(run["task"])
    if repeated:
        lines += ["", f"Found in two folders with the same evaluations at every step, one run made twice and counted "
                  f"once, from the first folder ({len(report.gathered.repeated)} runs):", ""]
        lines += [f"- {label} seed {seed}: {', '.join(tasks)} (`{first}`, `{second}`)"
                  for (label, seed, first, second), tasks in repeated.items()]
    return lines + [""]


def _versus_published(report: BenchmarkReport) -> list[str]:
    """Per method and domain, our mean normalised score beside Table 6's, and its figure."""
    if not report.versus_published:
        return []
    domains = list(dict.fromkeys(row["domain"] for row in report.versus_published))
    cells = {(row["method"], row["domain"]): f"{fmt(row['ours'])} / {fmt(row['published'])}" for row in report.versus_published}
    lines = ["## Ours against Table 6, per domain", "",
             "Mean normalised score over the domain's tasks (each task's mean over runs): ours / Table 6's.", "",
             "| method | " + " | ".join(domains) + " |", "|---|" + "---:|" * len(domains)]
    for label in sorted({row["method"] for row in report.versus_published}):
        lines.append(f"| {label} | " + " | ".join(cells.get((label, d), "–") for d in domains) + " |")
    return lines + ["", f"![ours against published]({VERSUS_PUBLISHED})", ""]


def _differences(differences: dict[str, Any] | None) -> list[str]:
    """Per method and task, how much a second pre-training (and its fine-tuning) moves the final return."""
    if differences is None:
        return []
    first, second = differences["seeds"]
    labels = sorted(differences["returns"])
    lines = [f"## How much does a second pre-training move a score? (seed {second} minus seed {first})", "",
             f"Final return of the run of seed {second} minus that of seed {first}, each fine-tuned from the pre-training "
             "of its own seed (DDPG: two runs from scratch). Last row: the mean absolute difference of normalised scores.",
             "", "| task | " + " | ".join(labels) + " |", "|---|" + "---:|" * len(labels)]
    for task in URLB_TASKS:
        row = [differences["returns"][label].get(task) for label in labels]
        lines.append(f"| {task} | " + " | ".join("–" if d is None else f"{d:+.1f}" for d in row) + " |")
    lines.append("| mean abs. (normalised) | " + " | ".join(fmt(differences["normalised"].get(label)) for label in labels) + " |")
    return lines + [""]


def _verdict_lines(said: list[dict[str, str]]) -> list[str]:
    """Each claim with its word and its figures, and how many of each word."""
    lines = [f"- {v['claim']}: **{v['word']}** ({v['figures']})." for v in said]
    counts = ", ".join(f"{sum(v['word'] == word for v in said)} {word}" for word in WORDS)
    return lines + ["", f"Verdicts: {counts}.", ""]


def _verdicts(report: BenchmarkReport) -> list[str]:
    """The seed's claims, then CIC's variants (where the report has several labels of CIC)."""
    lines = ["## The seed's claims, and MOSS above CIC", "",
             "Holds: the intervals do not overlap, on the claim's side; does not hold: they do not overlap, on the other "
             "side; undecided: they overlap (the order: Spearman's interval over the methods and runs against 0). A "
             "statistic shown without an interval is a method's with one run per task: its interval is a point, and a "
             "verdict on it rests on one draw.", ""]
    lines += _verdict_lines(report.verdicts)
    if report.variant_verdicts:
        lines += ["## CIC's variants and skill choices", "",
                  "`cic`: the paper's variant with the skill grid sweep (the defaults); `cic_code`: the reference code's "
                  "variant, `+fixed` with its skill fixed at 0.5 (as the code, and Table 6), `+sweep` with the grid "
                  "sweep. Each against APS, ProtoRL, each other and Table 5, with the words above.", ""]
        lines += _verdict_lines(report.variant_verdicts)
    return lines


def render_benchmark(report: BenchmarkReport) -> str:
    """The ``report.md`` of the whole benchmark."""
    lines = [
        "# URLB over the 12 tasks",
        "",
        f"Studies: {', '.join(f'`{short_name(s)}`' for s in report.studies)}; fine-tuning seeds "
        f"{', '.join(map(str, report.seeds))}. Final return = the last evaluation's mean return; normalised score = "
        "return / expert score.",
        "",
        *_runs_read(report),
        "## Per task, beside Table 6",
        "",
        "Ours: mean final return over seeds (n); Table 6: mean ± standard error over 10 seeds (2M pre-training, full size).",
        "",
    ]
    lines += _per_task_beside_table6(report.returns) + _over_the_12_tasks(report)
    lines += ["## Per domain (Figure 8's view)", ""]
    for domain, agg in report.domains.items():
        lines += [f"### {domain}", ""] + aggregate_table(agg, report.published[domain], report.domain_runs[domain]) + [""]
    if len(report.domains) == len(URLB_DOMAINS):
        lines += [f"![IQM per domain]({DOMAINS})", ""]
    if report.curves:
        lines += ["### Learning curves per domain", "", "Mean normalised score over the domain's tasks against fine-tuning "
                  "steps: the mean over the runs, shaded from the lowest run to the highest.", "",
                  f"![learning curves per domain]({LEARNING_CURVES})", ""]
    lines += _versus_published(report) + _agreement_table(report.rank_agreement, report.reps) + [""]
    lines += _differences(report.differences) + _verdicts(report)
    return "\n".join(lines)
