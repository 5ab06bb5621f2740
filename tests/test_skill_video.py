"""``sb3-cic skills``: the grid video of a snapshot's skills and the plot of where they go."""

import os
import sys

import imageio.v2 as imageio
import numpy as np
import pytest

from sb3_cic import CIC, ICM
from sb3_cic.skill_video import grid_frames, show_skills
from waiting import run_process

RENDER_PROBE = (
    "import gymnasium as gym, sb3_cic.envs; e = gym.make('URLB/point_mass-v0', render_mode='rgb_array'); e.reset(); e.render()"
)


def egl_or_skip() -> dict:
    env = {**os.environ, "MUJOCO_GL": "egl"}
    probe = run_process([sys.executable, "-c", RENDER_PROBE], "the EGL rendering probe", env=env)
    if probe.returncode != 0:
        pytest.skip(f"no EGL rendering here: {probe.stderr.strip().splitlines()[-1] if probe.stderr else 'failed'}")
    return env


@pytest.fixture(scope="module")
def snapshot(tmp_path_factory):
    path = tmp_path_factory.mktemp("skills") / "cic"
    model = CIC("MlpPolicy", "URLB/walker-v0", policy_kwargs={"hidden_dim": 32}, batch_size=32, buffer_size=1000,
                learning_starts=100, seed=0)
    model.learn(150)
    model.save(path)
    return path.with_suffix(".zip")


@pytest.mark.parametrize("suffix", [".mp4", ".gif"])
def test_skills_command_writes_a_grid_video(snapshot, tmp_path, suffix):
    env = egl_or_skip()
    out, plot = tmp_path / f"skills{suffix}", tmp_path / "where.png"
    command = [sys.executable, "-m", "sb3_cic.cli", "skills", str(snapshot), "--n", "5", "--steps", "12", "--size", "48",
               "--out", str(out), "--plot", str(plot)]
    done = run_process(command, "sb3-cic skills", env=env)
    assert done.returncode == 0, done.stderr
    frames = imageio.mimread(out)
    assert len(frames) == 13  # the start and 12 steps
    assert frames[0].shape[:2] == (2 * 48, 3 * 48)  # 5 tiles: 2 rows of 3
    assert frames[0][2 * 48 - 1, -1].max() == 0  # the sixth tile is empty
    assert frames[-1].std() > 0 and plot.stat().st_size > 0


def test_tiles_are_labelled_and_placed():
    frames = np.zeros((2, 3, 32, 32, 3), dtype=np.uint8)
    frames[:, 1] = 100
    grid = grid_frames(frames, ["a", "b", "c"], columns=2)
    assert grid.shape == (2, 64, 64, 3)
    assert grid[0, 20:32, 32:].min() == 100 and grid[0, 32:, 32:].max() == 0  # tile 1 top right, no tile 4
    assert (grid[0, :16, :32] == 255).any() and (grid[0, 32:48, :32] == 255).any()  # labels drawn


def test_where_the_skills_go_on_the_point_mass(tmp_path):
    model = CIC("MlpPolicy", "URLB/point_mass-v0", policy_kwargs={"hidden_dim": 32}, batch_size=32, buffer_size=1000,
                learning_starts=50, seed=0, skill_dim=4)
    model.learn(80)
    model.save(tmp_path / "pm")
    skills, positions = show_skills(tmp_path / "pm.zip", n=3, steps=25, out=None, plot=tmp_path / "pm.png")
    assert skills.shape == (3, 4) and positions.shape == (3, 26, 3)
    assert np.allclose(positions[:, 0], positions[0, 0])  # the same start for every skill
    assert (tmp_path / "pm.png").stat().st_size > 0


def test_plot_only_needs_no_opengl(snapshot, tmp_path):
    plot = tmp_path / "where.png"
    command = [sys.executable, "-m", "sb3_cic.cli", "skills", str(snapshot), "--n", "2", "--steps", "5", "--no-video",
               "--plot", str(plot)]
    done = run_process(command, "sb3-cic skills --no-video", env={**os.environ, "MUJOCO_GL": "disable"})
    assert done.returncode == 0, done.stderr
    assert plot.stat().st_size > 0 and f"wrote {plot}" in done.stdout
    refused = run_process(command[:-2], "sb3-cic skills --no-video without --plot", env={**os.environ, "MUJOCO_GL": "disable"})
    assert refused.returncode != 0 and "give --plot PNG" in refused.stderr


def test_a_model_without_skills_is_refused(tmp_path):
    ICM("MlpPolicy", "URLB/walker-v0", policy_kwargs={"hidden_dim": 8}, batch_size=8, buffer_size=100).save(tmp_path / "icm")
    with pytest.raises(ValueError, match="ICM model, which has no skills"):
        show_skills(tmp_path / "icm.zip", out=None)
