"""URLB-faithful DDPG: the engine every unsupervised method of this package runs on."""

from __future__ import annotations

import operator
from functools import reduce
from typing import Any, Callable, ClassVar, TypeVar

import numpy as np
import torch as th
import torch.nn.functional as F
from stable_baselines3 import DDPG
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.noise import ActionNoise, NormalActionNoise
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, ReplayBufferSamples, Schedule

from sb3_cic.buffers import URLBReplayBuffer
from sb3_cic.common.arguments import (
    FLAG,
    FRACTION,
    NON_NEGATIVE,
    NON_NEGATIVE_INT,
    POSITIVE,
    POSITIVE_INT,
    SEED,
    Flag,
    Range,
    check_range,
    check_ranges,
)
from sb3_cic.common.env_util import check_finite_step, dict_layout_of, env_id_of, prepare_env, vec_normalize_of
from sb3_cic.common.fast_update import UpdateMetrics, compiled_step
from sb3_cic.common.method import MethodMixin
from sb3_cic.common.rollout import LeanRolloutMixin
from sb3_cic.common.save_util import SaveLoadMixin, package_version
from sb3_cic.common.skill_mixin import SkillMixin
from sb3_cic.envs.dict_obs import StateDictLayout
from sb3_cic.finetune import start_finetuning, with_finetune_callback
from sb3_cic.policies import URLBPolicy, min_q, normalize_policy_kwargs
from sb3_cic.rewards.base import RewardModule
from sb3_cic.skills import SKILL_DIM, SkillPrior
from sb3_cic.speed import lean_action, speed_options
from sb3_cic.tensor_buffer import TensorReplayBuffer

SelfURLBDDPG = TypeVar("SelfURLBDDPG", bound="URLBDDPG")


class URLBDDPG(MethodMixin, SkillMixin, LeanRolloutMixin, SaveLoadMixin, DDPG):
    """DDPG as in the Unsupervised RL Benchmark (Laskin et al., 2021), the base of every method here.

    Reference implementation: https://github.com/rll-research/url_benchmark (``agent/ddpg.py``).
    Differences from SB3's DDPG, all URLB's: a twin critic with LayerNorm/Tanh trunks
    (:class:`~sb3_cic.policies.URLBPolicy`); exploration ``mu + N(0, 0.2^2)``; for the target and
    the actor loss the noise is clipped to +-0.3 and the action clamped with a straight-through
    gradient; target ``r + disc * min(Q1', Q2')`` with the target action from the online actor (URLB has
    no target actor); actor loss ``-min(Q1, Q2)`` at every update; n-step (3) returns; 4,000 random
    steps, then one update every 2 env steps.

    A method (``sb3_cic.methods``) is this class plus four parts, declared as class attributes
    (:class:`~sb3_cic.common.method.MethodMixin`): a skill prior (the env is wrapped with
    :class:`~sb3_cic.envs.SkillObservationWrapper`), a reward module, a fine-tuning skill choice, the critic layers
    that fine-tuning keeps. One update is one step on a sampled batch (:meth:`_step`): in pre-training
    (``reward_free=True``) the replay buffer's relabel hook trains the reward module on the batch and replaces
    its reward with the intrinsic reward; then the critic, actor and target steps. The step's metrics stay on the
    device until SB3 dumps its logs (``train/`` and ``reward/`` keys: means over the updates since the last dump).
    Fine-tuning starts with :meth:`load_pretrained`. A non-finite observation or reward from the env is a
    ``ValueError`` before it is stored.

    Deliberate deviations from the reference code: the intrinsic reward of a batch is computed by the
    reward networks as they were when the batch was sampled (URLB: just after their update on that
    batch); at fine-tuning the target critic starts as a copy of the loaded critic (URLB leaves it at
    its random initialisation).

    :param policy: the policy model (``"MlpPolicy"``; width through ``policy_kwargs={"hidden_dim": ...}``), or
        ``"MultiInputPolicy"`` for a Dict observation of state entries (shimmy's ``dm_control/...`` ids; 1-D or scalar
        Boxes, Discrete, MultiDiscrete and MultiBinary entries, one-hot as SB3's): the env is wrapped with
        :class:`~sb3_cic.envs.dict_obs.FlatStateDict` (a VecEnv with :class:`~sb3_cic.envs.vec_dict_obs.VecFlatStateDict`;
        the entries concatenated in the Dict's key order, alphabetical for shimmy's; actions in [-1, 1] rescaled to the
        env's bounds) and the policy is ``"MlpPolicy"``'s on the flat state; ``predict`` takes the env's own Dict
        observations and returns the env's actions (``multi_input`` and ``dict_layout`` are saved with the model)
    :param env: environment id, environment or VecEnv
    :param learning_rate: Adam learning rate of actor and critic
    :param buffer_size: replay capacity
    :param learning_starts: random-action steps before learning
    :param batch_size: minibatch size
    :param tau: soft target update coefficient (at every update)
    :param gamma: discount factor
    :param train_freq: env steps between updates
    :param gradient_steps: updates per ``train_freq``
    :param action_noise: exploration noise of the actions taken in the env (default: URLB's
        ``N(0, exploration_std^2)``); the target action and the actor loss keep URLB's clipped noise
    :param replay_buffer_class: a subclass of :class:`~sb3_cic.buffers.URLBReplayBuffer` (the default; with
        ``compile_update`` it is replaced by :class:`~sb3_cic.tensor_buffer.TensorReplayBuffer`, on the model's device)
    :param replay_buffer_kwargs: extra arguments of :class:`~sb3_cic.buffers.URLBReplayBuffer`
    :param optimize_memory_usage: not supported (``ValueError`` if True; lower ``buffer_size`` instead)
    :param n_steps: n of the n-step return
    :param exploration_std: std of the gaussian exploration noise
    :param exploration_clip: clip of that noise for the target action and the actor loss
    :param reward_free: pre-training: train the reward module and use its reward (default: True for a method
        with a reward module; a warning says so on an env other than ``URLB/<domain>-v0``)
    :param skill_prior: skill prior (default: the method's :attr:`skill_prior_class`, of size ``skill_dim``)
    :param skill_dim: size of the method's skill (default: its prior's)
    :param skill_resample_every: skill resampling period of the skill wrapper
    :param finetune_skill_choice: one of the method's :attr:`finetune_skill_choices` (default: the first)
    :param compile_update: run the update step compiled as one graph (:func:`~sb3_cic.common.fast_update.compile_step`;
        the same math, equal to float rounding); the first update compiles it. True, or a dict of
        ``torch.compile`` arguments (``{"backend": "aot_eager"}``, ``{"mode": "max-autotune"}``)
    :param stats_window_size: episodes averaged in the rollout logs
    :param tensorboard_log: tensorboard log folder
    :param policy_kwargs: policy arguments: ``hidden_dim`` (or SB3's ``net_arch=[h, h]``), ``n_critics`` (2)
    :param verbose: verbosity
    :param seed: random seed
    :param device: torch device
    :param _init_setup_model: build the networks at construction
    :param method_kwargs: the method's reward-module arguments (:attr:`reward_module_args`)
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"MlpPolicy": URLBPolicy}  # type: ignore[assignment]
    policy: URLBPolicy
    replay_buffer: URLBReplayBuffer

    #: freeze the critic's weights during the actor step (no weight gradients; same actor update)
    freeze_critic_in_actor_step: bool = True
    #: the range of each numeric (or bool) argument (a method adds its own: :func:`~sb3_cic.common.arguments.ranges_of`);
    #: ``learning_rate`` may also be a schedule, ``gradient_steps`` -1, ``train_freq`` a ``(frequency, unit)`` tuple,
    #: ``batch_size`` is at most ``buffer_size`` (:func:`~sb3_cic.common.arguments.check_ranges`)
    argument_ranges: ClassVar[dict[str, Range | Flag]] = {
        "learning_rate": POSITIVE, "buffer_size": POSITIVE_INT, "batch_size": POSITIVE_INT,
        "learning_starts": NON_NEGATIVE_INT, "tau": FRACTION, "gamma": FRACTION, "gradient_steps": NON_NEGATIVE_INT,
        "train_freq": POSITIVE_INT, "n_steps": POSITIVE_INT, "exploration_std": NON_NEGATIVE,
        "exploration_clip": NON_NEGATIVE, "stats_window_size": POSITIVE_INT, "skill_dim": SKILL_DIM,
        "skill_resample_every": POSITIVE_INT, "verbose": Range(0, 2, integer=True), "seed": SEED, "reward_free": FLAG,
    }
    #: the ``compile_update`` argument (a class default for models saved before it existed)
    compile_update: bool | dict[str, Any] = False
    #: built with ``"MultiInputPolicy"``: Dict observations are flattened (a class default for older models)
    multi_input: bool = False
    #: how the env's Dict observations are flattened (None: flat observations; a class default for older models)
    dict_layout: StateDictLayout | None = None

    def __init__(
        self,
        policy: str | type[URLBPolicy],
        env: GymEnv | str,
        learning_rate: float | Schedule = 1e-4,
        buffer_size: int = 1_000_000,
        learning_starts: int = 4000,
        batch_size: int = 1024,
        tau: float = 0.01,
        gamma: float = 0.99,
        train_freq: int = 2,
        gradient_steps: int = 1,
        action_noise: ActionNoise | None = None,
        replay_buffer_class: type[URLBReplayBuffer] | None = None,
        replay_buffer_kwargs: dict[str, Any] | None = None,
        optimize_memory_usage: bool = False,
        n_steps: int = 3,
        exploration_std: float = 0.2,
        exploration_clip: float = 0.3,
        reward_free: bool | None = None,
        skill_prior: SkillPrior | None = None,
        skill_dim: int | None = None,
        skill_resample_every: int | None = 50,
        finetune_skill_choice: str | None = None,
        compile_update: bool | dict[str, Any] = False,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
        **method_kwargs: Any,
    ) -> None:
        replay_buffer_class = replay_buffer_class or URLBReplayBuffer
        check_ddpg_arguments(locals(), URLBDDPG.argument_ranges)
        self._declare(method_kwargs, skill_prior, skill_dim, finetune_skill_choice)  # the method's parts
        policy_kwargs = normalize_policy_kwargs(policy_kwargs)
        #: the id of the env the model was built on (None if it has none), and what saved it: read by
        #: :meth:`load` to explain a snapshot loaded onto the wrong env or class
        self.env_id = env_id_of(env)
        self.algorithm = type(self).__name__
        self.package_version = package_version()
        self.multi_input = policy == "MultiInputPolicy"
        policy = "MlpPolicy" if self.multi_input else policy  # URLB's networks on the flattened Dict
        if _init_setup_model:  # ``load`` prepares the env itself, with the saved prior
            self._warn_if_reward_ignored(env, reward_free)
            env = prepare_env(env, self.skill_prior, skill_resample_every, self.multi_input)
        super().__init__(
            policy, env, learning_rate=learning_rate, buffer_size=buffer_size, learning_starts=learning_starts,
            batch_size=batch_size, tau=tau, gamma=gamma, train_freq=train_freq, gradient_steps=gradient_steps,
            action_noise=action_noise, replay_buffer_class=replay_buffer_class, replay_buffer_kwargs=replay_buffer_kwargs,
            tensorboard_log=tensorboard_log, policy_kwargs=policy_kwargs, verbose=verbose, seed=seed, device=device,
            _init_setup_model=False,
        )
        if self.env is not None:  # (``load`` without an env: the saved layout)
            self.dict_layout = dict_layout_of(self.env)
        self._vec_normalize_env = vec_normalize_of(self.env)  # a VecNormalize of Dicts, seen flat
        self.n_steps = n_steps
        self._stats_window_size = stats_window_size
        self.exploration_std = exploration_std
        self.exploration_clip = exploration_clip
        self.skill_resample_every = skill_resample_every
        self.reward_free = reward_free
        self.compile_update = compile_update
        #: act with the policy (instead of uniformly) during the first ``learning_starts`` steps
        self.warmup_with_policy = False
        self.finetune_skill: np.ndarray | None = None
        self.reward_module: RewardModule | None = None
        self.skill: np.ndarray | None = None
        if _init_setup_model:
            self._setup_model()

    # construction -------------------------------------------------------------------------------
    def _setup_model(self) -> None:
        if self.action_noise is None:
            shape = self.action_space.shape
            self.action_noise = NormalActionNoise(np.zeros(shape), np.full(shape, self.exploration_std))
        extra = {"n_steps": self.n_steps, "gamma": self.gamma, "skill_dim": self.skill_dim}
        self.replay_buffer_kwargs = {**self.replay_buffer_kwargs, **extra}
        if self.compile_update and self.replay_buffer_class is URLBReplayBuffer:
            self.replay_buffer_class = TensorReplayBuffer
        n_steps, self.n_steps = self.n_steps, 1  # n-step returns are configured on our buffer
        super()._setup_model()
        self.n_steps = n_steps
        self.policy.skill_dim = self.skill_dim
        self.reward_module = self.make_reward_module()
        if self.reward_module is not None:
            self.reward_module.to(self.device)
        if self.reward_free is None:
            self.reward_free = self.reward_module is not None
        if self.reward_free and self.reward_module is None:
            raise ValueError(f"{type(self).__name__} has no intrinsic reward module: reward_free must be False")
        self._critic_params = list(self.critic.parameters())
        self._critic_target_params = list(self.critic_target.parameters())
        self._update_metrics = UpdateMetrics()
        self._compiled_step: Callable[[ReplayBufferSamples], dict[str, th.Tensor]] | None = None
        self._install_relabel()

    def _install_relabel(self) -> None:
        self.replay_buffer.relabel = self._relabel if self.reward_free else None

    def load_replay_buffer(self, path: Any, truncate_last_traj: bool = True) -> None:
        super().load_replay_buffer(path, truncate_last_traj)
        self._install_relabel()

    # the update (the one statement of the math) -------------------------------------------------
    def _relabel(self, data: ReplayBufferSamples) -> tuple[ReplayBufferSamples, dict[str, th.Tensor]]:
        """The relabel hook of pre-training: one update of the reward module on ``data``, and ``data`` with its
        intrinsic reward; also the module's metrics."""
        assert self.reward_module is not None
        reward, metrics = self.reward_module.update_and_reward(data)
        metrics["intrinsic_reward_mean"] = reward.mean()
        metrics["intrinsic_reward_std"] = reward.std()
        return data._replace(rewards=reward), metrics

    def _noisy(self, mu: th.Tensor) -> th.Tensor:
        """``mu`` plus clipped gaussian noise, clamped to (-1, 1) with a straight-through gradient."""
        noise = th.randn_like(mu).mul_(self.exploration_std).clamp_(-self.exploration_clip, self.exploration_clip)
        action = mu + noise
        return action - action.detach() + action.detach().clamp(-1.0 + 1e-6, 1.0 - 1e-6)

    def critic_loss(self, data: ReplayBufferSamples) -> tuple[th.Tensor, th.Tensor]:
        """Twin-critic loss ``MSE(Q1, y) + MSE(Q2, y)`` and the mean target ``y``."""
        with th.no_grad():
            next_actions = self._noisy(self.actor(data.next_observations))
            next_q = min_q(self.critic_target(data.next_observations, next_actions))
            discounts = data.discounts if data.discounts is not None else self.gamma
            target_q = data.rewards + (1.0 - data.dones) * discounts * next_q
        losses = [F.mse_loss(q, target_q) for q in self.critic(data.observations, data.actions)]
        return reduce(operator.add, losses), target_q.mean()

    def actor_loss(self, obs: th.Tensor) -> th.Tensor:
        """``-min(Q1, Q2)`` at the noisy, clipped action of the actor."""
        return -min_q(self.critic(obs, self._noisy(self.actor(obs)))).mean()

    def _update(self, data: ReplayBufferSamples) -> dict[str, th.Tensor]:
        critic_loss, target_q = self.critic_loss(data)
        self.critic.optimizer.zero_grad(set_to_none=True)
        critic_loss.backward()
        self.critic.optimizer.step()

        # (a compiled step cannot switch requires_grad: the critic's weight gradients of the actor step are dropped
        # by the next critic step's zero_grad instead, the same update)
        freeze = self.freeze_critic_in_actor_step and not th.compiler.is_compiling()
        frozen = self._critic_params if freeze else []
        for param in frozen:  # no critic weight gradients in the actor step
            param.requires_grad_(False)
        actor_loss = self.actor_loss(data.observations)
        self.actor.optimizer.zero_grad(set_to_none=True)
        actor_loss.backward()
        self.actor.optimizer.step()
        for param in frozen:
            param.requires_grad_(True)

        with th.no_grad():
            th._foreach_lerp_(self._critic_target_params, self._critic_params, self.tau)
        return {"critic_loss": critic_loss.detach(), "actor_loss": actor_loss.detach(), "target_q": target_q}

    def _step(self, data: ReplayBufferSamples) -> dict[str, th.Tensor]:
        """One update on a sampled batch: the relabel hook (pre-training), then :meth:`_update`.

        A function of the batch and the networks' state: it returns 0-d tensors and never waits for the device,
        so that ``compile_update`` compiles it as it is.
        """
        metrics: dict[str, th.Tensor] = {}
        relabel = self.replay_buffer.relabel
        if relabel is not None:
            data, reward_metrics = relabel(data)
            metrics.update({f"reward/{key}": value for key, value in reward_metrics.items()})
        metrics.update({f"train/{key}": value for key, value in self._update(data).items()})
        if th.compiler.is_compiling():  # every compiled step starts without gradients (else it recompiles)
            for module in (self.policy, self.reward_module):
                for param in module.parameters() if module is not None else ():
                    param.grad = None
        return metrics

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        if not (speed_options.lean_acting and self.policy.training):  # lean acting leaves the policy in training mode
            self.policy.set_training_mode(True)
        self._update_learning_rate([self.actor.optimizer, self.critic.optimizer])
        step = compiled_step(self) if self.compile_update else self._step
        for _ in range(gradient_steps):
            self._n_updates += 1
            data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)  # type: ignore[union-attr]
            self._update_metrics.add(step(data))
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")

    def dump_logs(self) -> None:
        """SB3's, after recording the updates' metrics (means since the last dump) and the share of fixed skills."""
        self._update_metrics.record(self.logger)
        if self.skill_prior is not None and self.env is not None:
            self.logger.record("train/skill_fixed", float(np.mean(self.env.get_attr("fixed"))))
        super().dump_logs()

    # acting -------------------------------------------------------------------------------------
    def _sample_action(self, learning_starts: int, action_noise: Any = None, n_envs: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """SB3's exploration action; the policy acts from step 0 while a skill sweep asks it (``warmup_with_policy``),
        in one forward pass of the actor with ``speed_options.lean_acting`` (:func:`~sb3_cic.speed.lean_action`)."""
        learning_starts = 0 if self.warmup_with_policy else learning_starts
        if speed_options.lean_acting and isinstance(self._last_obs, np.ndarray) and self.num_timesteps >= learning_starts:
            return lean_action(self.policy, self._last_obs, action_noise)
        return super()._sample_action(learning_starts, action_noise, n_envs)

    def _store_transition(  # type: ignore[override]
        self, replay_buffer: ReplayBuffer, buffer_action: np.ndarray, new_obs: np.ndarray, reward: np.ndarray,
        dones: np.ndarray, infos: list[dict[str, Any]],
    ) -> None:
        """SB3's, after :func:`~sb3_cic.common.env_util.check_finite_step` (a non-finite value: ``ValueError``)."""
        check_finite_step(self.num_timesteps, new_obs, reward, infos)
        super()._store_transition(replay_buffer, buffer_action, new_obs, reward, dones, infos)

    def learn(
        self: SelfURLBDDPG,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 4,
        tb_log_name: str | None = None,
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfURLBDDPG:
        """Train for ``total_timesteps`` env steps (see SB3's ``learn``); when fine-tuning a skill-based method,
        its skill-selection callback runs first unless ``callback`` holds one (:func:`.finetune.with_finetune_callback`)."""
        check_range("total_timesteps", total_timesteps, 0)
        return super().learn(
            total_timesteps,
            callback=with_finetune_callback(self, callback),
            log_interval=log_interval,
            tb_log_name=tb_log_name or type(self).__name__,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )

    # fine-tune --------------------------------------------------------------------------------
    @classmethod
    def load_pretrained(
        cls: type[SelfURLBDDPG],
        path: Any,
        env: GymEnv | str,
        finetune_critic: str | None = None,
        device: th.device | str = "auto",
        **kwargs: Any,
    ) -> SelfURLBDDPG:
        """Start fine-tuning on a task from a pre-trained model: actor, reward module and critic (its trunk by
        default, as URLB) kept; fresh optimisers, empty replay buffer, extrinsic reward, step 0
        (:func:`~sb3_cic.finetune.start_finetuning`).

        :param path: saved pre-trained model
        :param env: the task environment (id, env or VecEnv)
        :param finetune_critic: "trunk", "all" or "none" (default: the class's :attr:`finetune_critic`)
        :param device: torch device
        :param kwargs: attributes to override (for example ``learning_starts``, ``tensorboard_log``)
        """
        model = cls.load(path, env=env, device=device, reward_free=False, **kwargs)
        start_finetuning(model, env, finetune_critic or cls.finetune_critic)
        return model


def check_ddpg_arguments(args: dict[str, Any], ranges: dict[str, Range | Flag]) -> None:
    """``ValueError`` naming the first of :class:`URLBDDPG`'s arguments that it cannot take.

    :param args: the constructor's arguments by name (its ``locals()``)
    :param ranges: the range of each (:attr:`URLBDDPG.argument_ranges`)
    """
    if args["optimize_memory_usage"]:
        raise ValueError(
            "optimize_memory_usage is not supported: URLB's n-step replay buffer keeps next observations; "
            "lower buffer_size to save memory"
        )
    buffer_class = args["replay_buffer_class"]
    if not (isinstance(buffer_class, type) and issubclass(buffer_class, URLBReplayBuffer)):
        raise ValueError(
            f"replay_buffer_class must subclass sb3_cic.URLBReplayBuffer (n-step returns, skill-consistent next "
            f"observations, intrinsic-reward relabelling), got {buffer_class!r}; HerReplayBuffer needs goal-conditioned "
            "Dict observations, which URLB agents do not take"
        )
    check_ranges(args, ranges, ranges)
