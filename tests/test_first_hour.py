"""What a user meets in the first hour of ``sb3-cic``: every refusal is one line (exit code 2, nothing left behind),
an interrupted command says how to go on, a silent choice says what it does, and a typo is refused before the heavy
modules load.

Each case counts the lines on stderr and lists the working folder before and after; the heavy-module cases look at
``sys.modules`` of a fresh process, not at a clock.
"""

from __future__ import annotations

import builtins
import errno
import io
import json
import os
import re
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest
import torch as th

from sb3_cic import cli
from sb3_cic.cli import main
from sb3_cic.common import progress
from sb3_cic.study.checkpoint import RunFolder
from sb3_cic.study.engine import announce_resumed
from sb3_cic.study.graph import Run
from waiting import wait_for

ROOT = Path(__file__).resolve().parent.parent
WALKER_SNAPSHOT = ROOT / "sb3_cic" / "pretrained" / "cic_walker_h256_100k.zip"
#: tiny protocol settings of a run from scratch
TINY = ["--small", "--eval-episodes", "1", "--eval-freq", "100000", "--buffer-size", "5000"]
ENV = {**os.environ, "MUJOCO_GL": "disable", "OMP_NUM_THREADS": "1",
       "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
#: the modules a typo must not wait for
HEAVY = ("torch", "rl_zoo3", "dm_control", "stable_baselines3", "ray")


def _listing(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def _one_line(arguments: list[str], capsys: pytest.CaptureFixture, folder: Path) -> str:
    """Run ``sb3-cic arguments`` in-process: exit code 2, one line on stderr, nothing on stdout, ``folder`` unchanged."""
    before = _listing(folder)
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit_info:
        main(arguments)
    out, err = capsys.readouterr()
    assert exit_info.value.code == 2, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert out == "", out
    assert _listing(folder) == before
    return err.strip()


@pytest.fixture
def workdir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.chdir(tmp_path)
    return tmp_path


@pytest.fixture
def read_only(workdir: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A folder ``ro`` of the working folder on which every write fails as on a read-only file system (EROFS; chmod
    does not stop root, who runs these tests): creating, opening for writing, renaming or deleting in it."""
    root = workdir / "ro"
    root.mkdir()

    def inside(path: object) -> bool:
        if not isinstance(path, (str, bytes, os.PathLike)):
            return False  # a file descriptor
        return Path(os.path.abspath(os.fsdecode(path))).is_relative_to(root)

    def refuse(path: object) -> None:
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), os.fsdecode(path))  # type: ignore[arg-type]

    real_open, real_os_open, real_mkdir = builtins.open, os.open, os.mkdir
    real_replace, real_rename, real_unlink = os.replace, os.rename, os.unlink

    def open_(file, mode="r", *args, **kwargs):
        if any(flag in mode for flag in "wax+") and inside(file):
            refuse(file)
        return real_open(file, mode, *args, **kwargs)

    def os_open(path, flags, *args, **kwargs):
        if flags & (os.O_WRONLY | os.O_RDWR | os.O_CREAT) and inside(path):
            refuse(path)
        return real_os_open(path, flags, *args, **kwargs)

    def mkdir(path, *args, **kwargs):
        if inside(path):
            if os.path.exists(path):
                raise FileExistsError(errno.EEXIST, os.strerror(errno.EEXIST), os.fsdecode(path))
            refuse(path)
        return real_mkdir(path, *args, **kwargs)

    def two_paths(real):
        def move(src, dst, *args, **kwargs):
            if inside(src) or inside(dst):
                refuse(dst)
            return real(src, dst, *args, **kwargs)
        return move

    def unlink(path, *args, **kwargs):
        if inside(path):
            refuse(path)
        return real_unlink(path, *args, **kwargs)

    for module in (builtins, io):
        monkeypatch.setattr(module, "open", open_)
    monkeypatch.setattr(os, "open", os_open)
    monkeypatch.setattr(os, "mkdir", mkdir)
    monkeypatch.setattr(os, "replace", two_paths(real_replace))
    monkeypatch.setattr(os, "rename", two_paths(real_rename))
    monkeypatch.setattr(os, "unlink", unlink)
    return root


# 2. one line where a traceback was ------------------------------------------------------------------------------
@pytest.mark.parametrize("item, message", [
    ("batch_size:abc", "--hyperparams batch_size:abc: the value is not a Python expression \\(NameError"),
    ("batchsize:64", "unexpected keyword argument 'batchsize': not a hyperparameter of CIC"),
])
def test_a_bad_hyperparameter_is_one_line_and_leaves_no_monitor_file(item, message, workdir, capsys):
    line = _one_line(["train", "--algo", "cic", "--env", "URLB/walker-v0", "--small", "-n", "200", "--hyperparams", item],
                     capsys, workdir)
    assert re.search(message, line), line
    assert not (workdir / "logs").exists()  # rl-zoo's run folder and its 0.monitor.csv are gone


def test_a_file_where_a_folder_is_needed_is_one_line(workdir, capsys):
    (workdir / "afile").write_text("a file")
    line = _one_line(["study", "afile", "--methods", "ddpg", "--domains", "walker", "--tasks", "stand", "--seeds", "0",
                      *TINY, "--finetune-steps", "1000"], capsys, workdir)
    assert line == "sb3-cic study: error: cannot use afile: a file stands where a folder is needed: choose another " \
                   "path (File exists)"
    line = _one_line(["train", "--algo", "ddpg", "--env", "URLB/walker-stand-v0", "--small", "-n", "200", "-f", "afile"],
                     capsys, workdir)
    assert line.startswith("sb3-cic train: error: cannot use afile/ddpg: a file stands where a folder is needed")


def test_read_only_protocol_and_train_are_one_line(read_only: Path, workdir: Path, capsys):
    line = _one_line(["protocol", "--method", "ddpg", "--tasks", "stand", "--seeds", "0", "--study", "ro/study", *TINY,
                      "--finetune-steps", "1000"], capsys, workdir)
    assert line.startswith("sb3-cic protocol: error: cannot write ") and "ro/study" in line
    assert line.endswith(": read-only file system: choose a writable folder (Read-only file system)")
    line = _one_line(["train", "--algo", "ddpg", "--env", "URLB/walker-stand-v0", "--small", "-n", "200", "-f", "ro/logs"],
                     capsys, workdir)
    assert line.startswith("sb3-cic train: error: cannot write ro/logs") and "read-only file system" in line


def test_read_only_skills_and_benchmark_report_are_one_line(read_only: Path, workdir: Path, capsys):
    line = _one_line(["skills", str(WALKER_SNAPSHOT), "--n", "2", "--steps", "3", "--no-video", "--plot", "ro/where.png"],
                     capsys, workdir)
    assert line.startswith("sb3-cic skills: error: cannot write") and "ro/where.png" in line and "read-only" in line
    from test_benchmark_report import published_study

    studies = [str(study) for study in published_study(workdir / "studies")]
    line = _one_line(["benchmark-report", *studies, "--out", "ro/report", "--reps", "10"], capsys, workdir)
    assert line.startswith("sb3-cic benchmark-report: error: cannot write ro/report") and "read-only" in line


def test_skills_without_opengl_is_one_line_with_the_advice(workdir, capsys):
    assert os.environ["MUJOCO_GL"] == "disable"  # tests/conftest.py
    line = _one_line(["skills", str(WALKER_SNAPSHOT), "--n", "2", "--steps", "3", "--out", "v.mp4"], capsys, workdir)
    assert line.startswith("sb3-cic skills: error: MuJoCo could not render") and "Set MUJOCO_GL=egl" in line


def test_a_walker_snapshot_on_a_quadruped_task_prints_only_the_error(workdir, capsys):
    """rl-zoo's hyperparameter dump (stdout) is held until the model is built: a refused snapshot prints one line."""
    line = _one_line(["finetune", "--algo", "cic", "--env", "URLB/quadruped-jump-v0", "-i", str(WALKER_SNAPSHOT),
                      "-n", "100", "--seed", "0"], capsys, workdir)
    assert "cannot act on URLB/quadruped-jump-v0" in line


def _read_all(fd: int, chunks: list[bytes]) -> None:
    while True:
        try:
            data = os.read(fd, 65536)
        except OSError:
            return
        if not data:
            return
        chunks.append(data)


def test_ctrl_c_in_protocol_is_one_line_and_the_run_resumes(workdir: Path, capsys):
    """SIGINT while the fine-tuning trains, its progress bar drawn on a terminal: exit code 130 and one line that says
    how to resume; the same command again says it resumed, and from which step."""
    import pty

    command = ["protocol", "--method", "ddpg", "--tasks", "stand", "--seeds", "0", "--study", "s", *TINY,
               "--finetune-steps", "3000", "--learning-starts", "1000", "--checkpoint-every", "1000"]
    folder = workdir / "s" / "finetune" / "ddpg" / "walker_stand" / "seed_0"
    controller, terminal = pty.openpty()
    screen: list[bytes] = []
    reader = threading.Thread(target=_read_all, args=(controller, screen), daemon=True)
    reader.start()
    driver = subprocess.Popen([sys.executable, "-m", "sb3_cic.cli", *command], env=ENV, cwd=workdir, stdout=terminal,
                              stderr=subprocess.PIPE, text=True)
    os.close(terminal)
    try:
        # the checkpoint is renamed into place before progress.json records its step: wait for the record, or a
        # SIGINT between the two finds progress.json still at step 0
        wait_for(lambda: (RunFolder(folder).read_progress() or {}).get("checkpoint_step", 0) >= 1000,
                 "the run's first checkpoint", driver, lambda: driver.stderr.read() if driver.poll() is not None else "")
        driver.send_signal(signal.SIGINT)
        _, err = driver.communicate()
    finally:
        if driver.poll() is None:
            driver.kill()
            driver.wait()
        os.close(controller)
    assert b"\x1b[" in b"".join(screen)  # the bar was drawn (the progress of a terminal)
    assert driver.returncode == 130, err
    assert err.strip().splitlines() == [
        "sb3-cic protocol: interrupted (SIGINT); each run keeps its last checkpoint: run the same command to resume"
    ]
    step = RunFolder(folder).read_meta()["step"]  # what resumes: the checkpoint itself (a later one may have come)
    assert step >= 1000 and not (folder / "result.json").exists()

    capsys.readouterr()
    main(command)  # stdout is not a terminal here: progress lines, no bar
    out = capsys.readouterr().out
    assert f"ddpg walker_stand seed 0: resumed from its checkpoint at step {step:,} of 3,000" in out.splitlines()
    assert json.loads((folder / "result.json").read_text())["resumed_from_step"] == step


# 3. one line where there was silence -----------------------------------------------------------------------------
def test_finetune_on_the_reward_free_id_is_refused(workdir, capsys):
    line = _one_line(["finetune", "--algo", "cic", "--env", "URLB/walker-v0", "-i", str(WALKER_SNAPSHOT)], capsys, workdir)
    assert "URLB/walker-v0 is a reward-free pre-training env" in line and "fine-tune on a task id" in line


@pytest.mark.parametrize("arguments", [
    ["protocol", "--device", "cuda", "--study", "s"],
    ["study", "s", "--methods", "ddpg", "--domains", "walker", "--tasks", "stand", "--device", "cuda:0"],
    ["train", "--algo", "cic", "--env", "URLB/walker-v0", "--small", "--device", "cuda"],
    ["enjoy", "--algo", "cic", "--env", "URLB/walker-flip-v0", "--device", "cuda"],
])
def test_cuda_without_cuda_is_refused(arguments, workdir, capsys, monkeypatch):
    monkeypatch.setattr(th.cuda, "is_available", lambda: False)
    line = _one_line(arguments, capsys, workdir)
    assert "torch sees no CUDA device on this machine; use --device cpu (or auto)" in line


def test_a_resumed_study_run_is_announced(tmp_path, capsys):
    """The study's driver says which runs resume, and from which step (their ``progress.json``)."""
    resumed, fresh = Run("ddpg", "walker", "walker_stand", 0), Run("ddpg", "walker", "walker_stand", 1)
    folder = Path(resumed.folder(tmp_path))
    folder.mkdir(parents=True)
    (folder / "progress.json").write_text(json.dumps({"pid": 1, "checkpoint_step": 20000}))
    announce_resumed(tmp_path, [resumed, fresh])
    assert capsys.readouterr().out.splitlines() == ["ddpg walker_stand seed 0: resumes from its checkpoint at step 20,000"]


def test_a_short_skill_sweep_is_one_warning_line(tmp_path):
    """--small's learning_starts 500: the fine-tuning sweep tries 5 of the paper's 40 candidates, and says so."""
    command = [sys.executable, "-m", "sb3_cic.cli", "finetune", "--algo", "cic", "--env", "URLB/walker-stand-v0",
               "-i", str(WALKER_SNAPSHOT), "--small", "-n", "600", "--eval-freq", "100000", "--eval-episodes", "1",
               "--seed", "0", "--verbose", "0"]
    done = subprocess.run(command, env=ENV, cwd=tmp_path, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    warnings = [line for line in done.stderr.splitlines() if "warning" in line.lower()]
    assert warnings == [
        "sb3-cic finetune: warning: the fine-tuning skill sweep tries 5 candidates, not the paper's 40: it lasts "
        "learning_starts 500 steps at 100 per candidate (learning_starts 4000 for the full sweep)"
    ], done.stderr


def test_too_many_steps_are_refused(workdir, capsys):
    line = _one_line(["protocol", "--pretrain-steps", "100000000000000", "--study", "s"], capsys, workdir)
    assert "argument --pretrain-steps: must be an int in [1, 1000000000], got '100000000000000'" in line


def test_progress_lines_when_stdout_is_not_a_terminal(workdir, capsys, monkeypatch):
    monkeypatch.setattr(progress, "PROGRESS_INTERVAL_S", 0.0)
    capsys.readouterr()
    main(["protocol", "--method", "ddpg", "--tasks", "stand", "--seeds", "0", "--study", "s", *TINY,
          "--finetune-steps", "600", "--learning-starts", "500"])
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("ddpg walker_stand seed 0: step")]
    assert len(lines) >= 600 and lines[-1].startswith("ddpg walker_stand seed 0: step 600 of 600 (100%)")
    assert re.fullmatch(r"ddpg walker_stand seed 0: step 300 of 600 \(50%\), [\d,]+ steps/s, about .+ left", lines[299])


# 5. a typo is refused before the heavy modules load ----------------------------------------------------------------
TYPOS = [
    ["train", "--algo", "cic", "--env", "URLB/walker-v0", "--smal"],
    ["train", "--algo", "cic", "--env", "URLB/walker-v0", "--save-frq", "1000"],
    ["train", "--algo", "cic", "--env", "URLB/walker-v0", "-n", "-100"],
    ["finetune", "--algo", "cic", "--env", "URLB/walker-flip-v0", "-i", "m.zip", "--smal"],
    ["enjoy", "--algo", "cic", "--env", "URLB/walker-flip-v0", "--no-rendr"],
    ["protocol", "--smal"],
    ["study", "s", "--max-ret", "2"],
]


def test_a_typo_is_refused_before_torch_loads(tmp_path):
    script = (
        "import json, sys\nfrom sb3_cic.cli import main\nresults = []\n"
        f"for arguments in {TYPOS!r}:\n"
        "    try:\n        main(arguments)\n    except SystemExit as exit_:\n        code = exit_.code\n"
        f"    results.append([code, [m for m in {HEAVY!r} if m in sys.modules]])\n"
        "print(json.dumps(results))\n"
    )
    done = subprocess.run([sys.executable, "-c", script], env=ENV, cwd=tmp_path, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout) == [[2, []]] * len(TYPOS), done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == len(TYPOS) and all(" error: " in line for line in lines), lines
    assert "unrecognized arguments: --save-frq" in lines[1] and "got '-100'" in lines[2]
    assert list(tmp_path.iterdir()) == []


def _script_options(module: str, function: str | None) -> set[str]:
    """The options of one of rl-zoo's scripts, read from its parser."""
    import argparse
    import runpy

    class Parsed(Exception):
        pass

    seen: list[argparse.ArgumentParser] = []

    def parse_args(self, *args, **kwargs):
        seen.append(self)
        raise Parsed

    saved = argparse.ArgumentParser.parse_args
    argparse.ArgumentParser.parse_args = parse_args  # type: ignore[method-assign]
    try:
        if function is None:
            runpy.run_module(module, run_name="__main__")
        else:
            getattr(__import__(module, fromlist=[function]), function)()
    except Parsed:
        pass
    finally:
        argparse.ArgumentParser.parse_args = saved  # type: ignore[method-assign]
    return {option for action in seen[0]._actions for option in action.option_strings}


@pytest.mark.parametrize("script, module, function", [
    ("train", "rl_zoo3.train", "train"), ("enjoy", "rl_zoo3.enjoy", "enjoy"), ("record_video", "rl_zoo3.record_video", None),
])
def test_zoo_options_are_rl_zoos(script, module, function):
    """The options sb3-cic lets through to rl-zoo (:data:`sb3_cic.cli.ZOO_SCRIPT_OPTIONS`) are those of rl-zoo's script."""
    assert cli.ZOO_SCRIPT_OPTIONS[script] == _script_options(module, function)
