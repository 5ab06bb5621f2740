"""URLB-faithful DDPG: the engine every unsupervised method of this package runs on."""

from __future__ import annotations

import operator
import zipfile
from functools import reduce
from typing import Any, ClassVar, TypeVar

import gymnasium as gym
import numpy as np
import torch as th
import torch.nn.functional as F
from gymnasium import spaces
from stable_baselines3 import DDPG
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.noise import ActionNoise, NormalActionNoise
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.save_util import json_to_data, open_path
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, ReplayBufferSamples, Schedule
from stable_baselines3.common.vec_env import VecEnv, unwrap_vec_normalize

from envs.skill_wrapper import SkillObservationWrapper, VecSkillObservation
from sb3_cic.buffers import URLBReplayBuffer
from sb3_cic.policies import URLBPolicy, check_positive_int, hidden_dim_from_net_arch, min_q
from sb3_cic.rewards.base import RewardModule
from sb3_cic.skills import SkillPrior
from sb3_cic.speed import speed_options

SelfURLBDDPG = TypeVar("SelfURLBDDPG", bound="URLBDDPG")


def _find_skill_wrapper(env: gym.Env) -> SkillObservationWrapper | None:
    while isinstance(env, gym.Wrapper):
        if isinstance(env, SkillObservationWrapper):
            return env
        env = env.env
    return None


def env_id_of(env: GymEnv | str | None) -> str | None:
    """The Gymnasium id of ``env`` (an id, an env or a VecEnv), or None when it has none."""
    if env is None or isinstance(env, str):
        return env
    try:
        spec = env.get_attr("spec", indices=[0])[0] if isinstance(env, VecEnv) else env.spec
    except AttributeError:
        spec = None
    return None if spec is None else spec.id


def read_saved_data(path: Any, custom_objects: dict[str, Any] | None = None) -> dict[str, Any]:
    """The saved attributes of a model file (its ``data`` entry only; the networks are not read).

    :param path: a path (``.zip`` added when missing, as SB3's ``load``) or a file object (left at its position)
    :param custom_objects: see SB3's ``load``
    """
    file = open_path(path, "r", suffix="zip")
    start = file.tell()
    try:
        with zipfile.ZipFile(file) as archive:
            if "data" not in archive.namelist():
                raise ValueError(f"{path} holds no saved model data")
            return json_to_data(archive.read("data").decode(), custom_objects=custom_objects)
    except zipfile.BadZipFile as error:
        raise ValueError(f"Error: the file {path} wasn't a zip-file") from error
    finally:
        if file is path:
            file.seek(start)
        else:
            file.close()


def package_version() -> str:
    """This package's version (saved with each model)."""
    from sb3_cic import __version__

    return __version__


def check_range(name: str, value: Any, low: float, high: float = float("inf"), low_open: bool = False) -> None:
    """Raise a ``ValueError`` naming ``name`` unless ``low <= value <= high`` (``low < value`` with ``low_open``).

    :param name: argument name for the message
    :param value: the value given
    :param low: lower bound
    :param high: upper bound
    :param low_open: exclude ``low`` itself
    """
    number = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool) and not np.isnan(value)
    if not number or not (value > low if low_open else value >= low) or value > high:
        bounds = f"{'(' if low_open else '['}{low}, {high}]" if np.isfinite(high) else f"{'>' if low_open else '>='} {low}"
        raise ValueError(f"{name} must be {'in ' if np.isfinite(high) else ''}{bounds}, got {value!r}")


def normalize_policy_kwargs(policy_kwargs: dict[str, Any] | None) -> dict[str, Any]:
    """``policy_kwargs`` in the form the model saves: SB3's ``net_arch`` as ``hidden_dim``, ``n_critics`` set (2).

    :param policy_kwargs: the user's policy arguments
    """
    policy_kwargs = dict(policy_kwargs or {})
    if "net_arch" in policy_kwargs:  # SB3's form of the width
        width = hidden_dim_from_net_arch(policy_kwargs.pop("net_arch"))
        if policy_kwargs.setdefault("hidden_dim", width) != width:
            raise ValueError(f"net_arch says width {width}, hidden_dim {policy_kwargs['hidden_dim']}: give one of them")
    if "hidden_dim" in policy_kwargs:
        check_positive_int("hidden_dim", policy_kwargs["hidden_dim"])
    policy_kwargs.setdefault("n_critics", 2)  # URLB's twin critic (SB3's DDPG would set 1)
    return policy_kwargs


def prepare_env(env: GymEnv | str, prior: SkillPrior | None, resample_every: int | None = 50) -> GymEnv:
    """Make ``env`` (an id, an env or a VecEnv) ready for a URLB agent.

    Checks that actions are continuous and observations flat states, and adds the skill when the agent
    has a skill prior and the env does not carry it yet: an env is wrapped with
    :class:`~envs.SkillObservationWrapper`, a VecEnv of plain envs with :class:`~envs.VecSkillObservation`.
    A wrapper with another skill size is a ``ValueError``, and so is a VecNormalize below the skill
    (its statistics would have the state's size).

    :param env: environment id, environment or VecEnv
    :param prior: the agent's skill prior, or None
    :param resample_every: skill resampling period given to a new wrapper
    """
    if isinstance(env, str):
        env = gym.make(env)
    if not isinstance(env.action_space, spaces.Box):
        raise ValueError(f"URLB agents need a continuous (Box) action space, got {env.action_space}")
    obs_space = env.observation_space
    if not isinstance(obs_space, spaces.Box) or len(obs_space.shape) != 1:
        raise ValueError(
            f"URLB agents work on flat state observations (a 1-D Box), got {obs_space}; "
            "image or Dict observations are not supported"
        )
    if prior is None:
        return env
    if isinstance(env, VecEnv):
        if not all(env.env_is_wrapped(SkillObservationWrapper)):
            if unwrap_vec_normalize(env) is not None:
                raise ValueError(
                    "a skill-based agent cannot add its skill above VecNormalize: wrap each env in "
                    "SkillObservationWrapper first (make_vec_env(..., wrapper_class=...)), then VecNormalize"
                )
            return VecSkillObservation(env, prior, resample_every=resample_every)
        dims = set(env.get_attr("skill_dim"))
        if dims != {prior.dim}:
            raise ValueError(f"the env's SkillObservationWrapper has skill_dim {dims}, the agent's prior {prior.dim}")
        return env
    wrapper = _find_skill_wrapper(env)
    if wrapper is None:
        return SkillObservationWrapper(env, prior, resample_every=resample_every)
    if wrapper.skill_dim != prior.dim:
        raise ValueError(f"the env's SkillObservationWrapper has skill_dim {wrapper.skill_dim}, the agent's prior {prior.dim}")
    return env


class SavedModel:
    """What :meth:`URLBDDPG.load` reads of a saved model before loading it, to explain a mistake.

    :param data: the saved attributes (:func:`read_saved_data`)
    """

    def __init__(self, data: dict[str, Any]) -> None:
        self.data = data
        self.algorithm: str | None = data.get("algorithm")
        self.prior: SkillPrior | None = data.get("skill_prior")
        self.skill_dim = 0 if self.prior is None else self.prior.dim
        self.obs_dim = int(data["observation_space"].shape[0])
        self.action_shape = tuple(data["action_space"].shape)

    def describe(self) -> str:
        """``"the snapshot (CIC, pre-trained on URLB/walker-v0: state 24 + skill 64, action 6)"``."""
        skill = f" + skill {self.skill_dim}" if self.skill_dim else ""
        where = f"pre-trained on {self.data['env_id']}: " if self.data.get("env_id") else ""
        action = int(np.prod(self.action_shape))
        state = self.obs_dim - self.skill_dim
        return f"the snapshot ({self.algorithm or 'a model'}, {where}state {state}{skill}, action {action})"

    def version_note(self) -> str:
        """A note on the package version that saved the snapshot when it is not this one (else empty)."""
        saved = self.data.get("package_version")
        if saved == package_version():
            return ""
        return f" (saved by {'sb3-cic ' + saved if saved else 'an earlier sb3-cic'}; this is sb3-cic {package_version()})"

    def check_class(self, cls: type) -> None:
        """``ValueError`` unless the snapshot was saved by ``cls``, one of its bases or a subclass of them."""
        names = {c.__name__ for c in cls.__mro__}
        if self.algorithm is not None and self.algorithm not in names:
            raise ValueError(
                f"{self.describe()} is a {self.algorithm} model: use {self.algorithm}.load_pretrained "
                f"(or {self.algorithm}.load), not {cls.__name__}'s{self.version_note()}"
            )

    def check_env(self, env: GymEnv | str) -> GymEnv:
        """``env`` prepared with the saved skill prior, or a ``ValueError`` saying how it differs from the snapshot's."""
        name = env_id_of(env) or type(env).__name__
        try:
            env = prepare_env(env, self.prior, self.data.get("skill_resample_every", 50))
        except ValueError as error:
            if "skill_dim" not in str(error):
                raise
            raise ValueError(
                f"{self.describe()}: {error}; pass the plain env (the model adds its own skill){self.version_note()}"
            ) from error
        obs_dim, action_shape = env.observation_space.shape[0], env.action_space.shape
        if obs_dim != self.obs_dim or action_shape != self.action_shape:
            raise ValueError(
                f"{self.describe()} cannot act on {name} (state {obs_dim - self.skill_dim}, action "
                f"{int(np.prod(action_shape))}): fine-tune a snapshot pre-trained on {name}'s domain{self.version_note()}"
            )
        return env


class URLBDDPG(DDPG):
    """DDPG as in the Unsupervised RL Benchmark (Laskin et al., 2021), the base of every method here.

    Reference implementation: https://github.com/rll-research/url_benchmark (``agent/ddpg.py``).
    Differences from SB3's DDPG, all URLB's: a twin critic with LayerNorm/Tanh trunks
    (:class:`~sb3_cic.policies.URLBPolicy`); exploration ``mu + N(0, 0.2^2)``; for the target and
    the actor loss the noise is clipped to +-0.3 and the action clamped with a straight-through
    gradient; target ``r + disc * min(Q1', Q2')`` with the target action from the online actor (URLB has
    no target actor); actor loss ``-min(Q1, Q2)`` at every update; n-step (3) returns; 4,000 random
    steps, then one update every 2 env steps.

    Unsupervised methods subclass it with a skill prior (:attr:`skill_prior`, the env is wrapped with
    :class:`~envs.SkillObservationWrapper`) and an intrinsic reward module (:meth:`_make_reward_module`).
    In pre-training (``reward_free=True``) the replay buffer's relabel hook trains the reward module on
    every sampled batch and replaces the batch's reward with the intrinsic reward. Fine-tuning starts
    with :meth:`load_pretrained`.

    Deliberate deviations from the reference code: the intrinsic reward of a batch is computed by the
    reward networks as they were when the batch was sampled (URLB: just after their update on that
    batch); at fine-tuning the target critic starts as a copy of the loaded critic (URLB leaves it at
    its random initialisation).

    :param policy: the policy model (``"MlpPolicy"``; width through ``policy_kwargs={"hidden_dim": ...}``)
    :param env: environment id, environment or VecEnv
    :param learning_rate: Adam learning rate of actor and critic
    :param buffer_size: replay capacity
    :param learning_starts: random-action steps before learning
    :param batch_size: minibatch size
    :param tau: soft target update coefficient (at every update)
    :param gamma: discount factor
    :param train_freq: env steps between updates
    :param gradient_steps: updates per ``train_freq``
    :param action_noise: exploration noise of the actions taken in the env (SB3's ``ActionNoise``); default:
        URLB's ``N(0, exploration_std^2)`` (:class:`~stable_baselines3.common.noise.NormalActionNoise`). It
        replaces that noise in acting only: the target action and the actor loss keep URLB's clipped
        ``exploration_std`` noise
    :param replay_buffer_class: a subclass of :class:`~sb3_cic.buffers.URLBReplayBuffer` (the default)
    :param optimize_memory_usage: not supported (``ValueError`` if True): URLB's n-step buffer keeps next
        observations; lower ``buffer_size`` to save memory
    :param n_steps: n of the n-step return
    :param exploration_std: std of the gaussian exploration noise
    :param exploration_clip: clip of that noise for the target action and the actor loss
    :param reward_free: pre-training mode: train the reward module and use its reward
        (default: True for a method with a reward module)
    :param skill_prior: skill prior (None: no skill)
    :param skill_resample_every: skill resampling period of the skill wrapper
    :param replay_buffer_kwargs: extra arguments of :class:`~sb3_cic.buffers.URLBReplayBuffer`
    :param stats_window_size: episodes averaged in the rollout logs
    :param tensorboard_log: tensorboard log folder
    :param policy_kwargs: policy arguments: ``hidden_dim`` (or SB3's ``net_arch=[h, h]``), ``n_critics`` (2)
    :param verbose: verbosity
    :param seed: random seed
    :param device: torch device
    :param _init_setup_model: build the networks at construction
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"MlpPolicy": URLBPolicy}  # type: ignore[assignment]
    policy: URLBPolicy
    #: what fine-tuning keeps of the pre-trained critic: "trunk" (URLB), "all" (ProtoRL) or "none"
    finetune_critic: ClassVar[str] = "trunk"
    #: freeze the critic's weights during the actor step (no weight gradients; same actor update)
    freeze_critic_in_actor_step: bool = True

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
        skill_resample_every: int | None = 50,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
    ) -> None:
        replay_buffer_class = replay_buffer_class or URLBReplayBuffer
        self._check_arguments(locals())
        for name, value in vars(self).items():  # the methods' reward-module widths (cic_hidden_dim...), set before
            if name.endswith("_hidden_dim") and value is not None:
                check_positive_int(name, value)
        policy_kwargs = normalize_policy_kwargs(policy_kwargs)
        #: the id of the env the model was built on (None if it has none), and what saved it: read by
        #: :meth:`load` to explain a snapshot loaded onto the wrong env or class
        self.env_id = env_id_of(env)
        self.algorithm = type(self).__name__
        self.package_version = package_version()
        if _init_setup_model:  # ``load`` prepares the env itself, with the saved prior
            env = prepare_env(env, skill_prior, skill_resample_every)
        super().__init__(
            policy,
            env,
            learning_rate=learning_rate,
            buffer_size=buffer_size,
            learning_starts=learning_starts,
            batch_size=batch_size,
            tau=tau,
            gamma=gamma,
            train_freq=train_freq,
            gradient_steps=gradient_steps,
            action_noise=action_noise,
            replay_buffer_class=replay_buffer_class,
            replay_buffer_kwargs=replay_buffer_kwargs,
            tensorboard_log=tensorboard_log,
            policy_kwargs=policy_kwargs,
            verbose=verbose,
            seed=seed,
            device=device,
            _init_setup_model=False,
        )
        self.n_steps = n_steps
        self._stats_window_size = stats_window_size
        self.exploration_std = exploration_std
        self.exploration_clip = exploration_clip
        self.skill_prior = skill_prior
        self.skill_resample_every = skill_resample_every
        self.reward_free = reward_free
        #: act with the policy (instead of uniformly) during the first ``learning_starts`` steps
        self.warmup_with_policy = False
        #: the skill chosen for fine-tuning, once a skill-selection callback has chosen it
        self.finetune_skill: np.ndarray | None = None
        self.reward_module: RewardModule | None = None
        #: the skill last given to :meth:`set_skill` (appended to plain observations when there is no env)
        self.skill: np.ndarray | None = None
        if _init_setup_model:
            self._setup_model()

    @staticmethod
    def _check_arguments(args: dict[str, Any]) -> None:
        """``ValueError`` naming the first argument out of its range (before anything is built)."""
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
        learning_rate = args["learning_rate"]
        if not callable(learning_rate):
            check_range("learning_rate", learning_rate, 0.0, low_open=True)
        check_range("buffer_size", args["buffer_size"], 1)
        check_range("batch_size", args["batch_size"], 1, args["buffer_size"])
        check_range("learning_starts", args["learning_starts"], 0)
        check_range("tau", args["tau"], 0.0, 1.0)
        check_range("gamma", args["gamma"], 0.0, 1.0)
        if args["gradient_steps"] != -1:
            check_range("gradient_steps", args["gradient_steps"], 0)
        train_freq = args["train_freq"]
        check_range("train_freq", train_freq[0] if isinstance(train_freq, tuple) else train_freq, 1)
        check_range("n_steps", args["n_steps"], 1)
        check_range("exploration_std", args["exploration_std"], 0.0)
        check_range("exploration_clip", args["exploration_clip"], 0.0)
        check_range("stats_window_size", args["stats_window_size"], 1)

    # construction -----------------------------------------------------------------------------
    @property
    def skill_dim(self) -> int:
        """Size of the skill appended to the observation (0 without a skill prior)."""
        return 0 if self.skill_prior is None else self.skill_prior.dim

    @property
    def state_dim(self) -> int:
        """Size of the state part of the observation."""
        return int(self.observation_space.shape[0]) - self.skill_dim

    @property
    def action_dim(self) -> int:
        """Number of action entries (a multi-dimensional Box action is flattened)."""
        return int(np.prod(self.action_space.shape))

    @property
    def hidden_dim(self) -> int:
        """Hidden width of actor and critic."""
        return int(self.policy_kwargs.get("hidden_dim", 1024))

    def _make_reward_module(self) -> RewardModule | None:
        """Build the intrinsic reward module (None for plain DDPG). Overridden by the methods."""
        return None

    def _setup_model(self) -> None:
        if self.action_noise is None:
            shape = self.action_space.shape
            self.action_noise = NormalActionNoise(np.zeros(shape), np.full(shape, self.exploration_std))
        self.replay_buffer_kwargs = {
            **self.replay_buffer_kwargs,
            "n_steps": self.n_steps,
            "gamma": self.gamma,
            "skill_dim": self.skill_dim,
        }
        n_steps, self.n_steps = self.n_steps, 1  # n-step returns are configured on our buffer
        super()._setup_model()
        self.n_steps = n_steps
        self.policy.skill_dim = self.skill_dim
        self.reward_module = self._make_reward_module()
        if self.reward_module is not None:
            self.reward_module.to(self.device)
        if self.reward_free is None:
            self.reward_free = self.reward_module is not None
        if self.reward_free and self.reward_module is None:
            raise ValueError(f"{type(self).__name__} has no intrinsic reward module: reward_free must be False")
        self._critic_params = list(self.critic.parameters())
        self._critic_target_params = list(self.critic_target.parameters())
        self._install_relabel()

    def _install_relabel(self) -> None:
        assert isinstance(self.replay_buffer, URLBReplayBuffer)
        self.replay_buffer.relabel = self._relabel if self.reward_free else None

    def load_replay_buffer(self, path: Any, truncate_last_traj: bool = True) -> None:
        super().load_replay_buffer(path, truncate_last_traj)
        self._install_relabel()

    # skills -------------------------------------------------------------------------------------
    def set_skill(self, skill: np.ndarray, fixed: bool = True) -> None:
        """Set the skill of every training env (and of the pending observation) and of :meth:`predict`.

        :param skill: a skill of the prior's support
        :param fixed: keep it fixed instead of resampling
        """
        if self.skill_prior is None:
            raise ValueError(f"{type(self).__name__} has no skill")
        z = self.skill_prior.validate(skill)
        self.skill = z.copy()
        if self.env is not None:
            self.env.env_method("set_skill", z, fixed)
        if self._last_obs is not None:
            self._last_obs[:, -self.skill_dim :] = z  # type: ignore[index]

    def current_skill(self) -> np.ndarray:
        """The skill the model acts with on a plain observation: the fine-tuning skill once chosen, else the
        first training env's current skill, else the last :meth:`set_skill`; ``ValueError`` if none."""
        if self.skill_prior is None:
            raise ValueError(f"{type(self).__name__} has no skill")
        if self.finetune_skill is not None:
            return self.finetune_skill
        if self.env is not None:
            return np.asarray(self.env.env_method("get_skill", indices=[0])[0], dtype=np.float32)
        if self.skill is None:
            raise ValueError(
                f"{type(self).__name__} has no current skill to append to a state observation "
                f"(no env): call model.set_skill(z) first, or pass [state, skill] observations"
            )
        return self.skill

    def predict(
        self,
        observation: np.ndarray | dict[str, np.ndarray],
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """The action for ``observation`` (see SB3's ``predict``).

        A skill-based model also takes plain state observations (as a plain env or a VecEnv of plain envs
        returns them, for example in ``evaluate_policy`` or SB3's ``EvalCallback``): it appends
        :meth:`current_skill`. ``[state, skill]`` observations are used as they are.
        """
        if isinstance(observation, np.ndarray) and observation.ndim > 0:
            size = observation.shape[-1]
            if self.skill_prior is not None and size == self.state_dim:
                skill = np.broadcast_to(self.current_skill(), (*observation.shape[:-1], self.skill_dim))
                observation = np.concatenate([observation, skill], axis=-1)
            elif size not in (self.state_dim, self.observation_space.shape[0]):
                skill = f" + skill {self.skill_dim}" if self.skill_dim else ""
                raise ValueError(
                    f"{type(self).__name__} acts on observations of state {self.state_dim}{skill} (env "
                    f"{self.env_id or 'unknown'}), got shape {observation.shape}: is this env of another domain? "
                    "model.wrap_env(env) wraps an env of the model's domain as the training env is"
                )
        return super().predict(observation, state, episode_start, deterministic)

    def wrap_env(self, env: GymEnv | str) -> GymEnv:
        """``env`` (an id, an env or a VecEnv) wrapped as the training env is, for evaluation or SB3 callbacks.

        A skill-based model adds its skill wrapper (:class:`~envs.SkillObservationWrapper`, or
        :class:`~envs.VecSkillObservation` for a VecEnv of plain envs), with the skill fixed to the
        fine-tuning skill once one is chosen; other models check the env only. ``predict`` also takes
        plain state observations, so SB3's ``EvalCallback(plain_env)`` works without it.

        :param env: environment id, environment or VecEnv
        """
        env = prepare_env(env, self.skill_prior, self.skill_resample_every)
        if self.skill_prior is not None and self.finetune_skill is not None:
            if isinstance(env, VecEnv):
                env.env_method("set_skill", self.finetune_skill, True)
            else:
                wrapper = _find_skill_wrapper(env)
                assert wrapper is not None
                wrapper.set_skill(self.finetune_skill, True)
        return env

    def set_env(self, env: GymEnv | str, force_reset: bool = True) -> None:
        """Use ``env`` for training from now on (see SB3's ``set_env``); a plain env gets the model's skill wrapper."""
        super().set_env(prepare_env(env, self.skill_prior, self.skill_resample_every), force_reset)  # type: ignore[arg-type]

    def make_finetune_callback(self) -> BaseCallback | None:
        """The skill-selection callback :meth:`learn` adds when fine-tuning a skill-based method."""
        return None

    # the update ---------------------------------------------------------------------------------
    def _relabel(self, data: ReplayBufferSamples) -> ReplayBufferSamples:
        assert self.reward_module is not None
        reward, metrics = self.reward_module.update_and_reward(data)
        metrics["intrinsic_reward_mean"] = reward.mean()
        metrics["intrinsic_reward_std"] = reward.std()
        self._reward_metrics = metrics
        return data._replace(rewards=reward)

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

        frozen = self._critic_params if self.freeze_critic_in_actor_step else []
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

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        if not (speed_options.lean_acting and self.policy.training):  # lean acting leaves the policy in training mode
            self.policy.set_training_mode(True)
        self._update_learning_rate([self.actor.optimizer, self.critic.optimizer])
        for _ in range(gradient_steps):
            self._n_updates += 1
            data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)  # type: ignore[union-attr]
            metrics = self._update(data)

        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        for key, value in metrics.items():
            self.logger.record(f"train/{key}", value.item())
        if self.reward_free:
            for key, value in self._reward_metrics.items():
                self.logger.record(f"reward/{key}", value.item())
        if self.skill_prior is not None and self.env is not None:
            self.logger.record("train/skill_fixed", float(np.mean(self.env.get_attr("fixed"))))

    def _sample_action(
        self, learning_starts: int, action_noise: Any = None, n_envs: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        """SB3's exploration action (see ``OffPolicyAlgorithm._sample_action``).

        With ``speed_options.lean_acting`` the policy's action comes from one forward pass of the actor
        on the pending observations instead of SB3's ``predict``, which checks, converts and reshapes
        them and switches the networks to evaluation mode at every env step (URLB's actor has no
        layer that acts differently in training mode). The same float32 input, the same rescaling, the
        same noise: the same action.
        """
        learning_starts = 0 if self.warmup_with_policy else learning_starts
        obs = self._last_obs
        lean = speed_options.lean_acting and isinstance(obs, np.ndarray) and isinstance(self.action_space, spaces.Box)
        if not lean or self.num_timesteps < learning_starts:
            return super()._sample_action(learning_starts, action_noise, n_envs)
        with th.no_grad():
            mu = self.actor(th.as_tensor(obs, device=self.device).float())
        unscaled_action = self.policy.unscale_action(mu.cpu().numpy().reshape((-1, *self.action_space.shape)))
        scaled_action = self.policy.scale_action(unscaled_action)  # SB3's round trip, kept for the same numbers
        if action_noise is not None:
            scaled_action = np.clip(scaled_action + action_noise(), -1, 1)
        return self.policy.unscale_action(scaled_action), scaled_action

    def learn(
        self: SelfURLBDDPG,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 4,
        tb_log_name: str | None = None,
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfURLBDDPG:
        """Train for ``total_timesteps`` env steps (see SB3's ``learn``).

        When fine-tuning a skill-based method, the method's skill-selection callback
        (:meth:`make_finetune_callback`) runs first unless ``callback`` already holds one.
        """
        check_range("total_timesteps", total_timesteps, 0)
        return super().learn(
            total_timesteps,
            callback=self._with_finetune_callback(callback),
            log_interval=log_interval,
            tb_log_name=tb_log_name or type(self).__name__,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )

    def _with_finetune_callback(self, callback: MaybeCallback) -> MaybeCallback:
        from sb3_cic.callbacks import SkillSelectionCallback

        if self.reward_free or self.skill_prior is None:
            return callback
        user = callback if isinstance(callback, list) else [] if callback is None else [callback]
        flat = [c for cb in user for c in (cb.callbacks if isinstance(cb, CallbackList) else [cb])]
        if any(isinstance(c, SkillSelectionCallback) for c in flat):
            return callback
        selection = self.make_finetune_callback()
        if selection is None:
            return callback
        return CallbackList([selection, *user])

    # save / load / fine-tune --------------------------------------------------------------------
    def _excluded_save_params(self) -> list[str]:
        excluded = ["reward_module", "_critic_params", "_critic_target_params", "_reward_metrics"]
        return [*super()._excluded_save_params(), *excluded]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, variables = super()._get_torch_save_params()
        if self.reward_module is not None:
            state_dicts += ["reward_module", "reward_module.optimizer"]
        return state_dicts, variables

    @classmethod
    def load(  # type: ignore[override]
        cls: type[SelfURLBDDPG],
        path: Any,
        env: GymEnv | str | None = None,
        device: th.device | str = "auto",
        custom_objects: dict[str, Any] | None = None,
        print_system_info: bool = False,
        force_reset: bool = True,
        **kwargs: Any,
    ) -> SelfURLBDDPG:
        """Load a saved model (see SB3's ``load``); ``env`` may be an id and is wrapped with the saved skill prior.

        A snapshot of another method, or one whose state or action size differs from ``env``'s, is a
        ``ValueError`` that says which method or env it was saved with and what to do.
        """
        if "policy_kwargs" in kwargs:  # compared with the saved ones, which are normalised
            kwargs["policy_kwargs"] = normalize_policy_kwargs(kwargs["policy_kwargs"])
        saved = SavedModel(read_saved_data(path, custom_objects))
        saved.check_class(cls)
        if env is not None:
            env = saved.check_env(env)
        try:
            model = super().load(
                path, env=env, device=device, custom_objects=custom_objects,
                print_system_info=print_system_info, force_reset=force_reset, **kwargs,
            )
        except RuntimeError as error:  # the networks' state dicts do not fit this class's
            raise ValueError(f"{saved.describe()} does not fit {cls.__name__}: {error}{saved.version_note()}") from error
        model.package_version = package_version()  # what will save it next
        return model  # type: ignore[return-value]

    @classmethod
    def load_pretrained(
        cls: type[SelfURLBDDPG],
        path: Any,
        env: GymEnv | str,
        finetune_critic: str | None = None,
        device: th.device | str = "auto",
        **kwargs: Any,
    ) -> SelfURLBDDPG:
        """Start fine-tuning on a task from a pre-trained model.

        Keeps the actor, the reward module and the critic (its trunk only by default, as URLB), with
        fresh optimisers, an empty replay buffer, the extrinsic reward (``reward_free=False``) and step 0.

        :param path: saved pre-trained model
        :param env: the task environment (id, env or VecEnv)
        :param finetune_critic: "trunk", "all" or "none" (default: the class's :attr:`finetune_critic`)
        :param device: torch device
        :param kwargs: attributes to override (for example ``learning_starts``, ``tensorboard_log``)
        """
        model = cls.load(path, env=env, device=device, reward_free=False, **kwargs)
        model.env_id = env_id_of(env) or model.env_id
        keep = finetune_critic or cls.finetune_critic
        if keep not in ("trunk", "all", "none"):
            raise ValueError(f"finetune_critic must be 'trunk', 'all' or 'none', got {keep!r}")
        if keep == "trunk":
            model.critic.reset_heads()
        elif keep == "none":
            model.policy.critic = model.critic = model.policy.make_critic()
        model.critic_target.load_state_dict(model.critic.state_dict())
        policy = model.policy
        lr = model.lr_schedule(1)
        model.actor.optimizer = policy.optimizer_class(model.actor.parameters(), lr=lr, **policy.optimizer_kwargs)
        model.critic.optimizer = policy.optimizer_class(model.critic.parameters(), lr=lr, **policy.optimizer_kwargs)
        model._critic_params = list(model.critic.parameters())
        model.finetune_skill = None
        model.num_timesteps = 0
        model._n_updates = 0
        model._episode_num = 0
        model._install_relabel()
        return model
