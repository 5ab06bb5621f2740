"""The two appendix benchmarks run end to end at a tiny budget and write their files (``benchmarks/``)."""

from __future__ import annotations

import json

import pytest

from benchmark_module import load_benchmark


def test_gridworld_skills_writes_runs_and_figure(tmp_path, capsys):
    argv = ["--steps", "300", "--learning-starts", "100", "--batch-size", "32", "--hidden-dim", "16", "--cic-skills", "40",
            "--seeds", "0", "--out", str(tmp_path)]
    load_benchmark("gridworld_skills").main(argv)
    results = json.loads((tmp_path / "results.json").read_text())
    assert [run["method"] for run in results["runs"]] == ["diayn4", "diayn100", "cic"]
    for run in results["runs"]:
        assert 1 <= run["cells_final"] <= min(run["n_skills"], 100) and run["cells_final"] <= run["cells_visited"] <= 100
        assert 0.0 <= run["disc_accuracy"] <= 1.0 and run["mi_lower_bound_nats"] <= run["mi_max_nats"] + 1e-6
    assert results["runs"][0]["disc_chance"] == 0.25 and results["runs"][2]["disc_chance"] == pytest.approx(1 / 32)
    assert set(results["runs"][2]["skills_4"]) == {"cells_visited", "cells_final"}
    assert (tmp_path / "gridworld_skills_seed0.png").stat().st_size > 0 and (tmp_path / "cic_seed0.json").exists()
    assert "| diayn4 | 0 | 4 |" in capsys.readouterr().out

    # a second call with the same settings keeps the finished runs (a killed call resumes); a run whose file is gone reruns
    (tmp_path / "diayn100_seed0.json").unlink()
    load_benchmark("gridworld_skills").main(argv)
    printed = capsys.readouterr().out
    assert "diayn4 seed 0: kept from" in printed and "cic seed 0: kept from" in printed
    assert "diayn100 seed 0: kept" not in printed and (tmp_path / "diayn100_seed0.json").exists()
    assert json.loads((tmp_path / "results.json").read_text())["runs"][0] == results["runs"][0]


@pytest.mark.filterwarnings("ignore:.*reward is ignored")
def test_early_termination_records_extrinsic_returns(tmp_path, capsys):
    module = load_benchmark("early_termination")
    module.main(["--steps", "300", "--seeds", "0", "--methods", "diayn", "fixed", "--eval-freq", "150",
                 "--eval-episodes", "2", "--hidden-dim", "16", "--batch-size", "32", "--out", str(tmp_path),
                 "--project-steps", "100000"])
    for env in ("gym", "dmc"):
        run = json.loads((tmp_path / f"{env}_fixed_seed0.json").read_text())
        assert [e["step"] for e in run["evals"]] == [0, 150, 300] and len(run["evals"][0]["returns"]) == 2
        assert (tmp_path / f"{env}_diayn_seed0_episodes.csv").exists()
        if env == "gym":  # random hoppers fall: episodes end by termination, with an extrinsic return
            assert run["episodes"] and all(e["terminated"] for e in run["episodes"] if e["length"] < 1000)
            assert run["evals"][0]["lengths"][0] < 1000
        else:  # 300 steps: no episode of 1,000 steps ended yet; the evaluations run the full 1,000 steps
            assert run["episodes"] == [] and run["evals"][0]["lengths"] == [1000, 1000]
    assert (tmp_path / "early_termination.png").stat().st_size > 0
    (tmp_path / "dmc_fixed_seed0.json").unlink()  # as if killed during the last run: only that one runs again
    module.main(["--steps", "300", "--seeds", "0", "--methods", "diayn", "fixed", "--eval-freq", "150",
                 "--eval-episodes", "2", "--hidden-dim", "16", "--batch-size", "32", "--out", str(tmp_path)])
    printed = capsys.readouterr().out
    assert printed.count("kept from") == 3 and "dmc fixed seed 0: kept" not in printed
    assert (tmp_path / "dmc_fixed_seed0.json").exists()
    module.main(["--plot-only", "--out", str(tmp_path)])
