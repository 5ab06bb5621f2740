"""``compile_update``: the update step compiled as one graph, equal to the eager step.

* No graph break: every method's step, in pre-training and in fine-tuning, traces as one graph
  (``fullgraph=True``, and dynamo counts no break; the fine-tuning step through dynamo's own backend, which
  compiles nothing, to keep this fast).
* Equivalence: 20 updates from the same state, eager against compiled, give the same parameters, optimiser
  states, reward-module state and intrinsic rewards to float rounding: all eleven methods through AOTAutograd
  (``aot_eager``: the traced forward and backward graphs, run eagerly), DDPG and CIC through inductor, the
  default backend (its random numbers drawn as eager's, ``fallback_random``).
"""

import copy

import numpy as np
import pytest
import torch as th
import torch._dynamo
import torch._inductor.config
from stable_baselines3.common.logger import KVWriter, Logger
from torch._dynamo.utils import counters

import sb3_cic
from sb3_cic.common.fast_update import UpdateMetrics
from sb3_cic.tensor_buffer import TensorReplayBuffer

NAMES = ["URLBDDPG", "CIC", "ICM", "Disagreement", "RND", "APT", "ProtoRL", "DIAYN", "SMM", "APS", "MOSS"]
KW = dict(policy_kwargs={"hidden_dim": 32}, batch_size=32, buffer_size=2000, learning_starts=100, seed=0)


def env_ids(name):
    return ("URLB/walker-stand-v0",) * 2 if name == "URLBDDPG" else ("URLB/walker-v0", "URLB/walker-stand-v0")


def make_pair(name, compile_update):
    """An eager and a compiled model with the same weights, replay data and optimiser state."""
    cls, env = getattr(sb3_cic, name), env_ids(name)[0]
    eager = cls("MlpPolicy", env, **KW)
    eager.learn(200)  # 100 random steps, then 50 eager updates
    fast = cls("MlpPolicy", env, compile_update=compile_update, **KW)
    fast.learn(100)  # random steps only: sets up the logger, no update
    fast.policy.load_state_dict(eager.policy.state_dict())
    pairs = [(eager.actor.optimizer, fast.actor.optimizer), (eager.critic.optimizer, fast.critic.optimizer)]
    if eager.reward_module is not None:
        fast.reward_module.load_state_dict(eager.reward_module.state_dict())
        pairs.append((eager.reward_module.optimizer, fast.reward_module.optimizer))
    for a, b in pairs:
        b.load_state_dict(copy.deepcopy(a.state_dict()))
    assert isinstance(fast.replay_buffer, TensorReplayBuffer)  # the default with compile_update
    fast.replay_buffer = copy.deepcopy(eager.replay_buffer)  # the same batches: the step is what is compared
    fast._install_relabel()
    return eager, fast, pairs


def train(model, n=20):
    th.manual_seed(1)
    np.random.seed(1)
    model._update_metrics = UpdateMetrics()
    model.train(n, 32)
    return {k: v / model._update_metrics.count for k, v in model._update_metrics.sums.items()}


def assert_equal_runs(eager, fast, pairs, rtol=1e-4, atol=1e-5):
    metrics_eager, metrics_fast = train(eager), train(fast)
    assert metrics_eager.keys() == metrics_fast.keys()
    for key in metrics_eager:  # the intrinsic rewards' mean and std among them
        th.testing.assert_close(metrics_fast[key], metrics_eager[key], rtol=rtol, atol=atol, msg=key)
    for p, q in zip(eager.policy.state_dict().values(), fast.policy.state_dict().values()):
        th.testing.assert_close(q, p, rtol=rtol, atol=atol)
    if eager.reward_module is not None:
        state_eager, state_fast = eager.reward_module.state_dict(), fast.reward_module.state_dict()
        for key in state_eager:  # running statistics, queues and counters included
            th.testing.assert_close(state_fast[key], state_eager[key], rtol=rtol, atol=atol, msg=key)
    for a, b in pairs:
        for state_a, state_b in zip(a.state_dict()["state"].values(), b.state_dict()["state"].values()):
            assert float(state_a["step"]) == float(state_b["step"]) > 20
            for key in ("exp_avg", "exp_avg_sq"):
                th.testing.assert_close(state_b[key], state_a[key], rtol=rtol, atol=atol)


@pytest.mark.parametrize("name", NAMES)
def test_compiled_update_equals_eager_aot(name):
    eager, fast, pairs = make_pair(name, {"backend": "aot_eager"})
    counters.clear()
    # SMM's VAE (learning rate 1e-2) carries float rounding further than the others' networks
    assert_equal_runs(eager, fast, pairs, rtol=1e-3 if name == "SMM" else 1e-4)
    # the pre-training step (DDPG: the task step) traced as one graph
    assert counters["stats"]["unique_graphs"] >= 1 and not counters["graph_break"], dict(counters["graph_break"])


@pytest.mark.parametrize("name", ["URLBDDPG", "CIC"])
def test_compiled_update_equals_eager_inductor(name):
    eager, fast, pairs = make_pair(name, True)
    with torch._inductor.config.patch(fallback_random=True):  # eager's random draws (else inductor's own)
        assert_equal_runs(eager, fast, pairs)


@pytest.mark.parametrize("name", NAMES[1:])
def test_finetuning_step_is_one_graph(name, tmp_path):
    cls, (pretrain_env, task_env) = getattr(sb3_cic, name), env_ids(name)
    cls("MlpPolicy", pretrain_env, **KW).learn(110).save(tmp_path / "model.zip")
    counters.clear()
    task = cls.load_pretrained(tmp_path / "model.zip", env=task_env, learning_starts=100, compile_update={"backend": "eager"})
    assert not task.reward_free and task.replay_buffer.relabel is None
    task.learn(110)
    assert counters["stats"]["unique_graphs"] >= 1 and not counters["graph_break"], dict(counters["graph_break"])


def test_a_learning_rate_schedule_does_not_recompile():
    counters.clear()
    model = sb3_cic.CIC("MlpPolicy", "URLB/point_mass-v0", learning_rate=lambda progress: 1e-3 * (0.5 + progress),
                        compile_update={"backend": "aot_eager"}, **{**KW, "seed": 1})
    model.learn(300)
    rates = [float(lr) for lr in model.actor.optimizer._lr_tensors]
    assert rates == [pytest.approx(model.actor.optimizer.param_groups[0]["lr"])] and 5e-4 <= rates[0] < 1e-3  # moved
    assert counters["stats"]["unique_graphs"] == 1 and model._n_updates == 100


class Capture(KVWriter):
    """A logger output that keeps what each dump wrote."""

    def __init__(self):
        self.rows = []

    def write(self, key_values, key_excluded, step=0):
        self.rows.append(dict(key_values))


def test_metrics_stay_on_the_device_until_the_log_dump(tiny):
    model = sb3_cic.CIC("MlpPolicy", "URLB/point_mass-v0", **tiny)
    model.learn(300)
    capture = Capture()
    model.set_logger(Logger(None, [capture]))
    model.train(3, 32)
    sums, count = model._update_metrics.sums, model._update_metrics.count
    assert "train/critic_loss" in sums and "reward/intrinsic_reward_mean" in sums and count >= 3
    assert all(isinstance(v, th.Tensor) and v.dim() == 0 for v in sums.values())
    expected = {key: float(value) / count for key, value in sums.items()}
    model.dump_logs()
    written = capture.rows[-1]
    for key, value in expected.items():  # the means since the last dump
        assert written[key] == pytest.approx(value, rel=1e-6)
    assert "train/skill_fixed" in written
    assert model._update_metrics.count == 0 and float(sums["train/critic_loss"]) == 0.0


def test_compile_update_rejects_fullgraph_false_and_other_optimisers(tiny):
    model = sb3_cic.URLBDDPG("MlpPolicy", "URLB/point_mass-reach-v0", compile_update={"fullgraph": False}, **tiny)
    with pytest.raises(ValueError, match="fullgraph"):
        model.learn(210)
    kwargs = {**tiny, "policy_kwargs": {"hidden_dim": 32, "optimizer_class": th.optim.Adam}}
    model = sb3_cic.URLBDDPG("MlpPolicy", "URLB/point_mass-reach-v0", compile_update=True, **kwargs)
    with pytest.raises(ValueError, match="FusedAdam"):
        model.learn(210)
