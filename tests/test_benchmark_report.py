"""The whole-benchmark report (sb3_cic.report.benchmark): results of several study folders beside Tables 5 and 6."""

from __future__ import annotations

import json
import math
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from sb3_cic.cli import main as cli_main
from sb3_cic.constants import EXPERT_SCORES, PUBLISHED_RETURNS
from sb3_cic.envs.tasks import URLB_TASKS
from sb3_cic.report import benchmark, pairs, verdicts
from sb3_cic.report.commands import write_benchmark_report
from sb3_cic.study.layout import parse_label


def write_run(study: Path, label: str, task: str, seed: int, final_return: float, pretrain_seed: int | None = -1) -> None:
    """One fine-tuning's result.json and eval.csv as the protocol writes them (``pretrain_seed`` -1: paired, the run's
    own seed; DDPG from scratch: None)."""
    folder = study / "finetune" / label / task / f"seed_{seed}"
    folder.mkdir(parents=True)
    from_scratch = label == "ddpg"
    result = {
        "method": parse_label(label)[0],
        "label": label,
        "domain": task.split("_")[0],
        "task": task,
        "seed": seed,
        "from_scratch": from_scratch,
        "pretrain_seed": None if from_scratch else seed if pretrain_seed == -1 else pretrain_seed,
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
    for figure in ("aggregates.png", "domains.png", "learning_curves.png", "versus_published.png"):
        assert (tmp_path / "out" / figure).stat().st_size > 0, figure
    assert {(row["method"], row["domain"]) for row in report["versus_published"]} == {
        (label, domain) for label in PUBLISHED_RETURNS for domain in benchmark.URLB_DOMAINS
    }
    for row in report["versus_published"]:
        assert row["ours"] == pytest.approx(row["published"])
    text = (tmp_path / "out" / "report.md").read_text()
    assert "## Over the 12 tasks, beside Table 5" in text
    assert f"Studies: `{tmp_path.name}/quadruped`, `{tmp_path.name}/others`;" in text


def test_same_order_as_table6_is_rank_one_and_unlikely_by_chance(tmp_path):
    report = write_benchmark_report(published_study(tmp_path), tmp_path / "out", reps=50)
    agreement = report["rank_agreement"]["all 12 tasks"]
    assert agreement["rho"] == pytest.approx(1.0)
    assert agreement["p_permutation"] < 0.01
    assert agreement["seeds_low"] is None  # one seed: nothing to resample
    assert (agreement["joint_low"], agreement["joint_high"]) == (agreement["methods_low"], agreement["methods_high"])
    said = {v["claim"]: v for v in report["verdicts"]}
    assert said["cic above aps on every statistic over the 12 tasks"]["word"] == "holds"
    order = said["Table 6's order of the methods on all 12 tasks"]
    assert order["word"] == "holds"
    assert order["figures"] == (f"Spearman 1.000 [1.000, 1.000] over {len(PUBLISHED_RETURNS)} methods, "
                                f"permutation p {agreement['p_permutation']:.3f}")
    text = (tmp_path / "out" / "report.md").read_text()
    assert "- Table 6's order of the methods on all 12 tasks: **holds** (Spearman 1.000" in text


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
    agreement = both["rank_agreement"]["quadruped"]
    assert agreement["seeds_low"] is not None and agreement["joint_low"] is not None
    # the second run of each (method, task) ends 1.0 above the first (published_study adds the seed)
    differences = both["pre_training_differences"]
    assert differences["seeds"] == [0, 1]
    assert differences["returns"]["cic"] == {task: pytest.approx(1.0) for task in PUBLISHED_RETURNS["cic"]}
    assert differences["normalised"]["cic"] == pytest.approx(np.mean([1 / EXPERT_SCORES[t] for t in URLB_TASKS]))
    curve = both["learning_curves"]["walker"]["cic"]
    assert curve["runs"] == 2 and curve["low"][-1] < curve["high"][-1]
    assert "## How much does a second pre-training move a score? (seed 1 minus seed 0)" in (tmp_path / "both" / "report.md").read_text()
    only_0 = write_benchmark_report(studies, tmp_path / "zero", seeds=[0], reps=50)
    assert only_0["seeds"] == [0] and only_0["pre_training_differences"] is None
    assert only_0["returns"]["cic"]["walker_flip"] == [PUBLISHED_RETURNS["cic"]["walker_flip"][0]]


def test_only_paired_and_from_scratch_runs_are_counted_and_the_others_said(tmp_path):
    """A fine-tuning of seed 1 from the pre-training of seed 0 (the CIC code's shared protocol) is counted as read,
    named and left out of every number, also where a paired run of the same method, task and seed is counted from
    another study; the paired seed 1 and DDPG's seed 1 from scratch are counted."""
    shared, paired = tmp_path / "shared", tmp_path / "paired"
    tasks = ("walker_stand", "walker_walk")
    for task in tasks:
        write_run(shared, "cic", task, 0, 900.0)
        write_run(shared, "cic", task, 1, 100.0, pretrain_seed=0)  # shared: never paired
        write_run(shared, "ddpg", task, 1, 500.0)
        write_run(paired, "apt", task, 1, 800.0)
    write_run(paired, "cic", "walker_stand", 1, 700.0)  # the paired seed 1 of one task
    gathered = pairs.gather_results([shared, paired], seeds=[0, 1])
    assert gathered.kinds == {str(shared): {"paired": 2, "shared": 2, "from_scratch": 2}, str(paired): {"paired": 3}}
    assert sorted((r["label"], r["task"], r["seed"]) for r in gathered.results) == sorted(
        [("cic", t, 0) for t in tasks] + [("cic", "walker_stand", 1)] + [(m, t, 1) for m in ("ddpg", "apt") for t in tasks]
    )
    assert [(r["label"], r["seed"], r["pretrain_seed"]) for r in gathered.left_out] == [("cic", 1, 0)] * 2
    report = write_benchmark_report([shared, paired], tmp_path / "out", reps=20)
    assert report["returns"]["cic"] == {"walker_stand": [900.0, 700.0], "walker_walk": [900.0]}  # the shared 100 never mixed in
    text = (tmp_path / "out" / "report.md").read_text()
    assert (f"- `{tmp_path.name}/shared`: pre-training of its fine-tunings of the final snapshot: 2 paired (from the "
            "pre-training of the same seed), 2 from another seed's pre-training (not paired), 2 from scratch, 0 "
            "pre-training seed unknown (not paired)") in text
    assert "Counted at seeds 0, 1: 7 runs" in text
    assert f"- `{tmp_path.name}/shared`: cic seed 1 from the pre-training of seed 0 (2 tasks)" in text
    only_0 = pairs.gather_results([shared], seeds=[0])
    assert only_0.left_out == [] and only_0.kinds[str(shared)]["shared"] == 2  # counted as read, before the seeds


def test_one_run_in_two_studies_is_refused(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    write_run(a, "cic", "walker_flip", 0, 600.0)
    write_run(b, "cic", "walker_flip", 0, 500.0)
    with pytest.raises(ValueError, match="in both .* with other evaluations"):
        pairs.gather_results([a, b])
    # the same final return, another evaluation on the way: two runs, not one made twice
    shutil.rmtree(b / "finetune" / "cic" / "walker_flip")
    write_run(a, "cic", "walker_run", 0, 300.0)
    write_run(b, "cic", "walker_run", 0, 300.0)
    (b / "finetune" / "cic" / "walker_run" / "seed_0" / "eval.csv").write_text(
        "timestep,mean_return,std_return\n0,1.0,0.0\n100000,300.0,0.0\n")
    with pytest.raises(ValueError, match="walker_run.*with other evaluations"):
        pairs.gather_results([a, b])


def test_one_run_made_twice_is_counted_once_and_said(tmp_path):
    """DDPG from scratch at one seed and settings in two studies (the quadruped study's seed 1 and the paired seed-1
    study): the same evaluations, one run."""
    studies = published_study(tmp_path)
    again = tmp_path / "again"
    for task in ("quadruped_run", "quadruped_walk"):
        write_run(again, "ddpg", task, 0, PUBLISHED_RETURNS["ddpg"][task][0])
    gathered = pairs.gather_results([*studies, again])
    assert len(gathered.results) == sum(len(table) for table in PUBLISHED_RETURNS.values())
    assert [(r["task"], r["studies"][1]) for r in gathered.repeated] == [("quadruped_run", str(again)),
                                                                         ("quadruped_walk", str(again))]
    write_benchmark_report([*studies, again], tmp_path / "out", reps=50)
    text = (tmp_path / "out" / "report.md").read_text()
    assert "one run made twice and counted once, from the first folder (2 runs)" in text
    assert f"- ddpg seed 0: quadruped_run, quadruped_walk (`{tmp_path.name}/quadruped`, `{tmp_path.name}/again`)" in text


def test_snapshot_labels_left_out(tmp_path):
    write_run(tmp_path / "s", "cic", "walker_flip", 0, 600.0)
    write_run(tmp_path / "s", "cic@100000", "walker_flip", 0, 500.0)
    assert [r["label"] for r in pairs.gather_results([tmp_path / "s"]).results] == ["cic"]


def _interval(point: float, low: float | None = None, high: float | None = None) -> dict[str, float]:
    return {"point": point, "low": point if low is None else low, "high": point if high is None else high}


def test_three_words_from_the_intervals():
    """Holds when the intervals do not overlap on the claim's side, does not hold on the other, undecided when they
    overlap; several comparisons: each holds, one does not, else undecided."""
    assert verdicts.above(_interval(0.5, 0.4, 0.6), _interval(0.3, 0.2, 0.35)) == "holds"
    assert verdicts.above(_interval(0.3, 0.2, 0.35), _interval(0.5, 0.4, 0.6)) == "does not hold"
    assert verdicts.above(_interval(0.5, 0.4, 0.6), _interval(0.45, 0.3, 0.55)) == "undecided"
    assert verdicts.above(_interval(0.2), _interval(0.3), lower_is_better=True) == "holds"  # an optimality gap
    assert verdicts.all_of(["holds", "undecided"]) == "undecided"
    assert verdicts.all_of(["holds", "undecided", "does not hold"]) == "does not hold"
    stats = lambda x, spread: {m: _interval(x if m != "Optimality Gap" else 1 - x, (x if m != "Optimality Gap" else 1 - x) - spread,  # noqa: E731
                                             (x if m != "Optimality Gap" else 1 - x) + spread) for m in ("IQM", "Median", "Mean", "Optimality Gap")}
    for cic, aps, spread, word in ((0.8, 0.5, 0.05, "holds"), (0.5, 0.8, 0.05, "does not hold"), (0.6, 0.55, 0.05, "undecided")):
        said = verdicts.above_on_every_statistic({"cic": stats(cic, spread), "aps": stats(aps, spread)}, "cic", "aps")
        assert said["word"] == word, (cic, aps)
    said = verdicts.above_on_every_statistic({"cic": stats(0.6, 0.05), "aps": stats(0.55, 0.05)}, "cic", "aps")
    assert said["figures"].startswith("IQM 0.600 [0.550, 0.650] against 0.550 [0.500, 0.600]; Median")
    assert verdicts.above_on_every_statistic({"cic": stats(0.6, 0)}, "cic", "aps") is None  # no APS: no claim


def test_cic_the_one_method_good_on_all_domains():
    domains = {d: {"ddpg": {"IQM": _interval(0.3, 0.25, 0.35)}, "cic": {"IQM": _interval(0.6, 0.5, 0.7)},
                   "apt": {"IQM": _interval(0.5 if d != "jaco" else 0.1, None, None)}} for d in benchmark.URLB_DOMAINS}
    said = verdicts.one_good_on_all_domains(domains)
    assert said["word"] == "holds" and "other methods above ddpg in every domain: none; undecided: none" in said["figures"]
    domains["jaco"]["apt"]["IQM"] = _interval(0.32, 0.2, 0.4)  # APT's jaco interval overlaps DDPG's
    assert verdicts.one_good_on_all_domains(domains)["word"] == "undecided"
    domains["jaco"]["apt"]["IQM"] = _interval(0.9)  # APT above DDPG everywhere too
    said = verdicts.one_good_on_all_domains(domains)
    assert said["word"] == "does not hold" and "other methods above ddpg in every domain: apt;" in said["figures"]


def test_a_variant_of_cic_is_set_beside_cic_and_is_no_other_method(tmp_path):
    """``cic_code+fixed`` (the reference code's variant with its fixed skill) is set beside Table 6's CIC and Table 5's,
    is left out of the rank agreement (one row per published method), and is not another method good on all domains."""
    studies = published_study(tmp_path)
    for task, (mean, _) in PUBLISHED_RETURNS["cic"].items():
        write_run(studies[0] if task.startswith("quadruped") else studies[1], "cic_code+fixed", task, 0, 1.1 * mean)
    report = write_benchmark_report(studies, tmp_path / "out", reps=50)
    assert benchmark.published_aggregates("cic_code+fixed", URLB_TASKS)["IQM"] == (0.77, "Table 5")
    assert benchmark.published_aggregates("cic@100000", URLB_TASKS)["IQM"] == (None, "")  # another snapshot: none
    rows = {(row["method"], row["domain"]): row for row in report["versus_published"]}
    for domain in benchmark.URLB_DOMAINS:
        variant, cic = rows["cic_code+fixed", domain], rows["cic", domain]
        assert variant["published"] == cic["published"] and variant["ours"] == pytest.approx(1.1 * cic["ours"])
    assert "cic_code+fixed" not in report["rank_agreement"]["all 12 tasks"]["methods"]
    said = {v["claim"]: v for v in report["verdicts"]}
    good = said["cic the one method whose IQM is above ddpg's in all three domains"]["figures"]
    assert "cic_code" not in good and "other methods above ddpg in every domain: " in good
    variants = {v["claim"]: v["word"] for v in report["cic_variant_verdicts"]}
    assert variants["cic_code+fixed above cic by IQM over the 12 tasks"] in verdicts.WORDS
    assert "cic_code+fixed above aps on every statistic over the 12 tasks" in variants
    assert variants["cic's IQM over the 12 tasks above Table 5's CIC (0.770)"] in verdicts.WORDS
    text = (tmp_path / "out" / "report.md").read_text()
    assert "## CIC's variants and skill choices" in text
    assert f"{1.1 * PUBLISHED_RETURNS['cic']['jaco_reach_top_left'][0]:.1f} / 153" in text  # beside Table 6's CIC


def test_words_on_cics_variants():
    iqm = lambda point, spread=0.02: {m: _interval(point, point - spread, point + spread) for m in  # noqa: E731
                                      ("IQM", "Median", "Mean", "Optimality Gap")}
    aggregates = {"cic": iqm(0.7), "cic_code+fixed": iqm(0.85), "cic_code+sweep": iqm(0.86), "aps": iqm(0.8),
                  "protorl": iqm(0.6)}
    domains = {"jaco": {"cic": iqm(0.4), "cic_code+fixed": iqm(0.7), "cic_code+sweep": iqm(0.5), "aps": iqm(0.6),
                        "protorl": iqm(0.45)}}
    said = {v["claim"]: v["word"] for v in verdicts.cic_variant_verdicts(aggregates, domains)}
    assert said["cic_code+fixed above cic by IQM over the 12 tasks"] == "holds"
    assert said["cic_code+sweep above cic_code+fixed by IQM over the 12 tasks"] == "undecided"  # the intervals overlap
    assert said["cic above aps and protorl by IQM on jaco"] == "does not hold"
    assert said["cic_code+fixed above aps and protorl by IQM on jaco"] == "holds"
    assert said["cic_code+sweep above aps and protorl by IQM on jaco"] == "does not hold"  # below APS
    assert said["cic_code+fixed's IQM over the 12 tasks above Table 5's CIC (0.770)"] == "holds"
    assert said["cic's IQM over the 12 tasks above Table 5's CIC (0.770)"] == "does not hold"
    assert verdicts.cic_variant_verdicts({"cic": iqm(0.7), "aps": iqm(0.8)}, {}) == []  # one label of CIC: nothing


def test_published_order_words():
    row = {"rho": 0.5, "p_permutation": 0.04, "methods": ["a", "b", "c"], "joint_low": -0.2, "joint_high": 0.9}
    assert verdicts.published_order("walker", row)["word"] == "undecided"
    assert verdicts.published_order("walker", dict(row, joint_low=0.1))["word"] == "holds"
    assert verdicts.published_order("walker", dict(row, joint_low=-0.9, joint_high=-0.1))["word"] == "does not hold"
    assert verdicts.published_order("walker", None) is None


def test_two_seeds_that_overlap_are_undecided(tmp_path):
    """Through the whole report: CIC's and APS's two runs per task straddle each other, so their intervals overlap."""
    study = tmp_path / "s"
    for task in URLB_TASKS:
        for seed, (cic, aps) in enumerate(((0.9, 0.8), (0.6, 0.7))):
            write_run(study, "cic", task, seed, cic * EXPERT_SCORES[task])
            write_run(study, "aps", task, seed, aps * EXPERT_SCORES[task])
    report = write_benchmark_report([study], tmp_path / "out", reps=200)
    said = {v["claim"]: v["word"] for v in report["verdicts"]}
    assert said["cic above aps on every statistic over the 12 tasks"] == "undecided"
    assert "Verdicts: 0 holds, 0 does not hold, 1 undecided." in (tmp_path / "out" / "report.md").read_text()


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


def test_a_partial_benchmark_draws_only_the_figures_it_has_numbers_for(tmp_path):
    """One method on walker alone: no 12-task aggregate and no Figure 8 view, but its walker curve and its walker
    point against Table 6."""
    for task in benchmark.URLB_DOMAINS["walker"]:
        write_run(tmp_path / "s", "cic", task, 0, 500.0)
    report = write_benchmark_report([tmp_path / "s"], tmp_path / "out", reps=20)
    assert report["aggregates"] == {} and list(report["domains"]) == ["walker"] and report["verdicts"] == []
    assert sorted(path.name for path in (tmp_path / "out").glob("*.png")) == ["learning_curves.png", "versus_published.png"]
    assert [(row["method"], row["domain"]) for row in report["versus_published"]] == [("cic", "walker")]
    assert "No method has results on all 12 tasks yet." in (tmp_path / "out" / "report.md").read_text()


def test_published_comparison_breaks_a_tie_of_task_sets_the_same_way_every_time():
    """Two Table 6 methods on task sets of one method each: the comparison takes the larger set, whatever the order
    in which Python's hash seed lists a set (the study report's report.json once changed from one run to the next)."""
    import subprocess
    import sys

    script = (
        "from sb3_cic.report.scores import published_comparison\n"
        "runs = [{'label': 'ddpg', 'task': t, 'seed': 0, 'final_normalized_score': 0.5} for t in ('walker_stand', 'walker_run')]\n"
        "runs.append({'label': 'diayn', 'task': 'walker_stand', 'seed': 0, 'final_normalized_score': 0.5})\n"
        "print(published_comparison(runs, reps=5)['tasks'])\n"
    )
    outputs = {
        subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True,
                       env={**os.environ, "PYTHONHASHSEED": str(hash_seed)}).stdout
        for hash_seed in range(6)
    }
    assert outputs == {"['walker_run', 'walker_stand']\n"}
