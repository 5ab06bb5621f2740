"""The demo (make demo): the shipped snapshot, and a tiny run of the whole job."""

import math
import zipfile

import pytest
import torch as th

import sb3_cic  # noqa: F401
from sb3_cic import CIC, demo
from sb3_cic.common.save_util import is_optimizer_state, read_saved_data


@pytest.mark.parametrize("domain, steps, task", [("quadruped", 500_000, "jump"), ("walker", 100_000, "flip")])
def test_shipped_snapshots_are_hidden_256_cics_of_their_domain(domain, steps, task):
    path = demo.SNAPSHOTS[domain]
    data = read_saved_data(path)
    assert data["algorithm"] == "CIC" and data["env_id"] == f"URLB/{domain}-v0"
    assert data["policy_kwargs"]["hidden_dim"] == 256 and data["batch_size"] == 256 and data["num_timesteps"] == steps
    assert path.stat().st_size <= 10_000_000
    model = CIC.load_pretrained(path, env=f"URLB/{domain}-{task}-v0", buffer_size=100)
    assert model.reward_free is False and model.num_timesteps == 0 and model.skill_dim == 64
    assert demo.TASKS[domain][0] == task


def test_the_quadruped_snapshot_is_networks_only():
    with zipfile.ZipFile(demo.SNAPSHOTS["quadruped"]) as archive:
        names = archive.namelist()
    assert "policy.pth" in names and not any(is_optimizer_state(name) for name in names)


def test_demo_fine_tunes_beside_ddpg_and_writes_the_curves(tmp_path, capsys):
    snapshot = tmp_path / "tiny"
    pretrained = CIC("MlpPolicy", "URLB/walker-v0", policy_kwargs={"hidden_dim": 16}, batch_size=16, learning_starts=200,
                     buffer_size=1000, skill_dim=4, seed=0)
    pretrained.learn(400)
    pretrained.save(snapshot)
    out = tmp_path / "out"
    threads = th.get_num_threads()
    result = demo.main(["--domain", "walker", "--snapshot", str(snapshot) + ".zip", "--steps", "600",
                        "--learning-starts", "400", "--eval-every", "300", "--eval-episodes", "1", "--skills", "0",
                        "--out", str(out), "--task", "stand", "--num-threads", str(threads + 1)])
    assert th.get_num_threads() == threads  # the demo's thread count does not outlive it
    for name in ("CIC", "DDPG"):
        assert [h[0] for h in result[name]] == [0, 300, 600]
        assert all(h[1] >= 0 and h[2] == pytest.approx(h[1] / sb3_cic.EXPERT_SCORES["walker_stand"]) for h in result[name])
    assert (out / "learning_curves.png").stat().st_size > 10_000 and result["files"] == [out / "learning_curves.png"]
    assert (out / "cic_finetuned.zip").exists() and (out / "ddpg.zip").exists()
    printed = capsys.readouterr().out
    assert "CIC (pre-trained)" in printed and "DDPG (from scratch)" in printed and "chosen skill: c =" in printed
    last = result["CIC"][-1]
    assert f"{last[1]:7.1f}" in printed and not math.isnan(last[2])


@pytest.mark.parametrize("argv, message", [
    (["--steps", "1000", "--learning-starts", "4000"], "--steps 1000 must be above --learning-starts 4000"),
    (["--num-threads", "0"], "argument --num-threads: must be an int >= 1, got '0'"),
    (["--eval-episodes", "0"], "argument --eval-episodes: must be an int >= 1, got '0'"),
    (["--hidden-dim", "-3"], "argument --hidden-dim: must be an int >= 1, got '-3'"),
    (["--eval-ev", "100"], "unrecognized arguments: --eval-ev"),  # no abbreviated options
])
def test_demo_refuses_a_budget_shorter_than_its_random_steps_or_no_thread(tmp_path, capsys, argv, message):
    with pytest.raises(SystemExit):
        demo.main([*argv, "--out", str(tmp_path)])
    assert message in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_demo_on_quadruped_is_the_default(tmp_path, capsys):
    snapshot = tmp_path / "tiny_quadruped"
    pretrained = CIC("MlpPolicy", "URLB/quadruped-v0", policy_kwargs={"hidden_dim": 16}, batch_size=16,
                     learning_starts=200, buffer_size=1000, skill_dim=4, seed=0)
    pretrained.learn(300)
    pretrained.save(snapshot)
    result = demo.main(["--snapshot", str(snapshot) + ".zip", "--steps", "500",
                        "--learning-starts", "400", "--eval-every", "500", "--eval-episodes", "1", "--skills", "0",
                        "--out", str(tmp_path / "out")])
    assert [h[0] for h in result["CIC"]] == [0, 500]
    assert result["CIC"][-1][2] == pytest.approx(result["CIC"][-1][1] / sb3_cic.EXPERT_SCORES["quadruped_jump"])
    assert "URLB/quadruped-jump-v0" in capsys.readouterr().out


@pytest.mark.parametrize("argv", [["--task", "flip"], ["--domain", "walker", "--task", "jump"]])
def test_demo_refuses_a_task_the_domain_lacks(tmp_path, capsys, argv):
    with pytest.raises(SystemExit):
        demo.main([*argv, "--out", str(tmp_path)])
    assert "has no task" in capsys.readouterr().err
