"""The whole-benchmark report: URLB's 12 tasks over several study folders, beside the CIC paper's Tables 5 and 6,
built as a plain object (:class:`BenchmarkReport`).

:func:`build_benchmark_report` reads the fine-tuning results of one or more study folders (say the quadruped
study and the walker-and-jaco study), keeps the seeds asked for and, of those, the runs fine-tuned from the
pre-training of their own seed or from scratch (:func:`~sb3_cic.report.pairs.gather_results`: a run of another
seed's pre-training is counted, named and left out), and computes:

* per task, each method's final return beside Table 6 (:data:`~sb3_cic.constants.PUBLISHED_RETURNS`);
* per method over the 12 tasks, rliable's IQM, median, mean and optimality gap of normalised scores with
  stratified-bootstrap intervals over the runs, beside Table 5's (:data:`~sb3_cic.constants.PUBLISHED_AGGREGATES`;
  a Table 5 value that is not published is derived from Table 6 where that is exact: rliable's median and mean are
  the median and mean of the per-task means);
* the same four statistics per domain (the view of the paper's Figure 8), the learning curves per domain and our
  mean normalised score per method and domain beside Table 6's (:mod:`sb3_cic.report.domains`);
* Spearman's rank correlation of the methods' mean normalised scores with Table 6's, per domain and over the 12
  tasks, with statistics that each measure one thing (:func:`rank_agreement`): a permutation p-value (could
  the two orders agree this well by chance?), an interval that resamples the methods, one that resamples each
  method's seeds per task, and one that resamples both together;
* per method and task, the difference between two pre-trainings (:func:`~sb3_cic.report.pairs.pretraining_differences`);
* the seed's claims and MOSS above CIC, each holding, not holding or undecided (:mod:`sb3_cic.report.verdicts`).

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
from sb3_cic.report.domains import domain_curves, versus_published
from sb3_cic.report.pairs import Gathered, gather_results, pretraining_differences
from sb3_cic.report.scores import METRICS, aggregate_scores, published_method, score_matrices
from sb3_cic.report.verdicts import cic_variant_verdicts, verdicts

#: URLB's domains, each with its four tasks (``walker_stand``...) in the paper's order
URLB_DOMAINS: dict[str, tuple[str, ...]] = {
    domain: tuple(f"{domain}_{task}" for task in tasks) for domain, tasks in DOMAIN_TASKS.items()
    if f"{domain}_{tasks[0]}" in URLB_TASKS
}

#: the name of the 12 tasks together, beside the domains' names
ALL_12 = "all 12 tasks"

#: up to this many methods, the permutation p-value of :func:`rank_agreement` enumerates every re-ordering (8! = 40320)
EXACT_PERMUTATIONS_UP_TO = 8


def task_means(results: list[dict[str, Any]]) -> dict[str, dict[str, list[float]]]:
    """``{label: {task: [final return per seed]}}``."""
    means: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    for result in sorted(results, key=lambda r: r["seed"]):
        means[result["label"]][result["task"]].append(float(result["final_return"]))
    return means


def published_aggregates(label: str, tasks: Sequence[str]) -> dict[str, tuple[float | None, str]]:
    """Table 5's four statistics of ``label`` over ``tasks`` (those of the method it runs,
    :func:`~sb3_cic.report.scores.published_method`: Table 6's CIC beside ``cic_code+fixed``), each with where it
    comes from.

    Over the 12 tasks the published value (:data:`~sb3_cic.constants.PUBLISHED_AGGREGATES`) where there is one;
    otherwise the median and mean are computed from Table 6's per-task means (exact: rliable's median and mean are
    those of the per-task means), and IQM and optimality gap are not available (they need the runs).

    :return: ``{metric: (value or None, "Table 5" | "Table 6" | "")}``
    """
    out: dict[str, tuple[float | None, str]] = {metric: (None, "") for metric in METRICS}
    method = published_method(label)
    if tuple(sorted(tasks)) == tuple(sorted(URLB_TASKS)):
        for metric, value in PUBLISHED_AGGREGATES.get(method, {}).items():
            out[metric] = (value, "Table 5")
    table = PUBLISHED_RETURNS.get(method)
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


def _resampled_means(
    ours: dict[str, dict[str, list[float]]], labels: list[str], tasks: Sequence[str], reps: int, rng: np.random.Generator
) -> np.ndarray | None:
    """``(reps, methods)`` mean normalised scores over ``tasks``, each method's runs resampled per task (None with one
    run everywhere: nothing to resample)."""
    if not any(len(ours[label][t]) > 1 for label in labels for t in tasks):
        return None
    expert = np.array([EXPERT_SCORES[task] for task in tasks])
    means = np.zeros((reps, len(labels)))
    for j, label in enumerate(labels):
        for t, task in enumerate(tasks):
            runs = np.asarray(ours[label][task])
            means[:, j] += runs[rng.integers(0, len(runs), size=(reps, len(runs)))].mean(axis=1) / expert[t]
    return means / len(tasks)


def _interval(draws: np.ndarray) -> tuple[float, float]:
    low, high = np.nanpercentile(draws, [2.5, 97.5])
    return float(low), float(high)


def rank_agreement(
    ours: dict[str, dict[str, list[float]]], tasks: Sequence[str], reps: int = 10000, seed: int = 0
) -> dict[str, Any] | None:
    """Spearman's rank correlation of each Table 6 method's mean normalised score over ``tasks`` with Table 6's.

    Four statistics, each named for what it measures:

    * ``p_permutation``: the share of the re-orderings of our means over the methods whose correlation with
      Table 6 is at least the observed one (one-sided): how often two unrelated orders agree as well. Exact (every
      re-ordering) up to :data:`EXACT_PERMUTATIONS_UP_TO` methods, else over ``reps`` random ones;
    * ``methods_low``/``methods_high``: a 95% percentile interval over ``reps`` bootstrap resamples of the methods
      (pairs drawn with replacement; a resample whose values are all tied is left out): how much the correlation
      depends on which methods are compared;
    * ``seeds_low``/``seeds_high``: a 95% interval over ``reps`` resamples of each method's seeds per task, the
      methods fixed: how much it depends on the fine-tuning seeds (None with one seed everywhere);
    * ``joint_low``/``joint_high``: a 95% interval over ``reps`` resamples of the methods and, within each drawn
      method, of its runs per task, together (with one seed everywhere: the methods interval).

    :param ours: ``{label: {task: [final return per seed]}}``
    :param tasks: the tasks to average over
    :param reps: resamples of each statistic
    :param seed: seed of the resampling
    :return: ``{"methods", "rho", "p_permutation", "methods_low", "methods_high", "seeds_low", "seeds_high",
        "joint_low", "joint_high"}`` or None with fewer than three methods that ran every task
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
    methods_low, methods_high = _interval(spearman_rows(mine[picks], published[picks]))
    out: dict[str, Any] = {
        "methods": labels, "rho": rho, "p_permutation": float(np.mean(permuted >= rho - 1e-12)),
        "methods_low": methods_low, "methods_high": methods_high, "seeds_low": None, "seeds_high": None,
        "joint_low": methods_low, "joint_high": methods_high,
    }
    means = _resampled_means(ours, labels, tasks, reps, rng)
    if means is not None:
        out["seeds_low"], out["seeds_high"] = _interval(spearman_rows(means, published))
        joint = np.take_along_axis(means, picks, axis=1)
        out["joint_low"], out["joint_high"] = _interval(spearman_rows(joint, published[picks]))
    return out


@dataclass
class BenchmarkReport:
    """The numbers of the whole-benchmark report.

    :param studies: the study folders read
    :param seeds: the fine-tuning seeds kept (that some counted run has)
    :param reps: bootstrap replications (the rank agreement's resamples: ``5 * reps``)
    :param gathered: what was read, counted and left out (:class:`~sb3_cic.report.pairs.Gathered`)
    :param returns: ``{label: {task: [final return per seed]}}``
    :param aggregates: ``{label: {metric: {"point", "low", "high"}}}`` over the 12 tasks (the labels with all 12)
    :param runs: ``{label: runs}`` of the 12-task matrices
    :param domains: ``{domain: aggregates over its four tasks}``
    :param domain_runs: ``{domain: {label: runs}}``
    :param published: ``{"all 12 tasks" or domain: {label: published_aggregates(...)}}``, the published values beside
        each aggregate (:func:`published_aggregates`)
    :param rank_agreement: ``{domain or "all 12 tasks": rank_agreement(...)}``
    :param differences: per method and task, the second seed's final return minus the first's
        (:func:`~sb3_cic.report.pairs.pretraining_differences`; None with one seed)
    :param curves: ``{domain: {label: learning curve}}`` (:func:`~sb3_cic.report.domains.domain_curves`)
    :param versus_published: per method and domain, ours beside Table 6's (:func:`~sb3_cic.report.domains.versus_published`)
    :param verdicts: the seed's claims and MOSS above CIC, each with its word (:func:`~sb3_cic.report.verdicts.verdicts`)
    :param variant_verdicts: whether CIC's variant or skill choice moves its standing, where there are several labels
        of CIC (:func:`~sb3_cic.report.verdicts.cic_variant_verdicts`)
    """

    studies: list[str]
    seeds: list[int]
    reps: int
    gathered: Gathered
    returns: dict[str, dict[str, list[float]]]
    aggregates: dict[str, dict[str, dict[str, float]]]
    runs: dict[str, int]
    domains: dict[str, dict[str, dict[str, dict[str, float]]]]
    domain_runs: dict[str, dict[str, int]]
    published: dict[str, dict[str, dict[str, tuple[float | None, str]]]]
    rank_agreement: dict[str, dict[str, Any] | None]
    differences: dict[str, Any] | None
    curves: dict[str, dict[str, dict[str, Any]]]
    versus_published: list[dict[str, Any]]
    verdicts: list[dict[str, str]]
    variant_verdicts: list[dict[str, str]]

    @property
    def results(self) -> list[dict[str, Any]]:
        """The counted fine-tuning results (with their curves)."""
        return self.gathered.results

    def to_json(self) -> dict[str, Any]:
        """The ``report.json`` content."""
        return {
            "studies": self.studies,
            "seeds": self.seeds,
            "runs_read": self.gathered.runs_read,
            "pre_training_kinds": self.gathered.kinds,
            "left_out": self.gathered.left_out,
            "repeated": self.gathered.repeated,
            "returns": {label: dict(tasks) for label, tasks in self.returns.items()},
            "aggregates": self.aggregates,
            "domains": self.domains,
            "rank_agreement": self.rank_agreement,
            "pre_training_differences": self.differences,
            "learning_curves": self.curves,
            "versus_published": self.versus_published,
            "verdicts": self.verdicts,
            "cic_variant_verdicts": self.variant_verdicts,
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


def _published_beside(aggregates: dict[str, Any], domains: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The published values beside our aggregates over the 12 tasks (``all 12 tasks``) and per domain."""
    out = {ALL_12: {label: published_aggregates(label, URLB_TASKS) for label in aggregates}}
    out.update({d: {label: published_aggregates(label, URLB_DOMAINS[d]) for label in agg} for d, agg in domains.items()})
    return out


def build_benchmark_report(
    studies: Sequence[str | Path], seeds: Sequence[int] | None = None, reps: int = 2000, seed: int = 0
) -> BenchmarkReport:
    """The whole-benchmark report of the fine-tunings of ``studies``.

    :param studies: study folders whose results are read together
    :param seeds: fine-tuning seeds to keep (None: all)
    :param reps: bootstrap replications (the rank agreement's resamples: ``5 * reps``)
    :param seed: seed of the bootstrap and the permutations
    :raises ValueError: a folder without results, or one run in two folders (:func:`~sb3_cic.report.pairs.gather_results`)
    """
    gathered = gather_results(studies, seeds)
    results = gathered.results
    ours = task_means(results)
    matrices, _, seeds_of = score_matrices(results, URLB_TASKS)
    full = {label: m for label, m in matrices.items() if m.shape[1] == len(URLB_TASKS)}
    aggregates = aggregate_scores(full, reps=reps, seed=seed)
    domains, domain_runs = _domain_aggregates(results, reps, seed)
    agreement = {domain: rank_agreement(ours, tasks, reps=5 * reps, seed=seed) for domain, tasks in URLB_DOMAINS.items()}
    agreement[ALL_12] = rank_agreement(ours, URLB_TASKS, reps=5 * reps, seed=seed)
    return BenchmarkReport(
        studies=[str(s) for s in studies],
        seeds=sorted({r["seed"] for r in results}),
        reps=reps,
        gathered=gathered,
        returns=ours,
        aggregates=aggregates,
        runs={label: len(s) for label, s in seeds_of.items()},
        domains=domains,
        domain_runs=domain_runs,
        published=_published_beside(aggregates, domains),
        rank_agreement=agreement,
        differences=pretraining_differences(results),
        curves=domain_curves(results, URLB_DOMAINS),
        versus_published=versus_published(ours, URLB_DOMAINS),
        verdicts=verdicts(aggregates, domains if len(domains) == len(URLB_DOMAINS) else {}, agreement),
        variant_verdicts=cic_variant_verdicts(aggregates, domains),
    )
