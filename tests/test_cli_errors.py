"""Every error of ``sb3-cic`` on bad input: one line on stderr, exit code 2, nothing of the failed command left.

The commands run in a fresh working directory (``tmp_path``); "nothing left" is its listing before and after.
Nothing here trains: each command fails before (or while) building its model.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
from pathlib import Path

import pytest

from sb3_cic.study import cli as study_cli, driver
from sb3_cic.cli import main
from waiting import run_process

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
    assert re.match(r"sb3-cic( [\w-]+)?: error: ", lines[0]), lines[0]
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

    monkeypatch.setattr(driver, "run_protocol", broken)
    with pytest.raises(RuntimeError, match="a bug"):
        main(["protocol", "--method", "ddpg", "--study", "s"])
    assert argparse.ArgumentParser.error.__module__ == "argparse"  # restored


def test_entry_point_prints_one_line(tmp_path: Path):
    """The installed command's behaviour (a fresh process): no traceback, exit code 2."""
    env = {**os.environ, "MUJOCO_GL": "disable", "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    process = run_process([sys.executable, "-m", "sb3_cic.cli", "protocol", "--method", "cicc", "--study", "s"],
                          "sb3-cic protocol --method cicc", cwd=tmp_path, env=env)
    assert process.returncode == 2
    assert process.stderr.strip().splitlines() == [
        "sb3-cic protocol: error: unknown algorithm 'cicc'; known: "
        "['aps', 'apt', 'cic', 'cic_code', 'ddpg', 'diayn', 'disagreement', 'fixed', 'icm', 'moss', 'protorl', 'rnd', 'smm', 'urlbddpg']"
    ]
    assert list(tmp_path.iterdir()) == []


#: a run of the study command on one method, domain, task and seed (nothing runs: each case fails before)
STUDY = ["study", "s", "--methods", "ddpg", "--domains", "walker", "--tasks", "stand", "--seeds", "0"]


@pytest.mark.parametrize(
    "arguments, message",
    [
        # counts and sizes out of range: refused while the command line is read, before anything is written
        (["train", "--algo", "cic", "--env", "URLB/walker-v0", "-n", "-100"],
         "argument -n/--n-timesteps: must be an int in \\[1, 1000000000\\], got '-100'"),
        (["train", "--algo", "cic", "--env", "URLB/walker-v0", "--eval-episodes", "0"], "argument --eval-episodes: must be"),
        (["finetune", "--algo", "cic", "--env", "URLB/walker-flip-v0", "-i", str(WALKER_SNAPSHOT), "--seed", "-1"],
         "argument --seed: must be an int in \\[0, 4294967295\\], got '-1'"),
        (["protocol", "--pretrain-steps", "-5", "--study", "s"], "argument --pretrain-steps: must be an int in \\[1, 1000000000\\], got '-5'"),
        (["protocol", "--device", "gpu", "--study", "s"], "argument --device: 'gpu' is not a torch device"),
        ([*STUDY, "--device", "cuda:x"], "argument --device: 'cuda:x' is not a torch device"),
        (["protocol", "--finetune-steps", "-5", "--study", "s"], "argument --finetune-steps: must be an int in \\[1, 1000000000\\], got '-5'"),
        (["protocol", "--finetune-steps", "0", "--study", "s"], "argument --finetune-steps: must be an int in \\[1, 1000000000\\], got '0'"),
        ([*STUDY, "--finetune-steps", "-5"], "argument --finetune-steps: must be an int in \\[1, 1000000000\\], got '-5'"),
        (["protocol", "--eval-episodes", "0", "--study", "s"], "argument --eval-episodes: must be an int >= 1, got '0'"),
        (["protocol", "--eval-freq", "0", "--study", "s"], "argument --eval-freq: must be an int >= 1, got '0'"),
        (["protocol", "--hidden-dim", "0", "--study", "s"], "argument --hidden-dim: must be an int >= 1, got '0'"),
        (["protocol", "--batch-size", "0", "--study", "s"], "argument --batch-size: must be an int >= 1, got '0'"),
        (["protocol", "--batch-size", "1.5", "--study", "s"], "argument --batch-size: must be an int >= 1, got '1.5'"),
        (["protocol", "--seeds", "0", "-3", "--study", "s"], "argument --seeds: must be an int in"),
        (["protocol", "--num-threads", "0", "--study", "s"], "argument --num-threads: must be an int >= 1"),
        (["protocol", "--checkpoint-every", "-1", "--study", "s"], "argument --checkpoint-every: must be an int >= 0"),
        ([*STUDY, "--max-retries", "-1"], "argument --max-retries: must be an int >= 0, got '-1'"),
        ([*STUDY, "--cpus-per-run", "0"], "argument --cpus-per-run: must be a finite number > 0, got '0'"),
        ([*STUDY, "--gpus-per-run", "nan"], "argument --gpus-per-run: must be a finite number >= 0, got 'nan'"),
        (["report", "s", "--reps", "0"], "argument --reps: must be an int >= 1, got '0'"),
        (["skills", "x.zip", "--n", "0"], "argument --n: must be an int >= 1, got '0'"),
        (["skills", "x.zip", "--steps", "-1"], "argument --steps: must be an int >= 1, got '-1'"),
        (["enjoy", "--algo", "cic", "--env", "URLB/walker-flip-v0", "-n", "0"], "argument -n/--n-timesteps: must be"),
        (["record-video", "--algo", "cic", "--env", "URLB/walker-flip-v0", "--n-envs", "0"], "argument --n-envs: must be"),
        # options that do not go together
        (["protocol", "--snapshots", "5000", "--pretrain-steps", "3000", "--study", "s"],
         "--snapshots \\[5000\\] above the 3000 pre-training steps"),
        (["protocol", "--batch-size", "64", "--buffer-size", "32", "--study", "s"],
         "--batch-size 64 is above --buffer-size 32"),
        (["protocol", "--method", "ddpg", "--tasks", "stand", "--learning-starts", "99999999", "--study", "s"],
         "learning_starts 99999999 is not below the fine-tuning's 100000 steps"),
        (["protocol", "--method", "cic", "--tasks", "stand", "--learning-starts", "5000", "--pretrain-steps", "3000",
          "--finetune-steps", "10000", "--study", "s"], "learning_starts 5000 is not below the pre-training's 3000 steps"),
        ([*STUDY, "--learning-starts", "99999999"], "learning_starts 99999999 is not below the fine-tuning's 100000 steps"),
        # a bad hyperparameter reaches the constructor, which refuses it before building anything
        (["train", "--algo", "cic", "--env", "URLB/walker-v0", "--small", "-params", "batch_size:0"],
         "batch_size must be an int >= 1, got 0"),
        (["train", "--algo", "cic", "--env", "URLB/walker-v0", "--small", "-params", "temperature:0"],
         "temperature must be a finite number > 0, got 0"),
        # abbreviated options are not options
        (["protocol", "--smal", "--study", "s"], "unrecognized arguments: --smal"),
        (["train", "--algo", "cic", "--env", "URLB/walker-v0", "--smal"], "unrecognized arguments: --smal"),
        (["train", "--algo", "cic", "--env", "URLB/walker-v0", "--n-timestep", "10"], "unrecognized arguments: --n-timestep"),
        ([*STUDY, "--max-ret", "2"], "unrecognized arguments: --max-ret"),
        (["report", "s", "--rep", "5"], "unrecognized arguments: --rep"),
        (["skills", "x.zip", "--ste", "5"], "unrecognized arguments: --ste"),
    ],
)
def test_bad_values_are_refused_before_anything_runs(arguments, message, workdir: Path, capsys: pytest.CaptureFixture):
    line = _fails(arguments, capsys, workdir)
    assert re.search(message, line), line


def test_small_keeps_an_explicit_zero():
    """``--learning-starts 0`` with ``--small`` is 0 (it was taken for "not given" and became 500)."""
    args = study_cli.protocol_parser().parse_args(["--small", "--learning-starts", "0"])
    settings = study_cli.settings_from_args(args)
    assert settings.learning_starts == 0 and settings.batch_size == 32 and settings.hidden_dim == 32
