"""``sb3-cic pause``: the command that drives a study stops its runs at their next episode end, each checkpointed
there, and the same command resumes them as if nothing had happened (tiny scale: hidden 32, batch 32, walker's
1,000-step episodes, one torch thread). The pause on Ray, from another thread while the study runs, is in
``tests/test_study.py`` beside the other tests of its Ray instance."""

from __future__ import annotations

import fcntl
import json
import socket
from dataclasses import replace
from pathlib import Path

import pytest
import torch as th

from sb3_cic.cli import main
from sb3_cic.common.resumable import RunPaused
from sb3_cic.study.checkpoint import RunFolder
from sb3_cic.study.cli import PAUSED_CODE
from sb3_cic.study.driver import StudyPlan, drive, run_protocol
from sb3_cic.study.graph import run_state, status_report
from sb3_cic.study.layout import pause_file
from sb3_cic.study.record import Pairing, StudyLock, pause_requested
from sb3_cic.study.settings import Settings

SETTINGS = Settings(
    hidden_dim=32, batch_size=32, learning_starts=1500, buffer_size=10_000, pretrain_steps=3000, finetune_steps=3000,
    eval_freq=1000, eval_episodes=1, num_threads=1,
    pretrain_checkpoint_every=2500, finetune_checkpoint_every=2500,  # no periodic checkpoint before the pauses
)


def _pause_at_episode(episode: int):
    """In place of :func:`sb3_cic.protocol.pause_check`: each run's check says yes from the ``episode``-th episode
    boundary it is asked at (the first is the step it starts from): a pause that reaches the run at a known step
    (walker's episodes are 1,000 steps)."""

    def pause_check(study: Path):
        asked = []

        def check() -> bool:
            asked.append(1)
            return len(asked) >= episode

        return check

    return pause_check


def _curves(study: Path) -> dict[str, str]:
    return {str(p.relative_to(study)): p.read_text() for p in sorted(study.glob("finetune/*/*/seed_*/eval.csv"))}


def test_a_paused_run_resumes_as_the_run_that_never_stopped(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """The pre-training paused at step 2,000 and the fine-tuning at step 2,000 (in its skill sweep, learning_starts
    1,500 steps): each checkpoints there although no period is due, shows as pending with that checkpoint, and the
    command run again ends with the networks (bit for bit), sweep and evaluations of the uninterrupted run."""
    run_protocol(tmp_path / "uninterrupted", "cic", "walker", tasks=["stand"], seeds=[0], settings=SETTINGS)

    study = tmp_path / "paused"
    pretrain = RunFolder(study / "pretrain" / "cic_walker")
    finetune = RunFolder(study / "finetune" / "cic" / "walker_stand" / "seed_0")
    for folder in (pretrain, finetune):
        with monkeypatch.context() as patch:
            patch.setattr("sb3_cic.protocol.pause_check", _pause_at_episode(3))  # steps 0, 1,000, 2,000
            with pytest.raises(RunPaused) as paused:
                run_protocol(study, "cic", "walker", tasks=["stand"], seeds=[0], settings=SETTINGS)
        assert paused.value.step == 2000 and folder.read_meta()["step"] == 2000 and not folder.done
        progress = folder.read_progress()
        assert progress["pid"] is None and progress["checkpoint_step"] == 2000 and run_state(folder)[0] == "pending"
    text, finished = status_report(study)
    assert not finished and "cic walker_stand seed 0: pending, last checkpoint at step 2000" in text

    run_protocol(study, "cic", "walker", tasks=["stand"], seeds=[0], settings=SETTINGS)
    from sb3_cic import CIC

    for name in ("uninterrupted", "paused"):
        assert not list((tmp_path / name).rglob("checkpoint*")) and not list((tmp_path / name).rglob("progress.json"))
    resumed = CIC.load(pretrain.path / "snapshot_3000.zip", device="cpu")
    expected = CIC.load(tmp_path / "uninterrupted" / "pretrain" / "cic_walker" / "snapshot_3000.zip", device="cpu")
    for module in ("policy", "reward_module"):
        a, b = getattr(resumed, module).state_dict(), getattr(expected, module).state_dict()
        assert a.keys() == b.keys() and all(th.equal(a[k], b[k]) for k in a), module
    result, reference = (json.loads((tmp_path / name / "finetune" / "cic" / "walker_stand" / "seed_0" / "result.json")
                                    .read_text()) for name in ("paused", "uninterrupted"))
    assert result["resumed_from_step"] == 2000 and reference["resumed_from_step"] == 0
    for key in ("final_return", "finetune_skill", "skill_sweep", "n_evaluations"):
        assert result[key] == reference[key], key
    assert _curves(study) == _curves(tmp_path / "uninterrupted")


def test_a_run_without_checkpoints_ignores_the_pause(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """--checkpoint-every 0: a stop would lose the run, so it runs to its end."""
    monkeypatch.setattr("sb3_cic.protocol.pause_check", lambda study: lambda: True)
    settings = replace(SETTINGS, finetune_steps=1000, learning_starts=500, finetune_checkpoint_every=0)
    (result,) = run_protocol(tmp_path, "ddpg", "walker", tasks=["stand"], seeds=[0], settings=settings)
    assert result["finetune_steps"] == 1000 and result["resumed_from_step"] == 0


def test_a_run_paused_before_its_first_step_keeps_nothing_and_starts_over(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
):
    """Asked at step 0, the run writes no checkpoint (nothing to keep) and is pending at step 0; ``sb3-cic protocol``
    ends with exit code 75 and one line that says how to resume."""
    monkeypatch.setattr("sb3_cic.protocol.pause_check", lambda study: lambda: True)
    with pytest.raises(SystemExit) as exit_info:
        main(["protocol", "--method", "ddpg", "--domain", "walker", "--tasks", "stand", "--seeds", "0", "--study",
              str(tmp_path), "--hidden-dim", "32", "--batch-size", "32", "--learning-starts", "500", "--buffer-size", "10000",
              "--no-progress"])
    folder = RunFolder(tmp_path / "finetune" / "ddpg" / "walker_stand" / "seed_0")
    assert exit_info.value.code == PAUSED_CODE and not folder.checkpoint.exists()
    assert run_state(folder) == ("pending", {"checkpoint_step": 0})
    out, err = capsys.readouterr()
    assert "ddpg walker_stand seed 0: paused at step 0 of 100,000 (nothing done to keep)" in out
    assert err == ("sb3-cic protocol: paused (sb3-cic pause): its runs stopped at their checkpoints; run the same "
                   "command to resume\n")


def test_pause_asks_the_driving_command_and_refuses_without_one(tmp_path: Path, capsys: pytest.CaptureFixture):
    study = tmp_path / "study"
    study.mkdir()
    with pytest.raises(SystemExit) as exit_info:
        main(["pause", str(study)])
    assert exit_info.value.code == 2 and not pause_file(study).exists()
    assert capsys.readouterr().err == (f"sb3-cic pause: error: no command drives {study}: there is nothing to pause "
                                       f"(sb3-cic status {study})\n")
    with StudyLock(study):  # a driver holds the lock
        main(["pause", str(study)])  # exit code 0: no SystemExit
        out = capsys.readouterr().out
        assert f"asked the command that drives {study} (pid " in out and f"exit code {PAUSED_CODE}" in out
        assert pause_requested(study) == json.loads(pause_file(study).read_text())["requested"]


def test_pause_refuses_a_driver_that_would_not_read_it(tmp_path: Path, capsys: pytest.CaptureFixture):
    """A command of a version before ``sb3-cic pause`` holds the lock: a request would never be seen."""
    study = tmp_path / "study"
    study.mkdir()
    with open(study / "study.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        lock.write("pid 12 on elsewhere, since 2026-01-01 00:00:00\n")  # what such a command writes
        lock.flush()
        with pytest.raises(SystemExit) as exit_info:
            main(["pause", str(study)])
    assert exit_info.value.code == 2 and not pause_file(study).exists()
    assert "(pid 12 on elsewhere, since 2026-01-01 00:00:00) is of a version that does not read pause requests: stop it " \
        "with Ctrl-C or SIGTERM" in capsys.readouterr().err


def test_a_command_forgets_a_pause_of_an_earlier_command_and_its_own(tmp_path: Path):
    """A request left behind (its command ended before it saw it) does not stop the next command; the command's own
    request is gone when it ends."""
    study = tmp_path / "study"
    study.mkdir()
    pause_file(study).write_text(json.dumps({"requested": "long ago"}))
    seen = []

    class Executor:
        def run_settings(self, settings: Settings) -> Settings:
            return settings

        def run(self, plan: StudyPlan) -> list:
            seen.append(pause_requested(plan.study))
            pause_file(plan.study).write_text(json.dumps({"requested": "now"}))
            return []

    assert drive(StudyPlan(study, [], [], Pairing("paired"), Settings()), Executor()) == []
    assert seen == [None] and not pause_file(study).exists()


def test_a_progress_json_that_names_no_process_is_pending_on_any_host(tmp_path: Path):
    """A paused run's ``progress.json`` (no pid) of another host: pending, not running there."""
    folder = RunFolder(tmp_path / "run")
    folder.path.mkdir()
    for host in (socket.gethostname(), "elsewhere"):
        folder.progress.write_text(json.dumps({"host": host, "pid": None, "checkpoint_step": 2000, "paused": 1.0}))
        assert run_state(folder)[0] == "pending"
    folder.progress.write_text(json.dumps({"host": "elsewhere", "pid": 1234, "checkpoint_step": 2000}))
    assert run_state(folder)[0] == "running"
