"""A study folder that cannot lie, and the pairing of fine-tunings with pre-trainings.

Most cases read a copy of the committed quadruped study (made before runs recorded their settings and before
pairing existed; nothing is trained); the others train tiny runs (hidden 32, batch 32, 600 steps). Only
:func:`test_sigint_and_sigterm_stop_the_study_and_its_runs` starts Ray, in a subprocess it stops by signal.
"""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import signal
import subprocess
import sys
import warnings
from dataclasses import replace
from pathlib import Path

import pytest
import torch as th

from sb3_cic.cli import main
from sb3_cic.study.driver import run_protocol
from sb3_cic.study.settings import Settings
from sb3_cic.study.settings_record import conf_file_record
from sb3_cic.study.engine import execute
from sb3_cic.study.graph import Run, alive, build_graph, status_report, time_left
from sb3_cic.study import record
from sb3_cic.study.record import Pairing, StudyLock, changed_entries
from waiting import wait_for

ROOT = Path(__file__).resolve().parents[1]
QUADRUPED = ROOT / "docs" / "results" / "quadruped_reduced" / "runs"
#: the command line of the quadruped study's settings
QUADRUPED_FLAGS = ["--hidden-dim", "256", "--batch-size", "256", "--pretrain-steps", "500000", "--finetune-steps", "100000",
                   "--snapshots", "100000", "250000", "--no-progress"]
TINY = Settings(hidden_dim=32, batch_size=32, learning_starts=500, buffer_size=10_000, pretrain_steps=600, finetune_steps=600,
                eval_freq=10_000, eval_episodes=1, num_threads=1, pretrain_checkpoint_every=0, finetune_checkpoint_every=0)
TINY_FLAGS = ["--hidden-dim", "32", "--batch-size", "32", "--learning-starts", "500", "--buffer-size", "10000",
              "--pretrain-steps", "600", "--eval-freq", "10000", "--eval-episodes", "1", "--num-threads", "1",
              "--checkpoint-every", "0", "--no-progress"]


@pytest.fixture(autouse=True)
def _threads():
    threads = th.get_num_threads()
    yield
    th.set_num_threads(threads)


@pytest.fixture
def quadruped(tmp_path: Path) -> Path:
    """A copy of the committed quadruped study (tensorboard logs left out)."""
    folder = tmp_path / "quadruped"
    shutil.copytree(QUADRUPED, folder, ignore=shutil.ignore_patterns("tensorboard"))
    return folder


def _exit(arguments: list[str], capsys: pytest.CaptureFixture) -> tuple[int, str, str]:
    capsys.readouterr()
    try:
        main(arguments)
        code = 0
    except SystemExit as exit_:
        code = exit_.code
    out, err = capsys.readouterr()
    return code, out, err


def _refused(arguments: list[str], capsys: pytest.CaptureFixture) -> str:
    """The one line of a command refused with exit code 2."""
    code, _, err = _exit(arguments, capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    return err.strip()


def _quadruped_resume(folder: Path, *extra: str) -> list[str]:
    return ["study", str(folder), "--methods", "icm", "ddpg", "--domains", "quadruped", "--seeds", "0", "1", "2",
            *QUADRUPED_FLAGS, *extra]


# a folder made before this change ----------------------------------------------------------------------------
def test_a_study_made_before_run_settings_and_pairing_keeps_working(quadruped: Path, capsys: pytest.CaptureFixture):
    """status, study (resume: nothing to run, nothing started) and report read the committed quadruped study as it
    is: shared pre-training with seed 0, its seed-0 fine-tunings paired by construction, seeds 1 and 2 shared."""
    code, out, _ = _exit(["status", str(quadruped)], capsys)
    assert code == 0 and "73 runs, 73 done" in out and "pre-training: shared (pre-training seed 0" in out
    before = json.loads((quadruped / "study.json").read_text())
    code, out, _ = _exit(_quadruped_resume(quadruped), capsys)
    assert code == 0 and "0 runs ran now" in out
    after = json.loads((quadruped / "study.json").read_text())
    assert "pairing" not in after and after["pretrain_seed"] == 0 and after["settings"] == before["settings"]
    code, out, _ = _exit(["report", str(quadruped), "--reps", "20"], capsys)
    assert code == 0
    report = json.loads((quadruped / "report.json").read_text())
    assert report["pairing"]["cic"] == {"paired": [0], "shared": {"0": [1, 2]}, "from_scratch": [], "unknown": []}
    assert report["pairing"]["ddpg"]["from_scratch"] == [0, 1, 2]
    assert "| icm | paired: seed 0; shared pre-training seed 0: seeds 1, 2 |" in out
    # the two modes are not mixed in one folder by accident
    assert "pre-trains shared (pre-training seed 0" in _refused(_quadruped_resume(quadruped, "--pairing", "paired"), capsys)


def test_a_yaml_is_compared_entry_by_entry(tmp_path: Path):
    """A comment or a new environment's entry changes no run; a changed entry is named; a record made before entries
    were recorded (the sha256 of the whole file) warns for the default yaml and refuses a changed --conf-file."""
    yml = tmp_path / "icm.yml"
    yml.write_text("URLB/walker-v0: &p\n  batch_size: 256\n  tau: 0.01\nURLB/jaco-v0:\n  <<: *p\n")
    before = conf_file_record("icm", yml)
    yml.write_text("# a comment\nURLB/walker-v0: &p\n  tau: 0.01\n  batch_size: 256\nURLB/jaco-v0:\n  <<: *p\n"
                   "URLB/hopper-v0:\n  <<: *p\n")
    commented = conf_file_record("icm", yml)
    assert commented["sha256"] != before["sha256"] and changed_entries(before, commented, "here") == []
    yml.write_text("URLB/walker-v0: &p\n  batch_size: 256\n  tau: 0.02\nURLB/jaco-v0:\n  <<: *p\n")
    assert changed_entries(before, conf_file_record("icm", yml), "here") == ["URLB/jaco-v0", "URLB/walker-v0"]

    legacy = {"file": str(yml), "sha256": before["sha256"]}
    assert changed_entries(legacy, conf_file_record("icm", yml), "here") == ["(the whole file)"]
    default = conf_file_record("icm")
    assert changed_entries({"file": None, "sha256": default["sha256"]}, default, "here") == []
    with pytest.warns(UserWarning, match="here records the sha256 of the whole default yaml"):
        assert changed_entries({"file": None, "sha256": "0" * 64}, default, "here") == []


# 1. the settings of every run travel with the run ------------------------------------------------------------
def test_runs_record_their_settings_and_a_lost_study_json_is_rebuilt_or_refused(tmp_path: Path,
                                                                                capsys: pytest.CaptureFixture):
    study = tmp_path / "study"
    ddpg = ["protocol", "--method", "ddpg", "--domain", "walker", "--tasks", "stand", "--seeds", "0", "--study", str(study),
            *TINY_FLAGS]
    main([*ddpg, "--finetune-steps", "600"])
    run = study / "finetune" / "ddpg" / "walker_stand" / "seed_0"
    assert json.loads((run / "settings.json").read_text())["settings"]["finetune_steps"] == 600
    recorded = json.loads((study / "study.json").read_text())

    (study / "study.json").unlink()  # lost: the command with other settings is refused, by protocol and by study
    assert "finetune_steps" in _refused([*ddpg, "--finetune-steps", "700"], capsys)
    study_command = ["study", str(study), "--methods", "ddpg", "--domains", "walker", "--tasks", "stand", "--seeds", "0",
                     *TINY_FLAGS]
    assert "finetune_steps" in _refused([*study_command, "--finetune-steps", "700"], capsys)
    assert not (study / "study.json").exists()
    code, out, _ = _exit([*study_command, "--finetune-steps", "600"], capsys)  # the same settings: rebuilt
    assert code == 0 and "0 runs ran now" in out
    rebuilt = json.loads((study / "study.json").read_text())
    assert rebuilt["settings"] == recorded["settings"] and rebuilt["runs"] == recorded["runs"]

    # a study.json that says otherwise does not override what the run records
    rebuilt["settings"]["finetune_steps"] = 700
    (study / "study.json").write_text(json.dumps(rebuilt))
    assert f"the run {run} was made with other settings" in _refused([*study_command, "--finetune-steps", "700"], capsys)

    # a run that records nothing (made before runs did) and no study.json: refused, not guessed
    (study / "study.json").unlink()
    (run / "settings.json").unlink()
    assert "does not record its settings" in _refused([*study_command, "--finetune-steps", "600"], capsys)
    assert "does not record its settings" in _refused(["status", str(study)], capsys)


# 2. what the commands read is checked ------------------------------------------------------------------------
@pytest.mark.parametrize(
    "damage, message",
    [
        (lambda run: (run / "result.json").write_text("garbage"), "result.json is damaged"),
        (lambda run: (run / "eval.csv").write_text("not,a,curve\n1,2,3\n"), "eval.csv is damaged"),
        (lambda run: (run / "result.json").write_text(
            (run / "result.json").read_text().replace('"final_return": 946.9311384', '"final_return": 99999')),
         "says final_return 99999 but the last evaluation of its eval.csv"),
    ],
)
def test_a_damaged_result_is_named_and_never_counted_as_done(quadruped: Path, capsys: pytest.CaptureFixture, damage,
                                                            message):
    run = quadruped / "finetune" / "cic" / "quadruped_stand" / "seed_0"
    damage(run)
    code, out, _ = _exit(["status", str(quadruped)], capsys)
    assert code == 1 and "72 done" in out and "1 damaged" in out and message in out and str(run) in out
    line = _refused(["study", str(quadruped), "--methods", "cic", "--domains", "quadruped", "--tasks", "stand",
                     "--seeds", "0", *QUADRUPED_FLAGS], capsys)
    assert message in line and str(run) in line and "delete the run folder" in line
    with warnings.catch_warnings(record=True) as caught:  # the report: named in one line and not counted
        warnings.simplefilter("always")
        code, out, _ = _exit(["report", str(quadruped), "--reps", "20"], capsys)
    (said,) = [str(w.message) for w in caught if str(run) in str(w.message)]
    assert code == 0 and message in said and "delete the run folder" in said
    assert f"refused (not counted): {said}" in out
    report = json.loads((quadruped / "report.json").read_text())
    assert report["runs_read"]["refused"] == [said] and sum(report["runs_read"]["kinds"].values()) == 134


@pytest.mark.parametrize("content", ['{"settings": 5}', "[1, 2]", '{"runs": [["cic"]]}', "\x00garbage"])
def test_a_damaged_study_json_is_named(quadruped: Path, capsys: pytest.CaptureFixture, content: str):
    (quadruped / "study.json").write_text(content)
    for command in (["status", str(quadruped)], _quadruped_resume(quadruped)):
        line = _refused(command, capsys)
        assert f"{quadruped / 'study.json'} is damaged" in line and "restore it" in line


def test_status_says_the_time_the_unfinished_runs_need(quadruped: Path):
    """A run made pending again is expected to take the mean wall time of the done runs of its kind, method and
    domain; the line is in hours of one worker."""
    folder = quadruped / "finetune" / "cic" / "quadruped_walk" / "seed_2"
    (folder / "result.json").unlink()
    walls = [json.loads(f.read_text())["wall_time_s"]["finetune"]
             for f in (quadruped / "finetune" / "cic").glob("*/seed_*/result.json")]
    assert len(walls) == 11
    text, finished = status_report(quadruped)
    assert not finished and "cic quadruped_walk seed 2: pending, last checkpoint at step 0" in text
    assert f"Time left: about {sum(walls) / 11 / 3600:.1f} run-hours for 1 of the 1 unfinished runs" in text


def test_time_left_goes_by_the_method_then_the_domain_and_less_the_checkpoint():
    def done(method: str, domain: str, task: str | None, wall: float) -> tuple[Run, dict]:
        kind = "pretrain" if task is None else "finetune"
        steps = {"steps": 1000} if task is None else {"finetune_steps": 1000}
        return Run(method, domain, task, 0), {**steps, "wall_time_s": {kind: wall}}

    results = dict([done("cic", "walker", None, 3600.0), done("icm", "walker", None, 1800.0),
                    done("cic", "walker", "walker_run", 600.0), done("cic", "walker", "walker_flip", 800.0)])
    assert time_left([], results) is None
    left = [(Run("cic", "walker", None, 1), 0),  # its method's pre-training: 3600 s
            (Run("apt", "walker", None, 1), "unusable (truncated)"),  # walker's pre-trainings: 2700 s
            (Run("cic", "walker", "walker_stand", 1), 500),  # half of 700 s
            (Run("cic", "jaco", None, 1), 0)]  # nothing done on jaco
    line = time_left(left, results)
    assert line.startswith(f"Time left: about {(3600 + 2700 + 350) / 3600:.1f} run-hours for 3 of the 4 unfinished runs")
    assert "and 1 with no done run of their kind and domain" in line
    assert time_left(left[-1:], results).startswith("Time left: not known yet")


# 3. one driver per study folder --------------------------------------------------------------------------------
def test_a_second_driver_is_refused_and_a_killed_one_leaves_no_lock(quadruped: Path, capsys: pytest.CaptureFixture):
    assert "\nno command drives it now\n" in status_report(quadruped)[0] and not (quadruped / "study.lock").exists()
    with StudyLock(quadruped):
        line = _refused(_quadruped_resume(quadruped), capsys)
        assert f"another command drives {quadruped} (pid {os.getpid()}" in line
        assert f"\ndriven now by pid {os.getpid()} on " in status_report(quadruped)[0]
    assert StudyLock.holder(quadruped) is None
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time; from sb3_cic.study.record import StudyLock\n"
         f"with StudyLock({str(quadruped)!r}):\n    print('locked', flush=True); time.sleep(600)"],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        assert "another command drives" in _refused(_quadruped_resume(quadruped), capsys)
    finally:
        holder.kill()  # SIGKILL: no clean-up of its own
        holder.wait()
    code, out, _ = _exit(_quadruped_resume(quadruped), capsys)
    assert code == 0 and "0 runs ran now" in out


def test_a_driver_starting_while_status_probes_the_lock_is_not_refused(quadruped: Path, monkeypatch: pytest.MonkeyPatch):
    """`sb3-cic status` holds the lock for an instant to see whether a driver holds it; a driver that starts in that
    instant waits and tries again instead of being refused."""
    (quadruped / "study.lock").touch()
    probe = open(quadruped / "study.lock")
    fcntl.flock(probe, fcntl.LOCK_SH | fcntl.LOCK_NB)  # what StudyLock.holder takes for its probe
    waits = []
    monkeypatch.setattr(record.time, "sleep", lambda seconds: waits.append(seconds) or probe.close())  # the probe ends
    with StudyLock(quadruped):
        assert StudyLock.holder(quadruped).startswith(f"pid {os.getpid()} on ")
    assert len(waits) == 1


# 4. a run folder that cannot be written -------------------------------------------------------------------------
def test_a_run_whose_folder_cannot_be_written_fails_alone(tmp_path: Path):
    """The run's folder is a file: the run fails, and so does recording it; the status says both, nothing raises."""
    study = tmp_path / "study"
    blocked = study / "finetune" / "ddpg" / "walker_stand" / "seed_1"
    blocked.parent.mkdir(parents=True)
    blocked.write_text("not a folder")
    status = execute(str(study), Run("ddpg", "walker", "walker_stand", 1), TINY)
    assert status["state"] == "failed" and "not recorded in its folder" in status["error"]


def test_a_read_only_study_folder_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture,
                                              monkeypatch: pytest.MonkeyPatch):
    from sb3_cic.study import checkpoint

    def read_only(path, data):
        raise PermissionError(13, "Permission denied", str(path))

    monkeypatch.setattr(checkpoint, "write_json", read_only)
    monkeypatch.setattr("sb3_cic.study.settings_record.write_json", read_only)
    line = _refused(["protocol", "--method", "ddpg", "--domain", "walker", "--tasks", "stand", "--seeds", "0",
                     "--study", str(tmp_path / "study"), *TINY_FLAGS], capsys)
    assert "Permission denied" in line


# 5. SIGINT and SIGTERM ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("signum, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_sigint_and_sigterm_stop_the_study_and_its_runs(tmp_path: Path, signum: int, code: int):
    """The driver, signalled while a run trains on Ray, ends with one line that says how to resume, and the run's
    worker has ended with it (nothing writes in the folder afterwards)."""
    study = tmp_path / "study"
    command = [sys.executable, "-m", "sb3_cic.cli", "study", str(study), "--methods", "ddpg", "--domains", "walker",
               "--tasks", "stand", "--seeds", "0", *TINY_FLAGS, "--finetune-steps", "100000", "--checkpoint-every", "1000"]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MUJOCO_GL": "disable"}
    progress = study / "finetune" / "ddpg" / "walker_stand" / "seed_0" / "progress.json"
    driver = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        wait_for(progress.exists, "the run to start", driver,
                 lambda: driver.communicate()[1] if driver.poll() is not None else "")
        worker = json.loads(progress.read_text())["pid"]
        assert worker != driver.pid and alive(worker)
        driver.send_signal(signum)
        wait_for(lambda: driver.poll() is not None, f"the study to end after {signal.Signals(signum).name}")
        _, err = driver.communicate()
    finally:
        if driver.poll() is None:
            driver.kill()
            driver.wait()
    lines = err.strip().splitlines()
    assert driver.returncode == code and "Traceback" not in err, err
    assert lines[-1].startswith(f"sb3-cic study: interrupted ({signal.Signals(signum).name})")
    assert "run the same command to resume" in lines[-1]
    assert not alive(worker)


# issue 46: pairing -------------------------------------------------------------------------------------------
def test_build_graph_pairs_or_shares_pre_trainings(tmp_path: Path):
    paired = build_graph(["cic", "ddpg"], ["walker"], ["stand"], [0, 2], Pairing("paired"))
    assert [str(r) for r in paired] == ["pretrain cic walker seed 0", "pretrain cic walker seed 2", "cic walker_stand seed 0",
                                        "cic walker_stand seed 2", "ddpg walker_stand seed 0", "ddpg walker_stand seed 2"]
    assert [r.folder(tmp_path).name for r in paired[:2]] == ["cic_walker", "cic_walker_seed2"]
    assert [r.dependency() for r in paired[2:4]] == paired[:2] and paired[4].dependency() is None
    shared = build_graph(["cic"], ["walker"], ["stand"], [0, 2], Pairing("shared", 3))
    assert [str(r) for r in shared] == ["pretrain cic walker", "cic walker_stand seed 0", "cic walker_stand seed 2"]
    assert shared[0].folder(tmp_path).name == "cic_walker" and shared[0].seed == 3
    assert all(r.dependency() == shared[0] for r in shared[1:])


@pytest.fixture(scope="module")
def paired_and_shared(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """cic on walker stand, seeds 0 and 1: paired (the default of a new study), and shared with pre-training seed 0
    (seed 1 only: its seed 0 is the paired study's)."""
    threads = th.get_num_threads()
    paired, shared = tmp_path_factory.mktemp("paired"), tmp_path_factory.mktemp("shared")
    run_protocol(paired, "cic", "walker", tasks=["stand"], seeds=[0, 1], settings=TINY)
    run_protocol(shared, "cic", "walker", tasks=["stand"], seeds=[1], settings=TINY, pretrain_seed=0)
    th.set_num_threads(threads)
    return paired, shared


def _result(study: Path, seed: int) -> dict:
    return json.loads((study / "finetune" / "cic" / "walker_stand" / f"seed_{seed}" / "result.json").read_text())


def test_paired_study_fine_tunes_seed_s_from_pre_training_seed_s(paired_and_shared, capsys: pytest.CaptureFixture):
    from sb3_cic import CIC

    paired, shared = paired_and_shared
    assert json.loads((paired / "study.json").read_text())["pairing"] == "paired"
    assert "pretrain_seed" not in json.loads((paired / "study.json").read_text())
    for seed, folder in ((0, "cic_walker"), (1, "cic_walker_seed1")):
        assert json.loads((paired / "pretrain" / folder / "result.json").read_text())["seed"] == seed
        assert _result(paired, seed)["pretrain_seed"] == seed
    assert _result(shared, 1)["pretrain_seed"] == 0 and not (shared / "pretrain" / "cic_walker_seed1").exists()
    # a paired seed-0 pre-training is the shared seed-0 one: the same networks
    a = CIC.load(paired / "pretrain" / "cic_walker" / "snapshot_600.zip", device="cpu").policy.state_dict()
    b = CIC.load(shared / "pretrain" / "cic_walker" / "snapshot_600.zip", device="cpu").policy.state_dict()
    assert all(th.equal(a[k], b[k]) for k in a)
    assert _result(paired, 1)["final_return"] != _result(shared, 1)["final_return"]  # another pre-training

    text, finished = status_report(paired)
    assert finished and "2 runs" not in text and "4 runs, 4 done" in text and "pre-training: paired" in text
    code, out, _ = _exit(["report", str(paired), "--reps", "20"], capsys)
    assert code == 0 and "| cic | paired: seeds 0, 1 |" in out
    code, out, _ = _exit(["report", str(shared), "--reps", "20"], capsys)
    assert code == 0 and "| cic | shared pre-training seed 0: seed 1 |" in out


def test_resuming_keeps_the_pairing_and_mixing_is_refused(paired_and_shared, tmp_path: Path,
                                                          capsys: pytest.CaptureFixture):
    paired, shared = (shutil.copytree(p, tmp_path / p.name) for p in paired_and_shared)
    results = {p: p.read_text() for p in [*paired.rglob("result.json"), *shared.rglob("result.json")]}
    for study in (paired, shared):  # the same command without a pairing option: the study's, nothing runs again
        main(["protocol", "--method", "cic", "--domain", "walker", "--tasks", "stand", "--seeds", "1", "--study",
              str(study), *TINY_FLAGS, "--finetune-steps", "600"])
    assert {p: p.read_text() for p in results} == results
    protocol = ["protocol", "--method", "cic", "--domain", "walker", "--tasks", "stand", "--seeds", "1", *TINY_FLAGS,
                "--finetune-steps", "600"]
    assert "pre-trains paired" in _refused([*protocol, "--study", str(paired), "--pretrain-seed", "0"], capsys)
    assert "pre-trains paired" in _refused([*protocol, "--study", str(paired), "--pairing", "shared"], capsys)
    assert "pre-trains shared" in _refused([*protocol, "--study", str(shared), "--pairing", "paired"], capsys)
    assert "pretrain_seed': (0, 1)" in _refused([*protocol, "--study", str(shared), "--pretrain-seed", "1"], capsys)
    assert "--pretrain-seed is the one seed of shared pre-training" in _refused(
        [*protocol, "--study", str(tmp_path / "new"), "--pairing", "paired", "--pretrain-seed", "0"], capsys)
    assert not (tmp_path / "new").exists()


def test_help_names_the_pairing(capsys: pytest.CaptureFixture):
    for command in ("study", "protocol"):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        out = " ".join(capsys.readouterr().out.split())
        assert "--pairing {paired,shared}" in out and "URLB's protocol" in out and "CIC code's" in out
        assert "--pretrain-seed" in out
