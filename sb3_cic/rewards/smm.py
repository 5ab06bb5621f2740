"""SMM's reward module: a skill-conditioned VAE density and a skill discriminator."""

from __future__ import annotations

from typing import ClassVar

import math

import torch as th
import torch.nn.functional as F
from stable_baselines3.common.type_aliases import ReplayBufferSamples
from torch import nn

from sb3_cic.common.arguments import NON_NEGATIVE, POSITIVE, POSITIVE_INT, Flag, Range
from sb3_cic.policies import orthogonal_init
from sb3_cic.rewards.base import RewardModule, mlp


class SMMVAE(nn.Module):
    """VAE of ``[s, z]`` that reconstructs ``s``: its error stands for ``-log rho(s | z)``.

    Encoder ``[s, z] -> h -> h -> (mu, log var)`` of size ``code_dim``; decoder ``code -> h -> h -> s``.

    ``log var`` is clamped to ``logvar_range`` (not in the reference). Raw quadruped states reach
    ``|s| ~ 300`` (force/torque sensors). Usually the VAE's ``log var`` settles near 0 within 50 updates
    (as in the reference code), but when several such states recur in the first batches (quadruped,
    seed 0, batch and width 256) it swings further at each of them, past the float32 range of ``exp``
    at the 33rd update: reward ``inf``, then NaN weights and a NaN action. The clamp leaves every
    ``log var`` inside ``[-10, 10]`` as it was.

    :param state_dim: state size
    :param skill_dim: skill size
    :param hidden_dim: hidden width (150)
    :param code_dim: latent size (128)
    """

    logvar_range = (-10.0, 10.0)

    def __init__(self, state_dim: int, skill_dim: int, hidden_dim: int = 150, code_dim: int = 128) -> None:
        super().__init__()
        self.code_dim = code_dim
        self.encoder = mlp(state_dim + skill_dim, hidden_dim, hidden_dim, n_hidden=1).append(nn.ReLU())
        self.enc_mu = nn.Linear(hidden_dim, code_dim)
        self.enc_logvar = nn.Linear(hidden_dim, code_dim)
        self.decoder = mlp(code_dim, hidden_dim, state_dim)

    def forward(self, state: th.Tensor, skill: th.Tensor) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        """Reconstruction of ``state`` from one sampled code, and the code's ``mu`` and ``log var``."""
        h = self.encoder(th.cat([state, skill], dim=1))
        mu, logvar = self.enc_mu(h), self.enc_logvar(h).clamp(*self.logvar_range)
        code = mu + th.randn_like(mu) * (0.5 * logvar).exp()
        return self.decoder(code), mu, logvar


class SMMReward(RewardModule):
    """State Marginal Matching (Lee et al., 2019), as in URLB (``agent/smm.py``), on next states ``s'``.

    * ``vae``: :class:`SMMVAE`; loss ``beta * KL + mean squared reconstruction error`` (lr 1e-2).
    * ``discriminator``: ``s -> h -> h -> skill_dim`` (lr 1e-3), cross-entropy with the skill.
    * Reward: ``state_ent_coef * ||vae(s', z) - s'||^2 + latent_ent_coef * log K
      + latent_cond_ent_coef * log q(z | s')`` (reconstruction error for ``-log rho(s|z)``, ``log K``
      for ``-log p(z)``). The reconstruction uses one sampled code, shared with the VAE's loss.

    The reference code adds ``-log q(z|s)`` (the cross-entropy) instead of ``+log q(z|s)``, a sign
    slip against the SMM objective: not followed. It also reconstructs ``[s, z]`` and scores ``s``;
    here the VAE reconstructs the state and everything is computed on ``s'``. The VAE's ``log var``
    is clamped (see :class:`SMMVAE`), which the reference does not do.

    :param state_dim: state size
    :param action_dim: action size
    :param skill_dim: number of one-hot skills (4)
    :param hidden_dim: hidden width of the discriminator (1024)
    :param vae_hidden_dim: hidden width of the VAE (150)
    :param code_dim: VAE latent size (128)
    :param vae_lr: learning rate of the VAE (1e-2)
    :param disc_lr: learning rate of the discriminator (1e-3)
    :param vae_beta: weight of the VAE's KL term (0.5)
    :param state_ent_coef: weight of the reconstruction error (1)
    :param latent_ent_coef: weight of ``log K`` (1)
    :param latent_cond_ent_coef: weight of ``log q(z|s')`` (1)
    """

    parameter_ranges: ClassVar[dict[str, Range | Flag]] = {
        "vae_hidden_dim": POSITIVE_INT, "code_dim": POSITIVE_INT, "vae_lr": POSITIVE, "disc_lr": POSITIVE,
        "vae_beta": NON_NEGATIVE,
    }

    def __init__(
        self,
        state_dim: int,
        action_dim: int,
        skill_dim: int = 4,
        hidden_dim: int = 1024,
        vae_hidden_dim: int = 150,
        code_dim: int = 128,
        vae_lr: float = 1e-2,
        disc_lr: float = 1e-3,
        vae_beta: float = 0.5,
        state_ent_coef: float = 1.0,
        latent_ent_coef: float = 1.0,
        latent_cond_ent_coef: float = 1.0,
    ) -> None:
        super().__init__(state_dim, action_dim, skill_dim, vae_lr)
        self.vae_beta = vae_beta
        self.state_ent_coef, self.latent_ent_coef, self.latent_cond_ent_coef = state_ent_coef, latent_ent_coef, latent_cond_ent_coef
        self.vae = SMMVAE(state_dim, skill_dim, vae_hidden_dim, code_dim)
        self.discriminator = mlp(state_dim, hidden_dim, skill_dim)
        self.apply(orthogonal_init)
        self.make_optimizer(
            [{"params": self.vae.parameters(), "lr": vae_lr}, {"params": self.discriminator.parameters(), "lr": disc_lr}]
        )

    def terms(self, batch: ReplayBufferSamples) -> dict[str, th.Tensor]:
        """Per-sample reconstruction error and ``log q(z|s')`` ``(batch, 1)``, and the two losses."""
        next_state, skill = self.split(batch.next_observations)
        recon, mu, logvar = self.vae(next_state, skill)
        squared = (recon - next_state).pow(2)
        kl = -0.5 * (1 + logvar - mu.pow(2) - logvar.exp()).sum(dim=1).mean()
        log_q = F.log_softmax(self.discriminator(next_state), dim=1).gather(1, skill.argmax(dim=1, keepdim=True))
        return {
            "recon_error": squared.sum(dim=1, keepdim=True),
            "log_q": log_q,
            "vae_loss": self.vae_beta * kl + squared.mean(),
            "disc_loss": -log_q.mean(),
        }

    def _reward(self, terms: dict[str, th.Tensor]) -> th.Tensor:
        return (
            self.state_ent_coef * terms["recon_error"].detach()
            + self.latent_ent_coef * math.log(self.skill_dim)
            + self.latent_cond_ent_coef * terms["log_q"].detach()
        )

    def _step(self, terms: dict[str, th.Tensor]) -> dict[str, th.Tensor]:
        self.optimizer_step(terms["vae_loss"] + terms["disc_loss"])  # disjoint parameters: two Adam steps
        return {
            "vae_loss": terms["vae_loss"].detach(),
            "disc_loss": terms["disc_loss"].detach(),
            "recon_error": terms["recon_error"].detach().mean(),
        }

    def update(self, batch: ReplayBufferSamples) -> dict[str, th.Tensor]:
        return self._step(self.terms(batch))

    def reward(self, batch: ReplayBufferSamples) -> th.Tensor:
        return self._reward(self.terms(batch))

    def update_and_reward(self, batch: ReplayBufferSamples) -> tuple[th.Tensor, dict[str, th.Tensor]]:
        terms = self.terms(batch)
        return self._reward(terms), self._step(terms)
