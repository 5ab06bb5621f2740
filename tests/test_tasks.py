"""Tests of the URLB tasks that dm_control's suite lacks (walker flip, quadruped stand/jump, jaco reach)
and of the spaces and reward range of all 12 URLB tasks through Gymnasium."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from dm_control.utils import rewards

from sb3_cic import envs  # noqa: F401  (registers the URLB ids)
from sb3_cic.envs.tasks import URLB_TASKS, jaco, quadruped, walker

INF = float("inf")
OBS_DIM = {"walker": 24, "quadruped": 78, "jaco": 55}
ACT_DIM = {"walker": 6, "quadruped": 12, "jaco": 9}


def _gym_id(task: str) -> str:
    domain, name = task.split("_", 1)
    return f"URLB/{domain}-{name}-v0"


# walker flip -------------------------------------------------------------------------------------
def _walker_flip_formula(physics) -> float:
    standing = rewards.tolerance(physics.named.data.xpos["torso", "z"], bounds=(1.2, INF), margin=0.6)
    upright = (1 + physics.named.data.xmat["torso", "zz"]) / 2
    stand = (3 * standing + upright) / 4
    move = rewards.tolerance(
        physics.named.data.subtree_angmom["torso"][1], bounds=(5, INF), margin=5, value_at_margin=0, sigmoid="linear"
    )
    return float(stand * (5 * move + 1) / 6)


def test_walker_flip_reward_rises_with_angular_momentum():
    env = walker.flip(seed=0)
    env.reset()
    physics = env.physics
    values, momenta = [], []
    for spin in (0.0, 2.0, 4.0, 8.0, 50.0):
        with physics.reset_context():
            physics.data.qpos[:] = 0.0  # standing straight, torso well above 1.2 m
            physics.data.qvel[:] = 0.0
            physics.named.data.qvel["rooty"] = spin  # rotation about the world y axis
        momenta.append(physics.named.data.subtree_angmom["torso"][1])
        reward = env.task.get_reward(physics)
        assert reward == pytest.approx(_walker_flip_formula(physics), abs=1e-9)
        values.append(reward)
    assert np.all(np.diff(momenta) > 0) and momenta[0] == pytest.approx(0.0)
    assert np.all(np.diff(values) >= 0) and values[-1] > values[0]
    assert values[0] == pytest.approx(1 / 6, abs=1e-6)  # standing still: stand = 1, move = 0
    assert values[-1] == pytest.approx(1.0, abs=1e-6)  # standing, spinning fast


# quadruped ---------------------------------------------------------------------------------------
def _set_quadruped_root(physics, z: float, quaternion=(1.0, 0.0, 0.0, 0.0)) -> None:
    with physics.reset_context():
        physics.data.qpos[:] = 0.0
        physics.data.qvel[:] = 0.0
        physics.named.data.qpos["root"][:3] = (0.0, 0.0, z)
        physics.named.data.qpos["root"][3:] = quaternion


def _upright_formula(physics) -> float:
    return float(
        rewards.tolerance(
            physics.named.data.xmat["torso", "zz"], bounds=(1, INF), margin=2, value_at_margin=0, sigmoid="linear"
        )
    )


def test_quadruped_jump_reward_higher_for_raised_com():
    env = quadruped.jump(seed=0)
    env.reset()
    physics = env.physics
    values = []
    for z in (0.3, 0.8, 1.5):
        _set_quadruped_root(physics, z)
        physics.forward()
        com_z = physics.named.data.subtree_com["torso"][2]
        expected = _upright_formula(physics) * rewards.tolerance(
            com_z, bounds=(1.0, INF), margin=1.0, value_at_margin=0.5, sigmoid="linear"
        )
        reward = env.task.get_reward(physics)
        assert reward == pytest.approx(expected, abs=1e-9)
        values.append(reward)
    assert values[0] < values[1] < values[2]
    assert values[2] == pytest.approx(1.0)  # upright, centre of mass above 1 m


def test_quadruped_stand_reward_is_upright():
    env = quadruped.stand(seed=0)
    env.reset()
    physics = env.physics
    half = np.sqrt(0.5)
    for quaternion, expected in [((1, 0, 0, 0), 1.0), ((half, half, 0, 0), 0.5), ((0, 1, 0, 0), 0.0)]:
        _set_quadruped_root(physics, 1.0, quaternion)
        reward = env.task.get_reward(physics)
        assert reward == pytest.approx(_upright_formula(physics), abs=1e-9)
        assert reward == pytest.approx(expected, abs=1e-6)


@pytest.mark.parametrize("make", [quadruped.stand, quadruped.jump])
def test_quadruped_reset_does_not_touch(make):
    env = make(seed=3)
    physics = env.physics
    for _ in range(3):
        env.reset()
        assert physics.data.ncon == 0
        quaternion = physics.named.data.qpos["root"][3:]
        assert np.linalg.norm(quaternion) == pytest.approx(1.0)
        qpos = physics.data.qpos.copy()
        z = physics.named.data.qpos["root"][2]
        if z >= 0.01:  # the lowest non-contacting height (1 cm steps): 1 cm lower it touches
            with physics.reset_context():  # (resets the data: set the whole qpos)
                physics.data.qpos[:] = qpos
                physics.named.data.qpos["root"][2] = z - 0.01
            assert physics.data.ncon > 0


# jaco --------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def jaco_env():
    env = jaco.make("reach_bottom_right", seed=0)
    yield env
    env.close()


def test_jaco_target_and_reward(jaco_env):
    env = jaco_env
    env.reset()
    physics, task = env.physics, env.task
    brick = physics.bind(task.brick_frame).xpos.copy()
    # the settled brick lies at its task's fixed place; the observed position is a site above the origin
    np.testing.assert_allclose(brick[:2], jaco.TARGETS["reach_bottom_right"], atol=2e-3)
    assert abs(brick[2]) < 2e-3
    tcp = physics.bind(task.hand.tool_center_point).xpos.copy()
    assert np.all(tcp >= np.array(jaco.TCP_BOX.lower) - 1e-3) and np.all(tcp <= np.array(jaco.TCP_BOX.upper) + 1e-3)

    def reward_with_brick_at(position):
        task.brick.set_pose(physics, position=position)
        physics.forward()
        distance = np.linalg.norm(physics.bind(task.hand.tool_center_point).xpos - physics.bind(task.brick_frame).xpos)
        expected = rewards.tolerance(distance, bounds=(0, 0.05), margin=0.05)
        reward = task.get_reward(physics)
        assert reward == pytest.approx(expected, abs=1e-9)
        return reward

    assert reward_with_brick_at(tcp) == pytest.approx(1.0)
    assert reward_with_brick_at(tcp + [0.0, 0.0, 0.04]) == pytest.approx(1.0)  # inside the 5 cm radius
    assert 0.05 < reward_with_brick_at(tcp + [0.0, 0.0, 0.08]) < 0.5
    assert reward_with_brick_at(tcp + [0.3, 0.0, 0.0]) < 1e-3


def test_jaco_targets_differ():
    positions = {}
    for task in jaco.TARGETS:
        env = jaco.make(task, seed=1)
        env.reset()
        positions[task] = env.physics.bind(env.task.brick_frame).xpos[:2].copy()
        np.testing.assert_allclose(positions[task], jaco.TARGETS[task], atol=2e-3)
        env.close()


def test_jaco_episode_length_and_seeding():
    env = gym.make("URLB/jaco-reach_top_left-v0")
    obs_a, _ = env.reset(seed=5)
    obs_b, _ = env.reset(seed=5)
    np.testing.assert_array_equal(obs_a, obs_b)
    env.action_space.seed(0)
    steps, truncated, terminated = 0, False, False
    while not (truncated or terminated):
        obs, reward, terminated, truncated, _ = env.step(env.action_space.sample())
        assert 0.0 <= reward <= 1.0
        steps += 1
    assert steps == 250 and truncated and not terminated
    env.close()


# all 12 URLB tasks through Gymnasium -------------------------------------------------------------
@pytest.mark.parametrize("task", URLB_TASKS)
def test_urlb_task_spaces_and_reward_range(task):
    domain = task.split("_", 1)[0]
    env = gym.make(_gym_id(task))
    assert env.observation_space.shape == (OBS_DIM[domain],)
    assert env.action_space.shape == (ACT_DIM[domain],)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (OBS_DIM[domain],) and obs.dtype == np.float32
    env.action_space.seed(0)
    for _ in range(40 if domain == "jaco" else 150):
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        assert obs.shape == (OBS_DIM[domain],) and np.all(np.isfinite(obs))
        assert 0.0 <= reward <= 1.0 and 0.0 <= info["task_reward"] <= 1.0
        assert not (terminated or truncated)
    env.close()


@pytest.mark.parametrize("env_id", ["URLB/walker-flip-v0", "URLB/quadruped-jump-v0"])
def test_custom_task_episode_length(env_id):
    env = gym.make(env_id)
    env.reset(seed=0)
    env.action_space.seed(0)
    steps, truncated, terminated = 0, False, False
    while not (truncated or terminated):
        _, reward, terminated, truncated, _ = env.step(env.action_space.sample())
        assert 0.0 <= reward <= 1.0
        steps += 1
    assert steps == 1000 and truncated and not terminated
    env.close()
