"""Every error of ``sb3-cic`` on bad input: one line on stderr, exit code 2, nothing of the failed command left.

The commands run in a fresh working directory (``tmp_path``); "nothing left" is its listing before and after.
Nothing here trains: each command fails before (or while) building its model.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from sb3_cic import protocol
from sb3_cic.cli import main

ROOT = Path(__file__).resolve().parent.parent
#: the shipped walker snapshot (hidden 256, 100k steps)
WALKER_SNAPSHOT = ROOT / "sb3_cic" / "pretrained" / "cic_walker_h256_100k.zip"
#: tiny protocol settings (nothing trains in these tests, but the checks read them)
TINY = ["--small", "--pretrain-steps", "1000", "--finetune-steps", "1000", "--eval-episodes", "1", "--no-progress"]


def _listing(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def _fails(arguments: list[str], capsys: pytest.CaptureFixture, folder: Path) -> str:
    """Run ``sb3-cic arguments`` in-process; assert exit code 2, one stderr line and an unchanged ``folder``."""
    before = _listing(folder)
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit_info:
        main(arguments)
    err = capsys.readouterr().err
    assert exit_info.value.code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert re.match(r"sb3-cic( \w+)?: error: ", lines[0]), lines[0]
    assert _listing(folder) == before  # nothing left behind
    assert argparse.ArgumentParser.error is not None and argparse.ArgumentParser.error.__module__ == "argparse"
    return lines[0]


@pytest.fixture
def workdir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.mark.parametrize(
    "arguments, message",
    [
        (["protocol", "--method", "cicc", "--study", "s", *TINY], "unknown algorithm 'cicc'"),
        (["protocol", "--domain", "cheetah", "--study", "s"], "invalid choice: 'cheetah'"),
        (["protocol", "--method", "ddpg", "--domain", "walker", "--tasks", "backflip", "--study", "s", *TINY],
         "unknown task 'backflip'"),
        (["protocol", "--method", "ddpg", "--domain", "walker", "--tasks", "stand", "--study", "s",
          "--conf-file", "missing.yml", *TINY], "no yaml file missing.yml"),
        (["protocol", "--method", "cic", "--domain", "walker", "--tasks", "stand", "--study", "s", "--snapshot", "700",
          *TINY], "no snapshot at 700 steps: the pre-training saves \\[1000\\]"),
        (["protocol", "--checkpoint-every", "1", "2", "3", "--study", "s"], "--checkpoint-every takes one or two"),
        (["protocol", "--bogus"], "unrecognized arguments: --bogus \\(see sb3-cic protocol --help\\)"),
        (["study", "s", "--methods", "cicc"], "unknown algorithm 'cicc'"),
        (["study", "s", "--methods", "ddpg", "--domains", "walker", "--tasks", "stand", "--workers", "0"],
         "argument --workers: must be an int >= 1, got '0'"),
        (["study"], "the following arguments are required: study"),
        (["status", "s"], "s is not a study folder"),
        (["report", "s"], "no such study folder: s$"),
        (["train", "--algo", "cic", "--env", "URLB/walker-flip-v0", "--small"], "is a task: pre-train cic"),
        (["train", "--algo", "cicc", "--env", "URLB/walker-v0"], "unknown algorithm 'cicc'"),
        (["finetune", "--algo", "cic", "--env", "URLB/walker-flip-v0"], "arguments are required: -i/--trained-agent"),
        (["finetune", "--algo", "cic", "--env", "URLB/walker-flip-v0", "-i", "missing.zip"], "-i missing.zip: no saved"),
        (["enjoy", "--algo", "cic", "--env", "URLB/walker-flip-v0", "--no-render"], "folder was not found"),
        (["skills", "missing.zip"], "no snapshot at missing.zip"),
        (["nope"], "unknown command 'nope' \\(see sb3-cic --help\\)"),
    ],
)
def test_bad_input_is_one_line_and_exit_code_2(arguments, message, workdir: Path, capsys: pytest.CaptureFixture):
    line = _fails(arguments, capsys, workdir)
    assert re.search(message, line), line


def test_failed_finetune_leaves_no_run_folder(workdir: Path, capsys: pytest.CaptureFixture):
    """A walker snapshot onto a quadruped task: refused when rl-zoo loads it, after rl-zoo made its run folder."""
    arguments = ["finetune", "--algo", "cic", "--env", "URLB/quadruped-walk-v0", "-i", str(WALKER_SNAPSHOT), "-n", "100",
                 "--eval-freq", "100", "--eval-episodes", "1", "--seed", "0"]
    line = _fails(arguments, capsys, workdir)
    assert "cannot act on URLB/quadruped-walk-v0" in line and not (workdir / "logs").exists()
    earlier = workdir / "logs" / "cic" / "URLB-quadruped-walk-v0_1"  # an earlier run of the same task stays
    earlier.mkdir(parents=True)
    (earlier / "kept.txt").write_text("an earlier run")
    line = _fails(arguments, capsys, workdir)
    assert _listing(workdir / "logs") == ["cic", "cic/URLB-quadruped-walk-v0_1", "cic/URLB-quadruped-walk-v0_1/kept.txt"]


def test_other_errors_still_raise(workdir: Path, monkeypatch: pytest.MonkeyPatch):
    """A bug (not bad input) keeps its traceback."""

    def broken(*args, **kwargs):
        raise RuntimeError("a bug")

    monkeypatch.setattr(protocol, "run_protocol", broken)
    with pytest.raises(RuntimeError, match="a bug"):
        main(["protocol", "--method", "ddpg", "--study", "s"])
    assert argparse.ArgumentParser.error.__module__ == "argparse"  # restored


def test_entry_point_prints_one_line(tmp_path: Path):
    """The installed command's behaviour (a fresh process): no traceback, exit code 2."""
    env = {**os.environ, "MUJOCO_GL": "disable", "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    process = subprocess.run([sys.executable, "-m", "sb3_cic.cli", "protocol", "--method", "cicc", "--study", "s"],
                             cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert process.returncode == 2
    assert process.stderr.strip().splitlines() == [
        "sb3-cic protocol: error: unknown algorithm 'cicc'; known: "
        "['aps', 'apt', 'cic', 'ddpg', 'diayn', 'disagreement', 'icm', 'moss', 'protorl', 'rnd', 'smm', 'urlbddpg']"
    ]
    assert list(tmp_path.iterdir()) == []
