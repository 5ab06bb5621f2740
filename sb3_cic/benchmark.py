"""The whole-benchmark report: URLB's 12 tasks over several study folders, beside the CIC paper's Tables 5 and 6.

:func:`write_benchmark_report` reads the fine-tuning results of one or more study folders (say the quadruped
study and the walker-and-jaco study), keeps the seeds asked for, and writes into an output folder:

* per task, each method's final return beside Table 6 (:data:`~sb3_cic.constants.PUBLISHED_RETURNS`);
* per method over the 12 tasks, rliable's IQM, median, mean and optimality gap of normalised scores beside
  Table 5's (:data:`~sb3_cic.constants.PUBLISHED_AGGREGATES`; a Table 5 value that is not published is derived
  from Table 6 where that is exact: rliable's median and mean are the median and mean of the per-task means);
* the same four statistics per domain (the view of the paper's Figure 8);
* Spearman's rank correlation of the methods' mean normalised scores with Table 6's, per domain and over the 12
  tasks, with three statistics that each measure one thing (:func:`rank_agreement`): a permutation p-value (could
  the two orders agree this well by chance?), an interval that resamples the methods (how much does the
  correlation depend on which methods are compared?) and, with more than one seed, an interval that resamples
  each method's seeds per task (how much does it depend on the seeds?);
* the seed's claims at this scale (:func:`claims`).

With one seed per task, rliable's stratified bootstrap has nothing to resample within a task: the intervals of
the aggregates are then points, and the report says so.
"""

from __future__ import annotations

import itertools
import json
from collections import defaultdict
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from sb3_cic.common.arguments import argument_parser, option_type
from sb3_cic.constants import EXPERT_SCORES, PUBLISHED_AGGREGATES, PUBLISHED_RETURNS
from sb3_cic.evaluation import METRICS, _fmt, aggregate_scores, plot_aggregates, score_matrices

#: URLB's domains, each with its four tasks in the paper's order
DOMAIN_TASKS: dict[str, tuple[str, ...]] = {
    domain: tuple(task for task in EXPERT_SCORES if task.startswith(domain + "_")) for domain in ("walker", "quadruped", "jaco")
}

#: up to this many methods, the permutation p-value of :func:`rank_agreement` enumerates every re-ordering (8! = 40320)
EXACT_PERMUTATIONS_UP_TO = 8

#: a permutation p-value below this says that our order agrees with Table 6's beyond chance (:func:`claims`)
AGREEMENT_LEVEL = 0.05

#: the 12 tasks
ALL_TASKS: tuple[str, ...] = tuple(task for tasks in DOMAIN_TASKS.values() for task in tasks)


def gather_results(
    studies: Sequence[str | Path], seeds: Sequence[int] | None = None, read: dict[str, list[str]] | None = None
) -> list[dict[str, Any]]:
    """The fine-tuning results of several study folders: final snapshots only (no ``label@step``), ``seeds`` only.
    Each study's results are those it counts (:func:`sb3_cic.study.results.study_results`: the runs of its record,
    each checked; a run folder that disagrees is a one-line warning and not counted).

    :param studies: study folders
    :param seeds: fine-tuning seeds to keep (None: all)
    :param read: filled with ``{study: lines}``, how many runs of which kind each study counted
        (:meth:`~sb3_cic.study.results.StudyResults.describe`)
    :raises ValueError: a folder without results, one (label, task, seed) in two folders, or studies made with other
        settings (:func:`check_same_settings`)
    """
    from sb3_cic.study.results import study_results

    results, origin, settings = [], {}, {}
    for study in studies:
        counted = study_results(study)
        found = counted.results
        settings[str(study)] = counted.settings
        if read is not None:
            read[str(study)] = counted.describe()
        if not found:
            raise ValueError(f"no fine-tuning results under {Path(study) / 'finetune'}")
        for result in found:
            if "@" in result["label"] or (seeds is not None and result["seed"] not in seeds):
                continue
            key = (result["label"], result["task"], result["seed"])
            if key in origin:
                raise ValueError(f"{key} is in both {origin[key]} and {study}: give each run once")
            origin[key] = str(study)
            result["study"] = str(study)
            results.append(result)
    check_same_settings(settings)
    return results


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


def task_means(results: list[dict[str, Any]]) -> dict[str, dict[str, list[float]]]:
    """``{label: {task: [final return per seed]}}``."""
    means: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    for result in sorted(results, key=lambda r: r["seed"]):
        means[result["label"]][result["task"]].append(float(result["final_return"]))
    return means


def published_aggregates(label: str, tasks: Sequence[str]) -> dict[str, tuple[float | None, str]]:
    """Table 5's four statistics of ``label`` over ``tasks``, each with where it comes from.

    Over the 12 tasks the published value (:data:`~sb3_cic.constants.PUBLISHED_AGGREGATES`) where there is one;
    otherwise the median and mean are computed from Table 6's per-task means (exact: rliable's median and mean are
    those of the per-task means), and IQM and optimality gap are not available (they need the runs).

    :return: ``{metric: (value or None, "Table 5" | "Table 6" | "")}``
    """
    out: dict[str, tuple[float | None, str]] = {metric: (None, "") for metric in METRICS}
    if tuple(sorted(tasks)) == tuple(sorted(ALL_TASKS)):
        for metric, value in PUBLISHED_AGGREGATES.get(label, {}).items():
            out[metric] = (value, "Table 5")
    table = PUBLISHED_RETURNS.get(label)
    if table is not None and all(task in table for task in tasks):
        scores = [table[task][0] / EXPERT_SCORES[task] for task in tasks]
        for metric, value in (("Median", float(np.median(scores))), ("Mean", float(np.mean(scores)))):
            if out[metric][0] is None:
                out[metric] = (value, "Table 6")
    return out


def spearman_rows(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Spearman's rank correlation of each row of ``x`` (``(reps, n)``) with the same row of ``y`` (``(reps, n)``, or
    one ``(n,)`` row for all), ties ranked by their average; NaN where a row is constant."""
    from scipy.stats import rankdata

    x = np.atleast_2d(x)
    rx = rankdata(x, axis=1)
    ry = rankdata(np.broadcast_to(np.atleast_2d(y), x.shape), axis=1)
    rx, ry = rx - rx.mean(axis=1, keepdims=True), ry - ry.mean(axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return (rx * ry).sum(axis=1) / np.sqrt((rx**2).sum(axis=1) * (ry**2).sum(axis=1))


def rank_agreement(
    ours: dict[str, dict[str, list[float]]], tasks: Sequence[str], reps: int = 10000, seed: int = 0
) -> dict[str, Any] | None:
    """Spearman's rank correlation of each Table 6 method's mean normalised score over ``tasks`` with Table 6's.

    Three statistics, each named for what it measures:

    * ``p_permutation``: the share of the re-orderings of our means over the methods whose correlation with
      Table 6 is at least the observed one (one-sided): how often two unrelated orders agree as well. Exact (every
      re-ordering) up to :data:`EXACT_PERMUTATIONS_UP_TO` methods, else over ``reps`` random ones;
    * ``methods_low``/``methods_high``: a 95% percentile interval over ``reps`` bootstrap resamples of the methods
      (pairs drawn with replacement; a resample whose values are all tied is left out): how much the correlation
      depends on which methods are compared;
    * ``seeds_low``/``seeds_high``: a 95% interval over ``reps`` resamples of each method's seeds per task, the
      methods fixed: how much it depends on the fine-tuning seeds (None with one seed everywhere).

    :param ours: ``{label: {task: [final return per seed]}}``
    :param tasks: the tasks to average over
    :param reps: resamples of each statistic
    :param seed: seed of the resampling
    :return: ``{"methods", "rho", "p_permutation", "methods_low", "methods_high", "seeds_low", "seeds_high"}`` or
        None with fewer than three methods that ran every task
    """
    labels = sorted(label for label in ours if label in PUBLISHED_RETURNS and all(ours[label].get(t) for t in tasks))
    if len(labels) < 3:
        return None
    expert = np.array([EXPERT_SCORES[task] for task in tasks])
    mine = np.array([np.mean([np.mean(ours[label][t]) for t in tasks] / expert) for label in labels])
    published = np.array([np.mean([PUBLISHED_RETURNS[label][t][0] for t in tasks] / expert) for label in labels])
    rho = float(spearman_rows(mine, published)[0])
    rng = np.random.default_rng(seed)
    if len(labels) <= EXACT_PERMUTATIONS_UP_TO:
        reorderings = mine[np.array(list(itertools.permutations(range(len(labels)))))]
    else:
        reorderings = rng.permuted(np.tile(mine, (reps, 1)), axis=1)
    permuted = spearman_rows(reorderings, published)
    picks = rng.integers(0, len(labels), size=(reps, len(labels)))
    by_methods = spearman_rows(mine[picks], published[picks])
    out: dict[str, Any] = {
        "methods": labels,
        "rho": rho,
        "p_permutation": float(np.mean(permuted >= rho - 1e-12)),
        "methods_low": float(np.nanpercentile(by_methods, 2.5)),
        "methods_high": float(np.nanpercentile(by_methods, 97.5)),
        "seeds_low": None,
        "seeds_high": None,
    }
    if any(len(ours[label][t]) > 1 for label in labels for t in tasks):
        means = np.zeros((reps, len(labels)))
        for j, label in enumerate(labels):
            for t, task in enumerate(tasks):
                runs = np.asarray(ours[label][task])
                means[:, j] += runs[rng.integers(0, len(runs), size=(reps, len(runs)))].mean(axis=1) / expert[t]
        draws = spearman_rows(means / len(tasks), published)
        out["seeds_low"], out["seeds_high"] = (float(q) for q in np.nanpercentile(draws, [2.5, 97.5]))
    return out


def claims(
    aggregates: dict[str, dict[str, dict[str, float]]],
    domains: dict[str, dict[str, dict[str, dict[str, float]]]],
    agreement: dict[str, dict[str, Any] | None] | None = None,
) -> list[str]:
    """The seed's claims, each said as holding or not at this study's scale (point estimates).

    * CIC above APS and ProtoRL on every statistic over the 12 tasks (IQM, median and mean higher, optimality
      gap lower);
    * CIC the one method good on all three domains: whether CIC is the only method whose per-domain IQM is above
      DDPG from scratch's in every domain (the methods that are, and each domain's best method);
    * the published order per domain: whether our order agrees with Table 6's beyond chance (permutation p below
      :data:`AGREEMENT_LEVEL`).

    :param aggregates: ``{label: {metric: {"point", ...}}}`` over the 12 tasks
    :param domains: ``{domain: aggregates over its tasks}``
    :param agreement: ``{domain or "all 12 tasks": rank_agreement(...)}`` (None: no claim on the order)
    """
    lines = []

    def better(a: str, b: str, metric: str) -> bool:
        x, y = aggregates[a][metric]["point"], aggregates[b][metric]["point"]
        return x < y if metric == "Optimality Gap" else x > y

    for rival in ("aps", "protorl"):
        if "cic" in aggregates and rival in aggregates:
            won = [metric for metric in METRICS if better("cic", rival, metric)]
            verdict = "holds" if len(won) == len(METRICS) else f"does not hold (CIC ahead on {', '.join(won) or 'none'})"
            lines.append(f"CIC above {rival} on every statistic over the 12 tasks: {verdict}.")
    if domains and all("ddpg" in agg for agg in domains.values()):
        labels = set.intersection(*(set(agg) for agg in domains.values())) - {"ddpg"}
        good = sorted(
            label for label in labels if all(agg[label]["IQM"]["point"] > agg["ddpg"]["IQM"]["point"] for agg in domains.values())
        )
        if "cic" in labels:
            verdict = "holds" if good == ["cic"] else "does not hold"
            lines.append(f"CIC the one method whose IQM is above DDPG from scratch's in all three domains: {verdict}.")
        lines.append(f"Methods whose IQM is above DDPG from scratch's in all three domains: {', '.join(good) or 'none'}.")
        for domain, agg in domains.items():
            best = max(agg, key=lambda label: agg[label]["IQM"]["point"])
            lines.append(f"Best IQM on {domain}: {best} ({_fmt(agg[best]['IQM']['point'])}).")
    for name, row in (agreement or {}).items():
        if row is not None:
            p = row["p_permutation"]
            verdict = (f"agrees beyond chance (p < {AGREEMENT_LEVEL:g})" if p < AGREEMENT_LEVEL
                       else "not told apart from a random order")
            lines.append(f"Table 6's order on {name} ({len(row['methods'])} methods): Spearman {_fmt(row['rho'])}, "
                         f"permutation p {_fmt(p)}: {verdict}.")
    return lines


def _short(study: str | Path) -> str:
    """A study folder's name for the report: its last two path components (``quadruped_reduced/runs``)."""
    return "/".join(Path(study).resolve().parts[-2:])


def _aggregate_table(aggregates: dict[str, dict[str, dict[str, float]]], tasks: Sequence[str], n_runs: dict[str, int]) -> list[str]:
    lines = ["| method | runs | " + " | ".join(f"{m} ours | {m} published" for m in METRICS) + " |"]
    lines.append("|---|---:|" + "---:|---:|" * len(METRICS))
    for label, agg in sorted(aggregates.items(), key=lambda item: -item[1]["IQM"]["point"]):
        published = published_aggregates(label, tasks)
        cells = []
        for metric in METRICS:
            ours, (value, source) = agg[metric], published[metric]
            interval = "" if ours["low"] == ours["high"] else f" [{_fmt(ours['low'])}, {_fmt(ours['high'])}]"
            cells.append(f"{_fmt(ours['point'])}{interval}")
            cells.append(f"{_fmt(value)}" + (" (T6)" if source == "Table 6" else ""))
        lines.append(f"| {label} | {n_runs[label]} | " + " | ".join(cells) + " |")
    return lines


def write_benchmark_report(
    studies: Sequence[str | Path], out: str | Path, seeds: Sequence[int] | None = None, reps: int = 2000, seed: int = 0
) -> dict[str, Any]:
    """Write ``report.md``, ``report.json`` and ``aggregates.png`` of the whole benchmark into ``out``.

    :param studies: study folders whose results are read together
    :param out: output folder (created)
    :param seeds: fine-tuning seeds to keep (None: all)
    :param reps: bootstrap replications (the rank agreement's resamples: ``5 * reps``)
    :param seed: seed of the bootstrap and the permutations
    :return: the ``report.json`` content
    """
    read: dict[str, list[str]] = {}
    results = gather_results(studies, seeds, read)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    ours = task_means(results)
    matrices, _, seeds_of = score_matrices(results, ALL_TASKS)
    full = {label: m for label, m in matrices.items() if m.shape[1] == len(ALL_TASKS)}
    aggregates = aggregate_scores(full, reps=reps, seed=seed)
    domains = {}
    for domain, tasks in DOMAIN_TASKS.items():
        per_domain, _, _ = score_matrices(results, tasks)
        per_domain = {label: m for label, m in per_domain.items() if m.shape[1] == len(tasks)}
        if per_domain:
            domains[domain] = aggregate_scores(per_domain, reps=reps, seed=seed)
    agreement = {domain: rank_agreement(ours, tasks, reps=5 * reps, seed=seed) for domain, tasks in DOMAIN_TASKS.items()}
    agreement["all 12 tasks"] = rank_agreement(ours, ALL_TASKS, reps=5 * reps, seed=seed)
    said = claims(aggregates, domains if len(domains) == len(DOMAIN_TASKS) else {}, agreement)

    kept = sorted({r["seed"] for r in results})
    lines = [
        "# URLB over the 12 tasks",
        "",
        f"Studies: {', '.join(f'`{_short(s)}`' for s in studies)}; fine-tuning seeds {', '.join(map(str, kept))}. "
        "Final return = the last evaluation's mean return; normalised score = return / expert score.",
        "",
        "## Runs read (before the seeds were chosen)",
        "",
        *[f"- `{_short(study)}`: {line}" for study, described in read.items() for line in described],
        "",
        "## Per task, beside Table 6",
        "",
        "Ours: mean final return over seeds (n); Table 6: mean ± standard error over 10 seeds (2M pre-training, full size).",
        "",
    ]
    labels = sorted(ours)
    lines += ["| task | " + " | ".join(labels) + " |", "|---|" + "---:|" * len(labels)]
    for task in ALL_TASKS:
        cells = []
        for label in labels:
            runs = ours[label].get(task)
            mine = f"{np.mean(runs):.1f}" + (f" (n={len(runs)})" if runs and len(runs) > 1 else "") if runs else "–"
            table = PUBLISHED_RETURNS.get(label, {}).get(task)
            cells.append(mine + (f" / {table[0]:g}±{table[1]:g}" if table else ""))
        lines.append(f"| {task} | " + " | ".join(cells) + " |")
    n_runs = {label: len(s) for label, s in seeds_of.items()}
    lines += ["", "## Over the 12 tasks, beside Table 5", ""]
    if not aggregates:
        lines += ["No method has results on all 12 tasks yet.", ""]
    else:
        lines += [
            f"rliable, stratified bootstrap 95% intervals ({reps} reps; a point where each task has one run). Published: "
            "Table 5's value, or (T6) the median and mean of Table 6's per-task means (exact); – not published.",
            "",
        ]
        lines += _aggregate_table(aggregates, ALL_TASKS, n_runs)
        plot_aggregates(aggregates, out / "aggregates.png")
        lines += ["", "![aggregates](aggregates.png)", ""]
    lines += ["## Per domain (Figure 8's view)", ""]
    for domain, agg in domains.items():
        per_domain_runs = {label: len(score_matrices(results, DOMAIN_TASKS[domain])[2][label]) for label in agg}
        lines += [f"### {domain}", ""] + _aggregate_table(agg, DOMAIN_TASKS[domain], per_domain_runs) + [""]
    lines += [
        "## Does our order of the methods agree with Table 6's?",
        "",
        "Spearman's rank correlation of the mean normalised scores. p (permutation): the share of re-orderings of our "
        f"means that agree with Table 6 at least as well (one-sided; every re-ordering up to {EXACT_PERMUTATIONS_UP_TO} "
        f"methods, else {5 * reps} random ones). Methods interval: 95% over resamples of the "
        "methods. Seeds interval: 95% over resamples of each method's seeds per task, the methods fixed (– with one seed).",
        "",
        "| tasks | methods | Spearman | p (permutation) | methods interval | seeds interval |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for name, row in agreement.items():
        if row is None:
            lines.append(f"| {name} | – | – | – | – | – |")
            continue
        seeds_interval = "–" if row["seeds_low"] is None else f"[{_fmt(row['seeds_low'])}, {_fmt(row['seeds_high'])}]"
        lines.append(
            f"| {name} | {len(row['methods'])} | {_fmt(row['rho'])} | {_fmt(row['p_permutation'])} | "
            f"[{_fmt(row['methods_low'])}, {_fmt(row['methods_high'])}] | {seeds_interval} |"
        )
    lines += ["", "## The seed's claims at this scale (point estimates)", ""] + [f"- {line}" for line in said] + [""]
    (out / "report.md").write_text("\n".join(lines))
    report = {
        "studies": [str(s) for s in studies],
        "seeds": kept,
        "runs_read": read,
        "returns": {label: dict(tasks) for label, tasks in ours.items()},
        "aggregates": aggregates,
        "domains": domains,
        "rank_agreement": agreement,
        "claims": said,
    }
    (out / "report.json").write_text(json.dumps(report, indent=2, default=float))
    return report


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    """``sb3-cic benchmark-report <study> [<study> ...] --out <folder>``."""
    parser = argument_parser(
        "sb3-cic benchmark-report",
        "URLB over the 12 tasks: the results of several study folders (written by sb3-cic study or sb3-cic protocol) "
        "beside the CIC paper's Tables 5 and 6.",
    )
    parser.add_argument("studies", nargs="+", help="study folders")
    parser.add_argument("--out", required=True, help="output folder for report.md, report.json and aggregates.png")
    parser.add_argument("--seeds", type=option_type("seeds"), nargs="+", default=None, help="fine-tuning seeds to keep (default: all)")
    parser.add_argument("--reps", type=option_type("reps"), default=2000, help="bootstrap replications")
    parser.add_argument("--seed", type=option_type("seed"), default=0, help="seed of the bootstrap and the permutations")
    args = parser.parse_args(argv)
    for study in args.studies:
        if not Path(study).is_dir():
            parser.error(f"no such study folder: {study}")
    try:
        report = write_benchmark_report(args.studies, args.out, seeds=args.seeds, reps=args.reps, seed=args.seed)
    except ValueError as error:
        parser.error(str(error))
    print((Path(args.out) / "report.md").read_text())
    return report
