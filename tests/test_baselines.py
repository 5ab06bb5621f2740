"""The eight URLB baselines: reward formulas on hand-made batches, pre-train / save / load / fine-tune
smoke runs on the point mass, and APS's task regression."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
import torch as th
import torch.nn.functional as F
from stable_baselines3.common.type_aliases import ReplayBufferSamples

import sb3_cic
from sb3_cic import APS, APSRegressionCallback
from sb3_cic.methods.aps import APSCritic, regress_task
from sb3_cic.rewards.aps import APSReward
from sb3_cic.rewards.apt import APTReward
from sb3_cic.rewards.base import RewardModule
from sb3_cic.rewards.diayn import DIAYNReward
from sb3_cic.rewards.disagreement import DisagreementReward
from sb3_cic.rewards.icm import ICMReward
from sb3_cic.rewards.proto import ProtoReward, sinkhorn_knopp
from sb3_cic.rewards.rnd import RNDReward
from sb3_cic.rewards.smm import SMMReward

STATE, ACT = 5, 3


def make_batch(n: int = 16, skill: th.Tensor | None = None, seed: int = 0) -> ReplayBufferSamples:
    """A hand-made batch: random states, actions in [-1, 1], ``skill`` appended to both observations."""
    g = th.Generator().manual_seed(seed)
    state, next_state = th.randn(n, STATE, generator=g), th.randn(n, STATE, generator=g)
    actions = th.rand(n, ACT, generator=g) * 2 - 1
    if skill is not None:
        state, next_state = th.cat([state, skill], 1), th.cat([next_state, skill], 1)
    zeros = th.zeros(n, 1)
    return ReplayBufferSamples(state, actions, next_state, zeros, zeros, th.ones(n, 1))


def one_hot(n: int, k: int, seed: int = 0) -> th.Tensor:
    index = th.randint(k, (n,), generator=th.Generator().manual_seed(seed))
    return F.one_hot(index, k).float()


def brute_knn(source: th.Tensor, target: th.Tensor, k: int) -> th.Tensor:
    """Sorted distances to the k nearest ``target`` rows, by explicit broadcasting."""
    dist = ((source[:, None, :] - target[None, :, :]) ** 2).sum(-1).sqrt()
    return dist.sort(dim=1).values[:, :k]


# reward formulas ---------------------------------------------------------------------------------
def test_icm_reward():
    module = ICMReward(STATE, ACT, hidden_dim=8)
    batch = make_batch()
    s, s2, a = batch.observations, batch.next_observations, batch.actions
    expected = th.log1p(th.linalg.norm(s2 - module.forward_net(th.cat([s, a], 1)), dim=1, keepdim=True))
    th.testing.assert_close(module.reward(batch), expected)
    inverse = th.linalg.norm(a - module.inverse_net(th.cat([s, s2], 1)), dim=1).mean()
    metrics = module.update(batch)
    assert metrics["icm_loss"].item() == pytest.approx(th.expm1(expected).mean().item() + inverse.item(), rel=1e-5)


def test_disagreement_reward():
    module = DisagreementReward(STATE, ACT, hidden_dim=8, n_models=5)
    batch = make_batch()
    x = th.cat([batch.observations, batch.actions], 1)
    e = module.ensemble
    preds = [th.relu(x @ e.w1[m] + e.b1[m]) @ e.w2[m] + e.b2[m] for m in range(5)]
    mean = sum(preds) / 5
    variance = sum((p - mean) ** 2 for p in preds) / 4  # unbiased, as torch.var
    th.testing.assert_close(module.reward(batch), variance.mean(dim=1, keepdim=True))
    reward, metrics = module.update_and_reward(batch)
    th.testing.assert_close(reward, variance.mean(dim=1, keepdim=True))
    loss = sum(th.linalg.norm(p - batch.next_observations, dim=1).mean() for p in preds) / 5
    assert metrics["disagreement_loss"].item() == pytest.approx(loss.item(), rel=1e-5)


def test_rnd_reward():
    module = RNDReward(STATE, ACT, hidden_dim=8, rep_dim=4)
    batch = make_batch(n=40)
    batch.next_observations[0] += 100.0  # an outlier: its normalised coordinates exceed the clip
    s2 = batch.next_observations
    x = (s2 - s2.mean(0)) / th.sqrt(s2.var(0, unbiased=False) + module.normalize.eps)
    assert x.abs().max() > 5
    x = x.clamp(-5, 5)
    error = ((module.target(x) - module.predictor(x)) ** 2).mean(dim=1, keepdim=True)
    count, n = 1e-4, 40  # RunningMeanStd from (mean 0, var 1, count 1e-4)
    var = (count + error.var() * n + error.mean() ** 2 * count * n / (count + n)) / (count + n)
    reward = module.reward(batch)
    th.testing.assert_close(module.error_rms.var.squeeze(), var.detach())
    th.testing.assert_close(reward, error / (var.sqrt() + 1e-8))


def test_apt_reward():
    module = APTReward(STATE, ACT, hidden_dim=8, rep_dim=6)
    batch = make_batch(n=20)
    rep = module.trunk(batch.next_observations)
    mean_knn = brute_knn(rep, rep, 12).mean(dim=1, keepdim=True)  # k = 12, self included, no rms, clip 0
    th.testing.assert_close(module.reward(batch), th.log(1 + mean_knn), atol=1e-4, rtol=1e-4)


def test_proto_reward_and_sinkhorn():
    module = ProtoReward(STATE, ACT, pred_dim=4, proj_dim=8, num_protos=6, queue_size=12, topk=3)
    batch = make_batch()
    reward = module.reward(batch)
    th.testing.assert_close(module.protos.weight.norm(dim=1), th.ones(6))
    z = F.normalize(module.predictor(batch.next_observations), dim=1)
    queue = module.queue
    assert int(module.queue_ptr) == 6 and th.all(queue[6:] == 0)
    assert all(th.isclose(row, z, atol=1e-6).all(dim=1).any() for row in queue[:6])  # candidates are batch embeddings
    th.testing.assert_close(reward, brute_knn(z, queue, 3)[:, 2:3], atol=1e-4, rtol=1e-4)

    q = sinkhorn_knopp(th.randn(16, 6), 3)
    th.testing.assert_close(q.sum(dim=1), th.ones(16))
    th.testing.assert_close(sinkhorn_knopp(th.zeros(16, 6)), th.full((16, 6), 1 / 6))
    skewed = sinkhorn_knopp(th.tensor([[5.0, 0.0]] * 8))  # every sample prefers prototype 0
    assert skewed[:, 1].mean() > 0.4  # equipartition moves mass to prototype 1
    before = module.predictor_target.weight.clone()
    metrics = module.update(batch)
    assert metrics["proto_loss"].item() > 0
    th.testing.assert_close(module.predictor_target.weight, before.lerp(module.predictor.weight, 0.05))


def test_proto_reward_of_a_queued_copy_is_exactly_zero():
    """A point with three exact copies of itself in the queue is at distance 0 from its 3rd nearest, as in URLB."""
    module = ProtoReward(STATE, ACT, pred_dim=16, proj_dim=8, num_protos=4, queue_size=64, topk=3)
    batch = make_batch(n=8)
    z = module.embed(batch.next_observations)
    with th.no_grad():
        module.queue.copy_(F.normalize(th.randn(64, 16, generator=th.Generator().manual_seed(3)), dim=1))
        module.queue[:12] = z.detach().repeat(2, 1)[:12]  # rows 0-3 of the batch queued three times (one is re-queued)
        module.queue[12:16] = z.detach()[:4]
        module.queue_ptr.fill_(40.0)  # the reward's own candidates land past the copies
    reward = module.reward(batch)
    assert th.equal(reward[:4], th.zeros(4, 1))
    th.testing.assert_close(reward, brute_knn(z, module.queue, 3)[:, 2:3], atol=1e-6, rtol=1e-6)


MODULES = {
    "icm": lambda: ICMReward(STATE, ACT, hidden_dim=8),
    "disagreement": lambda: DisagreementReward(STATE, ACT, hidden_dim=8),
    "rnd": lambda: RNDReward(STATE, ACT, hidden_dim=8, rep_dim=4),
    "apt": lambda: APTReward(STATE, ACT, hidden_dim=8, rep_dim=6),
    "proto": lambda: ProtoReward(STATE, ACT, pred_dim=4, proj_dim=8, num_protos=6, queue_size=12, topk=3),
    "diayn": lambda: DIAYNReward(STATE, ACT, skill_dim=16, hidden_dim=8),
    "aps": lambda: APSReward(STATE, ACT, skill_dim=10, hidden_dim=8),
}
# SMM is not among them: its fused path draws the VAE's noise once for the reward and the loss, as the reference
# does, where reward-then-update draws it twice (the same in distribution, not draw for draw)
SKILLS = {"diayn": lambda: one_hot(32, 16), "aps": lambda: F.normalize(th.randn(32, 10), dim=1)}


@pytest.mark.parametrize("name", sorted(MODULES))
def test_fused_update_and_reward_equals_reward_then_update(name):
    """Each module's ``update_and_reward`` (fused or the base class's) gives the reward and leaves the networks,
    running statistics and queues exactly where the base class's reward-then-update does."""
    th.manual_seed(0)
    fused = MODULES[name]()
    plain = copy.deepcopy(fused)
    skill = SKILLS[name]() if name in SKILLS else None
    for step in range(3):
        batch = make_batch(n=32, skill=skill, seed=step)
        th.manual_seed(step)
        r_fused, _ = fused.update_and_reward(batch)
        th.manual_seed(step)
        r_plain, _ = RewardModule.update_and_reward(plain, batch)
        th.testing.assert_close(r_fused, r_plain, atol=1e-5, rtol=1e-5)
    for key, value in plain.state_dict().items():
        th.testing.assert_close(fused.state_dict()[key], value, atol=1e-5, rtol=1e-5, msg=f"{name}: {key}")


def test_diayn_reward():
    skill = one_hot(16, 16)
    module = DIAYNReward(STATE, ACT, skill_dim=16, hidden_dim=8)
    batch = make_batch(skill=skill)
    logits = module.discriminator(batch.next_observations[:, :STATE])
    expected = [
        logits[i, int(skill[i].argmax())] - th.logsumexp(logits[i], 0) + math.log(16) for i in range(16)
    ]
    th.testing.assert_close(module.reward(batch), th.stack(expected)[:, None])


def test_smm_reward_sign():
    skill = one_hot(16, 4)
    module = SMMReward(STATE, ACT, skill_dim=4, hidden_dim=8, vae_hidden_dim=8, code_dim=3)
    batch = make_batch(skill=skill)
    th.manual_seed(123)
    reward = module.reward(batch)
    th.manual_seed(123)
    s2 = batch.next_observations[:, :STATE]
    h = module.vae.encoder(th.cat([s2, skill], 1))
    mu, logvar = module.vae.enc_mu(h), module.vae.enc_logvar(h)
    recon = module.vae.decoder(mu + th.randn(16, 3) * th.exp(0.5 * logvar))
    recon_error = ((recon - s2) ** 2).sum(dim=1, keepdim=True)
    log_q = F.log_softmax(module.discriminator(s2), dim=1)[th.arange(16), skill.argmax(1)][:, None]
    assert th.all(log_q < 0)
    th.testing.assert_close(reward, recon_error + math.log(4) + log_q)  # + log q(z|s'): not the reference's sign


def test_aps_reward():
    w = F.normalize(th.randn(16, 4, generator=th.Generator().manual_seed(3)), dim=1)
    module = APSReward(STATE, ACT, skill_dim=4, hidden_dim=8)
    batch = make_batch(skill=w)
    feats = module.phi_net(batch.next_observations[:, :STATE])
    dist = brute_knn(feats, feats, 12)
    running_mean = dist.mean() * dist.numel() / (dist.numel() + 1e-4)  # RunningMeanStd from count 1e-4
    entropy = th.log(1 + th.clamp_min(dist.mean(dim=1, keepdim=True) / running_mean - 1e-4, 0))
    sf = (F.normalize(feats, dim=1) * w).sum(dim=1, keepdim=True)
    th.testing.assert_close(module.reward(batch), entropy + sf, atol=1e-4, rtol=1e-4)
    loss = module.update(batch)["aps_loss"]
    assert loss.item() == pytest.approx(-sf.mean().item(), rel=1e-5)


def test_aps_critic_is_task_weighted_successor_features():
    from gymnasium import spaces

    critic = APSCritic(spaces.Box(-1, 1, (STATE + 4,)), spaces.Box(-1, 1, (ACT,)), hidden_dim=8, output_dim=4)
    obs, act = th.randn(6, STATE + 4), th.rand(6, ACT)
    psi1, psi2 = critic.successor_features(obs, act)
    assert psi1.shape == (6, 4)
    q1, q2 = critic(obs, act)
    th.testing.assert_close(q1, (psi1 * obs[:, STATE:]).sum(1, keepdim=True))
    th.testing.assert_close(q2, (psi2 * obs[:, STATE:]).sum(1, keepdim=True))
    th.testing.assert_close(critic.q1_forward(obs, act), q1)


# pre-train, save / load, fine-tune ---------------------------------------------------------------
SMALL = dict(policy_kwargs={"hidden_dim": 32}, batch_size=32, learning_starts=500, buffer_size=5000, seed=0)
EXTRA = {
    "ICM": {},
    "Disagreement": {},
    "RND": dict(rnd_rep_dim=16),
    "APT": dict(apt_rep_dim=16),
    "ProtoRL": dict(pred_dim=8, proj_dim=16, num_protos=16, queue_size=64),
    "DIAYN": {},
    "SMM": dict(vae_hidden_dim=16, code_dim=4),
    "APS": dict(regression_step=600),
}
METRICS = {
    "ICM": "icm_loss",
    "Disagreement": "disagreement_loss",
    "RND": "rnd_loss",
    "APT": "icm_loss",
    "ProtoRL": "proto_loss",
    "DIAYN": "diayn_loss",
    "SMM": "vae_loss",
    "APS": "aps_loss",
}


#: APS runs on the walker, whose dense task reward gives its fine-tuning regression a signal
ENVS = {name: ("URLB/point_mass-v0", "URLB/point_mass-reach-v0") for name in EXTRA} | {
    "APS": ("URLB/walker-v0", "URLB/walker-walk-v0")
}


@pytest.mark.parametrize("name", list(EXTRA))
def test_pretrain_save_load_finetune(name, tmp_path, recwarn):
    cls = getattr(sb3_cic, name)
    pretrain_env, task_env = ENVS[name]
    model = cls("MlpPolicy", pretrain_env, **SMALL, **EXTRA[name])
    model.learn(2000)
    assert model.reward_free and model._n_updates == 750
    model._update_metrics.record(model.logger)  # the updates' means since the last log dump
    metrics = {k: v for k, v in model.logger.name_to_value.items() if k.startswith("reward/")}
    assert f"reward/{METRICS[name]}" in metrics and all(np.isfinite(v) for v in metrics.values())

    path = tmp_path / f"{name}.zip"
    model.save(path)
    loaded = cls.load(path, env=pretrain_env)
    obs = np.random.default_rng(0).normal(size=(5, *model.observation_space.shape)).astype(np.float32)
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])
    obs_t, act_t = th.as_tensor(obs), th.as_tensor(model.predict(obs, deterministic=True)[0])
    for q, q_loaded in zip(model.critic(obs_t, act_t), loaded.critic(obs_t, act_t)):
        th.testing.assert_close(q, q_loaded, rtol=0, atol=0)
    state, state_loaded = model.reward_module.state_dict(), loaded.reward_module.state_dict()
    assert state.keys() == state_loaded.keys()
    assert all(th.equal(state[k], state_loaded[k]) for k in state)

    task = cls.load_pretrained(path, env=task_env, learning_starts=300)
    assert not task.reward_free and task.num_timesteps == 0
    assert all(th.equal(a, b) for a, b in zip(task.actor.parameters(), model.actor.parameters()))
    heads_kept = all(th.equal(a, b) for a, b in zip(task.critic.q1_net.parameters(), model.critic.q1_net.parameters()))
    assert heads_kept == (name == "ProtoRL")  # ProtoRL keeps the whole critic, the others the trunk
    assert all(th.equal(a, b) for a, b in zip(task.critic.trunk.parameters(), model.critic.trunk.parameters()))
    task.learn(1000)
    assert task._n_updates == 350
    if model.skill_prior is not None:
        assert task.finetune_skill is not None
        skill = task.env.env_method("get_skill")[0]
        np.testing.assert_array_equal(skill, task.finetune_skill)
        assert all(task.env.get_attr("fixed"))
        task.skill_prior.validate(task.finetune_skill)
    assert not [w for w in recwarn if "APS regression" in str(w.message)]  # APS regressed a real w


def test_aps_regression_recovers_linear_task():
    # walker states (24-d) give a well-conditioned phi (condition number ~10); the point mass's 4-d
    # states give ~4,000, and the float32 rounding of the stored rewards then tilts w on a subset
    model = APS("MlpPolicy", "URLB/walker-v0", **SMALL)
    model.learn(400)  # random steps only: fills the buffer
    buffer = model.replay_buffer
    n = buffer.pos
    w_true = F.normalize(th.randn(10, generator=th.Generator().manual_seed(7)), dim=0)
    with th.no_grad():
        phi = model.reward_module.phi(th.as_tensor(buffer.next_observations[:n, 0, : model.state_dim]))
    buffer.rewards[:n, 0] = (3.0 * phi @ w_true).numpy()  # reward of s' exactly linear in phi(s')
    callback = APSRegressionCallback(regression_step=0)
    callback.init_callback(model)
    w = callback.regress()
    assert abs(np.linalg.norm(w) - 1) < 1e-5
    assert float(np.dot(w, w_true.numpy())) > 0.99
    small = APSRegressionCallback(max_samples=50)  # a random subset of the stored transitions
    small.init_callback(model)
    assert float(np.dot(small.regress(), w_true.numpy())) > 0.99
    # the swapped system lstsq(r, phi) does not recover it in general; ours does on any exact data
    assert float(np.dot(regress_task(phi, phi @ w_true), w_true.numpy())) > 0.999


def test_smm_vae_stays_finite_on_large_states():
    """Quadruped's raw states reach |s| ~ 300: the VAE's ``exp(log var)`` must not overflow."""
    th.manual_seed(0)
    module = SMMReward(STATE, ACT, skill_dim=4, hidden_dim=8, vae_hidden_dim=150, code_dim=128)
    batch = make_batch(64, skill=one_hot(64, 4))
    scale = th.ones_like(batch.next_observations)
    scale[:, :STATE] = 400.0
    batch = batch._replace(observations=batch.observations * scale, next_observations=batch.next_observations * scale)
    for _ in range(50):
        reward, metrics = module.update_and_reward(batch)
        assert th.isfinite(reward).all() and th.isfinite(metrics["vae_loss"])
    assert all(th.isfinite(p).all() for p in module.parameters())
