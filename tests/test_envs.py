"""The URLB Gymnasium environments: API checks, sizes, episode ends, determinism, rendering."""

import os

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

from sb3_cic import envs
import sb3_cic  # noqa: F401  (registers the ids as well)

DIMS = {
    "walker": (24, 6), "quadruped": (78, 12), "jaco": (55, 9), "point_mass": (4, 2), "hopper": (15, 4), "gridworld": (2, 2)
}
LENGTH = {"walker": 1000, "quadruped": 1000, "jaco": 250, "point_mass": 1000, "hopper": 1000, "gridworld": 20}


def domain_of(env_id: str) -> str:
    return env_id.split("/")[1].split("-")[0]


def test_all_ids_registered():
    ids = envs.env_ids()
    assert len(ids) == 5 + 1 + 12 + 1 + 1  # pre-training ids (and the gridworld), URLB's tasks, point mass, hopper
    for task in envs.URLB_TASKS:
        domain, name = task.split("_", 1) if not task.startswith("point") else ("point_mass", "reach")
        assert f"URLB/{domain}-{name}-v0" in gym.registry
    for domain in ("walker", "quadruped", "jaco", "point_mass", "hopper", "gridworld"):
        assert f"URLB/{domain}-v0" in gym.registry
    assert "URLB/hopper-hop-v0" in gym.registry


@pytest.mark.parametrize("env_id", envs.env_ids())
def test_env_checkers_and_dims(env_id):
    env = gym.make(env_id)
    obs_dim, act_dim = DIMS[domain_of(env_id)]
    assert env.observation_space.shape == (obs_dim,) and env.observation_space.dtype == np.float32
    assert env.action_space.shape == (act_dim,) and env.action_space.dtype == np.float32
    assert np.all(env.action_space.low == -1) and np.all(env.action_space.high == 1)
    gym_check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(env.unwrapped, warn=False)
    env.close()


@pytest.mark.parametrize(
    "env_id",
    ["URLB/walker-v0", "URLB/quadruped-run-v0", "URLB/jaco-reach_top_left-v0", "URLB/hopper-v0", "URLB/hopper-hop-v0"],
)
def test_episode_ends_by_truncation(env_id):
    env = gym.make(env_id)
    env.reset(seed=0)
    steps, terminated, truncated = 0, False, False
    while not (terminated or truncated):
        _, reward, terminated, truncated, info = env.step(env.action_space.sample())
        steps += 1
        assert "task_reward" in info
    assert steps == LENGTH[domain_of(env_id)]
    assert truncated and not terminated


def test_reward_free_env_reports_task_reward():
    env = gym.make("URLB/walker-v0")
    env.reset(seed=0)
    task_rewards = []
    for _ in range(20):
        _, reward, *_, info = env.step(env.action_space.sample())
        assert reward == 0.0
        task_rewards.append(info["task_reward"])
    assert max(task_rewards) > 0.0


def test_observation_in_dm_control_key_order():
    env = gym.make("URLB/walker-walk-v0").unwrapped
    obs, _ = env.reset(seed=1)
    physics = env.physics
    expected = np.concatenate([physics.orientations(), [physics.torso_height()], physics.velocity()])
    np.testing.assert_allclose(obs, expected.astype(np.float32), rtol=1e-6)


@pytest.mark.parametrize("physics_clamps", [True, False])
@pytest.mark.parametrize("env_id", ["URLB/point_mass-reach-v0", "URLB/quadruped-walk-v0", "URLB/jaco-reach_top_left-v0"])
def test_actions_rescaled_to_physics_bounds(env_id, physics_clamps):
    def make():
        env = gym.make(env_id).unwrapped
        assert env._physics_clamps  # MuJoCo clamps these envs' controls to the action spec's bounds
        env._physics_clamps = physics_clamps  # False: the adapter's own clip
        env.reset(seed=0)
        return env

    env, twin = make(), make()
    spec = env.dm_env.action_spec()
    ones = np.ones(spec.shape, dtype=np.float32)
    for action, expected in [(ones, spec.maximum), (-ones, spec.minimum), (0 * ones, (spec.maximum + spec.minimum) / 2),
                             (0.5 * ones, spec.minimum + 0.75 * (spec.maximum - spec.minimum))]:
        env.step(action)
        twin.step(action)
        np.testing.assert_allclose(env.physics.data.ctrl, expected, rtol=1e-12, atol=1e-12)
    # out of [-1, 1]: the same step as the clipped action (clipped by the adapter or clamped by MuJoCo)
    for outside in (3 * ones, -3 * ones, np.linspace(-2, 2, ones.size, dtype=np.float32)):
        obs, *_ = env.step(outside)
        obs_clipped, *_ = twin.step(np.clip(outside, -1, 1))
        np.testing.assert_array_equal(obs, obs_clipped)
        np.testing.assert_array_equal(env.physics.get_state(), twin.physics.get_state())


@pytest.mark.parametrize("env_id", ["URLB/walker-flip-v0", "URLB/quadruped-jump-v0", "URLB/jaco-reach_bottom_right-v0"])
def test_same_seed_same_trajectory(env_id):
    actions = np.random.default_rng(0).uniform(-1, 1, size=(30, DIMS[domain_of(env_id)][1])).astype(np.float32)

    def rollout(seed):
        env = gym.make(env_id)
        obs, _ = env.reset(seed=seed)
        trajectory = [obs]
        for action in actions:
            obs, reward, *_ = env.step(action)
            trajectory.append(np.append(obs, reward))
        return np.concatenate(trajectory)

    np.testing.assert_array_equal(rollout(3), rollout(3))
    assert not np.array_equal(rollout(3), rollout(4))


def test_render_rgb_array_or_clear_error():
    env = gym.make("URLB/walker-stand-v0", render_mode="rgb_array", render_size=(64, 80))
    env.reset(seed=0)
    if os.environ.get("MUJOCO_GL") == "disable":
        with pytest.raises(RuntimeError, match="MUJOCO_GL"):
            env.render()
    else:
        frame = env.render()
        assert frame.shape == (64, 80, 3) and frame.dtype == np.uint8 and frame.std() > 0


def test_render_with_egl_in_subprocess():
    """Rendering works where MuJoCo has a GL backend (EGL here); skipped only if EGL is absent."""
    import subprocess
    import sys

    code = (
        "import gymnasium as gym, envs, numpy as np;"
        "e=gym.make('URLB/walker-stand-v0', render_mode='rgb_array', render_size=(48, 64)); e.reset(seed=0);"
        "f=e.render(); assert f.shape==(48, 64, 3) and f.std()>0; print('ok')"
    )
    out = subprocess.run([sys.executable, "-c", code], env={**os.environ, "MUJOCO_GL": "egl"}, capture_output=True, text=True)
    if out.returncode != 0 and ("EGL" in out.stderr or "egl" in out.stderr) and "assert" not in out.stderr:
        pytest.skip(f"no EGL on this machine: {out.stderr.strip().splitlines()[-1]}")
    assert out.stdout.strip() == "ok", out.stderr
