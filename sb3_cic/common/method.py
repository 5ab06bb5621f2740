"""A method's declaration: the four parts a method class sets (skill prior, reward module, fine-tuning skill
choice, kept critic layers) and how the model builds them."""

from __future__ import annotations

import sys
import warnings
from typing import Any, ClassVar

from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.type_aliases import GymEnv

from sb3_cic.common.arguments import Flag, Range, check_argument, parameter_default, parameters_of, ranges_of
from sb3_cic.common.env_util import env_id_of, is_reward_free_env
from sb3_cic.rewards.base import RewardModule
from sb3_cic.skills import SkillPrior


class MethodMixin:
    """The parts of an unsupervised method, declared once per method class as class attributes.

    A method file reads, for example (CIC)::

        skill_prior_class = UniformSkillPrior
        reward_module_class = CICReward
        reward_module_args = {"cic_hidden_dim": "hidden_dim", "cic_lr": "lr", "knn_clip": "knn_clip", ...}
        finetune_skill_choices = {"sweep": (SkillGridSweepCallback, {"window": 100}),
                                  "fixed": (FixedSkillCallback, {"value": 0.5})}
        finetune_critic = "trunk"

    Each hyper-parameter default is written once: a reward-module argument left at None takes the module's
    default (a width ``*_hidden_dim`` the policy's), and the model keeps the value it used as an attribute.
    Mixed in before the algorithm (:class:`~sb3_cic.ddpg.URLBDDPG`), whose ``state_dim``, ``action_dim`` and
    ``skill_dim`` it reads.
    """

    #: the skill prior, built as ``skill_prior_class(skill_dim)`` (None: no skill unless ``skill_prior`` is given)
    skill_prior_class: ClassVar[type[SkillPrior] | None] = None
    #: the method's arguments that the skill prior also takes, ``{method argument: prior parameter}`` (MOSS's mode
    #: schedule); a name of :attr:`reward_module_args` too goes to both, with the reward module's default
    skill_prior_args: ClassVar[dict[str, str]] = {}
    #: the intrinsic reward module (None: no pre-training)
    reward_module_class: ClassVar[type[RewardModule] | None] = None
    #: the method's arguments that the reward module takes, ``{method argument: module parameter}``
    reward_module_args: ClassVar[dict[str, str]] = {}
    #: how fine-tuning chooses the skill: ``{name: (SkillSelectionCallback subclass, its arguments)}``, the
    #: first the default; the callback is built by its ``for_model``
    finetune_skill_choices: ClassVar[dict[str, tuple[type[BaseCallback], dict[str, Any]]]] = {}
    #: what fine-tuning keeps of the pre-trained critic: "trunk" (URLB), "all" (ProtoRL) or "none"
    finetune_critic: ClassVar[str] = "trunk"

    skill_prior: SkillPrior | None
    finetune_skill_choice: str | None
    policy_kwargs: dict[str, Any]
    policy_class: type
    state_dim: int
    action_dim: int
    skill_dim: int

    @property
    def hidden_dim(self) -> int:
        """Hidden width of actor and critic (the reward modules' default width)."""
        return int(self.policy_kwargs.get("hidden_dim", parameter_default(self.policy_class, "hidden_dim")))

    def _declare(
        self, method_kwargs: dict[str, Any], skill_prior: SkillPrior | None, skill_dim: int | None, choice: str | None
    ) -> None:
        """Set the method's arguments, skill prior and fine-tuning skill choice (before the algorithm is built).

        :param method_kwargs: the constructor's extra keyword arguments (:meth:`_set_method_args`)
        :param skill_prior: the constructor's ``skill_prior`` (:meth:`_make_skill_prior`)
        :param skill_dim: the constructor's ``skill_dim``
        :param choice: the constructor's ``finetune_skill_choice`` (:meth:`_check_finetune_skill_choice`)
        """
        self._set_method_args(method_kwargs)
        #: the method's skill prior (None: no skill)
        self.skill_prior = self._make_skill_prior(skill_prior, skill_dim)
        self.finetune_skill_choice = self._check_finetune_skill_choice(choice)

    @classmethod
    def loaded_argument_ranges(cls) -> dict[str, Range | Flag]:
        """The ranges of the arguments ``load`` may set: the algorithm's (``argument_ranges``) and the method's
        reward-module and skill-prior arguments (their parameters' ranges)."""
        ranges = ranges_of(cls, "argument_ranges")
        for args, owner in ((cls.reward_module_args, cls.reward_module_class), (cls.skill_prior_args, cls.skill_prior_class)):
            owned = ranges_of(owner) if owner is not None else {}
            ranges.update({name: owned[parameter] for name, parameter in args.items() if parameter in owned})
        return ranges

    def _set_method_args(self, method_kwargs: dict[str, Any]) -> None:
        """Set the method's reward-module and skill-prior arguments (:attr:`reward_module_args`,
        :attr:`skill_prior_args`) as attributes, their defaults the module's or the prior's; ``TypeError`` for an
        argument the method does not take, ``ValueError`` naming one out of its range
        (the range of its module's or prior's parameter, ``parameter_ranges``).

        :param method_kwargs: the constructor's extra keyword arguments
        """
        unknown = sorted(set(method_kwargs) - set(self.reward_module_args) - set(self.skill_prior_args))
        if unknown:
            raise TypeError(f"{type(self).__name__}.__init__() got an unexpected keyword argument {unknown[0]!r}")
        module_ranges = ranges_of(self.reward_module_class) if self.reward_module_class is not None else {}
        prior_ranges = ranges_of(self.skill_prior_class) if self.skill_prior_class is not None else {}
        for name, parameter in self.reward_module_args.items():
            value = method_kwargs.get(name)
            if value is None and parameter != "hidden_dim":
                value = parameter_default(self.reward_module_class, parameter)
            if value is not None:  # None: the module's own default (a width: the policy's)
                check_argument(name, value, module_ranges.get(parameter))
            setattr(self, name, value)
        for name, parameter in self.skill_prior_args.items():
            if name not in self.reward_module_args:
                value = method_kwargs.get(name)
                value = parameter_default(self.skill_prior_class, parameter) if value is None else value
                setattr(self, name, check_argument(name, value, prior_ranges.get(parameter)))

    def _make_skill_prior(self, skill_prior: SkillPrior | None, skill_dim: int | None) -> SkillPrior | None:
        """The given prior, else the method's :attr:`skill_prior_class` (of size ``skill_dim``, default its own) with
        the :attr:`skill_prior_args`.

        :param skill_prior: a prior given to the constructor
        :param skill_dim: the size of the method's prior
        """
        if skill_prior is not None or self.skill_prior_class is None:
            if skill_dim is not None:
                raise ValueError(f"skill_dim is the size of {type(self).__name__}'s own prior: give skill_prior or skill_dim")
            return skill_prior
        kwargs = {parameter: getattr(self, name) for name, parameter in self.skill_prior_args.items()}
        return self.skill_prior_class(**kwargs) if skill_dim is None else self.skill_prior_class(skill_dim, **kwargs)

    def _check_finetune_skill_choice(self, choice: str | None) -> str | None:
        """``choice``, or the first of :attr:`finetune_skill_choices` for None; ``ValueError`` for another name.

        :param choice: the constructor's ``finetune_skill_choice``
        """
        choices = tuple(self.finetune_skill_choices)
        if choice is None:
            return choices[0] if choices else None
        if choice not in choices:
            raise ValueError(f"finetune_skill_choice must be one of {choices}, got {choice!r}")
        return choice

    def _warn_if_reward_ignored(self, env: GymEnv | str, reward_free: bool | None) -> None:
        """Pre-training on an env that is not one of URLB's reward-free ones: say once that its reward is not used.

        :param env: the constructor's env
        :param reward_free: the constructor's ``reward_free``
        """
        pretraining = reward_free if reward_free is not None else self.reward_module_class is not None
        if pretraining and not is_reward_free_env(env):
            name = type(self).__name__
            frame, level = sys._getframe(1), 2  # the warning points at the line that built the model
            while frame.f_back is not None and frame.f_code.co_name == "__init__" and frame.f_locals.get("self") is self:
                frame, level = frame.f_back, level + 1
            warnings.warn(
                f"{name} pre-trains reward-free on {env_id_of(env) or type(env).__name__}: the env's reward is ignored "
                f"(replaced by {name}'s intrinsic reward). Pass reward_free=False to learn from it, or fine-tune a "
                f"pre-trained model with {name}.load_pretrained",
                UserWarning,
                stacklevel=level,
            )

    def make_reward_module(self) -> RewardModule | None:
        """The method's reward module: :attr:`reward_module_class` with the :attr:`reward_module_args` (None: none)."""
        if self.reward_module_class is None:
            return None
        parameters = parameters_of(self.reward_module_class)
        kwargs = {parameter: getattr(self, name) for name, parameter in self.reward_module_args.items()}
        kwargs = {parameter: value for parameter, value in kwargs.items() if value is not None}
        if "hidden_dim" in parameters:
            kwargs.setdefault("hidden_dim", self.hidden_dim)
        if "skill_dim" in parameters:
            kwargs["skill_dim"] = self.skill_dim
        return self.reward_module_class(self.state_dim, self.action_dim, **kwargs)

    def make_finetune_callback(self) -> BaseCallback | None:
        """The callback of :attr:`finetune_skill_choice` that chooses the fine-tuning skill (None: none)."""
        if self.finetune_skill_choice is None:
            return None
        callback_class, kwargs = self.finetune_skill_choices[self.finetune_skill_choice]
        return callback_class.for_model(self, **kwargs)  # type: ignore[attr-defined]
