"""The skill discriminator's check: its contrastive loss and accuracy on batches of distinct skills.

CIC's discriminator scores a batch of ``B`` transitions ``(s, z, s')``: each row's query ``g2(z)`` against
the ``B`` keys, its own key being the positive. When the batch holds **one transition per distinct skill**,
an uninformed discriminator scores chance exactly (loss ``log B``, top-1 accuracy ``1 / B``). A batch drawn
at random from a replay buffer or from rollouts holds several transitions of one skill (a skill lasts 50
steps), whose keys are all right answers, so its chance level is not ``log B``. The functions here build
such batches from fresh rollouts of a policy (:func:`skill_rollout`) and from a replay buffer
(:func:`replay_one_per_skill`), and score a discriminator on them (:func:`discriminator_scores`).
``benchmarks/cic_diagnostics.py`` prints them side by side.
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.type_aliases import ReplayBufferSamples

from sb3_cic.buffers import URLBReplayBuffer
from sb3_cic.rewards.cic import CICReward


def skill_rollout(
    model: Any | None,
    env_id: str,
    n_skills: int,
    skill_dim: int,
    segment: int = 50,
    noise: float = 0.2,
    seed: int = 0,
) -> list[np.ndarray]:
    """Fresh rollouts of ``n_skills`` skills ``z ~ U[0, 1]^skill_dim``, each held for ``segment`` steps or to the
    episode's end (as in pre-training: resampled every 50 steps and at each episode start).

    :param model: a skill model acting as in pre-training: its deterministic action plus Gaussian noise
        ``noise``, clipped to [-1, 1] (``None``: uniformly random actions)
    :param env_id: the domain's env id (``URLB/walker-v0``)
    :param n_skills: number of skills (segments)
    :param skill_dim: skill size
    :param segment: steps per skill
    :param noise: exploration noise of the model's actions
    :param seed: seed of the env, the skills and the noise
    :return: per skill, the array of its observations ``[s_t, z]`` (``segment + 1`` rows, or fewer at an
        episode's end: the first and last states of a segment are both kept)
    """
    env = gym.make(env_id)
    rng = np.random.default_rng(seed)
    state, _ = env.reset(seed=seed)
    segments: list[np.ndarray] = []
    while len(segments) < n_skills:
        skill = rng.uniform(size=skill_dim).astype(np.float32)
        rows = [np.concatenate([state, skill]).astype(np.float32)]
        for _ in range(segment):
            if model is None:
                action = rng.uniform(-1.0, 1.0, size=env.action_space.shape)
            else:
                mu, _ = model.predict(rows[-1][None], deterministic=True)
                action = np.clip(mu[0] + noise * rng.standard_normal(mu.shape[1:]), -1.0, 1.0)
            state, _, terminated, truncated, _ = env.step(action.astype(np.float32))
            rows.append(np.concatenate([state, skill]).astype(np.float32))
            if terminated or truncated:
                state, _ = env.reset()
                break
        segments.append(np.stack(rows))
    env.close()
    return segments


def one_per_skill(segments: list[np.ndarray], n_step: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """One transition ``([s_t, z], [s_{t+n}, z])`` per segment of :func:`skill_rollout`, ``t`` drawn uniformly
    among the steps whose ``t + n`` is inside the segment (segments shorter than ``n + 1`` rows are left out).

    :return: ``(obs, next_obs)``, one row per usable segment
    """
    usable = [rows for rows in segments if len(rows) > n_step]
    starts = [int(rng.integers(len(rows) - n_step)) for rows in usable]
    obs = np.stack([rows[t] for rows, t in zip(usable, starts)])
    next_obs = np.stack([rows[t + n_step] for rows, t in zip(usable, starts)])
    return obs, next_obs


def stored_skills(buffer: URLBReplayBuffer) -> np.ndarray:
    """For each stored transition of a skill buffer (one env), the index of its skill among the distinct stored skills."""
    if buffer.skill_dim <= 0 or buffer.n_envs != 1:
        raise ValueError(f"a buffer of skills from one env is needed (skill_dim {buffer.skill_dim}, n_envs {buffer.n_envs})")
    stored = buffer.buffer_size if buffer.full else buffer.pos
    _, skill_of = np.unique(buffer.observations[:stored, 0, -buffer.skill_dim :], axis=0, return_inverse=True)
    return skill_of.reshape(-1)


def replay_one_per_skill(
    buffer: URLBReplayBuffer,
    n: int,
    rng: np.random.Generator,
    indices: np.ndarray | None = None,
    skill_of: np.ndarray | None = None,
) -> ReplayBufferSamples:
    """A batch of the replay buffer's transitions as training samples them (n-step next observation), holding
    one transition per distinct skill: ``n`` skills drawn among the stored ones, one transition of each.

    :param buffer: a filled skill buffer (``skill_dim > 0``, one env)
    :param n: number of skills (at most the number of distinct stored skills)
    :param rng: random generator
    :param indices: draw only from these stored transitions (default: all)
    :param skill_of: :func:`stored_skills` of the buffer, if already computed
    """
    skill_of = stored_skills(buffer) if skill_of is None else skill_of
    order = rng.permutation(len(skill_of) if indices is None else indices)
    _, first = np.unique(skill_of[order], return_index=True)  # a random transition of each skill
    if n > len(first):
        raise ValueError(f"the transitions hold {len(first)} distinct skills, fewer than {n}")
    return buffer._get_samples(order[rng.choice(first, size=n, replace=False)])


@th.no_grad()
def discriminator_scores(module: CICReward, obs: th.Tensor | np.ndarray, next_obs: th.Tensor | np.ndarray) -> dict[str, float]:
    """The discriminator's contrastive loss, top-1 accuracy and rank on one batch, beside chance (``log B``, ``1/B``, 0.5).

    The loss is the paper's cross-entropy whatever the module's variant (chance is ``log B`` for it); chance is
    exact only when the batch holds one transition per distinct skill (see the module docstring). The rank is
    the graded form of the accuracy: per skill's query, the share of the other ``B - 1`` keys scored above its
    own transition's key, averaged (0: always first; 0.5: an uninformed discriminator; 1: always last), so a
    discriminator that places a skill coarsely, but not first among ``B``, shows it.

    :param module: the CIC reward module
    :param obs: ``(B, state + skill)`` observations ``[s, z]``
    :param next_obs: ``(B, state + skill)`` next observations ``[s', z]``
    """
    device = module.particle.rms.mean.device
    obs, next_obs = th.as_tensor(obs, device=device), th.as_tensor(next_obs, device=device)
    zeros = th.zeros(len(obs), 1, device=device)
    query, key, _ = module.query_key(ReplayBufferSamples(obs, zeros, next_obs, zeros, zeros, None))
    logits = module.logits(query, key)
    loss, accuracy = module.loss_of_logits(logits, variant="paper")
    n = len(obs)
    rank = ((logits > logits.diagonal()[:, None]).sum(dim=1).float() / max(n - 1, 1)).mean()
    return {"loss": loss.item(), "accuracy": accuracy.item(), "rank": rank.item(), "chance_loss": math.log(n),
            "chance_accuracy": 1 / n, "chance_rank": 0.5}
