"""The study on Ray and resumable runs, at tiny scale (hidden 32, batch 32, 500 random steps, episodes of 1,000 steps).

One local Ray instance with 2 CPUs serves the module (``ray.init`` here, ``ray.shutdown`` at the end). A
checkpoint is taken at an episode boundary, so a run killed "after its first checkpoint" is a run of more
than 1,000 steps with ``checkpoint_every=1000``.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

import pytest
import ray
import torch as th

import sb3_cic
from sb3_cic.cli import main
from sb3_cic.study.driver import run_protocol
from sb3_cic.study.settings import Settings
from sb3_cic.study.settings_record import check_study_settings
from sb3_cic.study.checkpoint import RunFolder
from sb3_cic.study.engine import run_study, start_ray
from sb3_cic.study.graph import build_graph, settings_use, status_report
from waiting import wait_for


SETTINGS = Settings(
    hidden_dim=32,
    batch_size=32,
    learning_starts=500,
    buffer_size=10_000,
    pretrain_steps=1000,
    finetune_steps=1000,
    eval_freq=1000,
    eval_episodes=1,
    num_threads=1,
    pretrain_checkpoint_every=1000,
    finetune_checkpoint_every=1000,
)
TASKS = ("stand", "flip")
SEEDS = (0, 1)
#: the command line of SETTINGS
FLAGS = [
    "--hidden-dim", "32", "--batch-size", "32", "--learning-starts", "500", "--buffer-size", "10000",
    "--eval-freq", "1000", "--eval-episodes", "1", "--num-threads", "1", "--checkpoint-every", "1000", "--no-progress",
]


@pytest.fixture(scope="module")
def ray_instance(tmp_path_factory: pytest.TempPathFactory):
    """A local instance started from inside a folder with another ``sb3_cic`` (a decoy that cannot be imported), as
    a study driven from inside another source checkout: the workers must import this one."""
    threads = th.get_num_threads()
    decoy = tmp_path_factory.mktemp("checkout")
    (decoy / "sb3_cic").mkdir()
    (decoy / "sb3_cic" / "__init__.py").write_text("raise ImportError('the sb3_cic of the working directory')\n")
    here = os.getcwd()
    os.chdir(decoy)
    try:
        start_ray(workers=2)
    finally:
        os.chdir(here)
    yield
    ray.shutdown()
    th.set_num_threads(threads)


def _results(study: Path) -> dict[tuple[str, str, int], dict]:
    out = {}
    for path in study.glob("finetune/*/*/seed_*/result.json"):
        result = json.loads(path.read_text())
        out[(result["label"], result["task"], result["seed"])] = result
    return out


def _curves(study: Path) -> dict[str, str]:
    return {str(p.relative_to(study)): p.read_text() for p in sorted(study.glob("finetune/*/*/seed_*/eval.csv"))}


def _files(folder: Path) -> dict[str, tuple[int, int]]:
    return {str(p.relative_to(folder)): (p.stat().st_size, p.stat().st_mtime_ns) for p in folder.rglob("*") if p.is_file()}


@pytest.fixture(scope="module")
def study(ray_instance, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """cic and ddpg x 2 tasks x 2 seeds on Ray, 2 runs at a time."""
    path = tmp_path_factory.mktemp("ray_study")
    runs, statuses = run_study(path, ["cic", "ddpg"], ["walker"], TASKS, SEEDS, SETTINGS, progress_bar=False,
                               pairing="shared")
    assert len(runs) == 9 and [s["state"] for s in statuses] == ["done"] * 9
    return path


def test_local_workers_import_the_drivers_package(ray_instance):
    """Ray starts its workers in the driver's working directory with it first on ``sys.path``; the fixture started
    Ray inside a folder with a decoy ``sb3_cic``."""

    @ray.remote(num_cpus=1)
    def package() -> str:
        import sb3_cic

        return sb3_cic.__file__

    assert ray.get(package.remote()) == sb3_cic.__file__


def test_local_workers_run_at_the_drivers_niceness(ray_instance):
    """Ray's default worker niceness (15) would leave a study's runs a few percent of a CPU on a busy machine."""

    @ray.remote(num_cpus=1)
    def niceness() -> int:
        return os.nice(0)

    assert "RAY_worker_niceness" not in os.environ  # set only while the local instance starts
    assert ray.get(niceness.remote()) == os.nice(0)


def test_study_on_ray_equals_sequential_protocol(study: Path, tmp_path: Path):
    results = _results(study)
    assert sorted(results) == sorted((m, f"walker_{t}", s) for m in ("cic", "ddpg") for t in TASKS for s in SEEDS)
    assert all(r["resumed_from_step"] == 0 for r in results.values())
    assert not list(study.rglob("checkpoint*")) and not list(study.rglob("progress.json"))  # deleted once done
    sequential = tmp_path / "sequential"
    for method in ("cic", "ddpg"):
        run_protocol(sequential, method, "walker", tasks=TASKS, seeds=SEEDS, settings=SETTINGS, pairing="shared")
    expected = _results(sequential)
    assert {k: r["final_return"] for k, r in results.items()} == {k: r["final_return"] for k, r in expected.items()}
    assert _curves(study) == _curves(sequential)  # every evaluation, not only the last
    assert json.loads((study / "study.json").read_text())["settings"] == SETTINGS.study_settings()

    text, finished = status_report(study)
    assert finished and "9 runs, 9 done, 0 running, 0 failed, 0 pending" in text
    assert "| cic | walker | 5 | 0 | 0 | 0 |" in text and "| ddpg | walker | 4 | 0 | 0 | 0 |" in text
    main(["status", str(study)])  # exit code 0: no SystemExit


def _kill_after_checkpoint(command: list[str], env: dict[str, str], checkpoint: Path) -> None:
    """Start ``command`` and SIGKILL it once ``checkpoint`` exists."""
    process = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        wait_for(checkpoint.exists, f"the checkpoint {checkpoint}", process,
                 lambda: process.stderr.read().decode() if process.poll() is not None else "")
        process.send_signal(signal.SIGKILL)
    finally:
        process.kill()
        process.wait()


def test_sigkill_after_first_checkpoint_resumes_identically(tmp_path: Path):
    """``sb3-cic protocol`` killed with SIGKILL after the first checkpoint of the pre-training, started again, killed
    again after the first checkpoint of the fine-tuning (in the middle of its skill sweep: learning_starts 1,500),
    started again: the same networks (bit for bit), sweep and evaluations as the uninterrupted run (one torch thread)."""
    settings = replace(SETTINGS, pretrain_steps=2000, finetune_steps=2000, learning_starts=1500)
    run_protocol(tmp_path / "uninterrupted", "cic", "walker", tasks=["stand"], seeds=[0], settings=settings)

    study = tmp_path / "killed"
    command = [sys.executable, "-m", "sb3_cic.cli", "protocol", "--method", "cic", "--domain", "walker", "--tasks", "stand",
               "--seeds", "0", "--study", str(study), "--pretrain-steps", "2000", "--finetune-steps", "2000", *FLAGS,
               "--learning-starts", "1500"]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MUJOCO_GL": "disable"}
    pretrain = study / "pretrain" / "cic_walker"
    finetune = study / "finetune" / "cic" / "walker_stand" / "seed_0"
    _kill_after_checkpoint(command, env, pretrain / "checkpoint.zip")
    assert not (pretrain / "result.json").exists()
    text, finished = status_report(study)  # the killed run waits with its checkpoint
    assert not finished and "pretrain cic walker seed 0: pending, last checkpoint at step 1000" in text
    _kill_after_checkpoint(command, env, finetune / "checkpoint.zip")
    assert (pretrain / "result.json").exists() and not (finetune / "result.json").exists()

    subprocess.run(command, env=env, check=True, stdout=subprocess.DEVNULL)
    pre = json.loads((pretrain / "result.json").read_text())
    assert pre["resumed_from_step"] == 1000 and not list(study.rglob("checkpoint*"))
    from sb3_cic import CIC

    killed = CIC.load(pretrain / "snapshot_2000.zip", device="cpu")
    uninterrupted = CIC.load(tmp_path / "uninterrupted" / "pretrain" / "cic_walker" / "snapshot_2000.zip", device="cpu")
    for module in ("policy", "reward_module"):
        a, b = getattr(killed, module).state_dict(), getattr(uninterrupted, module).state_dict()
        assert a.keys() == b.keys() and all(th.equal(a[k], b[k]) for k in a), module
    result = _results(study)[("cic", "walker_stand", 0)]
    expected = _results(tmp_path / "uninterrupted")[("cic", "walker_stand", 0)]
    assert result["resumed_from_step"] == 1000 and expected["resumed_from_step"] == 0
    for key in ("final_return", "finetune_skill", "skill_sweep", "n_evaluations"):
        assert result[key] == expected[key], key
    assert len(result["skill_sweep"]) == 15  # 1,500 steps of 100-step windows: the checkpoint fell in the sweep
    assert _curves(study) == _curves(tmp_path / "uninterrupted")


def test_ray_worker_killed_mid_study_is_retried(ray_instance, tmp_path: Path):
    """SIGKILL the Ray worker of a fine-tuning after its first checkpoint: Ray retries the task, the run resumes from
    its checkpoint and ends as the uninterrupted run."""
    settings = replace(SETTINGS, finetune_steps=2000)
    study = tmp_path / "study"
    folder = study / "finetune" / "ddpg" / "walker_stand" / "seed_0"
    killed, seen = [], []
    study_ended = threading.Event()

    def kill_worker_after_first_checkpoint() -> None:  # until the run is done or the study has ended: no clock
        while not study_ended.is_set() and not (folder / "result.json").exists():
            progress = folder / "progress.json"
            if (folder / "checkpoint.zip").exists() and progress.exists():
                pid = json.loads(progress.read_text())["pid"]
                seen.append(status_report(study)[0])
                os.kill(pid, signal.SIGKILL)  # the worker process running the run (started by this test's Ray)
                killed.append(pid)
                return
            time.sleep(0.05)

    watcher = threading.Thread(target=kill_worker_after_first_checkpoint)
    watcher.start()
    try:
        _, statuses = run_study(study, ["ddpg"], ["walker"], ["stand"], [0], settings, max_retries=2, progress_bar=False)
    finally:
        study_ended.set()
        watcher.join()
    assert killed and statuses == [{"run": "ddpg walker_stand seed 0", "state": "done", "error": None}]
    assert "1 run, 0 done, 1 running" in seen[0] and "ddpg walker_stand seed 0: running on" in seen[0]
    assert f"(pid {killed[0]}), last checkpoint at step 1000" in seen[0]
    result = json.loads((folder / "result.json").read_text())
    assert result["resumed_from_step"] == 1000
    run_protocol(tmp_path / "uninterrupted", "ddpg", "walker", tasks=["stand"], seeds=[0], settings=settings)
    assert _curves(study) == _curves(tmp_path / "uninterrupted")


def test_pause_stops_the_runs_at_their_checkpoints_and_the_same_command_resumes(
    ray_instance, tmp_path: Path, capsys: pytest.CaptureFixture
):
    """``sb3-cic pause`` from another thread once a run has checkpointed: the running runs checkpoint at their next
    episode end and stop (the second run's worker may still be starting: it stops at step 0, or before it starts),
    the third never starts, the command ends with exit code 75 and no pause request left; the same command resumes
    each run from its checkpoint."""
    study = tmp_path / "study"
    seeds = [study / "finetune" / "ddpg" / "walker_stand" / f"seed_{seed}" for seed in range(3)]
    command = ["study", str(study), "--methods", "ddpg", "--domains", "walker", "--tasks", "stand", "--seeds", "0", "1",
               "2", "--finetune-steps", "5000", "--workers", "2", *FLAGS]
    asked = []
    study_ended = threading.Event()

    def pause_after_first_checkpoint() -> None:  # until the study has ended: no clock
        while not study_ended.is_set():
            if (seeds[0] / "checkpoint.zip").exists():
                asked.append(main(["pause", str(study)]))
                return
            time.sleep(0.05)

    watcher = threading.Thread(target=pause_after_first_checkpoint)
    watcher.start()
    try:
        with pytest.raises(SystemExit) as exit_info:
            main(command)
    finally:
        study_ended.set()
        watcher.join()
    out, err = capsys.readouterr()
    assert asked == [None] and exit_info.value.code == 75
    assert "asked the command that drives" in out and "paused (sb3-cic pause)" in err
    assert not (study / "pause.json").exists() and not any((seed / "result.json").exists() for seed in seeds)
    steps = [(RunFolder(seed).read_meta() or {"step": 0})["step"] for seed in seeds]
    assert 1000 <= steps[0] < 5000 and steps[1] < 5000 and all(step % 1000 == 0 for step in steps), steps
    assert not (seeds[2] / "progress.json").exists()  # the third run never started
    text, _ = status_report(study)
    assert "3 runs, 0 done, 0 running, 0 failed, 3 pending" in text
    for seed, step in enumerate(steps):
        assert f"ddpg walker_stand seed {seed}: pending, last checkpoint at step {step}" in text

    main(command)  # exit code 0: no SystemExit
    results = [json.loads((seed / "result.json").read_text()) for seed in seeds]
    assert [r["resumed_from_step"] for r in results] == steps and all(r["n_evaluations"] == 6 for r in results)


def test_failing_run_is_reported_and_the_others_finish(ray_instance, tmp_path: Path, capsys: pytest.CaptureFixture):
    study = tmp_path / "study"
    broken = study / "finetune" / "ddpg" / "walker_stand" / "seed_1"
    (broken / "eval.csv").mkdir(parents=True)  # the run trains, then cannot write its eval.csv
    with pytest.raises(SystemExit) as exit_info:
        main(["study", str(study), "--methods", "ddpg", "--domains", "walker", "--tasks", "stand", "--seeds", "0", "1",
              "--finetune-steps", "1000", *FLAGS])
    assert exit_info.value.code == 1  # not everything finished
    assert (study / "finetune" / "ddpg" / "walker_stand" / "seed_0" / "result.json").exists()
    assert not (broken / "result.json").exists()
    assert "IsADirectoryError" in (broken / "error.txt").read_text()
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit_info:
        main(["status", str(study)])
    assert exit_info.value.code == 1
    text = capsys.readouterr().out
    assert "2 runs, 1 done, 0 running, 1 failed, 0 pending" in text
    assert "ddpg walker_stand seed 1: IsADirectoryError" in text and str(broken / "error.txt") in text


@pytest.mark.parametrize(
    "change, arguments, message",
    [
        (None, {"methods": ["cic", "nope"]}, "unknown algorithm 'nope'"),
        (None, {"domains": ["walker", "cheetah"]}, "unknown domain 'cheetah'"),
        (None, {"tasks": ["stand", "backflip"]}, "unknown task 'backflip'"),
        (None, {"settings": replace(SETTINGS, hidden_dim=64)}, "other settings.*hidden_dim.*32, 64"),
        ("corrupt_checkpoint", {}, "corrupt checkpoint"),
        ("lost_checkpoint", {}, "records a checkpoint at step 1000 but .* is missing"),
        ("missing_snapshot", {}, "snapshot .*snapshot_1000.zip is missing"),
        ("corrupt_snapshot", {}, "snapshot .*snapshot_1000.zip is corrupt"),
    ],
)
def test_bad_input_is_refused_before_any_work(study: Path, tmp_path: Path, change, arguments, message):
    folder = tmp_path / "study"
    shutil.copytree(study, folder)
    run = folder / "finetune" / "cic" / "walker_stand" / "seed_0"
    snapshot = folder / "pretrain" / "cic_walker" / "snapshot_1000.zip"
    if change is not None:  # the run must be unfinished for its checkpoint to count
        for name in ("result.json", "eval.csv"):
            (run / name).unlink()
    if change == "corrupt_checkpoint":
        (run / "checkpoint.zip").write_bytes(b"PK\x03\x04 not a zip")
    elif change == "lost_checkpoint":
        (run / "progress.json").write_text(json.dumps({"host": "elsewhere", "pid": 1, "checkpoint_step": 1000}))
    elif change == "missing_snapshot":
        snapshot.unlink()
    elif change == "corrupt_snapshot":
        snapshot.write_bytes(snapshot.read_bytes()[:-100])
    before = _files(folder)
    kwargs = {"methods": ["cic", "ddpg"], "domains": ["walker"], "tasks": list(TASKS), "seeds": list(SEEDS),
              "settings": SETTINGS, **arguments}
    with pytest.raises(ValueError, match=message):
        run_study(folder, progress_bar=False, **kwargs)
    assert _files(folder) == before  # nothing changed


def test_checkpoint_write_is_atomic(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """A write that dies half-way leaves the previous checkpoint readable and loadable."""
    from sb3_cic import URLBDDPG
    from sb3_cic.study import checkpoint as checkpoint_module
    from sb3_cic.study.checkpoint import RunFolder

    model = URLBDDPG("MlpPolicy", "URLB/walker-stand-v0", policy_kwargs={"hidden_dim": 32}, batch_size=32,
                     buffer_size=2000, learning_starts=500, seed=0, device="cpu")
    model.learn(1000)  # one episode: an episode boundary
    folder = RunFolder(tmp_path / "run")
    folder.start()
    folder.save_checkpoint(model, [], {"elapsed_s": 1.0})
    first = folder.checkpoint.read_bytes()

    def dies_half_way(obj, file, protocol=None):
        file.write(b"\0" * 1000)
        raise KeyboardInterrupt("killed during the write")

    model.num_timesteps = 2000  # what a later checkpoint would record
    monkeypatch.setattr(checkpoint_module.pickle, "dump", dies_half_way)
    with pytest.raises(KeyboardInterrupt):
        folder.save_checkpoint(model, [], {"elapsed_s": 2.0})
    monkeypatch.undo()
    assert folder.checkpoint_tmp.exists() and folder.checkpoint.read_bytes() == first
    assert folder.read_meta()["step"] == 1000 and folder.read_progress()["checkpoint_step"] == 1000
    loaded = folder.load_model(URLBDDPG, "URLB/walker-stand-v0", device="cpu")
    folder.restore(loaded, [])
    assert loaded.num_timesteps == 1000 and loaded.replay_buffer.size() == 1000


def test_fine_tuning_from_an_intermediate_snapshot(ray_instance, tmp_path: Path, capsys: pytest.CaptureFixture):
    """--from-snapshot: the runs start from that snapshot, in <method>@STEP folders; study.json rows of 4 still read."""
    settings = replace(SETTINGS, snapshots=(500,))
    study = tmp_path / "study"
    with pytest.raises(ValueError, match=r"no snapshot at 700 steps: the pre-training saves \[500, 1000\]"):
        run_study(study, ["cic"], ["walker"], ["stand"], [0], settings, from_snapshot=700, progress_bar=False)
    assert not study.exists()
    runs, statuses = run_study(study, ["cic", "ddpg"], ["walker"], ["stand"], [0], settings, from_snapshot=500,
                               progress_bar=False)
    assert [str(r) for r in runs] == ["pretrain cic walker seed 0", "cic@500 walker_stand seed 0", "ddpg walker_stand seed 0"]
    assert [s["state"] for s in statuses] == ["done"] * 3
    result = json.loads((study / "finetune" / "cic@500" / "walker_stand" / "seed_0" / "result.json").read_text())
    assert result["label"] == "cic@500" and result["snapshot_steps"] == 500
    assert (study / "finetune" / "ddpg" / "walker_stand" / "seed_0" / "result.json").exists()  # from scratch: no snapshot
    rows = json.loads((study / "study.json").read_text())["runs"]
    assert ["cic", "walker", "walker_stand", 0, 500] in rows and ["cic", "walker", None, 0, None] in rows
    data = json.loads((study / "study.json").read_text())
    data["runs"] = [row[:4] if row[4] is None else row for row in rows]  # rows of 4: written before snapshots counted
    (study / "study.json").write_text(json.dumps(data))
    runs, statuses = run_study(study, ["cic"], ["walker"], ["stand"], [0], settings, progress_bar=False)  # final snapshot
    assert [s["run"] for s in statuses] == ["cic walker_stand seed 0"]
    text, finished = status_report(study)
    assert finished and "4 runs, 4 done" in text and "| cic | walker | 3 | 0 | 0 | 0 |" in text


def test_a_done_run_killed_before_deleting_its_checkpoint_is_cleaned(study: Path, tmp_path: Path):
    """A run killed between writing ``result.json`` and deleting its checkpoint is done: the study does not run it
    again and deletes its checkpoint and ``progress.json``."""
    folder = tmp_path / "study"
    shutil.copytree(study, folder)
    run = RunFolder(folder / "finetune" / "cic" / "walker_flip" / "seed_1")
    run._write_progress(1000)  # what the killed run left beside its result.json
    run.checkpoint.write_bytes(b"PK\x05\x06" + b"\0" * 18)
    results = {p: p.read_text() for p in folder.glob("**/result.json")}
    runs, statuses = run_study(folder, ["cic", "ddpg"], ["walker"], list(TASKS), list(SEEDS), SETTINGS, progress_bar=False)
    assert len(runs) == 9 and statuses == []
    assert not run.checkpoint.exists() and not run.progress.exists()
    assert {p: p.read_text() for p in folder.glob("**/result.json")} == results
    assert status_report(folder)[1]


def test_runs_from_scratch_are_not_checked_against_pre_training_settings(study: Path, tmp_path: Path):
    """A DDPG command into a study whose pre-trainings used other steps, snapshots and seed: accepted (DDPG does not
    pre-train); a command that pre-trains is still held to them."""
    folder = tmp_path / "study"
    shutil.copytree(study, folder)
    other = replace(SETTINGS, pretrain_steps=5000, snapshots=(700,))
    ddpg = build_graph(["ddpg"], ["walker"], list(TASKS), list(SEEDS), 3)
    check_study_settings(folder, other, 3, **settings_use(ddpg))
    recorded = (folder / "study.json").read_text()
    runs, statuses = run_study(folder, ["ddpg"], ["walker"], list(TASKS), list(SEEDS), other, pretrain_seed=3,
                               progress_bar=False)
    assert len(runs) == 4 and statuses == [] and json.loads((folder / "study.json").read_text()) == json.loads(recorded)
    cic = build_graph(["cic"], ["walker"], list(TASKS), list(SEEDS), 3)
    with pytest.raises(ValueError, match="pretrain_steps.*1000, 5000.*pretrain_seed.*0, 3"):
        check_study_settings(folder, other, 3, **settings_use(cic))
    with pytest.raises(ValueError, match="hidden_dim.*32, 64"):
        run_study(folder, ["ddpg"], ["walker"], list(TASKS), list(SEEDS), replace(SETTINGS, hidden_dim=64), progress_bar=False)
