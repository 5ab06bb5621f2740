"""Each speed change of the update leaves losses, rewards and parameters unchanged (to float tolerance).

The changes (timed by ``benchmarks/throughput.py --ablations``): fused Adam, no critic weight
gradients in the actor step, one foreach lerp for the target critic, and the fused CIC reward
(``test_cic.py::test_fused_update_equals_reward_then_update``).
"""

import copy

import torch as th
from stable_baselines3.common.utils import polyak_update

from sb3_cic import CIC


def pair(tiny):
    """Two CIC models with the same weights and one batch of their (shared) replay data."""
    a = CIC("MlpPolicy", "URLB/walker-v0", seed=0, **tiny)
    b = CIC("MlpPolicy", "URLB/walker-v0", seed=1, **tiny)
    a.learn(300)  # 200 random steps, then 50 updates: compare from a trained state
    b.policy.load_state_dict(a.policy.state_dict())
    b.reward_module.load_state_dict(a.reward_module.state_dict())
    for opt_a, opt_b in zip(optimizers(a), optimizers(b)):
        opt_b.load_state_dict(copy.deepcopy(opt_a.state_dict()))  # no shared step tensors
    hook, a.replay_buffer.relabel = a.replay_buffer.relabel, None
    data = a.replay_buffer.sample(32)
    a.replay_buffer.relabel = hook
    return a, b, data


def optimizers(model):
    return [model.actor.optimizer, model.critic.optimizer, model.reward_module.optimizer]


def run_updates(model, data, n=3):
    """``n`` full updates (reward module, critic, actor, target) on ``data`` with fixed noise."""
    out = []
    for i in range(n):
        th.manual_seed(i)
        relabelled = model._relabel(data)
        metrics = {**model._update(relabelled), **model._reward_metrics}
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
