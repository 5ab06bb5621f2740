"""The reports over a study's runs: each built as a plain object, then written as markdown, json and figures.

* :mod:`sb3_cic.report.scores`: the numbers of a report (per-task means, pairings, score matrices, rliable's
  aggregates, the comparison with the published returns);
* :mod:`sb3_cic.report.study_report`: one study's report (``sb3-cic report``), :class:`StudyReport`;
* :mod:`sb3_cic.report.benchmark`: the 12 tasks over several studies beside the CIC paper's Tables 5 and 6
  (``sb3-cic benchmark-report``), :class:`BenchmarkReport`, with :mod:`sb3_cic.report.pairs` (which runs count:
  paired or from scratch), :mod:`sb3_cic.report.domains` (per domain) and :mod:`sb3_cic.report.verdicts` (the
  claims, each holding, not holding or undecided);
* :mod:`sb3_cic.report.markdown`, :mod:`sb3_cic.report.figures`, :mod:`sb3_cic.report.text`: how they are written;
* :mod:`sb3_cic.report.commands`: the two commands (build, then write).

A run's result is read and checked with the study's records (:mod:`sb3_cic.study.run_result`,
:mod:`sb3_cic.study.results`); the report sits above the study layer and below the command line.
"""

from sb3_cic.report.benchmark import BenchmarkReport, build_benchmark_report
from sb3_cic.report.study_report import StudyReport, build_study_report

__all__ = ["BenchmarkReport", "StudyReport", "build_benchmark_report", "build_study_report"]
