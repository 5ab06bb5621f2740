"""The whole-benchmark report: URLB's 12 tasks over several study folders, beside the CIC paper's Tables 5 and 6,
built as a plain object (:class:`BenchmarkReport`).

:func:`build_benchmark_report` reads the fine-tuning results of one or more study folders (say the quadruped
study and the walker-and-jaco study), keeps the seeds asked for, and computes:

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
the aggregates are then points, and the report says so. :mod:`sb3_cic.report.markdown` and
:mod:`sb3_cic.report.figures` write it.
"""

from __future__ import annotations

import itertools
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from sb3_cic.constants import EXPERT_SCORES, PUBLISHED_AGGREGATES, PUBLISHED_RETURNS
from sb3_cic.envs.tasks import DOMAIN_TASKS, URLB_TASKS
from sb3_cic.report.scores import METRICS, aggregate_scores, score_matrices
from sb3_cic.report.text import fmt

#: URLB's domains, each with its four tasks (``walker_stand``...) in the paper's order
URLB_DOMAINS: dict[str, tuple[str, ...]] = {
    domain: tuple(f"{domain}_{task}" for task in tasks) for domain, tasks in DOMAIN_TASKS.items()
    if f"{domain}_{tasks[0]}" in URLB_TASKS
}

#: up to this many methods, the permutation p-value of :func:`rank_agreement` enumerates every re-ordering (8! = 40320)
EXACT_PERMUTATIONS_UP_TO = 8

#: a permutation p-value below this says that our order agrees with Table 6's beyond chance (:func:`claims`)
AGREEMENT_LEVEL = 0.05


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
    :raises ValueError: a folder without results, or one (label, task, seed) in two folders
    """
    from sb3_cic.study.results import study_results

    results, origin = [], {}
    for study in studies:
        counted = study_results(study)
        found = counted.results
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
    return results


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
    if tuple(sorted(tasks)) == tuple(sorted(URLB_TASKS)):
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
            lines.append(f"Best IQM on {domain}: {best} ({fmt(agg[best]['IQM']['point'])}).")
    for name, row in (agreement or {}).items():
        if row is not None:
            p = row["p_permutation"]
            verdict = (f"agrees beyond chance (p < {AGREEMENT_LEVEL:g})" if p < AGREEMENT_LEVEL
                       else "not told apart from a random order")
            lines.append(f"Table 6's order on {name} ({len(row['methods'])} methods): Spearman {fmt(row['rho'])}, "
                         f"permutation p {fmt(p)}: {verdict}.")
    return lines




@dataclass
class BenchmarkReport:
    """The numbers of the whole-benchmark report.

    :param studies: the study folders read
    :param seeds: the fine-tuning seeds kept (that some run has)
    :param reps: bootstrap replications (the rank agreement's resamples: ``5 * reps``)
    :param runs_read: ``{study: lines}``, how many runs of which kind each study counted
    :param results: the fine-tuning results kept
    :param returns: ``{label: {task: [final return per seed]}}``
    :param aggregates: ``{label: {metric: {"point", "low", "high"}}}`` over the 12 tasks (the labels with all 12)
    :param runs: ``{label: runs}`` of the 12-task matrices
    :param domains: ``{domain: aggregates over its four tasks}``
    :param domain_runs: ``{domain: {label: runs}}``
    :param rank_agreement: ``{domain or "all 12 tasks": rank_agreement(...)}``
    :param claims: the seed's claims at this scale (:func:`claims`)
    """

    studies: list[str]
    seeds: list[int]
    reps: int
    runs_read: dict[str, list[str]]
    results: list[dict[str, Any]]
    returns: dict[str, dict[str, list[float]]]
    aggregates: dict[str, dict[str, dict[str, float]]]
    runs: dict[str, int]
    domains: dict[str, dict[str, dict[str, dict[str, float]]]]
    domain_runs: dict[str, dict[str, int]]
    rank_agreement: dict[str, dict[str, Any] | None]
    claims: list[str]

    def to_json(self) -> dict[str, Any]:
        """The ``report.json`` content."""
        return {
            "studies": self.studies,
            "seeds": self.seeds,
            "runs_read": self.runs_read,
            "returns": {label: dict(tasks) for label, tasks in self.returns.items()},
            "aggregates": self.aggregates,
            "domains": self.domains,
            "rank_agreement": self.rank_agreement,
            "claims": self.claims,
        }


def _domain_aggregates(results: list[dict[str, Any]], reps: int, seed: int) -> tuple[dict[str, Any], dict[str, dict[str, int]]]:
    """Per domain, the aggregates of the labels with all its tasks, and their runs."""
    domains, domain_runs = {}, {}
    for domain, tasks in URLB_DOMAINS.items():
        matrices, _, seeds_of = score_matrices(results, tasks)
        full = {label: m for label, m in matrices.items() if m.shape[1] == len(tasks)}
        if full:
            domains[domain] = aggregate_scores(full, reps=reps, seed=seed)
            domain_runs[domain] = {label: len(seeds_of[label]) for label in domains[domain]}
    return domains, domain_runs


def build_benchmark_report(
    studies: Sequence[str | Path], seeds: Sequence[int] | None = None, reps: int = 2000, seed: int = 0
) -> BenchmarkReport:
    """The whole-benchmark report of the fine-tunings of ``studies``.

    :param studies: study folders whose results are read together
    :param seeds: fine-tuning seeds to keep (None: all)
    :param reps: bootstrap replications (the rank agreement's resamples: ``5 * reps``)
    :param seed: seed of the bootstrap and the permutations
    :raises ValueError: a folder without results, or one run in two folders (:func:`gather_results`)
    """
    read: dict[str, list[str]] = {}
    results = gather_results(studies, seeds, read)
    ours = task_means(results)
    matrices, _, seeds_of = score_matrices(results, URLB_TASKS)
    full = {label: m for label, m in matrices.items() if m.shape[1] == len(URLB_TASKS)}
    aggregates = aggregate_scores(full, reps=reps, seed=seed)
    domains, domain_runs = _domain_aggregates(results, reps, seed)
    agreement = {domain: rank_agreement(ours, tasks, reps=5 * reps, seed=seed) for domain, tasks in URLB_DOMAINS.items()}
    agreement["all 12 tasks"] = rank_agreement(ours, URLB_TASKS, reps=5 * reps, seed=seed)
    return BenchmarkReport(
        studies=[str(s) for s in studies],
        seeds=sorted({r["seed"] for r in results}),
        reps=reps,
        runs_read=read,
        results=results,
        returns=ours,
        aggregates=aggregates,
        runs={label: len(s) for label, s in seeds_of.items()},
        domains=domains,
        domain_runs=domain_runs,
        rank_agreement=agreement,
        claims=claims(aggregates, domains if len(domains) == len(URLB_DOMAINS) else {}, agreement),
    )
