"""Every finished report under ``docs/results`` made again from the runs committed beside it.

A results page shows a report that ``sb3-cic report`` or ``sb3-cic benchmark-report`` wrote from its study's runs.
This script writes each again from the committed run folders, with the command its page gives, into a temporary
folder, and compares ``report.md`` and ``report.json`` with the committed files byte for byte (the figures are left
out: matplotlib's pixels may change with its version). ``--write`` copies the new files, figures included, over the
committed ones instead (after a deliberate change of what a report says). ``tests/test_committed_reports.py`` runs
the check.

A study report (``sb3-cic report``, which writes into the study folder) is made in a copy of the folder named as
its page names it, without snapshots and tensorboard logs, which no report reads. The seed-1 study's provisional
report is not listed while its runs are committed as they finish (its runs are ahead of it between its updates); it
joins the list when the study ends.

    MUJOCO_GL=disable python benchmarks/committed_reports.py [--write]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

from sb3_cic.cli import main as cli_main

ROOT = Path(__file__).resolve().parents[1]
RESULTS = "docs/results"
COMPARED = ("report.md", "report.json")


@dataclass(frozen=True)
class CommittedReport:
    """One committed report: where it is, and how it was written.

    :param where: its folder, relative to the repository
    :param studies: ``benchmark-report``: the study folders it reads (relative, as the page's command gives them)
    :param seeds: ``benchmark-report``: its ``--seeds``
    :param parts: ``report``: the study folder it reads, as ``(committed folder, place in the study folder)`` pairs
        (``"."``: the whole study folder), copied into a folder named ``name``
    :param name: ``report``: the study folder's name (the report's title)
    """

    where: str
    studies: tuple[str, ...] = ()
    seeds: tuple[int, ...] = ()
    parts: tuple[tuple[str, str], ...] = ()
    name: str = ""

    def write(self, scratch: Path) -> Path:
        """Write the report again under ``scratch`` (the command's printed tables left out); return its folder."""
        with contextlib.redirect_stdout(io.StringIO()):
            return self._write(scratch)

    def _write(self, scratch: Path) -> Path:
        if self.studies:  # from the repository, as the page's command (the report names the folders as given)
            out, here = scratch / "out", os.getcwd()
            os.chdir(ROOT)
            try:
                cli_main(["benchmark-report", *self.studies, "--seeds", *map(str, self.seeds), "--out", str(out)])
            finally:
                os.chdir(here)
            return out
        study = scratch / self.name
        for source, place in self.parts:
            shutil.copytree(ROOT / source, study / place, dirs_exist_ok=True,
                            ignore=shutil.ignore_patterns("*.zip", "tensorboard", "report.*", "*.png"))
        cli_main(["report", str(study)])
        return study


REPORTS = (
    CommittedReport(f"{RESULTS}/walker_jaco/report",
                    studies=(f"{RESULTS}/quadruped_reduced/runs", f"{RESULTS}/walker_jaco/runs"), seeds=(0,)),
    CommittedReport(f"{RESULTS}/quadruped_reduced", parts=((f"{RESULTS}/quadruped_reduced/runs", "."),),
                    name="quadruped_reduced"),
    CommittedReport(f"{RESULTS}/walker_reduced", parts=((f"{RESULTS}/walker_reduced/runs", "."),), name="walker"),
    CommittedReport(f"{RESULTS}/walker_reduced/after_init_fix", name="walker_init_fix", parts=(
        (f"{RESULTS}/walker_reduced/calibration_runs/pretrain/cic_walker", "pretrain/cic_walker"),
        (f"{RESULTS}/walker_reduced/calibration_runs/finetune/cic", "finetune/cic"),
        (f"{RESULTS}/walker_reduced/runs/finetune/ddpg", "finetune/ddpg"),
    )),
)


def differing(report: CommittedReport, scratch: Path) -> list[str]:
    """The files of :data:`COMPARED` in which the report written again differs from the committed one.

    :param report: the committed report
    :param scratch: an empty folder to write in
    """
    made = report.write(scratch)
    return [name for name in COMPARED if (made / name).read_bytes() != (ROOT / report.where / name).read_bytes()]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--write", action="store_true", help="copy the reports written again over the committed ones")
    args = parser.parse_args(argv)
    rows = []
    for report in REPORTS:
        with tempfile.TemporaryDirectory() as scratch:
            if args.write:
                made = report.write(Path(scratch))
                for file in [*COMPARED, *(path.name for path in made.glob("*.png"))]:
                    shutil.copy2(made / file, ROOT / report.where / file)
                rows.append((report.where, "written"))
            else:
                rows.append((report.where, ", ".join(differing(report, Path(scratch))) or "same"))
    print("| report | report.md and report.json written again |\n|---|---|")
    for where, state in rows:
        print(f"| {where} | {state} |")


if __name__ == "__main__":
    main()
