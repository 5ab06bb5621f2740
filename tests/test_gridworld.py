"""The Appendix G gridworld (``URLB/gridworld-v0``): start, moves, walls, observation, episode length, reward."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import sb3_cic  # noqa: F401  (registers the ids)
from sb3_cic.envs.gridworld import GridWorldEnv
from sb3_cic import CIC, DIAYN


def test_start_is_the_centre_and_the_observation_its_normalised_coordinates():
    env = gym.make("URLB/gridworld-v0")
    obs, info = env.reset(seed=0)
    np.testing.assert_array_equal(info["cell"], [5, 5])
    np.testing.assert_allclose(obs, [2 * 5 / 9 - 1] * 2, rtol=1e-6)
    assert obs.dtype == np.float32 and env.observation_space.contains(obs)
    assert env.unwrapped.size == 10 and env.unwrapped.episode_length == 20
    assert GridWorldEnv(size=7).start.tolist() == [3, 3]


@pytest.mark.parametrize("action, move", [
    ([0.9, 0.1], [1, 0]), ([-0.6, 0.5], [-1, 0]), ([0.2, 0.7], [0, 1]), ([0.3, -1.0], [0, -1]),
    ([0.7, -0.7], [1, 0]),  # a tie picks x
    ([0.49, -0.49], [0, 0]), ([0.0, 0.0], [0, 0]),  # the dead zone: stay
])
def test_the_larger_component_picks_the_move(action, move):
    env = GridWorldEnv()
    env.reset()
    _, reward, terminated, truncated, info = env.step(np.array(action, np.float32))
    np.testing.assert_array_equal(info["cell"], np.array([5, 5]) + move)
    assert reward == 0.0 and not terminated and not truncated


def test_moves_are_vectorised_like_the_step():
    env = GridWorldEnv()
    actions = np.random.default_rng(0).uniform(-1, 1, size=(200, 2))
    moves = env.move(actions)
    for action, move in zip(actions, moves):
        env.reset()
        env.step(action)
        np.testing.assert_array_equal(env.cell - env.start, move)
    # a uniform action stays with probability 1/4 (both components in the dead zone)
    stays = (env.move(np.random.default_rng(1).uniform(-1, 1, size=(20_000, 2))) == 0).all(axis=1).mean()
    assert stays == pytest.approx(0.25, abs=0.02)


def test_walls_stop_the_agent_and_episodes_end_by_truncation_after_20_steps():
    env = gym.make("URLB/gridworld-v0")
    env.reset(seed=0)
    cells, ends = [], []
    for _ in range(20):
        _, reward, terminated, truncated, info = env.step(np.array([-1.0, 0.0], np.float32))
        cells.append(info["cell"].tolist())
        ends.append((terminated, truncated))
        assert reward == 0.0
    assert cells[4] == [0, 5] and cells[-1] == [0, 5]  # five moves left to the wall, then it stays
    assert ends[-1] == (False, True) and not any(t or u for t, u in ends[:-1])
    unwrapped = env.unwrapped
    np.testing.assert_array_equal(unwrapped.cell_of(unwrapped.observe(np.array(cells))), cells)


@pytest.mark.parametrize("cls", [DIAYN, CIC])
def test_a_method_pretrains_on_the_gridworld(cls, tiny, recwarn):
    model = cls("MlpPolicy", "URLB/gridworld-v0", skill_dim=4, **tiny)
    model.learn(400)
    assert model.reward_free and model._n_updates == 100
    assert not [w for w in recwarn if "reward is ignored" in str(w.message)]  # a reward-free pre-training id
