"""Callbacks of the URLB protocol: skill selection for fine-tuning, evaluation with normalised scores."""

from __future__ import annotations

import copy
import warnings
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from stable_baselines3.common.callbacks import EvalCallback
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_cic.envs.skill_wrapper import SkillObservationWrapper
from sb3_cic.common.arguments import parameter_default
from sb3_cic.common.env_util import make_env, prepare_env
from sb3_cic.common.resumable import ResumableCallback, env_state, set_env_state
from sb3_cic.constants import normalized_score


class SkillSelectionCallback(ResumableCallback):
    """Base of the callbacks that choose the skill a skill-based agent is fine-tuned with.

    Once a skill is chosen it is stored in ``model.finetune_skill`` (saved with the model) and fixed
    in the training envs; a later ``learn`` call re-fixes it instead of choosing again.

    :param verbose: verbosity
    """

    @classmethod
    def for_model(cls, model: Any, **kwargs: Any) -> SkillSelectionCallback:
        """The callback a method's fine-tuning uses (its ``finetune_skill_choices`` entry), with the model's verbosity.

        :param model: the model about to be fine-tuned
        :param kwargs: the callback's arguments
        """
        return cls(**kwargs, verbose=model.verbose)

    def _on_training_start(self) -> None:
        if self.resumed:  # the checkpoint restored the selection, the skill and the envs
            return
        if self.model.finetune_skill is not None:
            self.model.set_skill(self.model.finetune_skill, fixed=True)
            self.done = True
        else:
            self.done = False
            self._start()

    def _start(self) -> None:
        """Begin the selection (called at the start of training when no skill was chosen yet)."""

    def choose(self, skill: np.ndarray) -> None:
        """Fix ``skill`` for the rest of fine-tuning."""
        self.model.set_skill(skill, fixed=True)
        self.model.finetune_skill = np.asarray(skill, dtype=np.float32).copy()
        self.model.warmup_with_policy = False
        self.done = True
        if self.verbose:
            print(f"{type(self).__name__}: fine-tuning with skill {np.array2string(skill[:4], precision=3)}...")

    def _on_step(self) -> bool:
        return True

    def get_checkpoint_state(self) -> dict[str, Any]:
        return {"done": self.done}

    def set_checkpoint_state(self, state: dict[str, Any]) -> None:
        self.done = state["done"]


class FixedSkillCallback(SkillSelectionCallback):
    """Fine-tune with one fixed skill (the CIC reference code fixes ``0.5 * 1``).

    :param value: a scalar ``c`` (skill ``c * 1``) or a full skill vector
    :param verbose: verbosity
    """

    def __init__(self, value: float | np.ndarray = 0.5, verbose: int = 0) -> None:
        super().__init__(verbose)
        self.value = value

    def _start(self) -> None:
        dim = self.model.skill_dim
        skill = np.full(dim, self.value, dtype=np.float32) if np.isscalar(self.value) else np.asarray(self.value)
        self.choose(skill)


class SkillSweepWarning(UserWarning):
    """A fine-tuning skill sweep shorter than the paper's (fewer candidates): ``learning_starts`` below 4,000."""


class SkillGridSweepCallback(SkillSelectionCallback):
    """The CIC paper's fine-tuning skill choice (Algorithm 1).

    During the first ``sweep_steps`` steps (no gradient updates yet), fix each candidate of the
    prior's grid in turn for ``window`` steps (CIC: constant skills ``c * 1``, ``c`` on an even grid
    over [0, 1], 40 candidates of 100 steps), sum the extrinsic reward each window earns, then fix
    the candidate whose window earned the most. Each candidate and its window return are logged
    (``sweep/``) and kept in :attr:`results`.

    While sweeping, the agent acts with its pre-trained policy and the candidate skill
    (``act_with_policy=True``): with uniformly random actions the skill could not change the reward.

    :param sweep_steps: length of the sweep (the random-action phase of URLB: 4,000)
    :param window: steps per candidate (100); for discrete priors, ``sweep_steps // n_skills``
    :param act_with_policy: act with the policy during the sweep instead of uniformly at random
    :param verbose: verbosity
    """

    def __init__(self, sweep_steps: int = 4000, window: int | None = 100, act_with_policy: bool = True, verbose: int = 0):
        super().__init__(verbose)
        self.sweep_steps = sweep_steps
        self.window = window
        self.act_with_policy = act_with_policy
        self.results: list[tuple[np.ndarray, float]] = []

    @classmethod
    def for_model(cls, model: Any, **kwargs: Any) -> SkillGridSweepCallback:
        """The sweep of a method's fine-tuning: as long as the model's random-action phase (``learning_starts``).

        :param model: the model about to be fine-tuned
        :param kwargs: the other arguments (``window``...)
        """
        return cls(sweep_steps=model.learning_starts, **kwargs, verbose=model.verbose)

    def _start(self) -> None:
        prior = self.model.skill_prior
        n = max(1, self.sweep_steps // self.window) if self.window else None  # a sweep shorter than a window: 1
        self.candidates = prior.grid(n)
        paper_steps = parameter_default(type(self), "sweep_steps")
        if self.window and self.sweep_steps < paper_steps:
            warnings.warn(
                f"the fine-tuning skill sweep tries {len(self.candidates)} candidates, not the paper's "
                f"{len(prior.grid(paper_steps // self.window))}: it lasts learning_starts {self.sweep_steps} steps at "
                f"{self.window} per candidate (learning_starts {paper_steps} for the full sweep)",
                SkillSweepWarning,
                stacklevel=2,
            )
        self._window = max(1, min(self.window, self.sweep_steps) if self.window else self.sweep_steps // len(self.candidates))
        if len(self.candidates) < 1:
            raise ValueError("the skill grid sweep needs at least one candidate")
        self.model.warmup_with_policy = self.act_with_policy
        self._index, self._steps, self._return = 0, 0, 0.0
        self.results = []
        self.model.set_skill(self.candidates[0], fixed=True)

    def _on_step(self) -> bool:
        if self.done:
            return True
        self._return += float(np.mean(self.locals["rewards"]))
        self._steps += 1
        if self._steps < self._window:
            return True
        skill = self.candidates[self._index]
        self.results.append((skill, self._return))
        self.logger.record("sweep/candidate", float(skill.mean()) if skill.size else 0.0)
        self.logger.record("sweep/window_return", self._return)
        self.logger.dump(self.num_timesteps)  # one record per window (records between dumps overwrite)
        self._index += 1
        self._steps, self._return = 0, 0.0
        if self._index < len(self.candidates):
            self.model.set_skill(self.candidates[self._index], fixed=True)
        else:
            best = int(np.argmax([ret for _, ret in self.results]))
            self.logger.record("sweep/best_return", self.results[best][1])
            self.choose(self.results[best][0])
        return True

    def get_checkpoint_state(self) -> dict[str, Any]:
        state = {**super().get_checkpoint_state(), "results": self.results}
        if hasattr(self, "candidates"):  # the sweep has started
            state["sweep"] = (self.candidates, self._window, self._index, self._steps, self._return)
        return state

    def set_checkpoint_state(self, state: dict[str, Any]) -> None:
        super().set_checkpoint_state(state)
        self.results = state["results"]
        if "sweep" in state:
            self.candidates, self._window, self._index, self._steps, self._return = state["sweep"]


class URLBEvalCallback(EvalCallback, ResumableCallback):
    """URLB evaluation: deterministic episodes every ``eval_freq`` steps and at step 0, normalised score.

    Logs ``eval/mean_reward`` and, when the task has an expert score, ``eval/normalized_score``
    (return / expert score). For skill-based agents the evaluation env gets the training env's
    current skill (fixed) before each evaluation. Results are kept in :attr:`history` as
    ``(timestep, mean return, normalised score or nan)``.

    :param eval_env: evaluation environment (id or env); wrapped with the agent's skill prior if needed
    :param task: URLB task name (``walker_flip``...) for the normalised score; None to skip it
    :param n_eval_episodes: episodes per evaluation (10)
    :param eval_freq: env steps between evaluations (10,000)
    :param kwargs: other :class:`~stable_baselines3.common.callbacks.EvalCallback` arguments
    """

    #: EvalCallback's attributes that a checkpoint keeps
    _RECORDS = (
        "best_mean_reward", "last_mean_reward", "evaluations_results", "evaluations_timesteps", "evaluations_length",
    )

    def __init__(
        self,
        eval_env: gym.Env | str,
        task: str | None = None,
        n_eval_episodes: int = 10,
        eval_freq: int = 10_000,
        **kwargs: Any,
    ) -> None:
        self._raw_eval_env = Monitor(make_env(eval_env)) if isinstance(eval_env, str) else eval_env
        super().__init__(self._raw_eval_env, n_eval_episodes=n_eval_episodes, eval_freq=eval_freq, **kwargs)
        self.task = task
        self.history: list[tuple[int, float, float]] = []

    def _init_callback(self) -> None:
        needs_skill = self.model.skill_prior is not None and not self.eval_env.env_is_wrapped(SkillObservationWrapper)[0]
        if needs_skill or isinstance(self.eval_env.observation_space, spaces.Dict):
            model = self.model
            env = prepare_env(self._raw_eval_env, model.skill_prior, model.skill_resample_every, model.multi_input)
            self.eval_env = DummyVecEnv([lambda: env])
        super()._init_callback()

    def _on_training_start(self) -> None:
        if not self.resumed:  # a resumed run evaluated step 0 before
            self._evaluate()

    def get_checkpoint_state(self) -> dict[str, Any]:
        """The evaluation history, EvalCallback's records and the eval env's state (taken after an evaluation's
        last reset, so at an episode start)."""
        records = {key: copy.deepcopy(getattr(self, key)) for key in self._RECORDS}
        return {"history": list(self.history), "records": records, "env": env_state(self._raw_eval_env)}

    def set_checkpoint_state(self, state: dict[str, Any]) -> None:
        self.history = list(state["history"])
        for key, value in state["records"].items():
            setattr(self, key, value)
        set_env_state(self._raw_eval_env, state["env"])

    def _on_step(self) -> bool:
        if self.eval_freq > 0 and self.n_calls % self.eval_freq == 0:
            self._evaluate()
        return True

    def _evaluate(self) -> None:
        if self.model.skill_prior is not None:
            skill = self.model.env.env_method("get_skill", indices=[0])[0]
            self.eval_env.env_method("set_skill", skill, True)
        n_calls, self.n_calls = self.n_calls, self.eval_freq  # run EvalCallback's evaluation now
        super()._on_step()
        self.n_calls = n_calls
        score = normalized_score(self.task, self.last_mean_reward) if self.task else float("nan")
        if self.task:
            self.logger.record("eval/normalized_score", score)
        self.history.append((self.num_timesteps, float(self.last_mean_reward), score))
        self.logger.dump(self.num_timesteps)
