"""CIC: contrastive loss, particle reward, fused update, skill selection, learning on the point mass."""

import copy
import math

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from stable_baselines3.common.type_aliases import ReplayBufferSamples

import sb3_cic  # noqa: F401
from sb3_cic.envs import SkillObservationWrapper
from sb3_cic import CIC, SkillGridSweepCallback
from sb3_cic.rewards.base import RewardModule
from sb3_cic.rewards.cic import CICReward
from sb3_cic.rewards.particle import ParticleEntropy, knn_distances
from sb3_cic.skills import UniformSkillPrior


def batch(state_dim=3, skill_dim=2, n=8, seed=0):
    g = th.Generator().manual_seed(seed)
    obs = th.cat([th.randn(n, state_dim, generator=g), th.rand(n, skill_dim, generator=g)], 1)
    next_obs = th.cat([th.randn(n, state_dim, generator=g), obs[:, state_dim:]], 1)
    return ReplayBufferSamples(obs, th.zeros(n, 1), next_obs, th.zeros(n, 1), th.zeros(n, 1), th.ones(n, 1))


def test_contrastive_loss_hand_computed():
    module = CICReward(3, 1, skill_dim=2, hidden_dim=8, temperature=0.5)
    q = th.tensor([[1.0, 0.0], [0.0, 2.0], [3.0, 4.0]])
    k = th.tensor([[2.0, 0.0], [1.0, 1.0], [0.0, -1.0]])
    loss, accuracy = module.contrastive_loss(q, k)
    qn = [[x / math.hypot(*row) for x in row] for row in q.tolist()]
    kn = [[x / math.hypot(*row) for x in row] for row in k.tolist()]
    expected, correct = 0.0, 0
    for i in range(3):
        logits = [sum(a * b for a, b in zip(qn[i], kn[j])) / 0.5 for j in range(3)]
        expected += -(logits[i] - math.log(sum(math.exp(x) for x in logits))) / 3
        correct += int(max(range(3), key=lambda j: logits[j]) == i)
    assert loss.item() == pytest.approx(expected, rel=1e-6)
    assert accuracy.item() == pytest.approx(correct / 3)


def test_contrastive_loss_code_variant_hand_computed():
    """The reference code's loss: exp(1/T) subtracted from each row's denominator (clamped at 1e-6, plus 1e-6)."""
    module = CICReward(3, 1, skill_dim=2, hidden_dim=8, temperature=0.5, variant="code")
    q = th.tensor([[1.0, 0.0], [0.0, 2.0], [3.0, 4.0]])
    k = th.tensor([[2.0, 0.0], [1.0, 1.0], [0.0, -1.0]])
    loss, accuracy = module.contrastive_loss(q, k)
    qn = [[x / math.hypot(*row) for x in row] for row in q.tolist()]
    kn = [[x / math.hypot(*row) for x in row] for row in k.tolist()]
    expected = 0.0
    for i in range(3):
        logits = [sum(a * b for a, b in zip(qn[i], kn[j])) / 0.5 for j in range(3)]
        negatives = max(sum(math.exp(x) for x in logits) - math.exp(1 / 0.5), 1e-6)
        expected += -math.log(math.exp(logits[i]) / (negatives + 1e-6)) / 3
    assert loss.item() == pytest.approx(expected, rel=1e-6)
    paper, paper_accuracy = CICReward(3, 1, skill_dim=2, hidden_dim=8).contrastive_loss(q, k)
    assert loss.item() < paper.item() and accuracy == paper_accuracy
    with pytest.raises(ValueError, match="one of \\('paper', 'code'\\)"):
        CICReward(3, 1, skill_dim=2, hidden_dim=8, variant="Code")


def test_cic_code_variant_settings():
    model = CIC("MlpPolicy", "URLB/point_mass-v0", skill_dim=4, buffer_size=1024, cic_hidden_dim=8,
                policy_kwargs={"hidden_dim": 8}, cic_variant="code")
    rm = model.reward_module
    assert model.knn_k == 16 and rm.particle.k == 16 and rm.particle.divide_by == "var" and rm.variant == "code"
    paper = CIC("MlpPolicy", "URLB/point_mass-v0", skill_dim=4, buffer_size=1024, cic_hidden_dim=8,
                policy_kwargs={"hidden_dim": 8}, knn_k=5)
    assert paper.reward_module.particle.k == 5 and paper.reward_module.particle.divide_by == "mean"
    assert paper.cic_variant == "paper" and paper.reward_module.variant == "paper"
    with pytest.raises(ValueError, match="got 'Code'"):
        CIC("MlpPolicy", "URLB/point_mass-v0", cic_variant="Code")


def test_contrastive_loss_lower_for_aligned_pairs():
    module = CICReward(3, 1, skill_dim=16, hidden_dim=8)
    q = th.randn(64, 16, generator=th.Generator().manual_seed(0))
    aligned, acc_aligned = module.contrastive_loss(q, q + 0.05 * th.randn(64, 16))
    random, acc_random = module.contrastive_loss(q, th.randn(64, 16))
    assert aligned < random and acc_aligned > acc_random
    assert random.item() == pytest.approx(math.log(64), rel=0.15)


def test_knn_distances_match_brute_force():
    x = th.randn(50, 7, generator=th.Generator().manual_seed(1))
    d = knn_distances(x, x, 5)
    brute = (x[:, None] - x[None]).norm(dim=-1).sort(dim=1).values[:, :5]  # exact differences (cdist uses mm too)
    th.testing.assert_close(d, brute, atol=1e-4, rtol=1e-4)
    assert th.equal(d[:, 0], th.zeros(50))  # each point is its own nearest neighbour, at distance exactly 0


POINTS = [[0.0, 0.0], [1.0, 0.0], [0.0, 2.0], [3.0, 3.0], [1.0, 1.0]]


def hand_knn(points, k):
    """Each point's k smallest distances, ascending (the point itself first, at 0)."""
    return [sorted(math.dist(p, q) for q in points)[:k] for p in points]


def hand_running(values, stat):
    """URLB's RMS after one batch from (mean 0, var 1, pseudo-count 1e-4): the new mean or variance."""
    n0, n = 1e-4, len(values)
    mean = sum(values) / n
    var = sum((v - mean) ** 2 for v in values) / (n - 1)  # torch.var: unbiased
    if stat == "mean":
        return mean * n / (n0 + n)
    return (1.0 * n0 + var * n + mean**2 * n0 * n / (n0 + n)) / (n0 + n)


@pytest.mark.parametrize("divide_by", ["mean", "var"])
def test_particle_reward_hand_computed(divide_by):
    """URLB's PBE / the CIC code: each distance normalised, clipped and floored, then averaged, then log(1 + x)."""
    k, clip = 3, 0.5  # a clip large enough that flooring each distance differs from flooring the mean
    estimator = ParticleEntropy(k=k, avg=True, rms=True, clip=clip, divide_by=divide_by)
    reward = estimator(th.tensor(POINTS)).squeeze(1).tolist()
    knn = hand_knn(POINTS, k)
    m = hand_running([d for row in knn for d in row], divide_by)  # all k distances update the statistics
    expected = [math.log(1 + sum(max(d / m - clip, 0.0) for d in row) / k) for row in knn]
    assert reward == pytest.approx(expected, rel=1e-5)
    floored_after = [math.log(1 + max(sum(row) / k / m - clip, 0.0)) for row in knn]
    assert reward != pytest.approx(floored_after, rel=1e-3)  # the point's own 0 distance counts 0, not -clip
    plain = ParticleEntropy(k=k, avg=True, rms=False, clip=0.0)(th.tensor(POINTS)).squeeze(1).tolist()
    assert plain == pytest.approx([math.log(1 + sum(row) / k) for row in knn], rel=1e-5)


def test_particle_reward_kth_neighbour_hand_computed():
    """avg=False: the k-th distance alone is kept, and it alone updates the running mean (over 3 batches)."""
    k, clip = 3, 0.0005
    estimator = ParticleEntropy(k=k, avg=False, rms=True, clip=clip)
    g = th.Generator().manual_seed(0)
    n0, mean, var, count = 1e-4, 0.0, 1.0, 1e-4
    for scale in (1.0, 2.0, 0.5):
        points = (th.randn(16, 3, generator=g) * scale).double()
        reward = estimator(points).squeeze(1).tolist()
        kth = [row[-1] for row in hand_knn(points.tolist(), k)]
        n, batch_mean = len(kth), sum(kth) / len(kth)
        batch_var = sum((d - batch_mean) ** 2 for d in kth) / (n - 1)
        delta, total = batch_mean - mean, count + n
        var = (var * count + batch_var * n + delta**2 * count * n / total) / total
        mean, count = mean + delta * n / total, total
        assert reward == pytest.approx([math.log(1 + max(d / mean - clip, 0.0)) for d in kth], rel=1e-5)
    assert estimator.rms.mean.item() == pytest.approx(mean, rel=1e-5)
    assert estimator.rms.count.item() == pytest.approx(3 * 16 + n0)  # 16 k-th distances per batch, not 16 k


def test_particle_reward_larger_for_spread_states():
    g = th.Generator().manual_seed(0)
    spread = th.randn(256, 4, generator=g) * 3.0
    clustered = th.randn(256, 4, generator=g) * 0.1
    estimator = ParticleEntropy(k=12, rms=False)
    assert estimator(spread).mean() > estimator(clustered).mean()


def test_fused_update_equals_reward_then_update():
    """The speed change (one state_net pass for loss and reward) leaves rewards and updates unchanged."""
    fused = CICReward(3, 1, skill_dim=2, hidden_dim=16)
    plain = copy.deepcopy(fused)
    b = batch(n=32)
    r_fused, m_fused = fused.update_and_reward(b)
    r_plain, m_plain = RewardModule.update_and_reward(plain, b)
    th.testing.assert_close(r_fused, r_plain, atol=1e-6, rtol=1e-5)
    th.testing.assert_close(m_fused["contrastive_loss"], m_plain["contrastive_loss"])
    for a, p in zip(fused.parameters(), plain.parameters()):
        th.testing.assert_close(a, p, atol=1e-6, rtol=1e-5)


def test_cic_default_hyper_parameters():
    model = CIC("MlpPolicy", "URLB/walker-v0", buffer_size=1024, policy_kwargs={"hidden_dim": 32}, cic_hidden_dim=1024)
    assert model.skill_prior == UniformSkillPrior(64) and model.skill_resample_every == 50
    assert model.env.get_attr("resample_every") == [50]
    rm = model.reward_module
    shapes = lambda net: [(m.in_features, m.out_features) for m in net if isinstance(m, th.nn.Linear)]  # noqa: E731
    assert shapes(rm.state_net) == [(24, 1024), (1024, 1024), (1024, 64)]
    assert shapes(rm.pred_net) == [(128, 1024), (1024, 1024), (1024, 64)]
    assert shapes(rm.skill_net) == [(64, 1024), (1024, 1024), (1024, 64)]
    assert rm.temperature == 0.5 and rm.particle.k == 12 and rm.particle.clip == 0.0005 and rm.particle.use_rms
    assert rm.optimizer.param_groups[0]["lr"] == 1e-4
    assert model.reward_free and model.finetune_skill_choice == "sweep"
    one = CIC("MlpPolicy", "URLB/point_mass-v0", skill_dim=1, cic_embed_dim=16, buffer_size=1024, cic_hidden_dim=8)
    assert shapes(one.reward_module.skill_net) == [(1, 8), (8, 8), (8, 16)]
    assert shapes(one.reward_module.pred_net)[0] == (32, 8)


class SkillReward(gym.Wrapper):
    """Reward = 1 - |mean skill - 0.7|, read from the observation's skill part."""

    def step(self, action):
        obs, _, term, trunc, info = self.env.step(action)
        return obs, 1.0 - abs(float(obs[-2:].mean()) - 0.7), term, trunc, info


def test_grid_sweep_fixes_the_best_skill(tiny):
    env = SkillReward(SkillObservationWrapper(gym.make("URLB/point_mass-reach-v0"), UniformSkillPrior(2)))
    tiny["learning_starts"] = 1100
    model = CIC("MlpPolicy", env, skill_dim=2, reward_free=False, **tiny)
    sweep = SkillGridSweepCallback(sweep_steps=1100, window=100)
    model.learn(1300, callback=sweep)
    values = [float(z[0]) for z, _ in sweep.results]
    np.testing.assert_allclose(values, np.linspace(0, 1, 11), atol=1e-6)
    np.testing.assert_allclose(model.finetune_skill, [0.7, 0.7], atol=1e-6)
    assert model.env.get_attr("fixed") == [True]
    np.testing.assert_allclose(model.env.env_method("get_skill")[0], [0.7, 0.7], atol=1e-6)
    returns = [ret for _, ret in sweep.results]
    assert int(np.argmax(returns)) == 7 and returns[7] == pytest.approx(100.0)


def test_step_0_evaluation_uses_the_sweeps_first_candidate(tiny):
    """No skill is chosen at step 0, so the evaluation there takes the sweep's first candidate (sb3_cic.protocol)."""
    from sb3_cic.callbacks import URLBEvalCallback

    seen = []

    class Recording(URLBEvalCallback):
        def _evaluate(self):
            super()._evaluate()
            seen.append((self.num_timesteps, self.eval_env.env_method("get_skill")[0].copy()))

    env = SkillReward(SkillObservationWrapper(gym.make("URLB/point_mass-reach-v0"), UniformSkillPrior(2)))
    tiny["learning_starts"] = 1100
    model = CIC("MlpPolicy", env, skill_dim=2, reward_free=False, **tiny)
    evaluation = Recording("URLB/point_mass-reach-v0", eval_freq=1200, n_eval_episodes=1)
    model.learn(1300, callback=[SkillGridSweepCallback(sweep_steps=1100, window=100), evaluation])
    assert [step for step, _ in seen] == [0, 1200]
    np.testing.assert_allclose(seen[0][1], [0.0, 0.0])
    np.testing.assert_allclose(seen[1][1], [0.7, 0.7], atol=1e-6)


def test_fixed_choice_and_auto_sweep_on_finetune(tmp_path, tiny):
    model = CIC("MlpPolicy", "URLB/point_mass-v0", skill_dim=3, finetune_skill_choice="fixed", **tiny)
    model.learn(300)
    model.save(tmp_path / "pre")
    ft = CIC.load_pretrained(tmp_path / "pre", env="URLB/point_mass-reach-v0")
    ft.learn(250)
    np.testing.assert_allclose(ft.finetune_skill, 0.5)
    assert ft.env.get_attr("fixed") == [True]
    sweep = CIC.load_pretrained(tmp_path / "pre", env="URLB/point_mass-reach-v0", finetune_skill_choice="sweep",
                                learning_starts=500)
    sweep.learn(600)  # the paper's sweep is added by learn(): 5 candidates of 100 steps
    assert sweep.finetune_skill is not None and np.all(sweep.finetune_skill == sweep.finetune_skill[0])
    with pytest.raises(ValueError, match="finetune_skill_choice"):
        CIC("MlpPolicy", "URLB/point_mass-v0", finetune_skill_choice="best", **tiny)


def _cells_visited(positions: np.ndarray, bins: int = 20) -> int:
    """Cells of a ``bins x bins`` grid over the point-mass arena ([-0.3, 0.3]^2) that ``positions`` visit."""
    hist, *_ = np.histogram2d(positions[:, 0], positions[:, 1], bins=bins, range=[[-0.3, 0.3], [-0.3, 0.3]])
    return int((hist > 0).sum())


@pytest.mark.slow
def test_cic_learns_on_the_point_mass():
    """Short CIC pre-training with small networks on the point mass: the contrastive loss falls well
    below log(batch) and the mass covers more of the arena than under uniformly random actions.

    Small-study settings (skill_dim 8, batch 64, learning rate 1e-3, one update per step): at URLB's
    (skill 64, batch 1024, 1e-4, one update per 2 steps) the discriminator needs far more steps.
    """
    steps, batch = 6000, 64
    model = CIC("MlpPolicy", "URLB/point_mass-v0", skill_dim=8, policy_kwargs={"hidden_dim": 64}, batch_size=batch,
                buffer_size=steps, learning_starts=1000, train_freq=1, learning_rate=1e-3, cic_lr=1e-3, seed=0)
    model.learn(steps)
    buffer = model.replay_buffer
    buffer.relabel = None  # plain samples: measure the discriminator without training it
    with th.no_grad():
        loss = float(np.mean([model.reward_module._loss(buffer.sample(batch))[0].item() for _ in range(20)]))
    assert loss < 0.8 * math.log(batch), loss

    env = gym.make("URLB/point_mass-v0")
    env.reset(seed=0)
    env.action_space.seed(0)
    random_positions = []
    for _ in range(steps):
        obs, _, terminated, truncated, _ = env.step(env.action_space.sample())
        random_positions.append(obs[:2])
        if terminated or truncated:
            env.reset()
    cic_cells = _cells_visited(buffer.observations[:steps, 0, :2])
    random_cells = _cells_visited(np.array(random_positions))
    print(f"contrastive loss {loss:.3f} (log B {math.log(batch):.3f}), cells visited CIC {cic_cells} random {random_cells}")
    assert cic_cells > 2 * random_cells


def test_cic_networks_start_orthogonal_with_zero_bias():
    """As the CIC code (``utils.weight_init``) and URLB's other networks."""
    module = CICReward(24, 6, skill_dim=16, hidden_dim=32)
    linears = [m for m in module.modules() if isinstance(m, th.nn.Linear)]
    assert len(linears) == 9
    for layer in linears:
        w = layer.weight.detach()
        gram = w @ w.T if w.shape[0] <= w.shape[1] else w.T @ w
        th.testing.assert_close(gram, th.eye(min(w.shape)), atol=1e-5, rtol=0)
        assert layer.bias.abs().max() == 0


def test_particle_reward_of_identical_points_is_zero_not_nan():
    """A first batch of one repeated point: running mean 0; the floored divisor gives reward 0."""
    particle = ParticleEntropy(k=4)
    reward = particle(th.ones(8, 3))
    assert th.equal(reward, th.zeros(8, 1))


def test_cic_learns_from_the_first_step_without_nan(tiny):
    """learning_starts=0: the first updates sample batches of one or two repeated transitions."""
    model = CIC("MlpPolicy", "URLB/walker-v0", seed=0, **{**tiny, "learning_starts": 0})
    model.learn(20)
    params = [*model.policy.parameters(), *model.reward_module.parameters()]
    assert model._n_updates > 0 and all(th.isfinite(p).all() for p in params)
