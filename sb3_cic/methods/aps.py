"""Active Pre-training with Successor features (APS) as an SB3 algorithm."""

from __future__ import annotations

import warnings
from typing import Any, ClassVar

import numpy as np
import torch as th
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv

from sb3_cic.callbacks import SkillSelectionCallback
from sb3_cic.common.arguments import NON_NEGATIVE_INT, POSITIVE_INT, Flag, Range, check_ranges
from sb3_cic.ddpg import URLBDDPG
from sb3_cic.policies import URLBCritic, URLBPolicy
from sb3_cic.rewards.aps import APSReward
from sb3_cic.skills import SKILL_DIM, SphereSkillPrior


class APSCritic(URLBCritic):
    """Successor-feature twin critic: each head outputs ``psi`` (``output_dim``), ``Q = w . psi``.

    The task vector ``w`` is the last ``output_dim`` entries of the observation (the skill); APS sets
    ``output_dim`` to its ``sf_dim`` (10). The arguments are :class:`~sb3_cic.policies.URLBCritic`'s.
    """

    def successor_features(self, obs: th.Tensor, actions: th.Tensor) -> tuple[th.Tensor, ...]:
        """``psi`` of each head, each ``(batch, output_dim)``."""
        return super().forward(obs, actions)

    def forward(self, obs: th.Tensor, actions: th.Tensor) -> tuple[th.Tensor, ...]:
        w = obs[:, -self.output_dim :]
        return tuple((psi * w).sum(dim=1, keepdim=True) for psi in self.successor_features(obs, actions))

    def q1_forward(self, obs: th.Tensor, actions: th.Tensor) -> th.Tensor:
        return (super().q1_forward(obs, actions) * obs[:, -self.output_dim :]).sum(dim=1, keepdim=True)


class APSPolicy(URLBPolicy):
    """URLB policy with the successor-feature critic :class:`APSCritic` (``output_dim``: size of ``w``)."""

    critic_class = APSCritic


def regress_task(phi: th.Tensor, rewards: th.Tensor) -> np.ndarray:
    """Least-squares task vector: solve ``phi w = r`` for ``w`` and normalise it to unit norm.

    :param phi: ``(N, d)`` successor features of the transitions' next states
    :param rewards: ``(N,)`` or ``(N, 1)`` one-step task rewards
    :return: ``w / ||w||`` (float32, ``(d,)``); all zeros when the solution is zero
    """
    solution = th.linalg.lstsq(phi.double(), rewards.reshape(-1, 1).double()).solution.squeeze(1)
    norm = th.linalg.vector_norm(solution)
    w = solution / norm if norm > 0 else solution
    return w.float().cpu().numpy()


class APSRegressionCallback(SkillSelectionCallback):
    """APS fine-tuning: regress the task reward onto the pre-trained successor features, fix ``w``.

    Until step ``regression_step`` the task vector keeps being resampled as in pre-training; at that
    step, once, ``w`` solves ``phi(s') w = r`` by least squares over the one-step transitions stored
    in the replay buffer (all of them, a random subset of ``max_samples`` beyond that), with ``phi``
    the loaded model's reward module, and is normalised and fixed for the rest of fine-tuning.

    :param regression_step: step of the regression (URLB: 4,096)
    :param max_samples: most transitions used (100,000)
    :param verbose: verbosity
    """

    def __init__(self, regression_step: int = 4096, max_samples: int = 100_000, verbose: int = 0) -> None:
        super().__init__(verbose)
        self.regression_step = regression_step
        self.max_samples = max_samples
        #: transitions used by the last regression
        self.n_samples = 0

    @classmethod
    def for_model(cls, model: Any, **kwargs: Any) -> APSRegressionCallback:
        """The regression of APS's fine-tuning, with the model's ``regression_step`` and ``regression_max_samples``
        (None: this class's defaults).

        :param model: the APS model about to be fine-tuned
        :param kwargs: other arguments
        """
        given = {"regression_step": model.regression_step, "max_samples": model.regression_max_samples}
        return cls(**{k: v for k, v in given.items() if v is not None}, **kwargs, verbose=model.verbose)

    def _start(self) -> None:
        assert self.model.env is not None
        self.model.env.env_method("set_fixed", False)

    @th.no_grad()
    def regress(self) -> np.ndarray:
        """The normalised least-squares task vector from the replay buffer's raw one-step arrays."""
        buffer = self.model.replay_buffer
        stored = buffer.buffer_size if buffer.full else buffer.pos
        next_obs = buffer.next_observations[:stored].reshape(-1, buffer.next_observations.shape[-1])
        rewards = buffer.rewards[:stored].reshape(-1)
        index = np.arange(len(rewards))
        if len(index) > self.max_samples:
            # numpy's global generator: seeded with the model (``seed=``), so the subset is reproducible
            index = np.random.choice(len(index), self.max_samples, replace=False)
        self.n_samples = len(index)
        module = self.model.reward_module
        states = th.as_tensor(next_obs[index, : self.model.state_dim], device=self.model.device)
        phi = module.phi(states)
        return regress_task(phi, th.as_tensor(rewards[index], device=self.model.device))

    def _on_step(self) -> bool:
        if self.done or self.num_timesteps < self.regression_step:
            return True
        w = self.regress()
        if not np.any(w):  # no reward signal yet: keep a random task vector
            warnings.warn("APS regression: the stored task rewards are all zero, fine-tuning with a random w")
            w = self.model.skill_prior.sample(np.random.default_rng())
        else:
            self.logger.record("finetune/regression_samples", self.n_samples)
        self.choose(w)
        return True


class APS(URLBDDPG):
    """Active Pre-training with Successor features (Liu & Abbeel, 2021, https://arxiv.org/abs/2108.13956).

    Reference implementation: https://github.com/rll-research/url_benchmark (``agent/aps.py``).
    A competence-based method: task vectors ``w`` on the unit sphere (10-d) resampled every 5 steps,
    a successor-feature critic (:class:`APSPolicy`, ``Q = w . psi``) and the reward of
    :class:`~sb3_cic.rewards.aps.APSReward` (particle entropy of ``phi(s')`` + ``w . phi(s')``).

    Fine-tuning (:class:`APSRegressionCallback`): ``w`` keeps being resampled until step
    ``regression_step`` (4,096), then it is regressed once from the stored task rewards and fixed.
    Deliberate deviations from the reference code's slips: the regression solves ``phi(s') w = r``
    (the code calls ``lstsq(r, phi)``, the swapped system, and uses ``phi(s)``); it uses one-step
    rewards from the buffer's raw arrays (the code: 3-step sums from the replay iterator); and
    ``phi`` is the pre-trained one (the code's ``init_from`` does not copy the APS network from the
    snapshot, so its regression runs on a randomly initialised ``phi``).

    :param policy: policy (``"MlpPolicy"``: :class:`APSPolicy`)
    :param env: environment id, environment or VecEnv (wrapped with the skill wrapper if needed)
    :param sf_dim: size of ``phi``, ``psi`` and ``w`` (default: SphereSkillPrior's)
    :param aps_hidden_dim: hidden width of ``phi`` (default: the policy's)
    :param aps_lr: learning rate of ``phi`` (default: APSReward's)
    :param knn_k: neighbours of the particle estimator (default: APSReward's)
    :param knn_clip: clip of the particle estimator (default: APSReward's)
    :param knn_avg: average the k distances (default: APSReward's)
    :param knn_rms: divide by the running mean of the distances (default: APSReward's)
    :param regression_step: fine-tuning step of the task regression (default: APSRegressionCallback's)
    :param regression_max_samples: most transitions used by the regression (default: APSRegressionCallback's)
    :param skill_resample_every: task-vector resampling period (5)
    :param policy_kwargs: policy arguments (``hidden_dim``); ``output_dim`` is set to ``sf_dim``
    :param kwargs: arguments of :class:`URLBDDPG` (``batch_size``...)
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"MlpPolicy": APSPolicy}  # type: ignore[assignment]

    # the method ---------------------------------------------------------------------------------
    skill_prior_class = SphereSkillPrior
    reward_module_class = APSReward
    reward_module_args: ClassVar[dict[str, str]] = {
        "aps_hidden_dim": "hidden_dim",
        "aps_lr": "lr",
        "knn_k": "knn_k",
        "knn_clip": "knn_clip",
        "knn_avg": "knn_avg",
        "knn_rms": "knn_rms",
    }
    finetune_skill_choices: ClassVar[dict[str, Any]] = {"regression": (APSRegressionCallback, {})}
    finetune_critic: ClassVar[str] = "trunk"
    #: the ranges of APS's own arguments (URLBDDPG's: :attr:`~sb3_cic.ddpg.URLBDDPG.argument_ranges`)
    argument_ranges: ClassVar[dict[str, Range | Flag]] = {
        "sf_dim": SKILL_DIM, "regression_step": NON_NEGATIVE_INT, "regression_max_samples": POSITIVE_INT,
    }

    def __init__(
        self,
        policy: str | type,
        env: GymEnv | str,
        sf_dim: int | None = None,
        skill_resample_every: int | None = 5,
        regression_step: int | None = None,
        regression_max_samples: int | None = None,
        **kwargs: Any,
    ) -> None:
        if isinstance(policy, type) and not issubclass(policy, APSPolicy):
            raise ValueError(f"APS needs an APSPolicy (successor-feature critic), got {policy.__name__}")
        check_ranges({"sf_dim": sf_dim, "regression_step": regression_step, "regression_max_samples": regression_max_samples},
                     APS.argument_ranges)
        self.regression_step = regression_step
        self.regression_max_samples = regression_max_samples
        super().__init__(policy, env, skill_dim=sf_dim, skill_resample_every=skill_resample_every, **kwargs)

    def _setup_model(self) -> None:
        self.policy_kwargs = {**self.policy_kwargs, "output_dim": self.skill_dim}  # the critic's psi has w's size
        super()._setup_model()
