"""TensorReplayBuffer: URLBReplayBuffer's batches bit for bit, seeded sampling, pickling, memory, use by a model."""

from __future__ import annotations

import pickle
from types import SimpleNamespace

import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3.common.type_aliases import ReplayBufferSamples

from sb3_cic import URLBDDPG, tensor_buffer
from sb3_cic.buffers import URLBReplayBuffer
from sb3_cic.study.checkpoint import RunFolder
from sb3_cic.tensor_buffer import STORAGE, TensorReplayBuffer

OBS_DIM, SKILL_DIM, ACTION_DIM = 5, 2, 2
#: float64 observations: both buffers store float32
SPACES = (spaces.Box(-np.inf, np.inf, (OBS_DIM,), np.float64), spaces.Box(-1, 1, (ACTION_DIM,), np.float32))


def make_buffers(buffer_size: int, **kwargs) -> tuple[URLBReplayBuffer, TensorReplayBuffer]:
    kwargs = {"device": "cpu", "skill_dim": SKILL_DIM, "gamma": 0.9, **kwargs}
    return URLBReplayBuffer(buffer_size, *SPACES, **kwargs), TensorReplayBuffer(buffer_size, *SPACES, **kwargs)


def steps(rng: np.random.Generator, n_envs: int, length: int):
    """``add`` arguments of ``n_envs`` envs: episodes ending in a termination or a time-limit truncation after
    a few steps, the skill resampled within episodes (the next observation then carries the new skill), rewards
    of mixed magnitudes (float64, as the envs give them)."""
    skills = rng.uniform(size=(n_envs, SKILL_DIM))
    for _ in range(length):
        obs = rng.normal(size=(n_envs, OBS_DIM))
        next_obs = rng.normal(size=(n_envs, OBS_DIM))
        obs[:, -SKILL_DIM:] = skills
        switch = rng.uniform(size=n_envs) < 0.3
        skills[switch] = rng.uniform(size=(int(switch.sum()), SKILL_DIM))
        next_obs[:, -SKILL_DIM:] = skills
        done = rng.uniform(size=n_envs) < 0.25
        truncated = done & (rng.uniform(size=n_envs) < 0.5)
        infos = [{"TimeLimit.truncated": bool(t)} if d else {} for d, t in zip(done, truncated, strict=True)]
        reward = rng.normal(size=n_envs) * 10.0 ** rng.integers(-2, 5, size=n_envs)
        action = rng.uniform(-1, 1, size=(n_envs, ACTION_DIM)).astype(np.float32)
        yield obs, next_obs, action, reward, done, infos


def assert_same_batch(expected: ReplayBufferSamples, got: ReplayBufferSamples) -> None:
    for field in ReplayBufferSamples._fields:
        a, b = getattr(expected, field), getattr(got, field)
        assert a.dtype == b.dtype and a.shape == b.shape, field
        assert th.equal(a, b), field


def index_sets(buffer: URLBReplayBuffer, rng: np.random.Generator) -> list[np.ndarray]:
    """Every stored index (so every index near the write position and near an episode end), the window
    around the write position, and a random batch with repeats."""
    size = buffer.size()
    around = np.arange(buffer.pos - buffer.n_steps - 1, buffer.pos + buffer.n_steps + 2)
    around = around % size if buffer.full else around[(around >= 0) & (around < size)]
    return [np.arange(size), around, rng.integers(0, size, size=64)]


@pytest.mark.parametrize(
    "buffer_size, n_envs, n_steps, handle_timeout_termination, host_views",
    [(13, 1, 3, True, True), (13, 1, 3, True, False), (7, 1, 1, True, True), (9, 1, 7, True, True),
     (4, 1, 5, True, True), (11, 2, 3, True, True), (11, 2, 3, True, False), (12, 1, 3, False, True)],
)
def test_same_batches_as_urlb_buffer_at_every_write_position(buffer_size, n_envs, n_steps, handle_timeout_termination,
                                                             host_views):
    """Both buffers hold the same steps; after each add (not full, full, wrapped around several times),
    ``_get_samples`` gives the same batches, bit for bit, for the same indices and envs. Without host views,
    ``add`` writes as off the CPU (a host cast, then a tensor copy)."""
    reference, buffer = make_buffers(buffer_size, n_envs=n_envs, n_steps=n_steps,
                                     handle_timeout_termination=handle_timeout_termination)
    if not host_views:
        buffer._host_views = None
    rng = np.random.default_rng(buffer_size * 10 + n_envs)
    rows = max(buffer_size // n_envs, 1)
    for t, step in enumerate(steps(rng, n_envs, 3 * rows + 5)):
        reference.add(*step)
        buffer.add(*step)
        assert (buffer.pos, buffer.full) == (reference.pos, reference.full)
        for k, inds in enumerate(index_sets(reference, rng)):
            np.random.seed(1000 * t + k)
            env_indices = np.random.randint(0, n_envs, size=inds.shape)  # what the reference draws
            np.random.seed(1000 * t + k)
            assert_same_batch(reference._get_samples(inds), buffer._get_samples(inds, env_indices=env_indices))
    assert reference.full and t + 1 > 2 * rows  # wrapped around
    for name in STORAGE:
        stored = getattr(buffer, name)
        assert isinstance(stored, th.Tensor) and th.equal(th.from_numpy(getattr(reference, name)), stored), name


def test_the_checked_batches_hold_the_cases_that_matter():
    """The stream of the first parity case holds truncations, terminations and skill switches, and its
    batches windows cut short by an episode end."""
    stream = list(steps(np.random.default_rng(131), 1, 44))
    done = np.array([step[4][0] for step in stream])
    truncated = np.array([step[5][0].get("TimeLimit.truncated", False) for step in stream])
    assert (done & truncated).any() and (done & ~truncated).any()
    assert any(np.any(step[0][0, -SKILL_DIM:] != step[1][0, -SKILL_DIM:]) for step in stream)
    reference, _ = make_buffers(13)
    for step in stream:
        reference.add(*step)
    discounts = reference._get_samples(np.arange(13)).discounts.squeeze(1).numpy()
    assert {round(float(d), 6) for d in discounts} == {0.9, 0.81, 0.729}  # windows of 1, 2 and 3 steps


def test_torch_indices_give_the_batch_of_numpy_indices():
    _, buffer = make_buffers(10)
    for step in steps(np.random.default_rng(0), 1, 14):
        buffer.add(*step)
    inds = np.array([0, 3, 3, 9, 4, 5])
    assert_same_batch(buffer._get_samples(inds), buffer._get_samples(th.as_tensor(inds)))


def test_storage_is_tensors_only():
    _, buffer = make_buffers(1000)
    big_arrays = [k for k, v in vars(buffer).items() if isinstance(v, np.ndarray) and v.size > OBS_DIM]
    assert not big_arrays
    assert buffer.observations.shape == (1000, 1, OBS_DIM) and buffer.observations.dtype == th.float32
    assert buffer.rewards.shape == buffer.dones.shape == buffer.timeouts.shape == (1000, 1)
    assert isinstance(buffer, URLBReplayBuffer) and buffer.relabel is None
    assert buffer.observation_space.dtype == np.float32


def test_unsupported_options_are_refused_as_by_urlb_buffer():
    with pytest.raises(ValueError, match="optimize_memory_usage"):
        TensorReplayBuffer(10, *SPACES, device="cpu", optimize_memory_usage=True)
    with pytest.raises(NotImplementedError, match="optimize_memory_usage"):
        TensorReplayBuffer(10, *SPACES, device="cpu", optimize_memory_usage=True, handle_timeout_termination=False)
    _, buffer = make_buffers(10)
    with pytest.raises(ValueError, match="empty"):
        buffer.sample(4)
    for step in steps(np.random.default_rng(0), 1, 3):
        buffer.add(*step)
    with pytest.raises(NotImplementedError, match="VecNormalize"):
        buffer.sample(4, env=object())


def filled(buffer: TensorReplayBuffer, n: int) -> TensorReplayBuffer:
    """``n`` steps whose first observation entry is the step number (a sampled batch shows its indices)."""
    for t, (obs, next_obs, action, reward, done, infos) in enumerate(steps(np.random.default_rng(0), buffer.n_envs, n)):
        obs[:, 0] = t
        buffer.add(obs, next_obs, action, reward, done, infos)
    return buffer


def sampled_steps(buffer: TensorReplayBuffer, batch_size: int) -> set[int]:
    return set(buffer.sample(batch_size).observations[:, 0].long().tolist())


def test_sample_draws_stored_transitions_uniformly_and_skips_the_relabel_hook():
    buffer = filled(TensorReplayBuffer(8, *SPACES, device="cpu"), 5)
    assert sampled_steps(buffer, 500) == set(range(5))  # not full: below the write position
    buffer = filled(TensorReplayBuffer(8, *SPACES, device="cpu"), 11)
    assert sampled_steps(buffer, 500) == set(range(3, 11))  # full: all rows, the oldest (at pos) included
    calls = []
    buffer.relabel = lambda samples: calls.append(samples) or samples
    batch = buffer.sample(16)
    assert not calls and batch.rewards.shape == batch.discounts.shape == (16, 1)
    two_envs = filled(TensorReplayBuffer(16, *SPACES, device="cpu", n_envs=2), 8)
    obs = two_envs.sample(500).observations
    assert {tuple(row) for row in obs.numpy()} == {tuple(row) for row in two_envs.observations.reshape(-1, OBS_DIM).numpy()}


def test_same_seed_same_samples_and_pickling_keeps_the_generator_state():
    np.random.seed(3)
    a = filled(TensorReplayBuffer(20, *SPACES, device="cpu"), 25)
    np.random.seed(3)
    b = filled(TensorReplayBuffer(20, *SPACES, device="cpu"), 25)
    np.random.seed(4)
    c = filled(TensorReplayBuffer(20, *SPACES, device="cpu"), 25)
    batches = [a.sample(16) for _ in range(3)]
    for batch in batches:
        assert_same_batch(batch, b.sample(16))
    assert not th.equal(batches[0].observations, c.sample(16).observations)

    a.relabel = lambda samples: samples
    restored = pickle.loads(pickle.dumps(a, protocol=pickle.HIGHEST_PROTOCOL))
    assert restored.relabel is None and a.relabel is not None
    assert (restored.pos, restored.full, restored.device) == (a.pos, a.full, th.device("cpu"))
    for name in STORAGE:
        assert th.equal(getattr(a, name), getattr(restored, name)), name
    assert th.equal(a._generator.get_state(), restored._generator.get_state())
    restored.device = "cpu"  # as SB3's load_replay_buffer does: the generator keeps its state
    for _ in range(3):
        assert_same_batch(a.sample(16), restored.sample(16))
    restored.add(*next(steps(np.random.default_rng(1), 1, 1)))  # the unpickled tensors are writable
    assert restored.pos == (a.pos + 1) % 20
    assert not th.equal(restored.observations[a.pos], a.observations[a.pos])
    large = TensorReplayBuffer(5000, *SPACES, device="cpu")
    blob = pickle.dumps(large, protocol=pickle.HIGHEST_PROTOCOL)
    assert len(blob) < 1.1 * large.transition_nbytes() * 5000  # each array once


def test_transition_bytes_equal_urlb_buffer_and_the_full_size_figures():
    reference, buffer = make_buffers(64, n_envs=2)
    assert buffer.transition_nbytes() == reference.transition_nbytes() == 4 * (2 * OBS_DIM + ACTION_DIM + 3)
    assert TensorReplayBuffer.memory_nbytes(64, OBS_DIM, ACTION_DIM) == 64 * buffer.transition_nbytes()
    quadruped = TensorReplayBuffer.memory_nbytes(2_000_000, 78 + 64, 12)
    walker = TensorReplayBuffer.memory_nbytes(2_000_000, 24 + 64, 6)
    assert (quadruped, walker) == (2_392_000_000, 1_480_000_000)
    assert quadruped < 80e9 / 10  # fits an 80 GB card many times over


def test_a_buffer_larger_than_the_available_memory_warns(monkeypatch):
    memory = SimpleNamespace(virtual_memory=lambda: SimpleNamespace(available=10_000))
    monkeypatch.setattr(tensor_buffer, "psutil", memory)
    with pytest.warns(UserWarning, match="GB on cpu, more than"):
        TensorReplayBuffer(1000, *SPACES, device="cpu")


def tiny_model(**kwargs) -> URLBDDPG:
    kwargs = {"policy_kwargs": {"hidden_dim": 16}, "buffer_size": 2000, "batch_size": 16, "learning_starts": 100,
              "seed": 0, "device": "cpu", **kwargs}
    return URLBDDPG("MlpPolicy", "URLB/point_mass-reach-v0", replay_buffer_class=TensorReplayBuffer, **kwargs)


def test_a_model_learns_with_it_and_its_buffer_round_trips(tmp_path):
    model = tiny_model()
    model.learn(300)
    buffer = model.replay_buffer
    assert isinstance(buffer, TensorReplayBuffer) and buffer.pos == 300 and model._n_updates > 0
    assert (buffer.n_steps, buffer.gamma, buffer.skill_dim) == (3, model.gamma, model.skill_dim)
    assert buffer.observations[:300].abs().sum() > 0 and buffer.actions[:300].abs().sum() > 0
    model.save_replay_buffer(tmp_path / "buffer")
    other = tiny_model(seed=1)
    other.load_replay_buffer(tmp_path / "buffer")
    loaded = other.replay_buffer
    assert type(loaded) is TensorReplayBuffer and loaded is not buffer
    assert (loaded.pos, loaded.full, loaded.device) == (buffer.pos, buffer.full, other.device)
    for name in STORAGE:
        assert th.equal(getattr(buffer, name), getattr(loaded, name)), name
    assert_same_batch(buffer.sample(32), loaded.sample(32))


def test_a_run_resumed_from_a_checkpoint_continues_as_the_uninterrupted_one(tmp_path):
    model = tiny_model(learning_starts=900)
    model.learn(1000)  # one episode: an episode boundary
    folder = RunFolder(tmp_path / "run")
    folder.start()
    folder.save_checkpoint(model, [], {"elapsed_s": 0.0})
    model.learn(200, reset_num_timesteps=False)
    resumed = folder.load_model(URLBDDPG, "URLB/point_mass-reach-v0", device="cpu")
    folder.restore(resumed, [])
    resumed.learn(200, reset_num_timesteps=False)
    assert isinstance(resumed.replay_buffer, TensorReplayBuffer) and resumed.num_timesteps == 1200
    assert th.equal(model.replay_buffer._generator.get_state(), resumed.replay_buffer._generator.get_state())
    for name in STORAGE:
        assert th.equal(getattr(model.replay_buffer, name), getattr(resumed.replay_buffer, name)), name
    for a, b in zip(model.policy.parameters(), resumed.policy.parameters(), strict=True):
        assert th.equal(a, b)
