"""SB3's ``MultiInputPolicy`` convention for Dict observations of state vectors (shimmy's ``dm_control/...`` ids):
the flattening order, the actions rescaled to [-1, 1], the errors, and save / load / fine-tuning through a shimmy
id."""

from __future__ import annotations

from collections import OrderedDict

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.vec_env import VecNormalize

import shimmy  # noqa: F401  (registers the dm_control/... ids with gymnasium)
from sb3_cic.envs import FlatStateDict
from sb3_cic.envs.dict_obs import state_dict_keys
from sb3_cic import CIC, URLBDDPG, URLBEvalCallback
from sb3_cic.common.env_util import make_env

import method_classes

METHODS = [URLBDDPG, *method_classes.METHODS]


class DictStates(gym.Env):
    """A Dict of a 3-vector ``b``, a scalar ``a`` and a 2-vector ``c`` (built from a plain dict: gymnasium sorts the
    keys), actions in the physics bounds [0, 2]; each step records the action it received."""

    def __init__(self, spaces_: dict | None = None) -> None:
        self.observation_space = spaces.Dict(spaces_ or {
            "b": spaces.Box(-np.inf, np.inf, (3,), np.float64),
            "a": spaces.Box(-np.inf, np.inf, (), np.float64),
            "c": spaces.Box(-np.inf, np.inf, (2,), np.float64),
        })
        self.action_space = spaces.Box(0.0, 2.0, (2,), np.float64)
        self.received: list[np.ndarray] = []
        self.t = 0

    def _obs(self) -> dict:
        return {"b": np.array([1.0, 2.0, 3.0]) + self.t, "a": np.array(0.5 + self.t), "c": np.array([-1.0, -2.0])}

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        super().reset(seed=seed)
        self.t = 0
        return self._obs(), {}

    def step(self, action: np.ndarray) -> tuple[dict, float, bool, bool, dict]:
        self.received.append(np.array(action))
        self.t += 1
        return self._obs(), 0.0, False, self.t >= 30, {}


def test_a_dict_is_flattened_in_its_key_order_scalars_as_one_value():
    env = FlatStateDict(DictStates())
    assert state_dict_keys(env.env.observation_space) == ["a", "b", "c"]  # gymnasium sorted the plain dict
    obs, _ = env.reset()
    np.testing.assert_array_equal(obs, [0.5, 1, 2, 3, -1, -2])
    assert obs.dtype == np.float32 and env.observation_space.shape == (6,) and env.observation_space.dtype == np.float32
    ordered = OrderedDict([("c", spaces.Box(-1, 1, (2,))), ("a", spaces.Box(-1, 1, ()))])  # an OrderedDict keeps its order
    np.testing.assert_array_equal(FlatStateDict(DictStates(ordered)).reset()[0], [-1, -2, 0.5])


def test_shimmy_walker_is_flattened_alphabetically_not_in_dm_controls_order():
    env = FlatStateDict(make_env("dm_control/walker-walk-v0"))  # (imports shimmy, which registers its ids)
    assert env.keys == ["height", "orientations", "velocity"]  # dm_control's own order: orientations, height, velocity
    obs, _ = env.reset(seed=0)
    physics = env.unwrapped._env.physics
    expected = np.concatenate([[physics.torso_height()], physics.orientations(), physics.velocity()])
    np.testing.assert_allclose(obs, expected.astype(np.float32), rtol=1e-6)


def test_actions_in_unit_range_are_rescaled_to_the_physics_bounds():
    inner = DictStates()
    env = FlatStateDict(inner)
    assert env.action_space == spaces.Box(-1.0, 1.0, (2,), np.float32)
    env.reset()
    for action in ([-1.0, 1.0], [0.0, 0.5], [-3.0, 3.0]):
        env.step(np.array(action, np.float32))
    np.testing.assert_allclose(inner.received, [[0.0, 2.0], [1.0, 1.5], [0.0, 2.0]])  # clipped to [-1, 1] first


def test_image_and_nested_entries_are_refused_in_one_line():
    image = {"pixels": spaces.Box(0, 255, (84, 84, 3), np.uint8), "state": spaces.Box(-1, 1, (3,))}
    with pytest.raises(ValueError, match=r"entry 'pixels' .* \(an image\)") as error:
        FlatStateDict(DictStates(image))
    assert "\n" not in str(error.value)
    with pytest.raises(ValueError, match="entry 'inner'"):
        FlatStateDict(DictStates({"inner": spaces.Dict({"x": spaces.Box(-1, 1, (1,))})}))
    with pytest.raises(ValueError, match="entry 'pixels'"):
        CIC("MultiInputPolicy", DictStates(image))


def test_mlp_policy_on_a_dict_answers_as_sb3_does(tiny):
    with pytest.raises(ValueError, match="You must use `MultiInputPolicy` when working with dict observation space"):
        CIC("MlpPolicy", "dm_control/walker-walk-v0", **tiny)
    with pytest.raises(ValueError, match="MultiInputPolicy"):
        URLBDDPG("MlpPolicy", DictStates(), **tiny)


@pytest.mark.filterwarnings("ignore:.*reward is ignored")
@pytest.mark.parametrize("cls", METHODS, ids=lambda cls: cls.__name__)
def test_every_method_takes_multi_input_policy(cls, tiny):
    tiny.update(learning_starts=40, batch_size=16, buffer_size=200)
    extra = {"regression_step": 60} if cls.__name__ == "APS" else {}
    model = cls("MultiInputPolicy", DictStates(), **tiny, **extra)
    assert model.multi_input and model.state_dim == 6 and model.action_space == spaces.Box(-1, 1, (2,), np.float32)
    model.learn(60)
    assert model._n_updates == 10


@pytest.mark.filterwarnings("ignore:.*reward is ignored")
def test_a_shimmy_id_trains_predicts_evaluates_saves_loads_and_finetunes_on_its_own_dict_observations(tiny, tmp_path):
    """SB3's habit on shimmy's ``dm_control/walker-walk-v0``: train with MultiInputPolicy, ``predict`` on the env's Dict
    observation, ``evaluate_policy`` on the env itself, save, load (with and without an env) and fine-tune."""
    tiny.update(learning_starts=100, buffer_size=1000)
    env = gym.wrappers.TimeLimit(make_env("dm_control/walker-walk-v0"), 20)  # (imports shimmy; short episodes)
    model = CIC("MultiInputPolicy", env, skill_dim=4, seed=0, **tiny).learn(200)
    assert model.state_dim == 24  # height 1, orientations 14, velocity 9 (alphabetical)
    raw_obs, _ = env.reset(seed=0)
    assert isinstance(raw_obs, dict) and raw_obs["velocity"].dtype == np.float64
    action, _ = model.predict(raw_obs, deterministic=True)
    assert action.shape == (6,) and env.action_space.contains(action)
    mean, _ = evaluate_policy(model, env, n_eval_episodes=1, warn=False)
    assert np.isfinite(mean)

    model.save(tmp_path / "cic_walker")
    path = tmp_path / "cic_walker"
    for loaded in (CIC.load(path, env="dm_control/walker-walk-v0"), CIC.load(path)):  # (without an env: the saved layout)
        assert loaded.multi_input and loaded.dict_layout.keys == ["height", "orientations", "velocity"]
        loaded.set_skill(model.current_skill())
        np.testing.assert_array_equal(loaded.predict(raw_obs, deterministic=True)[0], action)
    loaded = CIC.load(tmp_path / "cic_walker", env=env)
    assert loaded.wrap_env(env).observation_space == loaded.observation_space  # flat, with the skill
    loaded.learn(40, reset_num_timesteps=False)
    assert loaded.num_timesteps == 240

    task = CIC.load_pretrained(tmp_path / "cic_walker", env=env, learning_starts=20)
    evaluation = URLBEvalCallback(env, n_eval_episodes=1, eval_freq=10_000)
    task.learn(60, callback=evaluation)
    assert task.multi_input and not task.reward_free and task.finetune_skill is not None
    assert len(evaluation.history) == 1  # step 0, on the flattened eval env
    np.testing.assert_array_equal(task.predict(raw_obs)[0].shape, (6,))
    mean, _ = evaluate_policy(task, env, n_eval_episodes=1, warn=False)
    assert np.isfinite(mean)


@pytest.mark.filterwarnings("ignore:.*reward is ignored")
@pytest.mark.parametrize("cls", METHODS, ids=lambda cls: cls.__name__)
def test_make_vec_env_of_a_shimmy_id_trains_every_class(cls, tiny):
    tiny.update(learning_starts=20, batch_size=16, buffer_size=200, policy_kwargs={"hidden_dim": 16})
    venv = make_vec_env("dm_control/walker-walk-v0", n_envs=2, seed=0)
    model = cls("MultiInputPolicy", venv, **tiny).learn(40)
    assert model._n_updates > 0 and model.observation_space.shape == (24 + model.skill_dim,)
    actions, _ = model.predict(venv.reset(), deterministic=True)
    assert actions.shape == (2, 6)


@pytest.mark.filterwarnings("ignore:.*reward is ignored")
@pytest.mark.parametrize("cls", [URLBDDPG, CIC], ids=lambda cls: cls.__name__)
def test_vec_normalize_of_a_shimmy_id(cls, tiny):
    """SB3's ``VecNormalize`` over shimmy's Dict VecEnv (walker's 0-d ``height`` included): learn and evaluate."""
    tiny.update(learning_starts=20, batch_size=16, buffer_size=200, policy_kwargs={"hidden_dim": 16})
    make = lambda: gym.wrappers.TimeLimit(make_env("dm_control/walker-walk-v0"), 20)  # noqa: E731
    env = VecNormalize(make_vec_env(make, n_envs=2, seed=0))
    model = cls("MultiInputPolicy", env, **tiny).learn(60)  # episodes end at 40 (20 steps of 2 envs)
    stored = model.replay_buffer.next_observations[: model.replay_buffer.pos, :, 0]  # height, not normalised
    assert ((stored > 0.0) & (stored < 2.0)).all() and env.obs_rms["height"].count > 1
    mean, _ = evaluate_policy(model, env, n_eval_episodes=2, warn=False)
    assert np.isfinite(mean)
