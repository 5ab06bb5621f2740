"""The SB3 contract: what an SB3 DDPG user does by habit works, or is refused in one clear line, for all eleven classes."""

import os
import subprocess
import sys
import tomllib
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3 import HerReplayBuffer
from stable_baselines3.common.callbacks import EvalCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.noise import OrnsteinUhlenbeckActionNoise
from stable_baselines3.common.torch_layers import FlattenExtractor
from stable_baselines3.common.utils import get_device

from sb3_cic.envs import SkillObservationWrapper, VecSkillObservation
from sb3_cic import APS, APT, CIC, DIAYN, ICM, MOSS, RND, SMM, Disagreement, ProtoRL, URLBDDPG, URLBReplayBuffer
from sb3_cic.policies import URLBActor

ALL = [URLBDDPG, CIC, ICM, Disagreement, RND, APT, ProtoRL, DIAYN, SMM, APS, MOSS]
SKILLED = [CIC, DIAYN, SMM, APS, MOSS]
SMALL = dict(policy_kwargs={"hidden_dim": 16}, batch_size=16, buffer_size=1000, learning_starts=20, seed=0)


def small(**overrides):
    kwargs = {**SMALL, **overrides}
    kwargs["policy_kwargs"] = {**SMALL["policy_kwargs"], **overrides.get("policy_kwargs", {})}
    return kwargs


class MatrixActionEnv(gym.Env):
    """A float64 observation and a (2, 2) Box action; reward -|action - 0.5|, 30-step episodes."""

    observation_space = spaces.Box(-1.0, 1.0, (3,), np.float64)
    action_space = spaces.Box(-1.0, 1.0, (2, 2), np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return self.np_random.uniform(-1, 1, 3), {}

    def step(self, action):
        assert action.shape == (2, 2)
        self.t += 1
        reward = -float(np.abs(action - 0.5).sum())
        return self.np_random.uniform(-1, 1, 3), reward, False, self.t >= 30, {}


def float64_pendulum():
    return gym.wrappers.DtypeObservation(gym.make("Pendulum-v1"), np.float64)


@pytest.mark.parametrize("cls", ALL)
def test_float64_observations_learn_predict_evaluate(cls):
    env = float64_pendulum()
    assert env.observation_space.dtype == np.float64
    model = cls("MlpPolicy", env, **small()).learn(40)
    assert model.replay_buffer.observations.dtype == np.float32  # cast once, when stored
    obs, _ = env.reset(seed=1)
    action, _ = model.predict(obs, deterministic=True)
    assert action.shape == (1,) and env.action_space.contains(action.astype(np.float32))
    mean, _ = evaluate_policy(model, env, n_eval_episodes=1, warn=False)
    assert np.isfinite(mean)


@pytest.mark.parametrize("cls", SKILLED)
def test_skill_methods_act_on_plain_observations(cls):
    env = gym.make("Pendulum-v1")
    model = cls("MlpPolicy", env, **small())
    z = model.skill_prior.grid(4)[1]
    model.set_skill(z)
    state, _ = env.reset(seed=0)
    states = np.stack([state, -state])
    augmented = np.concatenate([states, np.tile(z, (2, 1))], axis=1)
    for plain, full in ((states, augmented), (state, augmented[0])):
        np.testing.assert_array_equal(model.predict(plain, deterministic=True)[0], model.predict(full, deterministic=True)[0])
    # without an env the model appends the last set skill; once fine-tuning chose a skill, that one
    model.env = None
    np.testing.assert_array_equal(model.current_skill(), z)
    model.finetune_skill = model.skill_prior.grid(4)[2]
    np.testing.assert_array_equal(model.current_skill(), model.finetune_skill)


@pytest.mark.parametrize("cls", SKILLED)
def test_skill_methods_evaluate_on_the_plain_env(cls, tmp_path):
    eval_callback = EvalCallback(gym.make("Pendulum-v1"), n_eval_episodes=1, eval_freq=30, log_path=str(tmp_path), warn=False)
    model = cls("MlpPolicy", "Pendulum-v1", **small()).learn(60, callback=eval_callback)
    assert len(eval_callback.evaluations_results) == 2
    mean, _ = evaluate_policy(model, gym.make("Pendulum-v1"), n_eval_episodes=1, warn=False)
    assert np.isfinite(mean)


def test_a_skill_less_model_refuses_skills():
    model = URLBDDPG("MlpPolicy", "Pendulum-v1", **small())
    with pytest.raises(ValueError, match="has no skill"):
        model.current_skill()


def test_a_loaded_skill_model_without_env_asks_for_a_skill(tmp_path):
    CIC("MlpPolicy", "Pendulum-v1", **small()).save(tmp_path / "cic")
    model = CIC.load(tmp_path / "cic")
    with pytest.raises(ValueError, match="set_skill"):
        model.predict(np.zeros(3, dtype=np.float32))
    model.set_skill(np.full(64, 0.5))
    assert model.predict(np.zeros(3, dtype=np.float32))[0].shape == (1,)


@pytest.mark.parametrize("cls", SKILLED)
def test_skill_methods_take_a_vec_env_of_plain_envs(cls):
    venv = make_vec_env("Pendulum-v1", n_envs=2, seed=0)
    model = cls("MlpPolicy", venv, **small())
    assert isinstance(model.env, VecSkillObservation)
    assert model.observation_space.shape == (3 + model.skill_dim,)
    model.learn(60)
    assert model.replay_buffer.observations.shape[1:] == (2, 3 + model.skill_dim)
    z = model.skill_prior.grid(4)[1]
    model.env.env_method("set_skill", z, True)
    assert model.env.get_attr("fixed") == [True, True]
    assert all(np.array_equal(s, z) for s in model.env.env_method("get_skill"))
    assert all(model.env.env_is_wrapped(SkillObservationWrapper))


def test_vec_skill_observation_keeps_the_skill_of_an_ended_episode():
    from sb3_cic.skills import UniformSkillPrior

    venv = VecSkillObservation(make_vec_env("Pendulum-v1", n_envs=2, seed=0), UniformSkillPrior(2), resample_every=None)
    venv.seed(3)
    obs = venv.reset()
    skills = obs[:, 3:].copy()
    assert np.all((skills >= 0) & (skills <= 1))
    for _ in range(199):  # Pendulum's time limit is 200 steps
        obs, _, dones, infos = venv.step(np.zeros((2, 1)))
        np.testing.assert_array_equal(obs[:, 3:], skills)  # no resampling within the episode
    obs, _, dones, infos = venv.step(np.zeros((2, 1)))
    assert dones.all()
    for i, info in enumerate(infos):
        np.testing.assert_array_equal(info["terminal_observation"][3:], skills[i])
        np.testing.assert_array_equal(info["skill"], skills[i])
    assert not np.array_equal(obs[:, 3:], skills)  # a new episode, a new skill
    again = VecSkillObservation(make_vec_env("Pendulum-v1", n_envs=2, seed=0), UniformSkillPrior(2), resample_every=None)
    again.seed(3)
    np.testing.assert_array_equal(again.reset()[:, 3:], skills)  # seeded


def test_a_skill_model_refuses_vec_normalize_below_its_skill():
    from stable_baselines3.common.vec_env import VecNormalize

    with pytest.raises(ValueError, match="VecNormalize"):
        CIC("MlpPolicy", VecNormalize(make_vec_env("Pendulum-v1", n_envs=1)), **small())


@pytest.mark.parametrize("cls", ALL)
def test_policy_actor_and_critic_save_load_round_trip(cls, tmp_path):
    model = cls("MlpPolicy", "Pendulum-v1", **small(policy_kwargs={"n_critics": 3}))
    obs = th.as_tensor(np.random.default_rng(0).normal(size=(5, model.observation_space.shape[0])), dtype=th.float32)
    actions = th.zeros(5, 1)
    for net, net_class in ((model.policy, type(model.policy)), (model.actor, URLBActor), (model.critic, type(model.critic))):
        net.save(tmp_path / "net.pt")
        loaded = net_class.load(tmp_path / "net.pt")
        assert type(loaded) is type(net)
        assert loaded.state_dict().keys() == net.state_dict().keys()
        for key, value in net.state_dict().items():
            th.testing.assert_close(loaded.state_dict()[key], value)
    with th.no_grad():  # the last one loaded is the critic: three heads, the same values
        qs = loaded(obs, actions)
        assert len(qs) == 3
        for q, q_saved in zip(qs, model.critic(obs, actions)):
            th.testing.assert_close(q, q_saved)
    model.policy.save(tmp_path / "policy.pt")
    policy = type(model.policy).load(tmp_path / "policy.pt")
    np.testing.assert_array_equal(
        policy.predict(obs.numpy(), deterministic=True)[0], model.policy.predict(obs.numpy(), deterministic=True)[0]
    )


@pytest.mark.parametrize("cls", ALL)
def test_multi_dimensional_box_actions_are_flattened(cls):
    model = cls("MlpPolicy", MatrixActionEnv(), **small())
    assert model.actor.policy[-2].out_features == 4
    model.learn(50)
    assert model.replay_buffer.actions.shape[1:] == (1, 4)
    state = np.zeros(3)
    obs = state if model.skill_prior is None else np.concatenate([state, model.current_skill()])
    action, _ = model.predict(obs, deterministic=True)
    assert action.shape == (2, 2)


@pytest.mark.parametrize("cls", ALL)
def test_n_critics_is_honoured(cls):
    model = cls("MlpPolicy", "Pendulum-v1", **small(policy_kwargs={"n_critics": 3}))
    assert model.critic.n_critics == len(model.critic.q_networks) == 3
    assert [name for name, _ in model.critic.named_children()][-3:] == ["q1_net", "q2_net", "q3_net"]
    model.learn(40)
    assert len(cls("MlpPolicy", "Pendulum-v1", **small()).critic.q_networks) == 2  # URLB's default


def test_three_heads_give_the_minimum_of_three():
    model = URLBDDPG("MlpPolicy", "Pendulum-v1", **small(policy_kwargs={"n_critics": 3}))
    obs = th.randn(8, 3)
    with th.no_grad():
        th.manual_seed(0)
        loss = model.actor_loss(obs)
        th.manual_seed(0)
        noisy = model._noisy(model.actor(obs))
        expected = -th.stack(model.critic(obs, noisy)).min(dim=0).values.mean()
    th.testing.assert_close(loss, expected)


@pytest.mark.parametrize("cls", ALL)
def test_action_noise_replaces_the_exploration_noise(cls):
    noise = OrnsteinUhlenbeckActionNoise(np.zeros(1), 0.3 * np.ones(1))
    model = cls("MlpPolicy", "Pendulum-v1", action_noise=noise, **small())
    assert model.action_noise is noise
    model.learn(30)


class MyBuffer(URLBReplayBuffer):
    pass


@pytest.mark.parametrize("cls", ALL)
def test_replay_buffer_class_must_be_a_urlb_buffer(cls):
    assert isinstance(cls("MlpPolicy", "Pendulum-v1", replay_buffer_class=MyBuffer, **small()).replay_buffer, MyBuffer)
    with pytest.raises(ValueError, match="replay_buffer_class must subclass"):
        cls("MlpPolicy", "Pendulum-v1", replay_buffer_class=HerReplayBuffer, **small())


@pytest.mark.parametrize("cls", ALL)
@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"optimize_memory_usage": True}, "optimize_memory_usage"),
        ({"policy_kwargs": {"features_extractor_class": FlattenExtractor}}, "features_extractor_class"),
        ({"policy_kwargs": {"activation_fn": th.nn.ReLU}}, "activation_fn"),
        ({"policy_kwargs": {"net_arch": [64, 32]}}, "hidden_dim"),
        ({"policy_kwargs": {"hidden_dim": 0}}, "hidden_dim"),
        ({"policy_kwargs": {"n_critics": 0}}, "n_critics"),
        ({"n_steps": 0}, "n_steps"),
        ({"exploration_std": -0.2}, "exploration_std"),
        ({"exploration_clip": -0.3}, "exploration_clip"),
        ({"batch_size": 0}, "batch_size"),
        ({"batch_size": 2000}, "batch_size"),
        ({"buffer_size": 0}, "buffer_size"),
        ({"gamma": 1.5}, "gamma"),
        ({"tau": 2}, "tau"),
        ({"learning_rate": -1e-4}, "learning_rate"),
        ({"learning_starts": -1}, "learning_starts"),
        ({"train_freq": 0}, "train_freq"),
    ],
)
def test_bad_arguments_are_refused_at_construction(cls, kwargs, name):
    with pytest.raises(ValueError, match=name):
        cls("MlpPolicy", "Pendulum-v1", **small(**kwargs))


@pytest.mark.parametrize("cls", [c for c in ALL if c is not URLBDDPG and c is not ProtoRL])
@pytest.mark.parametrize("width", [0, -4, 2.5, "256"])
def test_reward_module_width_must_be_a_positive_int(cls, width):
    name = next(arg for arg, parameter in cls.reward_module_args.items() if parameter == "hidden_dim")  # MOSS: CIC's
    with pytest.raises(ValueError, match=f"{name} must be an int >= 1"):
        cls("MlpPolicy", "Pendulum-v1", **small(**{name: width}))


@pytest.mark.parametrize("cls", ALL)
def test_negative_total_timesteps_is_refused(cls):
    model = cls("MlpPolicy", "Pendulum-v1", **small())
    with pytest.raises(ValueError, match="total_timesteps"):
        model.learn(-5)
    assert model.num_timesteps == 0


@pytest.mark.parametrize("net_arch", [[24, 24], {"pi": [24, 24], "qf": [24, 24]}])
def test_sb3_net_arch_sets_the_width(net_arch):
    model = CIC("MlpPolicy", "Pendulum-v1", **{**small(), "policy_kwargs": {"net_arch": net_arch}})
    assert model.hidden_dim == model.policy.hidden_dim == 24
    assert model.actor.trunk[0].out_features == model.critic.trunk[0].out_features == 24
    assert model.reward_module.state_net[0].out_features == 24  # the reward networks follow the policy's width
    with pytest.raises(ValueError, match="net_arch says width 24, hidden_dim 16"):
        CIC("MlpPolicy", "Pendulum-v1", **small(policy_kwargs={"net_arch": net_arch}))


def test_import_without_a_display_is_silent():
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "DISPLAY", "WAYLAND_DISPLAY")}
    done = subprocess.run(
        [sys.executable, "-W", "error", "-c", "import os, sb3_cic; print(os.environ['MUJOCO_GL'])"],
        env=env, capture_output=True, text=True, timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert done.stderr == ""
    assert done.stdout.strip() in ("egl", "osmesa", "disable")


def test_license_is_an_spdx_expression():
    project = tomllib.loads((Path(__file__).parents[1] / "pyproject.toml").read_text())["project"]
    assert project["license"] == "MIT"  # a TOML table is deprecated by setuptools


@pytest.mark.parametrize("cls", SKILLED)
def test_set_env_wraps_a_plain_env(cls):
    model = cls("MlpPolicy", "Pendulum-v1", **small())
    model.set_env(gym.make("Pendulum-v1"))
    assert model.env.env_is_wrapped(SkillObservationWrapper) == [True]
    model.learn(10)


def test_the_policy_of_a_skill_model_refuses_state_only_observations(tmp_path):
    model = CIC("MlpPolicy", "Pendulum-v1", **small())
    model.policy.save(tmp_path / "policy.pt")
    for policy in (model.policy, type(model.policy).load(tmp_path / "policy.pt")):
        with pytest.raises(ValueError, match=r"\[state, skill\] observations \(3 \+ 64\).*model.predict"):
            policy.predict(np.zeros((2, 3), dtype=np.float32))
        assert policy.predict(np.zeros((2, 67), dtype=np.float32))[0].shape == (2, 1)


def test_load_compares_policy_kwargs_in_either_form(tmp_path):
    CIC("MlpPolicy", "Pendulum-v1", **{**small(), "policy_kwargs": {"hidden_dim": 24}}).save(tmp_path / "cic")
    assert CIC.load(tmp_path / "cic", policy_kwargs={"net_arch": [24, 24]}).hidden_dim == 24


class OldResetEnv(gym.Env):
    """An env whose ``reset`` takes no ``options`` (older Gymnasium code)."""

    observation_space = spaces.Box(-1.0, 1.0, (2,), np.float32)
    action_space = spaces.Box(-1.0, 1.0, (1,), np.float32)

    def reset(self, seed=None):
        return np.zeros(2, dtype=np.float32), {}

    def step(self, action):
        return np.zeros(2, dtype=np.float32), 0.0, False, False, {}


def test_skill_wrapper_passes_options_only_when_given():
    from sb3_cic.skills import UniformSkillPrior

    obs, _ = SkillObservationWrapper(OldResetEnv(), UniformSkillPrior(2)).reset(seed=0)
    assert obs.shape == (4,)


@pytest.mark.parametrize("cls", ALL)
def test_every_saved_tensor_is_floating_point(cls):
    """SB3's parameter tools (``get_parameters``/``set_parameters``, ``th.rand_like`` over them) assume it."""
    params = cls("MlpPolicy", "Pendulum-v1", **small()).learn(30).get_parameters()
    for name, state in params.items():
        if "optim" not in name:
            assert all(t.is_floating_point() for t in state.values()), name


@pytest.mark.parametrize("cls", ALL)
def test_save_load(cls, tmp_path):
    """SB3's ``test_save_load`` (``tests/test_save_load.py``): ``set_parameters`` refuses an invalid object, a
    missing object with ``exact_match`` (ValueError), a missing tensor (torch's RuntimeError); it sets what it is
    given and nothing else; save and load keep the parameters and the actions, on every device; learning goes on."""
    from collections import OrderedDict
    from copy import deepcopy

    from stable_baselines3.common.envs import IdentityEnvBox
    from stable_baselines3.common.vec_env import DummyVecEnv

    env = DummyVecEnv([lambda: IdentityEnvBox(-10, 10)])
    model = cls("MlpPolicy", env, reward_free=False, **small()).learn(60)
    env.reset()
    observations = np.concatenate([env.step([env.action_space.sample()])[0] for _ in range(10)], axis=0)
    original_params = deepcopy(model.get_parameters())

    invalid_object_params = {**deepcopy(original_params), "I_should_not_be_a_valid_object": "and_I_am_an_invalid_tensor"}
    for exact_match in (True, False):
        with pytest.raises(ValueError):
            model.set_parameters(invalid_object_params, exact_match=exact_match)
    missing_object_params = dict(list(original_params.items())[:-1])  # the last one is an optimiser's state
    with pytest.raises(ValueError):
        model.set_parameters(missing_object_params, exact_match=True)
    for name in original_params:  # any one object missing, network or optimiser
        with pytest.raises(ValueError):
            model.set_parameters({k: v for k, v in original_params.items() if k != name}, exact_match=True)
    missing_state_dict_tensor_params = {
        name: dict(list(state.items())[:-1]) for name, state in original_params.items()
    }
    with pytest.raises(RuntimeError):
        model.set_parameters(missing_state_dict_tensor_params, exact_match=True)

    random_params = {
        name: state if "optim" in name else OrderedDict((k, th.rand_like(v)) for k, v in list(state.items())[:-1])
        for name, state in original_params.items()
    }
    model.set_parameters(random_params, exact_match=False)
    new_params = model.get_parameters()
    for name, state in original_params.items():
        if "optim" in name:
            continue
        last_key = list(state)[-1]
        for key, value in state.items():
            assert th.allclose(value, new_params[name][key]) == (key == last_key), (name, key)

    params = new_params
    selected_actions, _ = model.predict(observations, deterministic=True)
    model.save(tmp_path / "test_save.zip")
    del model
    for device in ["auto", "cpu", "cuda"] if th.cuda.is_available() else ["auto", "cpu"]:
        model = cls.load(str(tmp_path / "test_save.zip"), env=env, device=device)
        assert model.device.type == get_device(device).type
        new_params = model.get_parameters()
        for name in new_params:
            if "optim" in name:
                continue
            for key in params[name]:
                assert th.allclose(params[name][key].cpu(), new_params[name][key].cpu()), (name, key)
        new_selected_actions, _ = model.predict(observations, deterministic=True)
        assert np.allclose(selected_actions, new_selected_actions, 1e-4)
        model.learn(60)

