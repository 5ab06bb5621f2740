"""The Fixed baseline (an intrinsic reward of 1 per step) and the episode ends it depends on: a terminated episode
is not bootstrapped, a truncated one is (Gym's Hopper-v5 terminates, DMC's hopper only truncates)."""

from __future__ import annotations

import warnings
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces

import sb3_cic
from sb3_cic.envs import RewardFree
from sb3_cic import Fixed, URLBDDPG, zoo
from sb3_cic.rewards.fixed import ConstantReward
from sb3_cic.tensor_buffer import TensorReplayBuffer


class ConstantTaskReward(gym.Wrapper):
    """The wrapped env with a reward of ``value`` at every step."""

    def __init__(self, env: gym.Env, value: float = -2.0) -> None:
        super().__init__(env)
        self.value = value

    def step(self, action: np.ndarray) -> tuple[Any, float, bool, bool, dict]:
        obs, _, terminated, truncated, info = self.env.step(action)
        return obs, self.value, terminated, truncated, info


def test_fixed_is_a_registered_method_without_skills():
    assert sb3_cic.Fixed is Fixed and zoo.get_algo("fixed") is Fixed and zoo.has_reward_module(Fixed)
    from sb3_cic.study.graph import all_methods, build_graph

    assert "fixed" not in all_methods()  # --methods all: URLB's methods, MOSS and DDPG
    runs = build_graph(["fixed"], ["hopper"], None, [0, 1], 0)  # --methods fixed --domains hopper --pretrain-seed 0
    assert [str(run) for run in runs] == ["pretrain fixed hopper", "fixed hopper_hop seed 0", "fixed hopper_hop seed 1"]
    probe = Fixed("MlpPolicy", None, _init_setup_model=False)
    assert probe.skill_prior is None and probe.fixed_reward == 1.0


def test_fixed_reward_is_one_in_pretraining_and_extrinsic_in_finetuning(tiny, tmp_path):
    model = Fixed("MlpPolicy", "URLB/point_mass-v0", seed=0, **tiny)
    model.learn(400)
    assert model.reward_free and model._n_updates == 100
    batch = model.replay_buffer.sample(64)
    relabelled, metrics = model.replay_buffer.relabel(batch)
    assert th.equal(relabelled.rewards, th.ones_like(batch.rewards))
    assert metrics["intrinsic_reward_mean"].item() == 1.0 and metrics["intrinsic_reward_std"].item() == 0.0
    model.save(tmp_path / "fixed")

    task_env = ConstantTaskReward(gym.make("URLB/point_mass-reach-v0"), value=-2.0)
    task = Fixed.load_pretrained(tmp_path / "fixed", env=task_env, learning_starts=100)
    task.learn(300)
    assert not task.reward_free and task.replay_buffer.relabel is None and task._n_updates == 100
    rewards = task.replay_buffer.sample(64).rewards
    assert th.all(rewards <= -2.0)  # the env's n-step sums (-2, -2 - 1.98, ...), never the intrinsic 1


def test_fixed_save_load_round_trip(tiny, tmp_path):
    model = Fixed("MlpPolicy", "URLB/point_mass-v0", seed=0, **tiny)
    model.learn(300)
    model.save(tmp_path / "fixed.zip")
    loaded = Fixed.load(tmp_path / "fixed.zip", env="URLB/point_mass-v0")
    assert isinstance(loaded.reward_module, ConstantReward) and loaded.reward_free and loaded.fixed_reward == 1.0
    obs = np.random.default_rng(0).normal(size=(5, 4)).astype(np.float32)
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])
    for a, b in zip(model.critic.parameters(), loaded.critic.parameters()):
        assert th.equal(a, b)
    assert loaded.actor.optimizer.state_dict()["state"].keys() == model.actor.optimizer.state_dict()["state"].keys()
    loaded.learn(200)  # and it trains on


class FallsOrTimesOut(gym.Env):
    """Episodes of 4 steps that alternately end by termination (a fall) and by truncation (a time limit); the
    observation is ``[episode, step]``."""

    observation_space = spaces.Box(-np.inf, np.inf, (2,), np.float32)
    action_space = spaces.Box(-1, 1, (1,), np.float32)

    def __init__(self) -> None:
        self.episode, self.t = -1, 0

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self.episode, self.t = self.episode + 1, 0
        return np.array([self.episode, 0], np.float32), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        self.t += 1
        end = self.t == 4
        falls = self.episode % 2 == 0
        return np.array([self.episode, self.t], np.float32), 1.0, end and falls, end and not falls, {}


@pytest.mark.parametrize("buffer_class", [None, TensorReplayBuffer])
def test_a_terminated_episode_is_not_bootstrapped_and_a_truncated_one_is(buffer_class, tiny):
    tiny["learning_starts"] = 1000  # no update: only the stored transitions matter
    model = URLBDDPG("MlpPolicy", FallsOrTimesOut(), replay_buffer_class=buffer_class, **tiny)
    model.learn(8)  # episode 0 falls at its 4th step (index 3), episode 1 times out at its 4th (index 7)
    gamma = model.gamma
    samples = model.replay_buffer._get_samples(np.array([0, 2, 3, 6, 7]))
    dones, discounts = samples.dones.flatten().tolist(), samples.discounts.flatten().tolist()
    assert dones == [0.0, 1.0, 1.0, 0.0, 0.0]  # the fall ends the return; the time limit bootstraps
    np.testing.assert_allclose(discounts, [gamma**3, gamma**2, gamma, gamma**2, gamma], rtol=1e-6)
    np.testing.assert_array_equal(samples.next_observations.numpy(), [[0, 3], [0, 4], [0, 4], [1, 4], [1, 4]])
    expected = [1 + gamma + gamma**2, 1 + gamma, 1, 1 + gamma, 1]
    np.testing.assert_allclose(samples.rewards.flatten().numpy(), expected, rtol=1e-6)


def test_gym_hopper_pretrains_reward_free_and_still_terminates(tiny):
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*reward is ignored")  # RewardFree: nothing to ignore
        Fixed("MlpPolicy", RewardFree(gym.make("Hopper-v5")), **tiny)
    with pytest.warns(UserWarning, match="reward is ignored"):
        Fixed("MlpPolicy", "Hopper-v5", **tiny)
    env = RewardFree(gym.make("Hopper-v5"))
    env.reset(seed=0)
    rewards, task_rewards, terminated = [], [], False
    for _ in range(1000):
        _, reward, terminated, truncated, info = env.step(np.ones(3, np.float32))  # full torque: it falls
        rewards.append(reward)
        task_rewards.append(info["task_reward"])
        if terminated or truncated:
            break
    assert terminated and len(rewards) < 1000
    assert set(rewards) == {0.0} and sum(task_rewards) != 0.0
