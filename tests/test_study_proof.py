"""A result is what its folder proves (issue 73): each finding of the red team's report, on tiny studies.

The tiny study (walker flip; CIC, paired, and DDPG; seeds 0 and 1; hidden 32, 600 steps) is made once, in this
process (:func:`~sb3_cic.study.driver.run_protocol`, no Ray), and copied for each case that edits it.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import warnings
from dataclasses import replace
from pathlib import Path

import pytest
import torch as th

from sb3_cic.protocol import finetune
from sb3_cic.report.commands import write_report
from sb3_cic.report.scores import load_results
from sb3_cic.study.driver import run_protocol
from sb3_cic.study.settings import Settings
from sb3_cic.study.checkpoint import RunFolder
from sb3_cic.study.engine import stop_runs
from sb3_cic.study.graph import Run, run_state, status_report
from sb3_cic.study.record import StudyLock
from test_study_folder import TINY_FLAGS, _exit  # a command's exit code, stdout and stderr, run in process

TINY = Settings(hidden_dim=32, batch_size=32, learning_starts=500, buffer_size=10_000, pretrain_steps=600, finetune_steps=600,
                eval_freq=10_000, eval_episodes=1, num_threads=1, pretrain_checkpoint_every=0, finetune_checkpoint_every=0)
#: a fine-tuning long enough for a checkpoint at step 1000 (an episode boundary)
CHECKPOINTED = replace(TINY, finetune_steps=1200, finetune_checkpoint_every=1000)


@pytest.fixture(autouse=True)
def _threads():
    threads = th.get_num_threads()
    yield
    th.set_num_threads(threads)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory: pytest.TempPathFactory) -> Path:
    study = tmp_path_factory.mktemp("tiny") / "study"
    threads = th.get_num_threads()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run_protocol(study, "cic", "walker", ["flip"], [0, 1], TINY)
        run_protocol(study, "ddpg", "walker", ["flip"], [0, 1], TINY)
    th.set_num_threads(threads)
    return study


@pytest.fixture
def study(tiny: Path, tmp_path: Path) -> Path:
    """A copy of the tiny study, to edit."""
    folder = tmp_path / "study"
    shutil.copytree(tiny, folder, ignore=shutil.ignore_patterns("tensorboard"))
    return folder


def _run(study: Path, label: str, seed: int) -> Path:
    return study / "finetune" / label / "walker_flip" / f"seed_{seed}"


def _edit(path: Path, **changes) -> None:
    data = json.loads(path.read_text())
    data.update(changes)
    path.write_text(json.dumps(data))


def _counted(study: Path) -> tuple[list[tuple[str, int]], list[str]]:
    """The (label, seed) of the results the study counts, and the run folders refused (one warning each)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        results = load_results(study)
    return sorted((r["label"], r["seed"]) for r in results), [str(w.message) for w in caught]


def _start_time(pid: int) -> int:
    """Field 22 of ``/proc/<pid>/stat``: when the process started."""
    with open(f"/proc/{pid}/stat") as file:
        return int(file.read().rsplit(")", 1)[1].split()[19])


def _status_counts(study: Path) -> str:
    return status_report(study)[0].splitlines()[0]


ALL = [("cic", 0), ("cic", 1), ("ddpg", 0), ("ddpg", 1)]


def test_the_tiny_study_is_counted_whole(tiny: Path):
    counted, refused = _counted(tiny)
    assert counted == ALL and not refused
    assert _status_counts(tiny).endswith("6 runs, 6 done, 0 running, 0 failed, 0 pending, 0 damaged")
    result = json.loads((_run(tiny, "cic", 1) / "result.json").read_text())
    pre = json.loads((tiny / "pretrain" / "cic_walker_seed1" / "result.json").read_text())
    assert result["pretrain_seed"] == 1 and result["snapshot_sha256"] == pre["snapshot_sha256"]["600"]
    assert result["run_settings"] == {"num_threads": 1, "compile_update": False, "tf32": False, "device": "cpu"}


# 1. fields the checks did not read ---------------------------------------------------------------------------
def test_an_edited_normalized_score_is_refused(study: Path):
    result = _run(study, "cic", 0) / "result.json"
    _edit(result, final_normalized_score=0.9)
    counted, refused = _counted(study)
    assert counted == [r for r in ALL if r != ("cic", 0)]
    assert len(refused) == 1 and str(result) in refused[0] and "final_normalized_score 0.9" in refused[0]
    assert "5 done" in _status_counts(study) and "1 damaged" in _status_counts(study)


def test_an_edited_seed_is_refused(study: Path):
    result = _run(study, "cic", 1) / "result.json"
    _edit(result, seed=0)
    counted, refused = _counted(study)
    assert counted == [r for r in ALL if r != ("cic", 1)]
    assert len(refused) == 1 and str(result) in refused[0] and "seed 0" in refused[0]
    assert "1 damaged" in _status_counts(study)


def test_a_return_edited_with_its_eval_csv_is_refused(study: Path):
    folder = _run(study, "cic", 0)
    _edit(folder / "result.json", final_return=257.0)
    lines = (folder / "eval.csv").read_text().splitlines()
    step, _, score = lines[-1].split(",")
    (folder / "eval.csv").write_text("\n".join([*lines[:-1], f"{step},257.0,{score}"]) + "\n")
    counted, refused = _counted(study)
    assert ("cic", 0) not in counted and len(refused) == 1 and "final_return 257.0" in refused[0]


# 2. folders the study never made -----------------------------------------------------------------------------
def test_a_renamed_run_folder_is_not_counted(study: Path):
    _run(study, "cic", 1).rename(_run(study, "cic", 5))
    counted, refused = _counted(study)
    assert counted == [("cic", 0), ("ddpg", 0), ("ddpg", 1)]
    assert len(refused) == 1 and "seed_5" in refused[0] and "settings.json" in refused[0]
    report = status_report(study)[0]
    assert "5 done" in report.splitlines()[0] and "1 pending" in report.splitlines()[0]
    assert "does not count" in report and "seed_5" in report


def test_a_run_of_another_study_counts_only_with_the_studys_settings(study: Path, tmp_path: Path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run_protocol(tmp_path / "same", "ddpg", "walker", ["flip"], [7], TINY)
        run_protocol(tmp_path / "longer", "ddpg", "walker", ["flip"], [8], replace(TINY, finetune_steps=700))
    shutil.copytree(_run(tmp_path / "same", "ddpg", 7), _run(study, "ddpg", 7))
    shutil.copytree(_run(tmp_path / "longer", "ddpg", 8), _run(study, "ddpg", 8))
    counted, refused = _counted(study)
    assert counted == sorted([*ALL, ("ddpg", 7)])
    assert len(refused) == 1 and "seed_8" in refused[0] and "finetune_steps" in refused[0]
    with pytest.warns(UserWarning, match="seed_8"):
        report = write_report(study, reps=20)
    assert report["runs_read"]["kinds"] == {"listed": 4, "copied": 1}
    text = (study / "report.md").read_text()
    assert "4 runs listed in study.json" in text and "1 run not listed, its settings.json equal to the study's" in text
    assert "refused (not counted)" in text and "seed_8" in text
    assert _status_counts(study).endswith("6 runs, 6 done, 0 running, 0 failed, 0 pending, 0 damaged")


def test_a_benchmark_report_refuses_studies_made_with_other_settings(tiny: Path, tmp_path: Path):
    from sb3_cic.report.commands import write_benchmark_report

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run_protocol(tmp_path / "same", "ddpg", "walker", ["flip"], [7], TINY)
        run_protocol(tmp_path / "longer", "ddpg", "walker", ["flip"], [8], replace(TINY, finetune_steps=700))
    report = write_benchmark_report([tiny, tmp_path / "same"], tmp_path / "out", reps=20)
    assert len(report["returns"]["ddpg"]["walker_flip"]) == 3 and report["seeds"] == [0, 1, 7]
    with pytest.raises(ValueError, match=r"other settings.*finetune_steps.*600.*700"):
        write_benchmark_report([tiny, tmp_path / "longer"], tmp_path / "mixed", reps=20)
    assert not (tmp_path / "mixed").exists()


# 3. inputs with no identity ----------------------------------------------------------------------------------
def test_a_snapshot_copied_over_another_is_refused(study: Path):
    ours, theirs = study / "pretrain" / "cic_walker" / "snapshot_600.zip", study / "pretrain" / "cic_walker_seed1" / "snapshot_600.zip"
    shutil.copyfile(theirs, ours)
    shutil.rmtree(_run(study, "cic", 0))
    with pytest.raises(ValueError, match="snapshot_600.zip is not the one its pre-training saved"):
        finetune(study, Run("cic", "walker", "walker_flip", 0, pretrain_seed=0), TINY)
    assert not (_run(study, "cic", 0) / "result.json").exists()


def test_a_fine_tuning_that_records_another_snapshot_is_refused(study: Path):
    _edit(_run(study, "cic", 0) / "result.json", snapshot_sha256="0" * 64)
    counted, refused = _counted(study)
    assert ("cic", 0) not in counted and len(refused) == 1 and "snapshot_sha256" in refused[0]


def _interrupted_after_first_checkpoint(study: Path, seed: int, monkeypatch: pytest.MonkeyPatch,
                                        settings: Settings = CHECKPOINTED) -> Path:
    """A DDPG fine-tuning of ``seed`` stopped right after its first checkpoint (step 1000); its folder."""
    save = RunFolder.save_checkpoint

    def save_then_stop(self, *args, **kwargs):
        save(self, *args, **kwargs)
        raise KeyboardInterrupt("stopped after the checkpoint")

    with monkeypatch.context() as patch:
        patch.setattr(RunFolder, "save_checkpoint", save_then_stop)
        with pytest.raises(KeyboardInterrupt), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            run_protocol(study, "ddpg", "walker", ["flip"], [seed], settings)
    folder = _run(study, "ddpg", seed)
    assert (folder / "checkpoint.zip").exists() and not (folder / "result.json").exists()
    return folder


def test_a_checkpoint_copied_from_another_run_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    study = tmp_path / "study"
    seed0 = _interrupted_after_first_checkpoint(study, 0, monkeypatch)
    seed1 = _run(study, "ddpg", 1)
    seed1.mkdir(parents=True)
    shutil.copyfile(seed0 / "checkpoint.zip", seed1 / "checkpoint.zip")
    with pytest.raises(ValueError, match=r"checkpoint.zip belongs to another run .*'ddpg', 'walker', 'walker_flip', 0"):
        run_protocol(study, "ddpg", "walker", ["flip"], [1], CHECKPOINTED)
    assert not (seed1 / "result.json").exists()


def test_a_checkpoint_period_that_ends_mid_episode_waits_for_its_end(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """500 steps is half of walker's 1000-step episode: the checkpoint is taken at the next episode boundary (step
    1000, not 500, where the episode start could not be reproduced), and the resumed run ends as the whole one."""
    settings = replace(CHECKPOINTED, finetune_checkpoint_every=500)
    folder = _interrupted_after_first_checkpoint(tmp_path / "study", 0, monkeypatch, settings)
    assert RunFolder(folder).read_meta()["step"] == 1000
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        (resumed,) = run_protocol(tmp_path / "study", "ddpg", "walker", ["flip"], [0], settings)
        (whole,) = run_protocol(tmp_path / "whole", "ddpg", "walker", ["flip"], [0], replace(settings, finetune_checkpoint_every=0))
    assert resumed["resumed_from_step"] == 1000 and resumed["final_return"] == whole["final_return"]


# 4. settings that change results -----------------------------------------------------------------------------
def test_run_settings_are_recorded_and_a_resume_with_others_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    study = tmp_path / "study"
    folder = _interrupted_after_first_checkpoint(study, 0, monkeypatch)
    assert json.loads((folder / "settings.json").read_text())["run_settings"]["num_threads"] == 1
    with pytest.raises(ValueError, match=r"other run settings.*'num_threads': \(1, 2\)"):
        run_protocol(study, "ddpg", "walker", ["flip"], [0], replace(CHECKPOINTED, num_threads=2))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        (result,) = run_protocol(study, "ddpg", "walker", ["flip"], [0], CHECKPOINTED)
    assert result["resumed_from_step"] == 1000 and result["run_settings"]["num_threads"] == 1


def test_a_report_says_when_runs_mix_run_settings(study: Path):
    result = _run(study, "ddpg", 1) / "result.json"
    _edit(result, run_settings={**json.loads(result.read_text())["run_settings"], "num_threads": 2})
    from sb3_cic.study.results import study_results

    lines = study_results(study).describe()
    assert any(line.startswith("the runs mix run settings") and "1 with" in line and "3 with" in line for line in lines)


# 5. signals reach only the study's processes -----------------------------------------------------------------
def test_a_reused_pid_is_neither_signalled_nor_called_running(study: Path):
    bystander = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.read()"], stdin=subprocess.PIPE)
    try:
        run = Run("ddpg", "walker", "walker_flip", 0)
        folder = RunFolder(run.folder(study))
        folder.result.unlink()
        started = _start_time(bystander.pid)
        # the dead worker's progress.json: its pid is now the bystander's, its start time an earlier one
        folder.progress.write_text(json.dumps({"host": socket.gethostname(), "pid": bystander.pid, "start_time": started - 1,
                                               "checkpoint_step": 0, "updated": 1e12}))
        assert run_state(folder)[0] == "pending"
        assert f"pid {bystander.pid}" not in status_report(study)[0]
        stop_runs(study, [run], since=0, grace_s=0)
        assert bystander.poll() is None
        # the process it names, proven by its start time, is stopped
        _edit(folder.progress, start_time=started)
        assert run_state(folder)[0] == "running"
        stop_runs(study, [run], since=0, grace_s=0)
        assert bystander.wait() == -9
    finally:
        if bystander.poll() is None:
            bystander.kill()
            bystander.wait()


def test_a_progress_json_that_proves_no_process_is_no_running_run(study: Path, monkeypatch: pytest.MonkeyPatch):
    """A pid that is no pid (-1 and 0 name many processes to ``kill``), garbage, or a live process of this host
    recorded without its start time: nothing proves the run's process, so ``status`` says pending, in one piece, and
    ``stop_runs`` neither signals nor waits."""
    bystander = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.read()"], stdin=subprocess.PIPE)
    try:
        run = Run("ddpg", "walker", "walker_flip", 0)
        folder = RunFolder(run.folder(study))
        folder.result.unlink()
        here = socket.gethostname()
        for progress in ({"host": here, "pid": -1, "start_time": 1}, {"host": here, "pid": 0}, {"host": here, "pid": None},
                         {"host": here, "pid": "abc"}, {"host": here, "pid": 10**12}, [1, 2], {"host": here, "pid": bystander.pid}):
            folder.progress.write_text(json.dumps(progress if isinstance(progress, list) else {**progress, "updated": 1e12}))
            assert run_state(folder)[0] == "pending", progress
            assert "ddpg walker_flip seed 0: pending" in status_report(study)[0]
            with monkeypatch.context() as patch:  # stop_runs sleeps only while it waits for a process it would stop
                patch.setattr("sb3_cic.study.engine.time.sleep", lambda s: pytest.fail(f"stop_runs waits for {progress}"))
                stop_runs(study, [run], since=0, grace_s=60)
            assert bystander.poll() is None
    finally:
        bystander.kill()
        bystander.wait()


# the smaller points ------------------------------------------------------------------------------------------
def test_a_command_stopped_at_once_leaves_no_folder(tmp_path: Path):
    new, old = tmp_path / "new", tmp_path / "old"
    old.mkdir()
    for folder in (new, old):
        with pytest.raises(KeyboardInterrupt), StudyLock(folder):
            raise KeyboardInterrupt
    assert not new.exists() and old.exists()


def _signal_during_ray_init(signum: int, then: str):
    """A stand-in for ``ray.init`` during which ``signum`` arrives (the whole process group signalled): ``then`` is
    what Ray's start makes of it: ``"exit"`` (Ray's SIGTERM handler, installed first: ``sys.exit``) or ``"error"``
    (the interrupt cut a start short, which fails with its own error)."""

    def init(**kwargs):
        if then == "exit":
            signal.signal(signal.SIGTERM, lambda number, frame: sys.exit(number))
        try:
            os.kill(os.getpid(), signum)
            for _ in range(10**6):  # the handler runs between two bytecodes of this thread
                pass
        except KeyboardInterrupt as interrupt:
            raise RuntimeError("Failed to connect to GCS") from interrupt
        raise AssertionError("the signal did not arrive")

    return init


@pytest.mark.parametrize(("signum", "then"), [(signal.SIGTERM, "exit"), (signal.SIGINT, "error"), (signal.SIGTERM, "error")])
def test_a_signal_while_ray_starts_is_one_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture,
                                               signum: int, then: str):
    import ray

    before = signal.getsignal(signal.SIGTERM)
    monkeypatch.setattr(ray, "init", _signal_during_ray_init(signum, then))
    code, _, err = _exit(["study", str(tmp_path / "study"), "--methods", "ddpg", "--domains", "walker", "--tasks", "flip",
                          "--seeds", "0", "--finetune-steps", "600", *TINY_FLAGS], capsys)
    assert code == 128 + signum and err.strip().splitlines() == [
        f"sb3-cic study: interrupted ({signal.Signals(signum).name}); its runs are stopped and keep their last checkpoint: "
        "run the same command to resume"], err
    assert signal.getsignal(signal.SIGTERM) is before  # the command's own handler, not Ray's, is gone with it
    assert status_report(tmp_path / "study")[0].splitlines()[0].endswith("1 run, 0 done, 0 running, 0 failed, 1 pending, 0 damaged")


def test_report_refuses_a_damaged_or_edited_study_json(study: Path, capsys: pytest.CaptureFixture):
    record = json.loads((study / "study.json").read_text())
    (study / "study.json").write_text(json.dumps({"settings": 5}))
    code, _, err = _exit(["report", str(study), "--reps", "20"], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "study.json is damaged" in err
    (study / "study.json").write_text(json.dumps({**record, "settings": {**record["settings"], "finetune_steps": 2000}}))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        code, _, err = _exit(["report", str(study), "--reps", "20"], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "4 refused" in err
    said = [str(w.message) for w in caught]
    assert len(said) == 4 and all("records other settings than" in line and "'finetune_steps': (600, 2000)" in line
                                  for line in said)


def test_status_of_a_study_without_runs_is_not_finished(study: Path):
    _edit(study / "study.json", runs=[])
    text, finished = status_report(study)
    assert not finished and "no runs recorded yet" in text


def test_a_corrupt_checkpoint_needs_one_round_of_advice(tmp_path: Path):
    folder = RunFolder(tmp_path / "run")
    folder.start(1000)
    folder.checkpoint.write_bytes(b"PK\x03\x04 not a zip")
    with pytest.raises(ValueError, match="corrupt checkpoint") as error:
        folder.read_meta()
    named = [Path(word.rstrip(",;")) for word in str(error.value).split("delete ", 1)[1].split() if word.startswith("/")]
    for path in named:
        path.unlink()
    assert folder.read_meta() is None


def test_status_into_a_closed_pipe_ends_without_a_traceback(tiny: Path):
    command = [sys.executable, "-c", "from sb3_cic.cli import main; main()", "status", str(tiny)]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env={**os.environ, "MUJOCO_GL": "disable"})
    process.stdout.close()  # the reader is gone before the status is written (``| head`` that had enough)
    err = process.stderr.read().decode()
    assert process.wait() == 0 and "Traceback" not in err and "BrokenPipeError" not in err, err
