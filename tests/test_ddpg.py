"""URLBDDPG: architecture, n-step targets, relabelling, learning, save/load/resume, errors."""

import pickle
import zipfile

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor
from torch import nn

import sb3_cic  # noqa: F401
from sb3_cic import CIC, URLBDDPG
from sb3_cic.buffers import URLBReplayBuffer
from sb3_cic.common.save_util import NETWORKS_ONLY_ENTRY, is_networks_only, networks_only

from method_classes import METHODS


def test_policy_layers_match_spec():
    model = URLBDDPG("MlpPolicy", "URLB/walker-walk-v0", buffer_size=1024)
    actor, critic = model.actor, model.critic
    kinds = [type(m) for m in [*actor.trunk, *actor.policy]]
    assert kinds == [nn.Linear, nn.LayerNorm, nn.Tanh, nn.Linear, nn.ReLU, nn.Linear, nn.Tanh]
    assert (actor.trunk[0].in_features, actor.trunk[0].out_features) == (24, 1024)
    assert (actor.policy[0].in_features, actor.policy[0].out_features) == (1024, 1024)
    assert (actor.policy[2].in_features, actor.policy[2].out_features) == (1024, 6)
    assert [type(m) for m in critic.trunk] == [nn.Linear, nn.LayerNorm, nn.Tanh]
    assert (critic.trunk[0].in_features, critic.trunk[0].out_features) == (24 + 6, 1024)
    for head in (critic.q1_net, critic.q2_net):
        assert [type(m) for m in head] == [nn.Linear, nn.ReLU, nn.Linear]
        assert (head[0].in_features, head[0].out_features, head[2].out_features) == (1024, 1024, 1)
    w = actor.policy[0].weight.detach()
    th.testing.assert_close(w @ w.T, th.eye(1024), atol=1e-4, rtol=0)  # orthogonal init
    assert actor.policy[0].bias.abs().max() == 0
    assert model.actor_target is model.actor  # URLB has no target actor
    # URLB hyper-parameters are the defaults
    assert (model.batch_size, model.tau, model.gamma, model.learning_starts, model.n_steps) == (1024, 0.01, 0.99, 4000, 3)
    assert model.train_freq.frequency == 2 and model.gradient_steps == 1
    assert model.actor.optimizer.param_groups[0]["lr"] == 1e-4 and model.critic.optimizer.param_groups[0]["lr"] == 1e-4
    np.testing.assert_allclose(model.action_noise._sigma, 0.2)
    assert model.exploration_clip == 0.3


def test_training_mode_of_actor_and_critic(tiny):
    policy = CIC("MlpPolicy", "URLB/walker-v0", **tiny).policy
    for mode in (True, False, True):
        policy.set_training_mode(mode)
        assert policy.training is mode
        assert all(m.training is mode for m in (*policy.actor.modules(), *policy.critic.modules()))
        assert not any(m.training for m in policy.critic_target.modules())  # always in evaluation mode


def test_nstep_target_on_hand_filled_buffer_with_skills():
    """Rewards 1..6; the first episode is truncated after 3 steps; skill = step index."""
    obs_space = spaces.Box(-np.inf, np.inf, (3,), np.float32)  # state 2 + skill 1
    act_space = spaces.Box(-1, 1, (1,), np.float32)
    buffer = URLBReplayBuffer(10, obs_space, act_space, device="cpu", n_steps=3, gamma=0.5, skill_dim=1)
    for t in range(6):
        obs = np.array([[t, 10 + t, t]], dtype=np.float32)
        next_obs = np.array([[t + 1, 11 + t, t + 1]], dtype=np.float32)  # next skill differs
        truncated = t == 2
        buffer.add(obs, next_obs, np.zeros((1, 1)), np.array([t + 1.0]), np.array([truncated]),
                   [{"TimeLimit.truncated": truncated}])
    s = buffer._get_samples(np.array([0, 1, 2, 3]))
    # t=0: 1 + .5*2 + .25*3 (episode ends at t=2, inclusive); bootstrap .5^3 from s_3
    # t=1: 2 + .5*3; bootstrap .5^2; t=2: 3, bootstrap .5; t=3: 4 + .5*5 (t=5 is the last stored: cut)
    np.testing.assert_allclose(s.rewards.squeeze(1).numpy(), [2.75, 3.5, 3.0, 4 + 2.5 + 0.25 * 6][:3] + [4 + 2.5 + 1.5])
    np.testing.assert_allclose(s.discounts.squeeze(1).numpy(), [0.125, 0.25, 0.5, 0.125])
    np.testing.assert_allclose(s.next_observations[:, 0].numpy(), [3, 3, 3, 6])
    assert s.dones.sum() == 0  # a truncation bootstraps
    # the next observation carries the skill of the observation
    np.testing.assert_array_equal(s.next_observations[:, -1].numpy(), s.observations[:, -1].numpy())
    np.testing.assert_array_equal(s.observations[:, -1].numpy(), [0, 1, 2, 3])


def test_critic_target_formula():
    model = URLBDDPG("MlpPolicy", "URLB/point_mass-reach-v0", policy_kwargs={"hidden_dim": 16}, buffer_size=500, batch_size=32,
                     learning_starts=0, exploration_clip=0.0, seed=0)
    model.learn(64)
    data = model.replay_buffer.sample(16)
    _, target_mean = model.critic_loss(data)
    with th.no_grad():
        next_action = model.actor(data.next_observations).clamp(-1 + 1e-6, 1 - 1e-6)
        q = th.min(*model.critic_target(data.next_observations, next_action))
        expected = data.rewards + (1 - data.dones) * data.discounts * q
    th.testing.assert_close(target_mean, expected.mean())


@pytest.mark.slow
def test_urlbddpg_learns_pendulum():
    """A short run with small networks clearly beats the random policy (well under 2 minutes)."""
    env = gym.make("Pendulum-v1")
    # URLB's update, with a higher learning rate and one update per step to fit the test's budget
    model = URLBDDPG("MlpPolicy", env, policy_kwargs={"hidden_dim": 64}, batch_size=128, learning_starts=1000,
                     buffer_size=20_000, learning_rate=5e-4, train_freq=1, seed=1)
    random_return = np.mean([sum(r for r in _random_episode(gym.make("Pendulum-v1"), s)) for s in range(5)])
    model.learn(8000)
    mean_return, _ = evaluate_policy(model, Monitor(gym.make("Pendulum-v1")), n_eval_episodes=5)
    assert mean_return > random_return + 500, (mean_return, random_return)


def _random_episode(env, seed):
    env.reset(seed=seed)
    env.action_space.seed(seed)
    done = False
    while not done:
        _, r, term, trunc, _ = env.step(env.action_space.sample())
        done = term or trunc
        yield r


def test_relabel_in_pretraining_and_extrinsic_in_finetuning(tmp_path, tiny):
    model = CIC("MlpPolicy", "URLB/walker-v0", skill_dim=4, seed=0, **tiny)
    model.learn(400)
    assert model.replay_buffer.relabel is not None
    th.manual_seed(0)
    np.random.seed(0)
    before = {k: v.clone() for k, v in model.reward_module.state_dict().items()}
    data = model.replay_buffer.sample(32)
    stored = model.replay_buffer.rewards  # the reward-free env stores zeros, and sample() returns them
    assert np.all(stored[: model.replay_buffer.size()] == 0) and data.rewards.abs().sum() == 0
    relabelled, metrics = model.replay_buffer.relabel(data)  # the hook the update step applies
    assert relabelled.rewards.abs().sum() > 0 and th.equal(relabelled.observations, data.observations)
    assert {"contrastive_loss", "intrinsic_reward_mean"} <= metrics.keys()
    after = model.reward_module.state_dict()
    assert any(not th.equal(before[k], after[k]) for k in before)  # the module was trained on the batch
    model.save(tmp_path / "pre")
    ft = CIC.load_pretrained(tmp_path / "pre", env="URLB/walker-stand-v0", learning_starts=100)
    assert ft.replay_buffer.relabel is None and not ft.reward_free and ft.replay_buffer.size() == 0
    ft.learn(150)
    data = ft.replay_buffer.sample(32)
    assert data.rewards.abs().sum() > 0  # extrinsic walker-stand rewards, n-step sums
    assert float(data.rewards.max()) <= 1 + 0.99 + 0.99**2 + 1e-5


def test_load_pretrained_keeps_actor_and_critic_trunk(tmp_path, tiny):
    model = CIC("MlpPolicy", "URLB/walker-v0", skill_dim=4, seed=0, **tiny)
    model.learn(300)
    model.save(tmp_path / "pre")
    ft = CIC.load_pretrained(tmp_path / "pre", env="URLB/walker-run-v0")
    for a, b in zip(model.actor.parameters(), ft.actor.parameters()):
        assert th.equal(a, b)
    for a, b in zip(model.critic.trunk.parameters(), ft.critic.trunk.parameters()):
        assert th.equal(a, b)
    assert not th.equal(model.critic.q1_net[0].weight, ft.critic.q1_net[0].weight)
    for a, b in zip(ft.critic.parameters(), ft.critic_target.parameters()):
        assert th.equal(a, b)
    assert len(ft.actor.optimizer.state) == 0 and len(ft.critic.optimizer.state) == 0  # fresh optimisers
    assert ft.num_timesteps == 0
    full = CIC.load_pretrained(tmp_path / "pre", env="URLB/walker-run-v0", finetune_critic="all")
    assert th.equal(model.critic.q1_net[0].weight, full.critic.q1_net[0].weight)
    with pytest.raises(ValueError, match="finetune_critic"):
        CIC.load_pretrained(tmp_path / "pre", env="URLB/walker-run-v0", finetune_critic="heads")


def test_save_load_resume(tmp_path, tiny):
    model = CIC("MlpPolicy", "URLB/point_mass-v0", skill_dim=3, seed=0, **tiny)
    model.learn(500)
    model.save(tmp_path / "model")
    model.save_replay_buffer(tmp_path / "buffer")
    loaded = CIC.load(tmp_path / "model", env="URLB/point_mass-v0")
    obs = np.random.default_rng(0).normal(size=(5, 7)).astype(np.float32)
    obs[:, 4:] = 0.3
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])
    for (k, a), (_, b) in zip(model.reward_module.state_dict().items(), loaded.reward_module.state_dict().items()):
        assert th.equal(a, b), k
    assert loaded.reward_module.particle.rms.count > 1  # running statistics restored
    opt_a, opt_b = model.reward_module.optimizer.state_dict(), loaded.reward_module.optimizer.state_dict()
    assert opt_a["state"][0]["step"] == opt_b["state"][0]["step"]
    assert loaded.critic.optimizer.state_dict()["state"][0]["step"] > 0
    loaded.load_replay_buffer(tmp_path / "buffer")
    assert loaded.replay_buffer.size() == model.replay_buffer.size()
    assert loaded.replay_buffer.relabel is not None
    loaded.learn(300, reset_num_timesteps=False)
    assert loaded.num_timesteps == 800


def test_replay_buffer_pickle_holds_no_networks(tiny):
    model = CIC("MlpPolicy", "URLB/point_mass-v0", skill_dim=3, **tiny)
    model.learn(250)
    blob = pickle.dumps(model.replay_buffer)
    assert b"CICReward" not in blob and b"torch.nn" not in blob
    assert pickle.loads(blob).relabel is None


def test_transition_bytes():
    walker = URLBDDPG("MlpPolicy", "URLB/walker-walk-v0", policy_kwargs={"hidden_dim": 8}, buffer_size=1024)
    cic = CIC("MlpPolicy", "URLB/walker-v0", policy_kwargs={"hidden_dim": 8}, buffer_size=1024)
    # float32: obs + next obs + action + reward + done + timeout
    assert walker.replay_buffer.transition_nbytes() == 4 * (24 * 2 + 6 + 3)
    assert cic.replay_buffer.transition_nbytes() == 4 * ((24 + 64) * 2 + 6 + 3)


def test_clear_errors_for_unsupported_spaces():
    with pytest.raises(ValueError, match="continuous"):
        URLBDDPG("MlpPolicy", "CartPole-v1")

    class ImageEnv(gym.Env):
        observation_space = spaces.Box(0, 255, (16, 16, 3), np.uint8)
        action_space = spaces.Box(-1, 1, (2,), np.float32)

    with pytest.raises(ValueError, match="flat state"):
        URLBDDPG("MlpPolicy", ImageEnv())
    with pytest.raises(ValueError, match="reward_free"):
        URLBDDPG("MlpPolicy", "URLB/walker-walk-v0", reward_free=True, buffer_size=1024)


def test_skill_size_mismatch_is_clear_error(tiny):
    from sb3_cic.envs import SkillObservationWrapper
    from sb3_cic.skills import UniformSkillPrior

    env = SkillObservationWrapper(gym.make("URLB/point_mass-v0"), UniformSkillPrior(5))
    with pytest.raises(ValueError, match="skill_dim 5"):
        CIC("MlpPolicy", env, skill_dim=3, **tiny)
    model = CIC("MlpPolicy", env, skill_dim=5, **tiny)  # an env already wrapped right is kept
    assert model.observation_space.shape == (9,)


def test_networks_only_snapshot_loads_with_fresh_optimisers(tmp_path, tiny):
    model = CIC("MlpPolicy", "URLB/walker-v0", skill_dim=4, seed=0, tensorboard_log=str(tmp_path / "tb"), **tiny)
    model.learn(300)
    model.save(tmp_path / "full.zip")
    small = networks_only(tmp_path / "full.zip", tmp_path / "networks.zip")
    with zipfile.ZipFile(small) as archive:
        names = archive.namelist()
        assert str(tmp_path).encode() not in archive.read("data")  # no local path in a snapshot to share
    with zipfile.ZipFile(tmp_path / "full.zip") as archive:
        assert str(tmp_path).encode() in archive.read("data")  # the full save keeps SB3's tensorboard_log
    assert "policy.pth" in names and "reward_module.pth" in names and not any("optimizer" in n for n in names)
    assert NETWORKS_ONLY_ENTRY in names and is_networks_only(small) and not is_networks_only(tmp_path / "full.zip")
    assert small.stat().st_size < (tmp_path / "full.zip").stat().st_size
    written = small.read_bytes()
    assert networks_only(small) == small and small.read_bytes() == written  # done once: left as it is
    with pytest.raises(ValueError):  # set_parameters is SB3's: the optimisers' states are missing objects
        model.set_parameters(small, exact_match=True)
    loaded = CIC.load(small, env="URLB/walker-v0")
    for a, b in zip(model.policy.state_dict().values(), loaded.policy.state_dict().values()):
        assert th.equal(a, b)
    for a, b in zip(model.reward_module.state_dict().values(), loaded.reward_module.state_dict().values()):
        assert th.equal(a, b)
    assert loaded.critic.optimizer.state_dict()["state"] == {}  # fresh
    task = CIC.load_pretrained(small, env="URLB/walker-stand-v0", learning_starts=100)
    assert all(th.equal(a, b) for a, b in zip(task.actor.parameters(), model.actor.parameters()))
    task.learn(150)
    with pytest.raises(ValueError):  # a missing network is still an error
        with zipfile.ZipFile(small) as src, zipfile.ZipFile(tmp_path / "broken.zip", "w") as dst:
            for name in src.namelist():
                if name != "reward_module.pth":
                    dst.writestr(name, src.read(name))
        CIC.load(tmp_path / "broken.zip", env="URLB/walker-v0")
    with zipfile.ZipFile(small) as src, zipfile.ZipFile(tmp_path / "older.zip", "w") as dst:  # written before the entry
        for name in src.namelist():
            if name != NETWORKS_ONLY_ENTRY:
                dst.writestr(name, src.read(name))
    assert is_networks_only(tmp_path / "older.zip")
    older = CIC.load(tmp_path / "older.zip", env="URLB/walker-v0")
    assert all(th.equal(a, b) for a, b in zip(older.actor.parameters(), model.actor.parameters()))


@pytest.mark.parametrize("cls", METHODS, ids=lambda cls: cls.__name__)
def test_a_finetuning_from_the_networks_only_snapshot_is_the_one_from_the_full_save(cls, tmp_path, tiny):
    # a study commits its pre-trainings' networks-only snapshots: a fine-tuning that starts from one elsewhere must
    # be the fine-tuning that the full save gives (fine-tuning starts fresh optimisers either way)
    model = cls("MlpPolicy", "URLB/point_mass-v0", seed=0, tensorboard_log=str(tmp_path / "tb"), **tiny)
    model.learn(400)
    model.save(tmp_path / "full.zip")
    networks_only(tmp_path / "full.zip", tmp_path / "networks.zip")
    tuned = []
    for name in ("full.zip", "networks.zip"):
        task = cls.load_pretrained(tmp_path / name, env="URLB/point_mass-reach-v0", seed=1, learning_starts=100,
                                   tensorboard_log=None)
        task.learn(300)
        tuned.append(task)
    full, small = tuned
    assert full._n_updates == small._n_updates > 0
    for part in ("policy", "reward_module"):
        a, b = getattr(full, part).state_dict(), getattr(small, part).state_dict()
        assert a.keys() == b.keys() and all(th.equal(a[k], b[k]) for k in a), part
    for part in ("actor", "critic"):
        a, b = getattr(full, part).optimizer.state_dict(), getattr(small, part).optimizer.state_dict()
        assert a["state"].keys() == b["state"].keys() and a["state"]
        assert all(th.equal(a["state"][i]["exp_avg"], b["state"][i]["exp_avg"]) for i in a["state"])
    assert (full.finetune_skill is None) == (small.finetune_skill is None)
    if full.finetune_skill is not None:
        np.testing.assert_array_equal(full.finetune_skill, small.finetune_skill)
