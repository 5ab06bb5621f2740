"""Each speed change of the update leaves losses, rewards and parameters unchanged (to float tolerance).

The changes (timed by ``benchmarks/throughput.py``, the older ones by its ``--ablations``): fused Adam,
no critic weight gradients in the actor step, one foreach lerp for the target critic, the fused CIC
reward (``test_cic.py::test_fused_update_equals_reward_then_update``), and the switches of
``sb3_cic.speed.speed_options``: the lean Adam step, the kNN selection by partition, lean acting, the
lean forward pass of :class:`~sb3_cic.speed.LeanSequential`.
"""

import copy

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.utils import polyak_update

from sb3_cic import CIC, URLBDDPG
from sb3_cic.rewards.particle import knn_distances
from sb3_cic.speed import FusedAdam, LeanSequential, speed_options


def pair(tiny):
    """Two CIC models with the same weights and one batch of their (shared) replay data."""
    a = CIC("MlpPolicy", "URLB/walker-v0", seed=0, **tiny)
    b = CIC("MlpPolicy", "URLB/walker-v0", seed=1, **tiny)
    a.learn(300)  # 200 random steps, then 50 updates: compare from a trained state
    b.policy.load_state_dict(a.policy.state_dict())
    b.reward_module.load_state_dict(a.reward_module.state_dict())
    for opt_a, opt_b in zip(optimizers(a), optimizers(b)):
        opt_b.load_state_dict(copy.deepcopy(opt_a.state_dict()))  # no shared step tensors
    data = a.replay_buffer.sample(32)  # the stored rewards: the relabel hook is the update step's
    return a, b, data


def optimizers(model):
    return [model.actor.optimizer, model.critic.optimizer, model.reward_module.optimizer]


def run_updates(model, data, n=3):
    """``n`` full updates (reward module, critic, actor, target) on ``data`` with fixed noise."""
    out = []
    for i in range(n):
        th.manual_seed(i)
        relabelled, reward_metrics = model._relabel(data)
        metrics = {**model._update(relabelled), **reward_metrics}
        out.append((relabelled.rewards, metrics))
    params = [p.detach() for p in [*model.policy.parameters(), *model.reward_module.parameters()]]
    return out, params


def assert_same(result_a, result_b):
    (steps_a, params_a), (steps_b, params_b) = result_a, result_b
    for (reward_a, metrics_a), (reward_b, metrics_b) in zip(steps_a, steps_b):
        th.testing.assert_close(reward_a, reward_b, atol=1e-6, rtol=1e-5)
        assert metrics_a.keys() == metrics_b.keys()
        for key in metrics_a:
            th.testing.assert_close(metrics_a[key], metrics_b[key], atol=1e-6, rtol=1e-5)
    assert len(params_a) == len(params_b)
    for p, q in zip(params_a, params_b):
        th.testing.assert_close(p, q, atol=1e-6, rtol=1e-5)


def test_fused_adam_is_default_and_matches_per_tensor_adam(tiny):
    fused, plain, data = pair(tiny)
    for opt in optimizers(fused):
        assert all(group["fused"] for group in opt.param_groups)
    for opt in optimizers(plain):  # torch's per-tensor implementation (its default on CPU)
        for group in opt.param_groups:
            group["fused"], group["foreach"] = False, False
    assert_same(run_updates(fused, data), run_updates(plain, data))


def test_frozen_critic_in_actor_step_changes_nothing(tiny):
    frozen, unfrozen, data = pair(tiny)
    assert frozen.freeze_critic_in_actor_step
    unfrozen.freeze_critic_in_actor_step = False
    assert_same(run_updates(frozen, data), run_updates(unfrozen, data))
    assert all(p.requires_grad for p in frozen.critic.parameters())


def test_foreach_target_update_equals_polyak_update(tiny):
    model, _, data = pair(tiny)
    expected = [p.detach().clone() for p in model.critic_target.parameters()]
    run_updates(model, data, n=1)
    polyak_update(model.critic.parameters(), expected, model.tau)
    for p, q in zip(model.critic_target.parameters(), expected):
        th.testing.assert_close(p, q, atol=1e-7, rtol=1e-6)


def assert_identical(result_a, result_b):
    """Bit for bit: rewards, metrics and parameters."""
    (steps_a, params_a), (steps_b, params_b) = result_a, result_b
    for (reward_a, metrics_a), (reward_b, metrics_b) in zip(steps_a, steps_b):
        assert th.equal(reward_a, reward_b)
        assert all(th.equal(metrics_a[key], metrics_b[key]) for key in metrics_a)
    assert all(th.equal(p, q) for p, q in zip(params_a, params_b))


def test_lean_adam_step_is_torchs_fused_adam_bit_for_bit(tiny):
    lean, plain, data = pair(tiny)
    assert all(isinstance(opt, FusedAdam) for opt in optimizers(lean))
    result_lean = run_updates(lean, data)
    with speed_options.override(lean_adam=False):
        result_plain = run_updates(plain, data)
    assert_identical(result_lean, result_plain)
    # the lean step keeps the counters as views of one vector; the state dict keeps torch's format and values
    for opt_a, opt_b in zip(optimizers(lean), optimizers(plain)):
        state_a, state_b = opt_a.state_dict()["state"], opt_b.state_dict()["state"]
        assert state_a.keys() == state_b.keys()
        for key in state_a:
            assert all(th.equal(state_a[key][name], state_b[key][name]) for name in ("step", "exp_avg", "exp_avg_sq"))


def test_lean_adam_falls_back_to_torch_where_it_does_not_apply():
    net = th.nn.Linear(3, 2)
    optimizer = FusedAdam(net.parameters(), lr=0.1)
    assert all(group["fused"] for group in optimizer.param_groups)
    assert optimizer._lean_groups() is not None  # no state yet: torch's first step creates it
    net.weight.grad, net.bias.grad = th.ones(2, 3), None
    assert optimizer._lean_groups() is None
    optimizer.step()  # torch's step (state created for the weight only)
    net.bias.grad = th.ones(2)
    assert optimizer._lean_groups() is None  # the bias has no state yet
    optimizer.step()  # torch's step: the first one of the bias
    assert optimizer._lean_groups() is not None
    steps = []
    for lean in (True, False, True):  # torch's own step on the views increments each counter once too
        with speed_options.override(lean_adam=lean):
            optimizer.step()
        steps.append([optimizer.state[p]["step"].item() for p in (net.weight, net.bias)])
    assert steps == [[3.0, 2.0], [4.0, 3.0], [5.0, 4.0]]
    hook = optimizer.register_step_pre_hook(lambda *args: None)
    assert optimizer._lean_groups() is None
    hook.remove()
    assert FusedAdam(net.parameters(), amsgrad=True)._lean_groups() is None
    with speed_options.override(lean_adam=False):
        assert optimizer._lean_groups() is None


@pytest.mark.parametrize("k", [1, 5, 16])
def test_knn_partition_selects_what_topk_selects(k):
    gen = th.Generator().manual_seed(k)
    x = th.randn(16, 4, generator=gen)
    x[8:12] = x[0]  # exact ties
    y = th.randn(10, 4, generator=gen)
    for source, target, kk in ((x, x, k), (x, y, min(k, 10))):
        fast = knn_distances(source, target, kk)
        with speed_options.override(knn_partition=False):
            assert th.equal(fast, knn_distances(source, target, kk))
    assert th.equal(knn_distances(x, x, 16)[:, 0], th.zeros(16))  # k = B: topk (nothing to partition)


def test_knn_partition_leaves_the_cic_update_unchanged(tiny):
    fast, plain, data = pair(tiny)
    result_fast = run_updates(fast, data)
    with speed_options.override(knn_partition=False):
        result_plain = run_updates(plain, data)
    assert_identical(result_fast, result_plain)


def test_lean_forward_leaves_the_cic_update_unchanged(tiny):
    lean, plain, data = pair(tiny)
    assert isinstance(lean.actor.trunk, LeanSequential) and isinstance(lean.reward_module.state_net, LeanSequential)
    result_lean = run_updates(lean, data)
    with speed_options.override(lean_forward=False):
        result_plain = run_updates(plain, data)
    assert_identical(result_lean, result_plain)


def test_lean_sequential_is_nn_sequential_bit_for_bit():
    """Outputs and gradients of every layer kind it shortcuts, an unknown layer, hooks honoured."""
    th.manual_seed(0)
    layers = [th.nn.Linear(5, 8), th.nn.LayerNorm(8), th.nn.Tanh(), th.nn.Linear(8, 8), th.nn.ReLU(inplace=True)]
    layers += [th.nn.Linear(8, 8), th.nn.ReLU(), th.nn.Sigmoid(), th.nn.Linear(8, 3)]
    lean, plain = LeanSequential(*layers), th.nn.Sequential(*copy.deepcopy(layers))
    assert lean.state_dict().keys() == plain.state_dict().keys()
    x = th.randn(16, 5)
    out_lean, out_plain = lean(x), plain(x)
    assert th.equal(out_lean, out_plain)
    out_lean.square().sum().backward()
    out_plain.square().sum().backward()
    assert all(th.equal(p.grad, q.grad) for p, q in zip(lean.parameters(), plain.parameters()))
    seen = []
    handle = lean[1].register_forward_hook(lambda module, inputs, output: seen.append(output.shape))
    assert th.equal(lean(x), out_plain) and seen == [(16, 8)]  # a layer with a hook is called as a module
    handle.remove()
    handle = th.nn.modules.module.register_module_forward_hook(lambda module, inputs, output: seen.append(type(module)))
    try:
        lean(x)
    finally:
        handle.remove()
    assert seen.count(th.nn.Linear) == 4  # global hooks: every layer called as a module


@pytest.mark.parametrize("cls, env_id", [(URLBDDPG, "URLB/walker-stand-v0"), (CIC, "URLB/walker-v0")])
def test_lean_acting_takes_the_same_actions(tiny, cls, env_id):
    """Same seed, lean acting on and off: the same transitions are stored and the same parameters learnt."""
    models = []
    for lean in (True, False):
        with speed_options.override(lean_acting=lean):
            model = cls("MlpPolicy", env_id, seed=3, **tiny)
            model.learn(300)  # 200 random steps, then the policy acts (with noise) and trains
        models.append(model)
    a, b = models
    n = a.replay_buffer.pos
    assert n == b.replay_buffer.pos == 300
    assert np.array_equal(a.replay_buffer.actions[:n], b.replay_buffer.actions[:n])
    assert np.array_equal(a.replay_buffer.observations[:n], b.replay_buffer.observations[:n])
    assert all(th.equal(p, q) for p, q in zip(a.policy.parameters(), b.policy.parameters()))
    assert a.policy.training  # lean acting leaves the policy in training mode; predict switches it off
    a.predict(a.observation_space.sample())
    assert not a.policy.training


def test_speed_options_override_restores_and_refuses_unknown_names():
    assert speed_options.lean_adam
    with speed_options.override(lean_adam=False):
        assert not speed_options.lean_adam
    assert speed_options.lean_adam
    with pytest.raises(ValueError, match="unknown speed option"):
        with speed_options.override(fast=True):
            pass


def test_training_mode_reaches_every_module_after_the_critic_is_replaced(tiny):
    model = URLBDDPG("MlpPolicy", "URLB/walker-stand-v0", **tiny)
    policy = model.policy
    policy.set_training_mode(False)  # lists the modules once
    policy.critic = model.critic = policy.make_critic()  # as load_pretrained(finetune_critic="none") does
    for mode in (False, True, False):
        policy.set_training_mode(mode)
        assert all(m.training == mode for m in (*policy.actor.modules(), *policy.critic.modules()))
    assert not any(m.training for m in policy.critic_target.modules())
