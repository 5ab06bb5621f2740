"""The finished reports under docs/results are what the code writes today from the runs committed beside them
(``benchmarks/committed_reports.py``): a change that moves a committed figure fails here until the report is
written again (``python benchmarks/committed_reports.py --write``) and its page says so."""

from __future__ import annotations

import dataclasses
import json
import shutil

import pytest

from benchmark_module import load_benchmark

committed_reports = load_benchmark("committed_reports")
ROOT = committed_reports.ROOT


@pytest.mark.parametrize("report", committed_reports.REPORTS, ids=lambda report: report.where)
def test_committed_report_is_written_again_byte_for_byte(report, tmp_path):
    assert (ROOT / report.where / "report.md").is_file()
    assert committed_reports.differing(report, tmp_path) == []


def test_a_changed_run_moves_the_report(tmp_path):
    """The check reads the runs: in a copy of the walker study, DDPG's walker run seed 0 ends 100 higher (its
    result.json and the last row of its eval.csv, consistently), and both files of the report differ."""
    walker = next(report for report in committed_reports.REPORTS if report.where.endswith("walker_reduced"))
    copy = tmp_path / "copy"
    shutil.copytree(ROOT / walker.parts[0][0], copy)
    run = copy / "finetune" / "ddpg" / "walker_run" / "seed_0"
    result = json.loads((run / "result.json").read_text())
    result["final_return"] += 100.0
    result["final_normalized_score"] = result["final_return"] / result["expert_score"]
    (run / "result.json").write_text(json.dumps(result))
    rows = (run / "eval.csv").read_text().splitlines()
    step = rows[-1].split(",")[0]
    rows[-1] = f"{step},{result['final_return']},{result['final_normalized_score']}"
    (run / "eval.csv").write_text("\n".join(rows) + "\n")
    changed = dataclasses.replace(walker, parts=((str(copy), "."),))  # an absolute folder: pathlib's / keeps it
    assert committed_reports.differing(changed, tmp_path / "scratch") == ["report.md", "report.json"]
