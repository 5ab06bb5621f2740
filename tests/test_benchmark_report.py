"""The whole-benchmark report (sb3_cic.report.benchmark): results of several study folders beside Tables 5 and 6."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from sb3_cic.cli import main as cli_main
from sb3_cic.constants import EXPERT_SCORES, PUBLISHED_RETURNS
from sb3_cic.envs.tasks import URLB_TASKS
from sb3_cic.report import benchmark
from sb3_cic.report.commands import write_benchmark_report


def write_run(study: Path, label: str, task: str, seed: int, final_return: float) -> None:
    """One fine-tuning's result.json and eval.csv as the protocol writes them."""
    folder = study / "finetune" / label / task / f"seed_{seed}"
    folder.mkdir(parents=True)
    result = {
        "method": label,
        "label": label,
        "domain": task.split("_")[0],
        "task": task,
        "seed": seed,
        "final_return": final_return,
        "final_normalized_score": final_return / EXPERT_SCORES[task],
        "wall_time_s": {"finetune": 1.0, "pretrain": None},
    }
    (folder / "result.json").write_text(json.dumps(result))
    (folder / "eval.csv").write_text(f"timestep,mean_return,std_return\n0,0.0,0.0\n100000,{final_return},0.0\n")


def published_study(root: Path, seeds: tuple[int, ...] = (0,), scale: float = 1.0) -> list[Path]:
    """Two study folders (quadruped; walker and jaco) whose runs end at Table 6's mean returns times ``scale``."""
    quadruped, others = root / "quadruped", root / "others"
    for label, table in PUBLISHED_RETURNS.items():
        for task, (mean, _) in table.items():
            for seed in seeds:
                write_run(quadruped if task.startswith("quadruped") else others, label, task, seed, scale * mean + seed)
    return [quadruped, others]


def test_table6_returns_give_table6_median_and_mean(tmp_path):
    studies = published_study(tmp_path)
    report = write_benchmark_report(studies, tmp_path / "out", reps=50)
    assert set(report["aggregates"]) == set(PUBLISHED_RETURNS)
    for label, aggregates in report["aggregates"].items():
        published = benchmark.published_aggregates(label, URLB_TASKS)
        for metric in ("Median", "Mean"):
            if published[metric][1] == "Table 6":  # derived from the same means: exact
                assert aggregates[metric]["point"] == pytest.approx(published[metric][0])
    assert benchmark.published_aggregates("cic", URLB_TASKS)["IQM"] == (0.77, "Table 5")
    for domain in benchmark.URLB_DOMAINS:
        assert set(report["domains"][domain]) == set(PUBLISHED_RETURNS)
    assert (tmp_path / "out" / "aggregates.png").stat().st_size > 0
    text = (tmp_path / "out" / "report.md").read_text()
    assert "## Over the 12 tasks, beside Table 5" in text
    assert f"Studies: `{tmp_path.name}/quadruped`, `{tmp_path.name}/others`;" in text


def test_same_order_as_table6_is_rank_one_and_unlikely_by_chance(tmp_path):
    report = write_benchmark_report(published_study(tmp_path), tmp_path / "out", reps=50)
    agreement = report["rank_agreement"]["all 12 tasks"]
    assert agreement["rho"] == pytest.approx(1.0)
    assert agreement["p_permutation"] < 0.01
    assert agreement["seeds_low"] is None  # one seed: nothing to resample
    assert "CIC above aps on every statistic over the 12 tasks: holds." in report["claims"]
    order = [line for line in report["claims"] if line.startswith("Table 6's order on all 12 tasks")]
    assert order == [f"Table 6's order on all 12 tasks ({len(PUBLISHED_RETURNS)} methods): Spearman 1.000, "
                     f"permutation p {agreement['p_permutation']:.3f}: agrees beyond chance (p < 0.05)."]


def test_reversed_order_is_not_agreement(tmp_path):
    ours = {label: {task: [-mean] for task, (mean, _) in table.items()} for label, table in PUBLISHED_RETURNS.items()}
    agreement = benchmark.rank_agreement(ours, URLB_TASKS, reps=500)
    assert agreement["rho"] == pytest.approx(-1.0)
    assert agreement["p_permutation"] == pytest.approx(1.0)


@pytest.mark.parametrize("n_methods", [3, 6])
def test_permutation_p_is_exact_for_few_methods(n_methods):
    """Up to 8 methods every re-ordering is counted: the same order as Table 6 is the one of n! that agrees as well."""
    labels = sorted(PUBLISHED_RETURNS)[:n_methods]
    ours = {label: {task: [mean] for task, (mean, _) in PUBLISHED_RETURNS[label].items()} for label in labels}
    agreement = benchmark.rank_agreement(ours, URLB_TASKS, reps=10)
    assert agreement["rho"] == pytest.approx(1.0)
    assert agreement["p_permutation"] == pytest.approx(1 / math.factorial(n_methods))


def test_seed_interval_with_several_seeds_and_seed_filter(tmp_path):
    studies = published_study(tmp_path, seeds=(0, 1))
    both = write_benchmark_report(studies, tmp_path / "both", reps=50)
    assert both["seeds"] == [0, 1]
    assert both["rank_agreement"]["quadruped"]["seeds_low"] is not None
    only_0 = write_benchmark_report(studies, tmp_path / "zero", seeds=[0], reps=50)
    assert only_0["seeds"] == [0]
    assert only_0["returns"]["cic"]["walker_flip"] == [PUBLISHED_RETURNS["cic"]["walker_flip"][0]]


def test_one_run_in_two_studies_is_refused(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    write_run(a, "cic", "walker_flip", 0, 600.0)
    write_run(b, "cic", "walker_flip", 0, 500.0)
    with pytest.raises(ValueError, match="in both"):
        benchmark.gather_results([a, b])


def test_snapshot_labels_left_out(tmp_path):
    write_run(tmp_path / "s", "cic", "walker_flip", 0, 600.0)
    write_run(tmp_path / "s", "cic@100000", "walker_flip", 0, 500.0)
    assert [r["label"] for r in benchmark.gather_results([tmp_path / "s"])] == ["cic"]


def test_claims_say_when_cic_is_behind():
    point = lambda x: {"point": x, "low": x, "high": x}  # noqa: E731
    aggregates = {
        "cic": {"IQM": point(0.5), "Median": point(0.5), "Mean": point(0.5), "Optimality Gap": point(0.5)},
        "aps": {"IQM": point(0.6), "Median": point(0.4), "Mean": point(0.4), "Optimality Gap": point(0.6)},
    }
    said = benchmark.claims(aggregates, {})
    assert said == ["CIC above aps on every statistic over the 12 tasks: does not hold (CIC ahead on Median, Mean, Optimality Gap)."]


def test_claims_on_domains_and_order():
    """CIC "the one method good on all three domains" holds only when no other method beats DDPG in every domain;
    an order whose permutation p is not below 0.05 is said not to be told apart from a random one."""
    point = lambda x: {"IQM": {"point": x}}  # noqa: E731
    domains = {
        d: {"ddpg": point(0.3), "cic": point(0.6), "apt": point(0.5 if d != "jaco" else 0.2)} for d in benchmark.URLB_DOMAINS
    }
    agreement = {"walker": {"rho": 0.2, "p_permutation": 0.35, "methods": ["a", "b", "c"]}, "jaco": None}
    said = benchmark.claims({}, domains, agreement)
    assert "CIC the one method whose IQM is above DDPG from scratch's in all three domains: holds." in said
    assert said[-1] == (
        "Table 6's order on walker (3 methods): Spearman 0.200, permutation p 0.350: not told apart from a random order."
    )
    domains["jaco"]["apt"] = point(0.4)
    said = benchmark.claims({}, domains)
    assert "CIC the one method whose IQM is above DDPG from scratch's in all three domains: does not hold." in said
    assert "Methods whose IQM is above DDPG from scratch's in all three domains: apt, cic." in said


def test_command_line_refuses_a_missing_folder(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        cli_main(["benchmark-report", str(tmp_path / "nowhere"), "--out", str(tmp_path / "out")])
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no such study folder" in err[0]
    assert not (tmp_path / "out").exists()


def test_command_line_writes_the_report(tmp_path, capsys):
    studies = published_study(tmp_path)
    cli_main(["benchmark-report", *map(str, studies), "--out", str(tmp_path / "out"), "--reps", "20"])
    assert "# URLB over the 12 tasks" in capsys.readouterr().out
    saved = json.loads((tmp_path / "out" / "report.json").read_text())
    assert np.isclose(saved["rank_agreement"]["all 12 tasks"]["rho"], 1.0)


def test_spearman_rows_is_scipys():
    from scipy.stats import spearmanr

    rng = np.random.default_rng(0)
    x, y = rng.integers(0, 4, size=(20, 7)).astype(float), rng.normal(size=7)  # with ties
    expected = [spearmanr(row, y).statistic for row in x]
    np.testing.assert_allclose(benchmark.spearman_rows(x, y), expected)
    np.testing.assert_allclose(benchmark.spearman_rows(x, x[::-1])[:3], [spearmanr(a, b).statistic for a, b in zip(x[:3], x[::-1][:3])])
