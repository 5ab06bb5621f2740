"""SkillObservationWrapper and the skill priors."""

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_cic import envs  # noqa: F401
from sb3_cic.envs import SkillObservationWrapper
from sb3_cic.skills import OneHotSkillPrior, SphereSkillPrior, UniformSkillPrior


def make(prior=None, every=50):
    return SkillObservationWrapper(gym.make("URLB/point_mass-v0"), prior or UniformSkillPrior(3), resample_every=every)


def test_observation_is_state_then_skill():
    env = make()
    obs, _ = env.reset(seed=0)
    assert env.state_dim == 4 and env.skill_dim == 3
    assert obs.shape == (7,) and obs.dtype == np.float32
    np.testing.assert_array_equal(obs[4:], env.skill)
    assert env.observation_space.contains(obs)


def test_resample_cadence_and_reset():
    env = make(every=5)
    obs, _ = env.reset(seed=0)
    skills = [obs[4:].copy()]
    for _ in range(15):
        obs, *_ = env.step(env.action_space.sample())
        skills.append(obs[4:].copy())
    changes = [t for t in range(1, 16) if not np.array_equal(skills[t], skills[t - 1])]
    assert changes == [5, 10, 15]
    before = env.skill
    env.reset()
    assert not np.array_equal(before, env.skill)


def test_resample_only_at_reset_when_none():
    env = make(every=None)
    obs, _ = env.reset(seed=0)
    for _ in range(120):
        nxt, *_ = env.step(env.action_space.sample())
        np.testing.assert_array_equal(nxt[4:], obs[4:])


def test_fixed_mode_keeps_skill_across_steps_and_resets():
    env = make(every=2)
    env.reset(seed=0)
    z = np.array([0.1, 0.2, 0.3], dtype=np.float32)
    env.set_skill(z)
    assert env.fixed
    for _ in range(7):
        obs, *_ = env.step(env.action_space.sample())
        np.testing.assert_array_equal(obs[4:], z)
    obs, _ = env.reset()
    np.testing.assert_array_equal(obs[4:], z)
    env.set_fixed(False)
    env.step(env.action_space.sample())
    obs, *_ = env.step(env.action_space.sample())
    assert not np.array_equal(obs[4:], z)


def test_set_skill_through_vecenv():
    venv = DummyVecEnv([make, make])
    venv.reset()
    z = np.array([0.7, 0.7, 0.7], dtype=np.float32)
    venv.env_method("set_skill", z, True)
    obs, *_ = venv.step(np.zeros((2, 2), dtype=np.float32))
    np.testing.assert_array_equal(obs[:, 4:], np.stack([z, z]))
    assert venv.get_attr("fixed") == [True, True]
    assert all(np.array_equal(s, z) for s in venv.env_method("get_skill"))


@pytest.mark.parametrize(
    "prior, bad, message",
    [
        (UniformSkillPrior(3), np.zeros(4), "shape"),
        (UniformSkillPrior(3), np.array([0.5, 1.5, 0.5]), r"\[0.0, 1.0\]"),
        (OneHotSkillPrior(3), np.array([1.0, 1.0, 0.0]), "one-hot"),
        (SphereSkillPrior(3), np.array([0.5, 0.5, 0.0]), "unit norm"),
    ],
)
def test_bad_skill_raises_value_error(prior, bad, message):
    env = make(prior)
    env.reset(seed=0)
    before = env.skill
    with pytest.raises(ValueError, match=message):
        env.set_skill(bad)
    np.testing.assert_array_equal(env.skill, before)  # nothing lost


def test_priors_sample_in_support_and_grid():
    rng = np.random.default_rng(0)
    for prior in (UniformSkillPrior(64), OneHotSkillPrior(16), SphereSkillPrior(10)):
        for _ in range(20):
            prior.validate(prior.sample(rng))
    grid = UniformSkillPrior(64).grid(40)
    assert grid.shape == (40, 64)
    np.testing.assert_allclose(grid[:, 0], np.linspace(0, 1, 40), rtol=1e-6)
    assert np.all(grid == grid[:, :1])  # constant skills c * 1
    np.testing.assert_array_equal(OneHotSkillPrior(4).grid(), np.eye(4))
    np.testing.assert_allclose(np.linalg.norm(SphereSkillPrior(10).grid(5), axis=1), 1.0, rtol=1e-5)


def test_wrapper_rejects_non_flat_observations():
    with pytest.raises(ValueError, match="flat Box"):
        SkillObservationWrapper(_ImageEnv(), UniformSkillPrior(2))


class _ImageEnv(gym.Env):
    observation_space = gym.spaces.Box(0, 255, (8, 8, 3), dtype=np.uint8)
    action_space = gym.spaces.Box(-1, 1, (2,), dtype=np.float32)
