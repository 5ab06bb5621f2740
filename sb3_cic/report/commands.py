"""``sb3-cic report`` and ``sb3-cic benchmark-report``: build a report, then write its markdown, json and figures."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Sequence

from sb3_cic.command_line import argument_parser, option_type
from sb3_cic.common.arguments import POSITIVE_INT, SEED
from sb3_cic.report import figures, markdown
from sb3_cic.report.benchmark import ALL_12, URLB_DOMAINS, build_benchmark_report
from sb3_cic.report.study_report import build_study_report


def write_report(study: str | Path, reps: int = 2000, seed: int = 0) -> dict[str, Any]:
    """Write ``report.md``, ``report.json``, ``aggregates.png`` (``aggregates_1.png``... for the smaller task sets)
    and ``learning_curves.png`` of a study into its folder.

    :param study: study folder
    :param reps: bootstrap replications of the intervals
    :param seed: seed of the bootstrap
    :return: the ``report.json`` content
    """
    report = build_study_report(study, reps=reps, seed=seed)
    study = Path(study)
    for i, group in enumerate(markdown.shown_comparisons(report)):
        figures.plot_aggregates(group.aggregates, study / figures.aggregates_name(i))
    figures.plot_learning_curves(report.results, study / figures.LEARNING_CURVES)
    (study / "report.md").write_text(markdown.render_study(report))
    content = report.to_json()
    (study / "report.json").write_text(json.dumps(content, indent=2, default=float))
    return content


def write_benchmark_report(
    studies: Sequence[str | Path], out: str | Path, seeds: Sequence[int] | None = None, reps: int = 2000, seed: int = 0
) -> dict[str, Any]:
    """Write ``report.md``, ``report.json`` and the figures of the whole benchmark into ``out``: ``aggregates.png``
    (the 12-task aggregates beside Table 5), ``domains.png`` (Figure 8's view), ``learning_curves.png`` (per domain)
    and ``versus_published.png`` (ours against Table 6, per method and domain); a figure without its numbers (no
    method on all 12 tasks, say) is not drawn.

    :param studies: study folders whose results are read together
    :param out: output folder (created)
    :param seeds: fine-tuning seeds to keep (None: all)
    :param reps: bootstrap replications (the rank agreement's resamples: ``5 * reps``)
    :param seed: seed of the bootstrap and the permutations
    :return: the ``report.json`` content
    """
    report = build_benchmark_report(studies, seeds=seeds, reps=reps, seed=seed)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if report.aggregates:
        figures.plot_aggregates_beside_published(report.aggregates, report.published[ALL_12], out / figures.aggregates_name(0))
    if len(report.domains) == len(URLB_DOMAINS):
        figures.plot_domains(report.domains, out / figures.DOMAINS)
    if report.curves:
        figures.plot_domain_curves(report.curves, out / figures.LEARNING_CURVES)
    if report.versus_published:
        figures.plot_versus_published(report.versus_published, out / figures.VERSUS_PUBLISHED)
    (out / "report.md").write_text(markdown.render_benchmark(report))
    content = report.to_json()
    (out / "report.json").write_text(json.dumps(content, indent=2, default=float))
    return content


def report_main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    """``sb3-cic report <study>``."""
    parser = argument_parser(
        "sb3-cic report",
        "Score report of a URLB study folder: per-task scores, rliable aggregates and plots, written into the folder.",
    )
    parser.add_argument("study", help="study folder, written by sb3-cic study or sb3-cic protocol")
    parser.add_argument("--reps", type=option_type(POSITIVE_INT), default=2000, help="bootstrap replications")
    parser.add_argument("--seed", type=option_type(SEED), default=0, help="bootstrap seed")
    args = parser.parse_args(argv)
    report = write_report(args.study, reps=args.reps, seed=args.seed)
    print((Path(args.study) / "report.md").read_text())
    return report


def benchmark_main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    """``sb3-cic benchmark-report <study> [<study> ...] --out <folder>``."""
    parser = argument_parser(
        "sb3-cic benchmark-report",
        "URLB over the 12 tasks: the results of several study folders (written by sb3-cic study or sb3-cic protocol) "
        "beside the CIC paper's Tables 5 and 6.",
    )
    parser.add_argument("studies", nargs="+", help="study folders")
    parser.add_argument("--out", required=True, help="output folder for report.md, report.json and the figures")
    parser.add_argument("--seeds", type=option_type(SEED), nargs="+", default=None, help="fine-tuning seeds to keep (default: all)")
    parser.add_argument("--reps", type=option_type(POSITIVE_INT), default=2000, help="bootstrap replications")
    parser.add_argument("--seed", type=option_type(SEED), default=0, help="seed of the bootstrap and the permutations")
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
