"""SB3's Dict-observation contract, for all eleven classes: the Dict cases of SB3's own ``tests/test_dict_env.py``
(consistency with the flattened env, mixed Dict spaces, several processes, ``VecFrameStack``, ``VecNormalize``) and
``tests/test_spaces.py`` (float64 action spaces), in our words, on Dicts of state entries (the methods are
state-based: SB3's image entries are left out). Whatever the env returns is what ``predict`` and ``evaluate_policy``
take, for a single env or a VecEnv."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecFrameStack, VecNormalize

from sb3_cic import APS, APT, CIC, DIAYN, ICM, MOSS, RND, SMM, Disagreement, ProtoRL, URLBDDPG
from sb3_cic.common.env_util import FlatVecNormalize

ALL = [URLBDDPG, CIC, ICM, Disagreement, RND, APT, ProtoRL, DIAYN, SMM, APS, MOSS]
SKILLED = [CIC, DIAYN, SMM, APS, MOSS]
SMALL = dict(policy_kwargs={"hidden_dim": 16}, batch_size=16, buffer_size=250, learning_starts=20, gamma=0.5, seed=1)

pytestmark = pytest.mark.filterwarnings("ignore:.*reward is ignored")

VEC = spaces.Box(-1.0, 1.0, (2,), np.float32)
#: SB3's ``DummyDictEnv`` without its image: a vector and a Discrete entry
MIXED = {"vec": VEC, "discrete": spaces.Discrete(4)}
#: the other entries SB3's preprocessing one-hots or keeps as 0/1, and a 0-d Box (shimmy's walker ``height``)
MULTI = {"vec": VEC, "multi_discrete": spaces.MultiDiscrete([3, 2]), "multi_binary": spaces.MultiBinary(3),
         "height": spaces.Box(-np.inf, np.inf, (), np.float64)}


class DictEnv(gym.Env):
    """SB3's ``DummyDictEnv``: observations sampled from the Dict space (seeded by ``reset(seed=...)``), reward 0.

    :param entries: the Dict's entries
    :param action_space: the action space (default: a float32 Box in [-1, 1] of shape (2,))
    """

    def __init__(self, entries: dict | None = None, action_space: spaces.Box | None = None) -> None:
        self.observation_space = spaces.Dict(entries or MIXED)
        self.action_space = action_space or spaces.Box(-1.0, 1.0, (2,), np.float32)

    def reset(self, *, seed=None, options=None):
        if seed is not None:
            self.observation_space.seed(seed)
        return self.observation_space.sample(), {}

    def step(self, action):
        assert self.action_space.contains(np.asarray(action, dtype=self.action_space.dtype)), action
        return self.observation_space.sample(), 0.0, False, False, {}


def dict_env(entries: dict | None = None, steps: int = 50, **kwargs) -> gym.Env:
    return gym.wrappers.TimeLimit(DictEnv(entries, **kwargs), steps)


def act_with_a_set_skill(model: URLBDDPG, observation) -> np.ndarray:
    """The deterministic action for ``observation``, with the skill (if any) set to the same value for every model."""
    if model.skill_prior is not None:
        model.set_skill(model.skill_prior.grid(4)[1])
    return model.predict(observation, deterministic=True)[0]


@pytest.mark.parametrize("cls", ALL)
def test_consistency(cls):
    """A Dict model and an ``MlpPolicy`` model on gymnasium's ``FlattenObservation`` of the same env act alike, before
    and after learning: the same networks on the same flat vector (the Discrete entry one-hot in both)."""
    env_a, env_b = dict_env(steps=100), gym.wrappers.FlattenObservation(dict_env(steps=100))
    obs, _ = env_a.reset(seed=10)
    flat = spaces.flatten(env_a.observation_space, obs)
    models, before, after = [], [], []
    for policy, env, observation in (("MultiInputPolicy", env_a, obs), ("MlpPolicy", env_b, flat)):
        model = cls(policy, env, train_freq=8, **SMALL)  # (seeds the global generators: one model at a time)
        before.append(act_with_a_set_skill(model, observation))
        if model.skill_prior is not None:
            model.env.env_method("set_fixed", False)  # resampled again while learning
        after.append(act_with_a_set_skill(model.learn(120), observation))
        models.append(model)
    dict_model, flat_model = models
    assert dict_model._n_updates == flat_model._n_updates > 0
    np.testing.assert_allclose(*before, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(*after, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("cls", ALL)
@pytest.mark.parametrize("entries", [MIXED, MULTI], ids=["mixed", "multi"])
def test_dict_spaces(cls, entries):
    """Mixed Dict spaces: learn, ``predict`` on the env's own observation, ``evaluate_policy`` on the env; the
    one-hot entries are stored one-hot."""
    env = dict_env(entries)
    model = cls("MultiInputPolicy", env, **SMALL).learn(80)
    assert model.observation_space.shape == (spaces.flatdim(env.observation_space) + model.skill_dim,)
    stored = model.replay_buffer.observations[: model.replay_buffer.pos, 0]
    key, ones = ("discrete", 1) if entries is MIXED else ("multi_discrete", 2)  # (the keys sorted: discrete first)
    one_hot = stored[:, model.dict_layout.slices[key]]
    assert set(np.unique(one_hot)) <= {0.0, 1.0} and (one_hot.sum(axis=1) == ones).all()
    action, _ = model.predict(env.reset(seed=0)[0])
    assert action.shape == (2,) and env.action_space.contains(action)
    mean, _ = evaluate_policy(model, env, n_eval_episodes=2, warn=False)
    assert mean == 0.0


def make_dict_env() -> gym.Env:
    return dict_env(steps=30)


@pytest.mark.parametrize("cls", ALL)
def test_multiprocessing(cls):
    """A ``SubprocVecEnv`` of Dict envs: learn, and ``predict`` on its batch of Dict observations."""
    env = make_vec_env(make_dict_env, n_envs=2, vec_env_cls=SubprocVecEnv, vec_env_kwargs={"start_method": "fork"})
    try:
        model = cls("MultiInputPolicy", env, train_freq=5, **SMALL).learn(60)
        assert model.num_timesteps == 60 and model._n_updates > 0
        actions, _ = model.predict(env.reset(), deterministic=True)
        assert actions.shape == (2, 2)
    finally:
        env.close()


@pytest.mark.parametrize("cls", ALL)
@pytest.mark.parametrize("n_envs", [1, 2])
def test_dict_vec_framestack(cls, n_envs):
    """``VecFrameStack`` of a VecEnv of Dicts (SB3 stacks each entry): learn and evaluate on the stacked env."""
    entries = {"vec": spaces.Box(-1.0, 1.0, (5,), np.float32), "pos": spaces.Box(-1.0, 1.0, (1,), np.float32)}
    env = VecFrameStack(DummyVecEnv([lambda: dict_env(entries)] * n_envs), n_stack=3)
    model = cls("MultiInputPolicy", env, **SMALL).learn(80)
    assert model.observation_space.shape == (3 * 6 + model.skill_dim,)
    mean, _ = evaluate_policy(model, env, n_eval_episodes=2, warn=False)
    assert mean == 0.0


@pytest.mark.parametrize("cls", ALL)
def test_vec_normalize(cls):
    """``VecNormalize`` of a Dict VecEnv (the Box entries normalised, a 0-d one included, the Discrete one not): the
    replay buffer stores the original observations (an episode's last one too), batches are normalised with the
    VecNormalize's statistics, and evaluation works."""
    entries = {"vec": spaces.Box(10.0, 11.0, (2,), np.float32), "height": spaces.Box(10.0, 11.0, (), np.float64),
               "discrete": spaces.Discrete(4)}
    env = VecNormalize(DummyVecEnv([lambda: dict_env(entries, steps=30)]), norm_obs_keys=["height", "vec"])
    model = cls("MultiInputPolicy", env, **SMALL).learn(70)  # episodes end at steps 30 and 60
    view = model.get_vec_normalize_env()
    assert isinstance(view, FlatVecNormalize) and view.obs_rms is env.obs_rms
    buffer, (discrete, height, vec) = model.replay_buffer, view.layout.slices.values()  # (keys sorted), then the skill
    boxes = np.r_[height, vec]
    for stored in (buffer.observations[: buffer.pos, 0], buffer.next_observations[: buffer.pos, 0]):
        assert ((stored[:, boxes] >= 10.0 - 1e-4) & (stored[:, boxes] <= 11.0 + 1e-4)).all()  # not normalised
    original = env.get_original_obs()
    last = buffer.next_observations[buffer.pos - 1]  # the last step's (no episode ended there)
    np.testing.assert_allclose(last[:, vec], original["vec"])
    np.testing.assert_allclose(last[:, height], original["height"][:, None])
    np.testing.assert_array_equal(last[:, discrete], np.eye(4)[original["discrete"]])
    normalized = view.normalize_obs(last)
    np.testing.assert_allclose(normalized[:, vec], env.normalize_obs(original)["vec"], rtol=1e-5)
    assert (np.abs(normalized[:, boxes]) < 5.0).all()
    np.testing.assert_array_equal(np.delete(normalized, boxes, axis=1), np.delete(last, boxes, axis=1))  # one-hot, skill
    np.testing.assert_allclose(view.unnormalize_obs(normalized), last, rtol=1e-5, atol=1e-5)
    mean, _ = evaluate_policy(model, env, n_eval_episodes=1, warn=False)
    assert mean == 0.0


@pytest.mark.parametrize("cls", ALL)
@pytest.mark.parametrize("b", [VEC, spaces.Box(-1.0, 1.0, (2,), np.float64)], ids=["b32", "b64"])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_float64_action_space(cls, b, dtype):
    """``predict`` on the env's own Dict observation returns the env's action dtype."""
    action_space = spaces.Box(-1.0, 1.0, (2,), dtype)
    env = gym.wrappers.TimeLimit(DictEnv({"a": VEC, "b": b}, action_space=action_space), 200)
    model = cls("MultiInputPolicy", env, **{**SMALL, "learning_starts": 60}).learn(64)
    action, _ = model.predict(env.reset()[0], deterministic=False)
    assert action.dtype == env.action_space.dtype and env.action_space.contains(action)


@pytest.mark.parametrize("cls", SKILLED)
def test_skill_methods_add_their_skill_to_a_dict_observation(cls):
    """A skill method appends its current skill to a Dict observation as to a flat one; the action is mapped to the
    env's bounds as the training env maps it."""
    env = DictEnv(action_space=spaces.Box(0.0, 4.0, (2,), np.float64))
    model = cls("MultiInputPolicy", env, **SMALL)
    z = model.skill_prior.grid(4)[1]
    model.set_skill(z)
    model.env = None  # the last set skill
    single, _ = env.reset(seed=0)
    batch = {key: np.stack([value, env.observation_space[key].sample()]) for key, value in single.items()}
    for obs in (single, batch):
        flat = model.dict_layout.flatten(obs)
        full = np.concatenate([flat, np.broadcast_to(z, (*flat.shape[:-1], z.size))], axis=-1)
        unit, _ = model.predict(full, deterministic=True)
        action, _ = model.predict(obs, deterministic=True)
        np.testing.assert_allclose(action, 2.0 * (np.clip(unit, -1, 1) + 1.0), rtol=1e-6)


def test_image_entries_stay_refused_in_one_line():
    image = {"img": spaces.Box(0, 255, (36, 36, 1), np.uint8), "vec": VEC}
    with pytest.raises(ValueError, match=r"entry 'img' .* \(an image\)") as error:
        CIC("MultiInputPolicy", DictEnv(image), **SMALL)
    assert "\n" not in str(error.value)
    with pytest.raises(ValueError, match="entry 'img'"):
        URLBDDPG("MultiInputPolicy", make_vec_env(lambda: DictEnv(image), n_envs=2), **SMALL)
