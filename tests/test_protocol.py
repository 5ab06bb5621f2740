"""End-to-end tests of the URLB protocol runner, the score report and the rl-zoo command line, at tiny scale.

Tiny scale: hidden width 32, batch 32, 500 random steps, 1,500 pre-training steps, 1,000 fine-tuning
steps evaluated every 500 steps with 2 episodes. The numbers mean nothing about the methods; the tests
check the plumbing and recompute the report's statistics with numpy.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import zipfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch as th
import yaml

from sb3_cic.cli import main
from sb3_cic.common.save_util import is_networks_only
from sb3_cic.constants import EXPERT_SCORES
from sb3_cic.report import figures, scores
from sb3_cic.skills import UniformSkillPrior
from sb3_cic.report.commands import write_report
from sb3_cic.study.driver import run_protocol
from sb3_cic.study.settings import Settings
from sb3_cic.study.settings_record import check_study_settings, conf_file_record, record_study_settings
from sb3_cic.study.checkpoint import RunFolder
from sb3_cic.study.snapshots import file_sha256

SETTINGS = Settings(
    hidden_dim=32,
    batch_size=32,
    learning_starts=500,
    buffer_size=10_000,
    pretrain_steps=1500,
    finetune_steps=1000,
    eval_freq=500,
    eval_episodes=2,
    num_threads=1,
)
SEEDS = (0, 1)
CIC_TASKS = ("stand", "flip")


def _run_study(study: Path) -> None:
    run_protocol(study, "cic", "walker", tasks=CIC_TASKS, seeds=SEEDS, settings=SETTINGS, pairing="shared")
    run_protocol(study, "ddpg", "walker", tasks=("stand",), seeds=SEEDS, settings=SETTINGS)


@pytest.fixture(scope="module")
def study(tmp_path_factory: pytest.TempPathFactory) -> Path:
    threads = th.get_num_threads()
    path = tmp_path_factory.mktemp("study")
    _run_study(path)
    write_report(path, reps=500)
    th.set_num_threads(threads)
    return path


def _results(study: Path) -> list[dict]:
    return [json.loads(p.read_text()) for p in sorted(study.glob("finetune/*/*/seed_*/result.json"))]


def test_study_layout(study: Path):
    pre = json.loads((study / "pretrain" / "cic_walker" / "result.json").read_text())
    snapshot = study / "pretrain" / "cic_walker" / "snapshot_1500.zip"
    assert pre["steps"] == 1500 and snapshot.stat().st_size > 0
    # networks only, naming no local path: a study's snapshots are shared as they are, and the recorded hash is theirs
    with zipfile.ZipFile(snapshot) as archive:
        assert is_networks_only(snapshot) and str(study).encode() not in archive.read("data")
    assert pre["snapshot_sha256"] == {"1500": file_sha256(snapshot)}
    assert pre["wall_time_s"]["pretrain"] > 0
    assert not (study / "pretrain" / "ddpg_walker").exists()  # DDPG runs from scratch
    results = _results(study)
    runs = sorted((r["label"], r["task"], r["seed"]) for r in results)
    expected = [("cic", f"walker_{t}", s) for t in CIC_TASKS for s in SEEDS] + [("ddpg", "walker_stand", s) for s in SEEDS]
    assert runs == sorted(expected)
    for r in results:
        assert r["from_scratch"] == (r["method"] == "ddpg")
        assert r["wall_time_s"]["finetune"] > 0
        assert (r["wall_time_s"]["pretrain"] is None) == (r["method"] == "ddpg")
        run_dir = study / "finetune" / r["label"] / r["task"] / f"seed_{r['seed']}"
        curve = np.genfromtxt(run_dir / "eval.csv", delimiter=",", names=True)
        assert curve["timestep"].tolist() == [0, 500, 1000]  # step 0 and every eval_freq
        assert r["final_return"] == pytest.approx(curve["mean_return"][-1])
        assert r["final_normalized_score"] == pytest.approx(r["final_return"] / EXPERT_SCORES[r["task"]])
        if r["method"] == "cic":  # the grid sweep chose a constant skill
            assert r["finetune_skill"] is not None and len(set(r["finetune_skill"])) == 1
            sweep = np.array(r["skill_sweep"])  # every candidate with its window return; the best was kept
            assert len(sweep) > 1 and sweep[:, 1].argmax() == np.abs(sweep[:, 0] - r["finetune_skill"][0]).argmin()
        else:
            assert r["skill_sweep"] is None
    assert list(study.glob("tensorboard/*/events.out.tfevents.*"))


def test_report_numbers(study: Path):
    report = json.loads((study / "report.json").read_text())
    markdown = (study / "report.md").read_text()
    results = _results(study)
    rows = {(row["method"], row["task"]): row for row in report["per_task"]}
    assert len(rows) == 3
    for (label, task), row in rows.items():
        returns = np.array([r["final_return"] for r in results if r["label"] == label and r["task"] == task])
        scores = returns / EXPERT_SCORES[task]
        assert row["n"] == len(returns) == 2
        assert row["return_mean"] == pytest.approx(returns.mean())
        assert row["return_se"] == pytest.approx(returns.std(ddof=1) / np.sqrt(2))
        assert row["score_mean"] == pytest.approx(scores.mean())
        assert row["score_se"] == pytest.approx(scores.std(ddof=1) / np.sqrt(2))
        assert f"| {label} | {task} | 2 | {returns.mean():.1f} ± {returns.std(ddof=1) / np.sqrt(2):.1f} |" in markdown
        areas = []  # the curve's area over its steps, by hand: evaluations at 0, 500, 1000 (trapezoids)
        for r in results:
            if r["label"] == label and r["task"] == task:
                run_dir = study / "finetune" / label / task / f"seed_{r['seed']}"
                curve = np.genfromtxt(run_dir / "eval.csv", delimiter=",", names=True)["mean_return"]
                areas.append((0.5 * (curve[0] + curve[1]) * 500 + 0.5 * (curve[1] + curve[2]) * 500) / 1000)
        assert row["auc_mean"] == pytest.approx(np.mean(areas))
        assert row["auc_se"] == pytest.approx(np.std(areas, ddof=1) / np.sqrt(2))
        assert f"| {label} | {task} | 2 | {np.mean(areas):.1f} ± " in markdown

    # CIC ran flip and stand, DDPG stand only: the two are compared on stand
    assert [c["tasks"] for c in report["comparisons"]] == [["walker_stand"]]
    assert "Over walker_stand:" in markdown and "Over walker_flip" not in markdown
    for tasks, comparison in ((c["tasks"], c) for c in report["comparisons"]):
        for label, agg in comparison["aggregates"].items():
            score = {(r["task"], r["seed"]): r["final_normalized_score"] for r in results if r["label"] == label}
            matrix = np.array([[score[(t, s)] for t in tasks] for s in SEEDS])  # runs x tasks
            np.testing.assert_allclose(comparison["matrices"][label]["scores"], matrix)
            flat = np.sort(matrix.ravel())
            cut = int(0.25 * flat.size)
            iqm = flat[cut : flat.size - cut].mean()
            assert agg["IQM"]["point"] == pytest.approx(iqm)
            assert agg["Median"]["point"] == pytest.approx(np.median(matrix.mean(axis=0)))  # rliable: median of task means
            assert agg["Mean"]["point"] == pytest.approx(matrix.mean())
            assert agg["Optimality Gap"]["point"] == pytest.approx(np.mean(1.0 - np.minimum(matrix, 1.0)))
            for metric in agg.values():
                assert metric["low"] <= metric["point"] + 1e-9 and metric["point"] <= metric["high"] + 1e-9
            assert f"| {label} | 2 x {len(tasks)} | {iqm:.3f} [" in markdown

    for name in ("aggregates.png", "learning_curves.png"):
        assert (study / name).stat().st_size > 1000
        assert (study / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_rerun_skips_finished_runs(study: Path):
    # no run trains again: no run's file is written or added (no checkpoint, TensorBoard events or snapshot); the
    # command's own lock and record are written again, the record the same
    def runs_files() -> dict[Path, int]:
        return {p: p.stat().st_mtime_ns for p in study.rglob("*") if p.is_file() and p.parent != study}

    mtimes, record = runs_files(), (study / "study.json").read_text()
    _run_study(study)
    assert runs_files() == mtimes and (study / "study.json").read_text() == record


def test_zoo_cli_train_finetune_enjoy(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture):
    threads = th.get_num_threads()
    monkeypatch.chdir(tmp_path)
    small = ["--small", "--seed", "0", "--num-threads", "1", "--verbose", "0"]
    main(["train", "--algo", "cic", "--env", "URLB/point_mass-v0", "-n", "600", *small,
          "--hyperparams", "learning_starts:300"])
    pretrained = tmp_path / "logs" / "cic" / "URLB-point_mass-v0_1" / "URLB-point_mass-v0.zip"
    assert pretrained.stat().st_size > 0
    config = yaml.load((pretrained.parent / "URLB-point_mass-v0" / "config.yml").read_text(), Loader=yaml.UnsafeLoader)
    assert config["batch_size"] == 32 and config["learning_starts"] == 300 and config["policy_kwargs"] == "dict(hidden_dim=32)"

    main(
        ["finetune", "--algo", "cic", "--env", "URLB/point_mass-reach-v0", "-i", str(pretrained), "-n", "500",
         "--eval-freq", "500", "--eval-episodes", "1", *small, "--hyperparams", "learning_starts:200"]
    )
    run = tmp_path / "logs" / "cic" / "URLB-point_mass-reach-v0_1"
    assert (run / "URLB-point_mass-reach-v0.zip").stat().st_size > 0
    config = yaml.load((run / "URLB-point_mass-reach-v0" / "config.yml").read_text(), Loader=yaml.UnsafeLoader)
    callbacks = {next(iter(c)): next(iter(c.values())) for c in config["callback"]}
    assert list(callbacks) == ["sb3_cic.callbacks.URLBEvalCallback"] and config["finetune_skill_choice"] == "sweep"
    assert callbacks["sb3_cic.callbacks.URLBEvalCallback"]["n_eval_episodes"] == 1
    chosen = np.array(config["env_wrapper"][0]["sb3_cic.zoo.skill_wrapper"]["skill"])  # the chosen skill, for enjoy
    grid = UniformSkillPrior(64).grid(2)  # learn's sweep: learning_starts (200) steps, windows of 100
    assert any(np.allclose(chosen, z) for z in grid) and not np.allclose(chosen, 0.5)
    assert not (run / "evaluations.npz").exists()  # rl-zoo's own EvalCallback is off; URLBEvalCallback evaluates

    from stable_baselines3.common.save_util import load_from_zip_file

    data, _, _ = load_from_zip_file(run / "URLB-point_mass-reach-v0.zip")
    assert data["reward_free"] is False and data["num_timesteps"] == 500 and data["finetune_skill"] is not None

    main(["enjoy", "--algo", "cic", "--env", "URLB/point_mass-reach-v0", "--no-render", "-n", "20", "--deterministic"])
    # the yaml's skill choice overridden: the code's fixed skill, no sweep
    main(["finetune", "--algo", "cic", "--env", "URLB/point_mass-reach-v0", "-i", str(pretrained), "-n", "300",
          "--eval-freq", "300", "--eval-episodes", "1", *small, "--hyperparams", "learning_starts:200",
          "finetune_skill_choice:'fixed'"])
    config = yaml.load((run.with_name("URLB-point_mass-reach-v0_2") / "URLB-point_mass-reach-v0" / "config.yml").read_text(),
                       Loader=yaml.UnsafeLoader)
    assert config["env_wrapper"][0]["sb3_cic.zoo.skill_wrapper"]["skill"] == [0.5] * 64
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit_info:
        main(["train", "--algo", "cic", "--env", "URLB/point_mass-reach-v0", *small])
    assert exit_info.value.code == 2 and "is a task: pre-train cic" in capsys.readouterr().err
    th.set_num_threads(threads)


def test_comparisons_give_each_task_set_its_methods():
    def run(label, task, seed, score):
        return {"label": label, "task": task, "seed": seed, "final_normalized_score": score}

    results = [run("cic", t, s, 0.1 * s + (t == "b")) for t in "ab" for s in (0, 1)]
    results += [run("ddpg", t, s, 0.2) for t in "ab" for s in (0, 1)] + [run("cic@100", "b", s, 0.5) for s in (0, 1)]
    # an early snapshot fine-tuned on task b only does not shrink the main comparison to b
    assert scores.comparisons(results) == [(["a", "b"], ["cic", "ddpg"]), (["b"], ["cic", "cic@100", "ddpg"])]
    results.append(run("ddpg", "c", 0, 0.9))  # a method alone on its task set is no comparison
    assert scores.comparisons(results) == [(["a", "b"], ["cic", "ddpg"]), (["b"], ["cic", "cic@100", "ddpg"])]
    disjoint = [run("cic", "a", 0, 0.1), run("ddpg", "b", 0, 0.2)]
    assert scores.comparisons(disjoint) == [(["a"], ["cic"]), (["b"], ["ddpg"])]
    everything, _, seeds_all = scores.score_matrices(results)
    assert seeds_all["ddpg"] == [0] and everything["ddpg"].shape == (1, 3)  # task c has seed 0 only
    matrices, tasks_of, seeds_of = scores.score_matrices(results, ["a", "b"])
    assert tasks_of["cic"] == tasks_of["ddpg"] == ["a", "b"] and seeds_of["ddpg"] == [0, 1]
    np.testing.assert_allclose(matrices["cic"], [[0.0, 1.0], [0.1, 1.1]])


def test_bootstrap_intervals_are_reproducible():
    rng = np.random.default_rng(3)
    matrices = {"cic": rng.random((5, 3)), "ddpg": rng.random((5, 3))}
    np.random.seed(7)
    outside = np.random.get_state()[1].copy()
    first = scores.aggregate_scores(matrices, reps=300, seed=0)
    np.testing.assert_array_equal(np.random.get_state()[1], outside)  # NumPy's global generator is left as it was
    np.random.rand(10)  # a draw in between changes nothing
    assert scores.aggregate_scores(matrices, reps=300, seed=0) == first
    # a method's interval does not depend on the other methods of the report
    assert scores.aggregate_scores({"ddpg": matrices["ddpg"]}, reps=300, seed=0)["ddpg"] == first["ddpg"]
    other = scores.aggregate_scores(matrices, reps=300, seed=1)
    assert other["cic"]["IQM"]["point"] == first["cic"]["IQM"]["point"]
    assert other["cic"]["IQM"]["low"] != first["cic"]["IQM"]["low"]  # the seed drives the resampling



def test_learning_curves_tell_eleven_methods_apart():
    # the quadruped study plots twelve labels: matplotlib's ten colours alone would repeat two of them
    styles = [figures.line_style(i) for i in range(40)]
    assert len(set(styles)) == 40 and styles[0] == ("C0", "-") and styles[10] == ("C0", "--")

#: the command line of SETTINGS' fine-tuning settings (a run from scratch uses no pre-training setting)
FINETUNE_FLAGS = [
    "--hidden-dim", "32", "--batch-size", "32", "--learning-starts", "500", "--buffer-size", "10000",
    "--finetune-steps", "1000", "--eval-freq", "500", "--eval-episodes", "2", "--num-threads", "1", "--no-progress",
]


def _refused(arguments: list[str], capsys: pytest.CaptureFixture) -> str:
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit_info:
        main(arguments)
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and len(err.strip().splitlines()) == 1, err
    return err


def test_settings_a_run_does_not_use_do_not_block_it(tmp_path: Path, capsys: pytest.CaptureFixture):
    """``protocol --method ddpg`` into a study made by ``--method cic --pretrain-steps 1000``: DDPG does not pre-train,
    so the pre-training settings (steps, snapshots, seed) do not block it; those it uses still do. The study records
    each method's ``--conf-file`` (its entries: another path to the same yaml, or a new comment, is the same)."""
    threads = th.get_num_threads()
    study = tmp_path / "study"
    record_study_settings(study, replace(SETTINGS, pretrain_steps=1000), 0)  # as `--method cic --pretrain-steps 1000`
    custom = tmp_path / "ddpg_custom.yml"
    default = (Path(__file__).resolve().parent.parent / "zoo_configs" / "ddpg.yml").read_text()
    entry = "URLB/point_mass-reach-v0:\n  <<: *scratch\n"
    assert entry in default
    custom.write_text(default.replace(entry, entry + "  gamma: 0.98\n"))  # one entry tuned
    ddpg = ["protocol", "--method", "ddpg", "--domain", "point_mass", "--tasks", "reach", "--seeds", "0",
            "--study", str(study), "--pretrain-seed", "7"]
    main([*ddpg, *FINETUNE_FLAGS, "--conf-file", str(custom)])
    th.set_num_threads(threads)
    assert json.loads((study / "finetune" / "ddpg" / "point_mass_reach" / "seed_0" / "result.json").read_text())["seed"] == 0
    recorded = json.loads((study / "study.json").read_text())
    assert recorded["settings"]["pretrain_steps"] == 1000 and recorded["pretrain_seed"] == 0  # cic's, kept
    assert recorded["conf_files"] == {"ddpg": conf_file_record("ddpg", str(custom))}
    assert recorded["conf_files"]["ddpg"]["sha256"] == hashlib.sha256(custom.read_bytes()).hexdigest()
    assert "URLB/point_mass-reach-v0" in recorded["conf_files"]["ddpg"]["entries"]

    # the settings a run uses are still checked
    assert "hidden_dim': (32, 64)" in _refused([*ddpg, *FINETUNE_FLAGS, "--conf-file", str(custom), "--hidden-dim", "64"],
                                              capsys)
    assert "conf_file of ddpg (entries URLB/point_mass-reach-v0)" in _refused([*ddpg, *FINETUNE_FLAGS], capsys)
    cic = ["protocol", "--method", "cic", "--domain", "walker", "--tasks", "stand", "--seeds", "0", "--study", str(study),
           *FINETUNE_FLAGS]
    assert "pretrain_steps': (1000, 2000)" in _refused([*cic, "--pretrain-steps", "2000"], capsys)
    assert "pretrain_seed': (0, 7)" in _refused([*cic, "--pretrain-steps", "1000", "--pretrain-seed", "7"], capsys)
    moved = tmp_path / "moved.yml"
    shutil.copy(custom, moved)
    main([*ddpg, *FINETUNE_FLAGS, "--conf-file", str(moved)])  # the same yaml elsewhere: accepted (the run is done)
    custom.write_text(custom.read_text() + "# a comment changes no run\n")
    main([*ddpg, *FINETUNE_FLAGS, "--conf-file", str(custom)])
    custom.write_text(custom.read_text().replace("gamma: 0.98", "gamma: 0.97"))
    assert "conf_file of ddpg (entries URLB/point_mass-reach-v0)" in _refused([*ddpg, *FINETUNE_FLAGS, "--conf-file",
                                                                               str(custom)], capsys)


def test_a_study_begun_from_scratch_takes_pre_training_settings_later(tmp_path: Path):
    """DDPG first records no pre-training setting; a method that pre-trains records them, and is then held to them."""
    ddpg = replace(SETTINGS, pretrain_steps=None, snapshots=(7,))
    record_study_settings(tmp_path, ddpg, 5, pretrained=False)
    assert "pretrain_steps" not in json.loads((tmp_path / "study.json").read_text())["settings"]
    record_study_settings(tmp_path, SETTINGS, 0)
    recorded = json.loads((tmp_path / "study.json").read_text())
    assert recorded["settings"] == SETTINGS.study_settings() and recorded["pretrain_seed"] == 0
    check_study_settings(tmp_path, ddpg, 5, pretrained=False)
    with pytest.raises(ValueError, match="pretrain_steps.*1500, None"):
        check_study_settings(tmp_path, ddpg, 0)
    with pytest.raises(ValueError, match="finetune_steps.*1000, 2000"):
        check_study_settings(tmp_path, replace(ddpg, finetune_steps=2000), 5, pretrained=False)


def test_run_killed_before_deleting_its_checkpoint_ends_clean(study: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """A run killed between writing ``result.json`` and deleting its checkpoint: done, and its checkpoint and
    ``progress.json`` are deleted when the protocol next sees it."""
    folder = tmp_path / "study"
    shutil.copytree(study, folder)
    runs = [RunFolder(folder / "pretrain" / "cic_walker"), RunFolder(folder / "finetune" / "ddpg" / "walker_stand" / "seed_0")]
    for run in runs:  # the run, at its end: a checkpoint and progress.json, then finish() killed after result.json
        result = json.loads(run.result.read_text())
        run.result.unlink()
        run.start(1000)
        run.checkpoint.write_bytes(b"PK\x05\x06" + b"\0" * 18)  # an (empty) zip stands for the checkpoint
        with monkeypatch.context() as patch:
            def killed(self, missing_ok=False):
                raise KeyboardInterrupt("killed")

            patch.setattr(Path, "unlink", killed)
            with pytest.raises(KeyboardInterrupt):
                run.finish(result)
        assert run.done and run.checkpoint.exists() and run.progress.exists()
    results = {p: p.read_text() for p in folder.glob("**/result.json")}
    _run_study(folder)
    assert not list(folder.rglob("checkpoint*")) and not list(folder.rglob("progress.json"))
    assert {p: p.read_text() for p in folder.glob("**/result.json")} == results  # done: nothing ran again


def _synthetic(label: str, task: str, seed: int, score: float) -> dict:
    return {"label": label, "method": label.split("@")[0], "task": task, "seed": seed, "final_normalized_score": score}


def test_published_comparison_against_table_6():
    from sb3_cic.constants import EXPERT_SCORES, MOSS_PUBLISHED_RETURNS, PUBLISHED_RETURNS

    tasks = ("quadruped_stand", "quadruped_walk")
    methods = ("apt", "cic", "ddpg", "smm")
    published = {m: np.mean([PUBLISHED_RETURNS[m][t][0] / EXPERT_SCORES[t] for t in tasks]) for m in methods}
    results = [_synthetic(m, t, s, PUBLISHED_RETURNS[m][t][0] / EXPERT_SCORES[t] + 0.01 * (s - 1))
               for m in methods for t in tasks for s in range(3)]
    results += [_synthetic("cic@100000", t, 0, 0.0) for t in tasks]  # an intermediate snapshot: not compared
    results += [_synthetic("moss", "quadruped_stand", s, 0.5) for s in range(2)]
    # CIC's code variant and a skill choice: beside CIC's published numbers, not in the rank correlation
    results += [_synthetic(label, t, 0, 0.0) for label in ("cic_code+fixed", "cic+fixed") for t in tasks]
    out = scores.published_comparison(results, reps=200)
    rows = {r["method"]: r for r in out["methods"]}
    assert set(rows) == {*methods, "moss", "cic_code+fixed", "cic+fixed"} and rows["moss"]["source"] == "MOSS"
    for label in ("cic_code+fixed", "cic+fixed"):
        assert rows[label]["published"] == rows["cic"]["published"] and rows[label]["ours"] == 0.0
        assert not rows[label]["ranked"] and rows["cic"]["ranked"]
    assert rows["moss"]["published"] == pytest.approx(MOSS_PUBLISHED_RETURNS["moss"]["quadruped_stand"][0] / 920)
    for m in methods:
        assert rows[m]["published"] == pytest.approx(published[m]) and rows[m]["ours"] == pytest.approx(published[m])
    assert out["ranked"] == sorted(methods) and out["tasks"] == list(tasks)
    assert out["spearman"] == pytest.approx(1.0) and out["low"] == pytest.approx(1.0) and out["high"] == pytest.approx(1.0)
    # the opposite order: -1
    order = sorted(methods, key=published.get)
    flipped = [dict(r, final_normalized_score=order.index(r["label"]) * -0.1) for r in results if r["label"] in methods]
    assert scores.published_comparison(flipped, reps=50)["spearman"] == pytest.approx(-1.0)
