"""The lean acting loop (``speed_options.lean_loop``, :class:`~sb3_cic.common.rollout.LeanRolloutMixin`) is SB3's.

With the same seed, ``learn`` with the switch on and off stores the same transitions, learns the same parameters,
counts the same steps and episodes, keeps the same episode statistics and calls the callbacks with the same
values; each lean part equals the SB3 form it replaces, and falls back to it where it does not apply.
"""

from __future__ import annotations

import copy
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.noise import NormalActionNoise
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_cic import CIC, URLBDDPG
from sb3_cic.common.rollout import ActorCall, copy_info, normal_noise, unit_rescale
from sb3_cic.speed import speed_options

#: the SB3 loop's local names that its callbacks read
SB3_LOCALS = ("actions", "buffer_actions", "new_obs", "rewards", "dones", "infos", "num_collected_steps",
              "num_collected_episodes", "continue_training", "idx", "done")


class ShortEpisodes(gym.Wrapper):
    """Episodes of ``length`` steps (a time-limit truncation) with an ``is_success`` info at their end, and a NaN in
    the observation of step ``nan_at`` (counted over all episodes)."""

    def __init__(self, env: gym.Env, length: int = 70, nan_at: int | None = None) -> None:
        super().__init__(env)
        self.length, self.nan_at, self.t, self.total = length, nan_at, 0, 0

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict]:
        self.t = 0
        return self.env.reset(**kwargs)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.t += 1
        self.total += 1
        if self.t == self.length:
            truncated = True
            info["is_success"] = bool(obs[0] > 0)
        if self.total == self.nan_at:
            obs = obs.copy()
            obs[-1] = np.nan
        return obs, reward, terminated, truncated, info


class Recorder(BaseCallback):
    """Records what each ``on_step`` sees, and stops training at ``stop_at`` env steps."""

    def __init__(self, stop_at: int | None = None) -> None:
        super().__init__()
        self.stop_at = stop_at
        self.seen: list[dict[str, Any]] = []
        self.names: set[str] = set()

    def _on_step(self) -> bool:
        self.names |= set(self.locals)
        infos = [{k: v for k, v in info.items() if k != "episode"} for info in self.locals["infos"]]
        self.seen.append({
            **{name: copy.deepcopy(self.locals[name]) for name in SB3_LOCALS if name in self.locals and name != "infos"},
            "infos": copy.deepcopy(infos),
            "num_timesteps": self.num_timesteps,
            "n_calls": self.n_calls,
        })
        return self.num_timesteps != self.stop_at


def run(cls: type, env_id: str, lean: bool, steps: int, tiny: dict, stop_at: int | None = None, nan_at: int | None = None,
        **kwargs: Any) -> tuple[Any, Recorder]:
    env = ShortEpisodes(gym.make(env_id), nan_at=nan_at)
    with speed_options.override(lean_loop=lean):
        model = cls("MlpPolicy", env, seed=5, **{**tiny, **kwargs})
        recorder = Recorder(stop_at)
        model.learn(steps, callback=recorder, log_interval=2)
    return model, recorder


def episodes(model: Any) -> list[dict]:
    return [{k: v for k, v in info.items() if k != "t"} for info in model.ep_info_buffer]  # "t": wall time


def assert_same(a: Any, b: Any) -> None:
    if isinstance(a, dict):
        assert a.keys() == b.keys()
        for key in a:
            assert_same(a[key], b[key])
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b)
        for x, y in zip(a, b):
            assert_same(x, y)
    elif isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and np.array_equal(a, b)
    else:
        assert type(a) is type(b) and a == b


def assert_same_runs(lean: tuple[Any, Recorder], sb3: tuple[Any, Recorder]) -> None:
    (a, ra), (b, rb) = lean, sb3
    assert a.num_timesteps == b.num_timesteps and a._episode_num == b._episode_num and a._n_updates == b._n_updates
    assert episodes(a) == episodes(b) and len(a.ep_info_buffer) > 2
    assert list(a.ep_success_buffer) == list(b.ep_success_buffer) and len(a.ep_success_buffer) > 2
    assert a._current_progress_remaining == b._current_progress_remaining
    for name in ("observations", "next_observations", "actions", "rewards", "dones", "timeouts"):
        assert np.array_equal(getattr(a.replay_buffer, name), getattr(b.replay_buffer, name)), name
    assert a.replay_buffer.pos == b.replay_buffer.pos
    assert np.array_equal(a._last_obs, b._last_obs)
    assert all(th.equal(p, q) for p, q in zip(a.policy.parameters(), b.policy.parameters()))
    assert len(ra.seen) == len(rb.seen) > 0
    assert_same(ra.seen, rb.seen)
    assert set(SB3_LOCALS) <= rb.names <= ra.names


@pytest.mark.parametrize("train_freq", [2, (1, "episode")])
def test_ddpg_learns_the_same_with_the_lean_loop(tiny, train_freq):
    runs = [run(URLBDDPG, "URLB/point_mass-reach-v0", lean, 500, tiny, train_freq=train_freq) for lean in (True, False)]
    assert_same_runs(*runs)
    assert runs[0][0]._n_updates > 0


@pytest.mark.parametrize("train_freq", [2, (2, "episode")])
def test_cic_learns_the_same_with_the_lean_loop(tiny, train_freq):
    """CIC: the skill wrapper resamples every 50 steps (inside the 70-step episodes) and at each reset."""
    runs = [run(CIC, "URLB/point_mass-v0", lean, 500, tiny, train_freq=train_freq) for lean in (True, False)]
    assert_same_runs(*runs)
    skills = {tuple(step["infos"][0]["skill"]) for step in runs[0][1].seen}
    assert len(skills) > len(runs[0][0].ep_info_buffer)  # resampled within episodes too


@pytest.mark.filterwarnings("ignore:rich is experimental")
@pytest.mark.parametrize("progress_bar", [False, True])
def test_learning_without_callback_is_the_same(tiny, progress_bar):
    """No callback (SB3's callback of none is not called) and the progress bar's callback list."""
    models = []
    for lean in (True, False):
        with speed_options.override(lean_loop=lean):
            model = URLBDDPG("MlpPolicy", ShortEpisodes(gym.make("URLB/point_mass-reach-v0")), seed=1, **tiny)
            models.append(model.learn(300, progress_bar=progress_bar))
    a, b = models
    assert a.num_timesteps == b.num_timesteps == 300 and episodes(a) == episodes(b)
    assert np.array_equal(a.replay_buffer.actions, b.replay_buffer.actions)
    assert np.array_equal(a.replay_buffer.next_observations, b.replay_buffer.next_observations)
    assert all(th.equal(p, q) for p, q in zip(a.policy.parameters(), b.policy.parameters()))


def test_the_policy_acts_in_evaluation_mode(tiny):
    model = URLBDDPG("MlpPolicy", "URLB/point_mass-reach-v0", gradient_steps=0, **tiny)
    model.learn(10)
    modules = [*model.policy.actor.modules(), *model.policy.critic.modules()]
    assert not model.policy.training and not any(m.training for m in modules)


def test_a_callback_stops_both_loops_at_the_same_step(tiny):
    runs = [run(URLBDDPG, "URLB/point_mass-reach-v0", lean, 500, tiny, stop_at=263) for lean in (True, False)]
    assert_same_runs(*runs)
    assert runs[0][0].num_timesteps == 263 and runs[0][0].replay_buffer.pos == 262  # the last step is not stored


def test_acting_with_the_policy_from_the_first_step_is_the_same(tiny):
    """``warmup_with_policy`` (a skill sweep's warm-up) and ``learning_starts=0``: the lean action from step 0."""
    runs = []
    for lean in (True, False):
        env = ShortEpisodes(gym.make("URLB/point_mass-v0"))
        with speed_options.override(lean_loop=lean):
            model = CIC("MlpPolicy", env, seed=2, **tiny)
            model.warmup_with_policy = True
            model.learn(150, callback=(recorder := Recorder()))
        runs.append((model, recorder))
    (a, _), (b, _) = runs
    assert np.array_equal(a.replay_buffer.actions[:150], b.replay_buffer.actions[:150])
    assert np.array_equal(a.replay_buffer.next_observations[:150], b.replay_buffer.next_observations[:150])


def test_a_non_finite_observation_is_the_same_error(tiny):
    messages = []
    for lean in (True, False):
        with pytest.raises(ValueError, match="non-finite observation at step 121") as error:
            run(URLBDDPG, "URLB/point_mass-reach-v0", lean, 300, tiny, nan_at=121)
        messages.append(str(error.value))
    assert messages[0] == messages[1]


# ------------------------------------------------------------------------------------------------
# the parts
def test_the_env_step_is_dummy_vec_envs(tiny):
    """Over episode ends: the same observations, rewards, dones and infos (``terminal_observation``,
    ``TimeLimit.truncated``, Monitor's ``episode``), and a fresh observation array each step."""
    from sb3_cic.common.rollout import _env_stepper, _single_env

    envs = [DummyVecEnv([lambda: Monitor(ShortEpisodes(gym.make("URLB/point_mass-reach-v0"), length=30))]) for _ in range(2)]
    for env in envs:
        env.seed(4)
        env.reset()
    lean = _env_stepper(envs[0], _single_env(envs[0]))
    actions = np.random.default_rng(0).uniform(-1, 1, (75, 1, 2)).astype(np.float32)
    previous = None
    for action in actions:
        got, expected = lean(action), envs[1].step(action)
        for x, y in zip(got[:3], expected[:3]):
            assert x.dtype == y.dtype and x.shape == y.shape and np.array_equal(x, y)
        strip = lambda infos: [{k: v for k, v in i.items() if k != "episode"} for i in infos]  # noqa: E731
        assert_same(strip(got[3]), strip(expected[3]))
        assert ("episode" in got[3][0]) == ("episode" in expected[3][0])
        assert got[0] is not previous and got[0].flags.owndata
        previous = got[0]
    monitors = [env.envs[0] for env in envs]
    assert monitors[0].get_episode_rewards() == monitors[1].get_episode_rewards()
    assert monitors[0].get_episode_lengths() == monitors[1].get_episode_lengths() == [30, 30]
    assert envs[0].actions is action


def test_a_replaced_env_step_is_called(tiny):
    model = URLBDDPG("MlpPolicy", "URLB/point_mass-reach-v0", **tiny)
    calls = []
    step = model.env.step
    model.env.step = lambda actions: calls.append(1) or step(actions)
    model.learn(20)
    assert len(calls) == 20


def test_a_subclass_with_its_own_store_transition_gets_it_called(tiny):
    class Counting(URLBDDPG):
        stored = 0

        def _store_transition(self, *args: Any) -> None:
            type(self).stored += 1
            super()._store_transition(*args)

    Counting("MlpPolicy", "URLB/point_mass-reach-v0", **tiny).learn(30)
    assert Counting.stored == 30


def test_sb3s_loop_runs_with_the_switch_off(tiny, monkeypatch):
    from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

    called = []
    original = OffPolicyAlgorithm.collect_rollouts
    monkeypatch.setattr(OffPolicyAlgorithm, "collect_rollouts", lambda *a, **k: called.append(1) or original(*a, **k))
    model = URLBDDPG("MlpPolicy", "URLB/point_mass-reach-v0", **tiny)
    model.learn(10)
    assert not called
    with speed_options.override(lean_loop=False):
        model.learn(10)
    assert len(called) == 5  # one rollout per two steps


def test_unit_rescale_is_sb3s_rescaling_on_unit_bounds():
    """SB3's ``unscale_action`` and ``scale_action`` on [-1, 1] float32 bounds, bit for bit, on the edge values
    and on a million float32 bit patterns (every float32 was checked once)."""
    low, high = np.full(1, -1, np.float32), np.full(1, 1, np.float32)
    edges = [-1, -0.75, -0.5, -0.25, -2.0**-24, -0.0, 0.0, 2.0**-30, 1e-38, 1e-45, 0.25, 0.5, 0.75, 1, 1.5, -3, 3,
             1e30, -1e30, 3.4e38, -3.4e38, np.inf, -np.inf, np.nan]
    x = np.concatenate([
        np.array(edges, np.float32),
        np.nextafter(np.array(edges[:14], np.float32), np.float32(2)),
        np.nextafter(np.array(edges[:14], np.float32), np.float32(-2)),
        np.random.default_rng(0).uniform(-1, 1, 500_000).astype(np.float32),
        np.random.default_rng(1).integers(0, 2**32, 500_000, dtype=np.uint64).astype(np.uint32).view(np.float32),
    ])
    with np.errstate(all="ignore"):
        lean = unit_rescale(x)
        for sb3 in (low + (0.5 * (x + 1.0) * (high - low)), 2.0 * ((x - low) / (high - low)) - 1.0):
            nan = np.isnan(sb3)
            assert sb3.dtype == lean.dtype == np.float32
            assert np.array_equal(nan, np.isnan(lean))
            assert np.array_equal(sb3[~nan].view(np.uint32), lean[~nan].view(np.uint32))


def test_the_normal_noise_is_sb3s_draw():
    """The same values from the same global generator; uneven or changed arrays: the noise's own call."""
    noise = NormalActionNoise(np.zeros(4), np.full(4, 0.2))
    draw = normal_noise(noise)
    assert draw is not noise
    np.random.seed(3)
    lean = [draw() for _ in range(50)]
    np.random.seed(3)
    sb3 = [noise() for _ in range(50)]
    assert all(x.dtype == y.dtype == np.float32 and np.array_equal(x, y) for x, y in zip(lean, sb3))
    noise._sigma[2] = 0.5  # changed in place: the noise's own call
    np.random.seed(4)
    changed = draw()
    np.random.seed(4)
    assert np.array_equal(changed, noise()) and np.std(changed) > 0
    assert normal_noise(None) is None
    uneven = NormalActionNoise(np.zeros(4), np.array([0.1, 0.2, 0.3, 0.4]))
    assert normal_noise(uneven) is uneven


def test_copy_info_is_deepcopy():
    skill = np.arange(3.0)
    info = {"task_reward": 0.5, "TimeLimit.truncated": False, "skill": skill, "n": np.int64(3), "none": None}
    copied = copy_info(info)
    assert_same(copied, copy.deepcopy(info))
    assert copied["skill"] is not skill
    nested = {"episode": {"r": 1.0}, "a": skill, "b": skill}
    assert_same(copy_info(nested), copy.deepcopy(nested))
    twice = copy_info({"a": skill, "b": skill})
    assert twice["a"] is twice["b"]  # deepcopy's memo: one array under two keys stays one


def test_the_actor_call_is_the_actors_forward(tiny):
    model = URLBDDPG("MlpPolicy", "URLB/point_mass-reach-v0", **tiny)
    actor = model.policy.actor
    call = ActorCall(actor)
    obs = th.randn(1, model.observation_space.shape[0])
    with th.no_grad():
        expected = actor(obs)
    assert call._ops is not None and call._current() and call._plain()  # the plain calls apply
    assert th.equal(call(obs), expected) and not call(obs).requires_grad
    seen = []
    handle = actor.trunk[0].register_forward_hook(lambda *args: seen.append(1))
    assert th.equal(call(obs), expected) and seen  # a hook: the module is called
    handle.remove()
    layer = actor.policy[2]
    layer.weight = th.nn.Parameter(th.zeros_like(layer.weight))  # a replaced parameter: read again
    with th.no_grad():
        assert th.equal(call(obs), actor(obs))
    assert th.equal(call(obs), th.tanh(layer.bias).expand(1, -1)) and call._ops is not None  # read again
    with speed_options.override(lean_forward=False):
        assert th.equal(call(obs), actor(obs))
    actor.policy.compile()  # a compiled module: called as a module (compiled at its first call)
    assert not call._current()
    call._read()
    assert call._ops is None


def test_a_saved_model_leaves_the_loops_cache_out(tiny, tmp_path):
    model = URLBDDPG("MlpPolicy", "URLB/point_mass-reach-v0", **tiny).learn(10)
    assert "_lean_rollout" in model.__dict__
    model.save(tmp_path / "model")
    loaded = URLBDDPG.load(tmp_path / "model", env="URLB/point_mass-reach-v0")
    assert "_lean_rollout" not in loaded.__dict__
    loaded.learn(10)
