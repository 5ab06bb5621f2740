"""The seed's claims, and MOSS above CIC, each given one of three words from the intervals of the report.

* **holds**: the intervals do not overlap, on the claim's side;
* **does not hold**: the intervals do not overlap, on the other side;
* **undecided**: they overlap.

A claim made of several comparisons holds when each holds, does not hold when one does not, and is undecided
otherwise. With one run per task the aggregates' intervals are points: a verdict then rests on one draw.
"""

from __future__ import annotations

from itertools import combinations
from typing import Any, Iterable

from sb3_cic.constants import PUBLISHED_AGGREGATES
from sb3_cic.report.scores import METRICS, published_method
from sb3_cic.report.text import fmt

HOLDS, DOES_NOT_HOLD, UNDECIDED = "holds", "does not hold", "undecided"

#: the three words, in the order a report counts them
WORDS: tuple[str, ...] = (HOLDS, DOES_NOT_HOLD, UNDECIDED)


def above(ours: dict[str, float], other: dict[str, float], lower_is_better: bool = False) -> str:
    """Whether the interval ``ours`` (``{"low", "high"}``) is above ``other``'s (below, where lower is better)."""
    if lower_is_better:
        ours, other = other, ours
    if ours["low"] > other["high"]:
        return HOLDS
    if ours["high"] < other["low"]:
        return DOES_NOT_HOLD
    return UNDECIDED


def all_of(words: Iterable[str]) -> str:
    """Holds when each holds, does not hold when one does not, else undecided."""
    words = list(words)
    if DOES_NOT_HOLD in words:
        return DOES_NOT_HOLD
    return HOLDS if all(word == HOLDS for word in words) else UNDECIDED


def negation(word: str) -> str:
    """The word of the opposite claim."""
    return {HOLDS: DOES_NOT_HOLD, DOES_NOT_HOLD: HOLDS}.get(word, UNDECIDED)


def interval(stat: dict[str, float]) -> str:
    """``0.744 [0.700, 0.790]``, or the point alone when the interval is one."""
    return fmt(stat["point"]) if stat["low"] == stat["high"] else f"{fmt(stat['point'])} [{fmt(stat['low'])}, {fmt(stat['high'])}]"


def above_on_every_statistic(aggregates: dict[str, Any], label: str, rival: str) -> dict[str, str] | None:
    """``label`` above ``rival`` on IQM, median and mean and below on the optimality gap, over the 12 tasks (None
    when one of them lacks the 12 tasks)."""
    if label not in aggregates or rival not in aggregates:
        return None
    mine, theirs = aggregates[label], aggregates[rival]
    words = [above(mine[m], theirs[m], lower_is_better=m == "Optimality Gap") for m in METRICS]
    figures = "; ".join(f"{m} {interval(mine[m])} against {interval(theirs[m])}" for m in METRICS)
    return {"claim": f"{label} above {rival} on every statistic over the 12 tasks", "word": all_of(words), "figures": figures}


def one_good_on_all_domains(domains: dict[str, Any], label: str = "cic", baseline: str = "ddpg") -> dict[str, str] | None:
    """``label`` the one method good on all three domains: its IQM above ``baseline``'s (DDPG from scratch) in every
    domain, and no other method's (None without every domain or without the two methods). The other methods are
    the labels named for a method alone: a variant, a skill choice or another snapshot of a method (``cic_code+fixed``,
    ``cic@100000``) is none (:func:`~sb3_cic.report.scores.published_method`)."""
    if not domains or not all(label in agg and baseline in agg for agg in domains.values()):
        return None
    shared = set.intersection(*(set(agg) for agg in domains.values())) - {baseline}
    labels = sorted(m for m in shared if m == label or (published_method(m) == m and m != published_method(label)))
    good = {m: all_of(above(agg[m]["IQM"], agg[baseline]["IQM"]) for agg in domains.values()) for m in labels}
    word = all_of([good[label]] + [negation(good[m]) for m in labels if m != label])
    mine = "; ".join(f"{d} {interval(agg[label]['IQM'])} against {interval(agg[baseline]['IQM'])}" for d, agg in domains.items())
    others = {w: [m for m in labels if m != label and good[m] == w] for w in (HOLDS, UNDECIDED)}
    figures = (f"IQM of {label} against {baseline}: {mine}; other methods above {baseline} in every domain: "
               f"{', '.join(others[HOLDS]) or 'none'}; undecided: {', '.join(others[UNDECIDED]) or 'none'}")
    return {"claim": f"{label} the one method whose IQM is above {baseline}'s in all three domains", "word": word,
            "figures": figures}


def published_order(name: str, row: dict[str, Any] | None) -> dict[str, str] | None:
    """Our order of the methods agrees with Table 6's on ``name``: Spearman's interval over resamples of the methods
    and runs together above 0 (a random order's), below 0 does not hold (None without a rank agreement)."""
    if row is None:
        return None
    zero = {"low": 0.0, "high": 0.0}
    word = above({"low": row["joint_low"], "high": row["joint_high"]}, zero)
    figures = (f"Spearman {fmt(row['rho'])} [{fmt(row['joint_low'])}, {fmt(row['joint_high'])}] over "
               f"{len(row['methods'])} methods, permutation p {fmt(row['p_permutation'])}")
    return {"claim": f"Table 6's order of the methods on {name}", "word": word, "figures": figures}


def _iqm_above(aggregates: dict[str, Any], label: str, rivals: Iterable[str], where: str) -> dict[str, str] | None:
    """``label``'s IQM above each of ``rivals``' (those in ``aggregates``), ``where`` naming the tasks (None without
    ``label`` or a rival)."""
    rivals = [rival for rival in rivals if rival in aggregates]
    if label not in aggregates or not rivals:
        return None
    mine = aggregates[label]["IQM"]
    word = all_of(above(mine, aggregates[rival]["IQM"]) for rival in rivals)
    figures = "; ".join(f"{interval(mine)} against {rival}'s {interval(aggregates[rival]['IQM'])}" for rival in rivals)
    return {"claim": f"{label} above {' and '.join(rivals)} by IQM {where}", "word": word, "figures": figures}


def cic_variant_verdicts(aggregates: dict[str, Any], domains: dict[str, Any]) -> list[dict[str, str]]:
    """Whether CIC's variant or skill choice moves its standing, where a report has more than one label of CIC
    (``cic``, ``cic_code+fixed``, ``cic_code+sweep``...; :func:`~sb3_cic.report.scores.published_method`): each
    other label above APS and above ProtoRL on every statistic over the 12 tasks; each label above each other by IQM
    (the later in sorted order above the earlier); each above APS and ProtoRL by IQM on jaco; each one's IQM above
    Table 5's CIC (a point). Empty with one label of CIC.

    :param aggregates: ``{label: {metric: {"point", "low", "high"}}}`` over the 12 tasks
    :param domains: ``{domain: aggregates over its tasks}``
    """
    labels = sorted(label for label in aggregates if published_method(label) == "cic")
    if len(labels) < 2:
        return []
    said = [above_on_every_statistic(aggregates, label, rival) for label in labels if label != "cic"
            for rival in ("aps", "protorl")]
    said += [_iqm_above(aggregates, later, [earlier], "over the 12 tasks") for earlier, later in combinations(labels, 2)]
    said += [_iqm_above(domains.get("jaco", {}), label, ["aps", "protorl"], "on jaco") for label in labels]
    table5 = PUBLISHED_AGGREGATES["cic"]["IQM"]
    for label in labels:
        mine = aggregates[label]["IQM"]
        said.append({"claim": f"{label}'s IQM over the 12 tasks above Table 5's CIC ({fmt(table5)})",
                     "word": above(mine, {"low": table5, "high": table5}), "figures": interval(mine)})
    return [verdict for verdict in said if verdict is not None]


def verdicts(
    aggregates: dict[str, Any], domains: dict[str, Any], agreement: dict[str, dict[str, Any] | None]
) -> list[dict[str, str]]:
    """The seed's claims (CIC above APS and above ProtoRL on every statistic; CIC the one method good on all three
    domains; the published order per domain and over the 12 tasks) and MOSS above CIC, each ``{"claim", "word",
    "figures"}``; a claim whose methods are not in the report is left out.

    :param aggregates: ``{label: {metric: {"point", "low", "high"}}}`` over the 12 tasks
    :param domains: ``{domain: aggregates over its tasks}``
    :param agreement: ``{domain or "all 12 tasks": rank agreement}`` (:func:`~sb3_cic.report.benchmark.rank_agreement`)
    """
    said = [above_on_every_statistic(aggregates, "cic", rival) for rival in ("aps", "protorl")]
    said.append(one_good_on_all_domains(domains))
    said += [published_order(name, row) for name, row in agreement.items()]
    said.append(above_on_every_statistic(aggregates, "moss", "cic"))
    return [verdict for verdict in said if verdict is not None]
