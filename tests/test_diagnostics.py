"""The discriminator check on batches of distinct skills (sb3_cic.diagnostics)."""

import math

import numpy as np
import pytest
import torch as th
from torch import nn

import sb3_cic  # noqa: F401
from sb3_cic import CIC
from sb3_cic.diagnostics import discriminator_scores, one_per_skill, replay_one_per_skill, skill_rollout, stored_skills
from sb3_cic.rewards.cic import CICReward


class SecondHalf(nn.Module):
    """pred_net that returns g1(s'), the second half of its input [g1(s), g1(s')]."""

    def forward(self, x: th.Tensor) -> th.Tensor:
        return x.chunk(2, dim=1)[1]


def distinct_skill_batch(n=64, dim=8, seed=0):
    """One transition per skill whose state carries the skill: obs [z + noise, z], next obs [z + noise, z]."""
    g = th.Generator().manual_seed(seed)
    z = th.rand(n, dim, generator=g)
    return th.cat([z + 0.01 * th.randn(n, dim, generator=g), z], 1), th.cat([z + 0.01 * th.randn(n, dim, generator=g), z], 1)


def test_a_discriminator_handed_the_skill_is_near_perfect_and_a_random_one_is_at_chance():
    obs, next_obs = distinct_skill_batch()
    handed = CICReward(8, 2, skill_dim=8, hidden_dim=16)
    handed.state_net, handed.pred_net, handed.skill_net = nn.Identity(), SecondHalf(), nn.Identity()  # key = s' ~ z = query
    perfect = discriminator_scores(handed, obs, next_obs)
    assert perfect["chance_loss"] == pytest.approx(math.log(64)) and perfect["chance_accuracy"] == pytest.approx(1 / 64)
    assert perfect["accuracy"] >= 0.95 and perfect["loss"] < 0.9 * math.log(64) and perfect["rank"] < 0.01
    handed.variant = "code"  # scored with the paper's cross-entropy whatever the training loss (chance: log B)
    assert discriminator_scores(handed, obs, next_obs) == perfect
    random = [discriminator_scores(CICReward(8, 2, skill_dim=8, hidden_dim=16), *distinct_skill_batch(seed=s))
              for s in range(10)]
    assert np.mean([r["loss"] for r in random]) == pytest.approx(math.log(64), rel=0.05)
    assert np.mean([r["accuracy"] for r in random]) < 0.1  # chance 1/64; the handed one scores >= 0.95
    assert np.mean([r["rank"] for r in random]) == pytest.approx(0.5, abs=0.05) and random[0]["chance_rank"] == 0.5


def test_rank_counts_the_keys_scored_above_the_positive():
    module = CICReward(2, 1, skill_dim=2, hidden_dim=8)
    module.state_net, module.pred_net, module.skill_net = nn.Identity(), SecondHalf(), nn.Identity()  # query z, key s'
    z = th.tensor([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    next_state = th.tensor([[0.0, 1.0], [0.1, 1.0], [1.0, 1.0]])
    scores = discriminator_scores(module, th.cat([next_state, z], 1), th.cat([next_state, z], 1))
    # cosines, row by row: (0, 0.0995, 0.707): both other keys above its own; (1, 0.995, 0.707): one of two;
    # (0.707, 0.774, 1): none. Rank (2/2 + 1/2 + 0) / 3; only row 2 is top-1.
    assert scores["rank"] == pytest.approx(0.5) and scores["accuracy"] == pytest.approx(1 / 3)


def test_fresh_rollout_batches_hold_one_transition_per_skill():
    segments = skill_rollout(None, "URLB/point_mass-v0", n_skills=12, skill_dim=3, segment=10, seed=1)
    assert len(segments) == 12 and all(rows.shape == (11, 4 + 3) for rows in segments)  # 10 steps: 11 states
    assert all(np.all(rows[:, 4:] == rows[0, 4:]) for rows in segments)  # one skill per segment
    assert np.all(segments[1][0, :4] == segments[0][-1, :4])  # the next skill starts where the last one ended
    obs, next_obs = one_per_skill(segments, n_step=3, rng=np.random.default_rng(0))
    assert obs.shape == next_obs.shape == (12, 7)
    assert len(np.unique(obs[:, 4:], axis=0)) == 12 and np.all(obs[:, 4:] == next_obs[:, 4:])
    for rows, o, n in zip(segments, obs, next_obs):  # s_{t+3} follows s_t inside the segment
        t = int(np.flatnonzero((rows == o).all(axis=1))[0])
        assert np.all(rows[t + 3] == n)


def test_replayed_batches_hold_one_transition_per_skill():
    model = CIC("MlpPolicy", "URLB/point_mass-v0", skill_dim=3, buffer_size=2000, batch_size=16, learning_starts=100,
                policy_kwargs={"hidden_dim": 16}, cic_hidden_dim=16, skill_resample_every=20, seed=0)
    model.learn(600)  # 30 skills of 20 steps
    batch = replay_one_per_skill(model.replay_buffer, 20, np.random.default_rng(0))
    skills = batch.observations[:, -3:].numpy()
    assert batch.observations.shape == (20, 4 + 3) and len(np.unique(skills, axis=0)) == 20
    scores = discriminator_scores(model.reward_module, batch.observations, batch.next_observations)
    assert 0.0 <= scores["accuracy"] <= 1.0 and scores["chance_loss"] == pytest.approx(math.log(20))
    with pytest.raises(ValueError, match="hold 30 distinct skills, fewer than 100"):
        replay_one_per_skill(model.replay_buffer, 100, np.random.default_rng(0))
    skill_of = stored_skills(model.replay_buffer)
    assert len(skill_of) == 600 and skill_of.max() == 29
    among = np.flatnonzero(skill_of < 10)  # draw only from the transitions of ten of the skills
    part = replay_one_per_skill(model.replay_buffer, 10, np.random.default_rng(1), indices=among, skill_of=skill_of)
    stored = model.replay_buffer.observations[among, 0, -3:]
    assert all((stored == z).all(axis=1).any() for z in part.observations[:, -3:].numpy())
    assert len(np.unique(part.observations[:, -3:].numpy(), axis=0)) == 10
    with pytest.raises(ValueError, match="hold 10 distinct skills, fewer than 11"):
        replay_one_per_skill(model.replay_buffer, 11, np.random.default_rng(1), indices=among, skill_of=skill_of)
    fresh = skill_rollout(model, "URLB/point_mass-v0", n_skills=4, skill_dim=3, segment=5)
    assert [rows.shape for rows in fresh] == [(6, 7)] * 4
