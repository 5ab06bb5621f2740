"""The actor acting as a CUDA graph (``compile_update`` on CUDA, :class:`~sb3_cic.common.fast_update.GraphedActor`).

These need a CUDA device: on a machine without one they are skipped (the CPU paths are tested elsewhere).
"""

import numpy as np
import pytest
import torch as th

from sb3_cic import CIC
from sb3_cic.common import fast_update
from sb3_cic.common.fast_update import GraphedActor
from sb3_cic.tensor_buffer import TensorReplayBuffer

pytestmark = pytest.mark.skipif(not th.cuda.is_available(), reason="needs a CUDA device (the actor's CUDA graph)")

SMALL = dict(policy_kwargs={"hidden_dim": 32}, batch_size=32, buffer_size=5000, learning_starts=0, seed=0, device="cuda")


def eager_actions(actor: th.nn.Module, observations: np.ndarray) -> np.ndarray:
    with th.no_grad():
        return actor(th.as_tensor(observations, device="cuda")).cpu().numpy()


def test_the_graph_gives_the_actors_output_and_follows_its_updates():
    model = CIC("MlpPolicy", "URLB/walker-v0", **SMALL)
    actor = model.policy.actor
    observations = np.random.default_rng(0).standard_normal((5, 1, *model.observation_space.shape)).astype(np.float32)
    graph = GraphedActor(actor, observations[0].shape)
    for obs in observations:
        np.testing.assert_allclose(graph(obs), eager_actions(actor, obs), rtol=0, atol=1e-6)
    # an optimiser step writes the parameters in place: the replay reads them
    loss = actor(th.as_tensor(observations[0], device="cuda")).square().sum()
    actor.optimizer.zero_grad()
    loss.backward()
    actor.optimizer.step()
    assert graph.current(actor, observations[0].shape)
    np.testing.assert_allclose(graph(observations[0]), eager_actions(actor, observations[0]), rtol=0, atol=1e-6)
    # a parameter replaced, another shape or another actor: captured again
    assert not graph.current(actor, (2, *model.observation_space.shape))
    assert not graph.current(CIC("MlpPolicy", "URLB/walker-v0", **SMALL).policy.actor, observations[0].shape)
    first = next(actor.parameters())
    first.data = first.data.clone()
    assert not graph.current(actor, observations[0].shape)


def test_learn_with_compile_update_acts_through_the_graph_with_the_eager_actions(monkeypatch):
    calls = []
    replay = GraphedActor.__call__

    def counted(self, observation):
        calls.append(1)
        return replay(self, observation)

    monkeypatch.setattr(fast_update.GraphedActor, "__call__", counted)
    buffers = {}
    for compiled in (False, True):  # the same buffer class (compile_update's default), so the same random draws
        model = CIC("MlpPolicy", "URLB/walker-v0", gradient_steps=0, compile_update=compiled,
                    replay_buffer_class=TensorReplayBuffer, **SMALL)
        model.learn(300)
        buffers[compiled] = model.replay_buffer
    assert len(calls) == 300  # every action of the compiled model, none of the eager one
    assert buffers[False].pos == buffers[True].pos == 300
    th.testing.assert_close(buffers[True].actions[:300], buffers[False].actions[:300], rtol=0, atol=1e-5)
