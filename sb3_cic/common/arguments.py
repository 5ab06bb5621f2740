"""Argument checks, the one place of every argument's range: a ``ValueError`` naming the argument in Python, an
argparse error naming the option on the command line (one line, exit code 2), before anything is written, built
or trained.

:data:`RANGES` holds the range of each numeric argument by name, shared by the classes (:class:`~sb3_cic.ddpg.URLBDDPG`
and the methods' reward-module arguments), the protocol's :class:`~sb3_cic.study.settings.Settings` and the command lines
(:mod:`sb3_cic.parsers`, through :func:`option_type`). This module imports nothing heavy (no torch, no gymnasium):
the command line builds its parsers and prints ``--help`` with it alone.
"""

from __future__ import annotations

import argparse
import inspect
import math
import numbers
from dataclasses import dataclass
from typing import Any, Callable, Iterable

#: the largest skill a method takes (``skill_dim``): the URLB methods use 4 to 64; a prior of thousands of
#: dimensions makes every update slow (the skill is part of every network's input) and a grid sweep meaningless
MAX_SKILL_DIM = 1024

#: the largest seed (numpy's ``SeedSequence`` and Gymnasium take seeds in [0, 2**32 - 1])
MAX_SEED = 2**32 - 1

#: the most environment steps a run takes: 500 times URLB's 2M pre-training (at a few thousand steps a second, days of
#: training); a larger count is a typo (``--pretrain-steps 100000000000000`` would run for centuries)
MAX_STEPS = 10**9


def _number(value: float) -> str:
    return str(int(value)) if float(value).is_integer() else repr(value)


@dataclass(frozen=True)
class Range:
    """The values an argument takes: an int (``integer``) or a finite real number in ``[low, high]`` (``low``
    excluded with ``low_open``). A bool is neither; NaN and infinity are refused.

    :param low: lower bound
    :param high: upper bound (``inf``: none)
    :param integer: whether the value must be an int (a Python or numpy integer)
    :param low_open: exclude ``low`` itself
    """

    low: float
    high: float = math.inf
    integer: bool = False
    low_open: bool = False

    def describe(self) -> str:
        """``"an int >= 1"``, ``"a finite number > 0"``, ``"a finite number in [0, 1]"``..."""
        kind = "an int" if self.integer else "a finite number"
        if not math.isfinite(self.low) and not math.isfinite(self.high):
            return kind
        if math.isfinite(self.high):
            return f"{kind} in {'(' if self.low_open else '['}{_number(self.low)}, {_number(self.high)}]"
        return f"{kind} {'>' if self.low_open else '>='} {_number(self.low)}"

    def accepts(self, value: Any) -> bool:
        """Whether ``value`` is of the range's type and within it.

        :param value: the value given
        """
        if isinstance(value, bool) or not isinstance(value, numbers.Integral if self.integer else numbers.Real):
            return False
        if not math.isfinite(value):
            return False
        return (value > self.low if self.low_open else value >= self.low) and value <= self.high

    def check(self, name: str, value: Any) -> Any:
        """Return ``value``, or raise a ``ValueError`` naming ``name`` when it is not in the range.

        :param name: argument name for the message
        :param value: the value given
        """
        if not self.accepts(value):
            raise ValueError(f"{name} must be {self.describe()}, got {value!r}")
        return value

    def parse(self, text: str) -> int | float:
        """An argparse ``type``: ``text`` as a number in the range, else ``argparse.ArgumentTypeError`` (argparse
        then names the option: ``argument --batch-size: must be an int >= 1, got '0'``).

        :param text: the command-line value
        """
        try:
            value: int | float = int(text) if self.integer else float(text)
        except ValueError:
            value = math.nan
        if not self.accepts(value):
            raise argparse.ArgumentTypeError(f"must be {self.describe()}, got {text!r}")
        return value


POSITIVE_INT = Range(1, integer=True)
NON_NEGATIVE_INT = Range(0, integer=True)
POSITIVE = Range(0.0, low_open=True)
NON_NEGATIVE = Range(0.0)
FRACTION = Range(0.0, 1.0)
SEED = Range(0, MAX_SEED, integer=True)
STEPS = Range(1, MAX_STEPS, integer=True)

#: the range of every numeric argument, by name: :class:`~sb3_cic.ddpg.URLBDDPG`'s (``learning_rate`` may also be a
#: schedule, ``gradient_steps`` -1, ``train_freq`` a ``(frequency, unit)`` tuple, ``batch_size`` is at most
#: ``buffer_size``), the policy's, the methods' reward-module and skill-prior parameters (checked under the method's
#: argument name, e.g. ``cic_hidden_dim`` for ``hidden_dim``), the protocol's :class:`~sb3_cic.study.settings.Settings`
#: and the command-line options (``--max-retries``, ``--reps``...)
RANGES: dict[str, Range] = {
    # URLBDDPG
    "learning_rate": POSITIVE,
    "buffer_size": POSITIVE_INT,
    "batch_size": POSITIVE_INT,
    "learning_starts": NON_NEGATIVE_INT,
    "tau": FRACTION,
    "gamma": FRACTION,
    "gradient_steps": NON_NEGATIVE_INT,
    "train_freq": POSITIVE_INT,
    "n_steps": POSITIVE_INT,
    "exploration_std": NON_NEGATIVE,
    "exploration_clip": NON_NEGATIVE,
    "stats_window_size": POSITIVE_INT,
    "skill_dim": Range(1, MAX_SKILL_DIM, integer=True),
    "sf_dim": Range(1, MAX_SKILL_DIM, integer=True),  # APS's skill_dim
    "regression_step": NON_NEGATIVE_INT,  # APS's fine-tuning
    "regression_max_samples": POSITIVE_INT,
    "skill_resample_every": POSITIVE_INT,
    "verbose": Range(0, 2, integer=True),
    "seed": SEED,
    # policy
    "hidden_dim": POSITIVE_INT,
    "n_critics": POSITIVE_INT,
    # reward modules and skill priors (their parameter names)
    "embed_dim": POSITIVE_INT,
    "rep_dim": POSITIVE_INT,
    "vae_hidden_dim": POSITIVE_INT,
    "code_dim": POSITIVE_INT,
    "pred_dim": POSITIVE_INT,
    "proj_dim": POSITIVE_INT,
    "num_protos": POSITIVE_INT,
    "queue_size": POSITIVE_INT,
    "topk": POSITIVE_INT,
    "knn_k": POSITIVE_INT,
    "n_models": POSITIVE_INT,
    "sinkhorn_iters": POSITIVE_INT,
    "lr": POSITIVE,
    "vae_lr": POSITIVE,
    "disc_lr": POSITIVE,
    "temperature": POSITIVE,
    "knn_clip": NON_NEGATIVE,
    "scale": NON_NEGATIVE,
    "vae_beta": NON_NEGATIVE,
    "target_tau": FRACTION,
    "partitions": POSITIVE,
    "episode_length": POSITIVE_INT,
    "value": Range(-math.inf),  # Fixed's constant reward: any finite number
    # the protocol's settings
    "pretrain_steps": STEPS,
    "finetune_steps": STEPS,
    "eval_freq": POSITIVE_INT,
    "eval_episodes": POSITIVE_INT,
    "snapshots": STEPS,
    "num_threads": POSITIVE_INT,
    "pretrain_checkpoint_every": NON_NEGATIVE_INT,
    "finetune_checkpoint_every": NON_NEGATIVE_INT,
    # command-line options
    "checkpoint_every": NON_NEGATIVE_INT,
    "pretrain_seed": SEED,
    "seeds": SEED,
    "snapshot": STEPS,
    "from_snapshot": STEPS,
    "workers": POSITIVE_INT,
    "cpus_per_run": POSITIVE,
    "gpus_per_run": NON_NEGATIVE,
    "max_retries": NON_NEGATIVE_INT,
    "reps": POSITIVE_INT,
    "n_timesteps": STEPS,
    "n_eval_envs": POSITIVE_INT,
    "n_envs": POSITIVE_INT,
    "exp_id": Range(-1, integer=True),
    "save_freq": POSITIVE_INT,
    "log_interval": POSITIVE_INT,
    "n_skills": POSITIVE_INT,
    "video_skills": NON_NEGATIVE_INT,
    "steps": POSITIVE_INT,
    "tile_size": Range(16, 1024, integer=True),
}

#: the arguments that are flags (a bool, not a number that happens to be true; None: the default of an optional one)
FLAGS: frozenset[str] = frozenset({"knn_avg", "knn_rms", "minus_mean", "reward_free"})

#: URLBDDPG's numeric arguments (checked by :func:`check_ddpg_arguments`)
DDPG_ARGUMENTS: tuple[str, ...] = (
    "learning_rate", "buffer_size", "batch_size", "learning_starts", "tau", "gamma", "gradient_steps", "train_freq",
    "n_steps", "exploration_std", "exploration_clip", "stats_window_size", "skill_dim", "skill_resample_every",
    "verbose", "seed", "reward_free",
)


def check_range(name: str, value: Any, low: float, high: float = math.inf, low_open: bool = False) -> None:
    """Raise a ``ValueError`` naming ``name`` unless ``value`` is a finite number with ``low <= value <= high``
    (``low < value`` with ``low_open``).

    :param name: argument name for the message
    :param value: the value given
    :param low: lower bound
    :param high: upper bound
    :param low_open: exclude ``low`` itself
    """
    Range(low, high, low_open=low_open).check(name, value)


def check_positive_int(name: str, value: int) -> int:
    """Return ``value``, or raise a ``ValueError`` naming the argument when it is not an int >= 1.

    :param name: argument name for the message
    :param value: the value given
    """
    return POSITIVE_INT.check(name, value)


def check_argument(name: str, value: Any, key: str | None = None) -> Any:
    """Return ``value``, or a ``ValueError`` naming ``name`` when it is outside the range of :data:`RANGES` (or not
    a bool for a name of :data:`FLAGS`); a name neither knows is not checked.

    :param name: the argument's name for the message
    :param value: the value given
    :param key: the name in :data:`RANGES` (default: ``name``; a method argument gives its module parameter's)
    """
    key = name if key is None else key
    if key in FLAGS and not isinstance(value, bool):
        raise ValueError(f"{name} must be True or False, got {value!r}")
    if key in RANGES:
        RANGES[key].check(name, value)
    return value


def check_ranges(args: dict[str, Any], names: Iterable[str] | None = None) -> None:
    """Check the arguments ``names`` found in ``args`` (a constructor's ``locals()``, or a subset); None is the
    default of an optional argument and is not checked.

    :param args: argument values by name
    :param names: the names to check (default: those of ``args`` that :data:`RANGES` or :data:`FLAGS` know)
    """
    for name in names if names is not None else [name for name in args if name in RANGES or name in FLAGS]:
        value = args.get(name)
        if value is None:
            continue
        if name == "learning_rate" and callable(value):  # a schedule
            continue
        if name == "gradient_steps" and not isinstance(value, bool) and value == -1:  # SB3: as many as env steps
            continue
        if name == "train_freq" and isinstance(value, tuple):  # (frequency, unit)
            value = value[0]
        check_argument(name, value)
    batch_size, buffer_size = args.get("batch_size"), args.get("buffer_size")
    if batch_size is not None and buffer_size is not None and batch_size > buffer_size:
        raise ValueError(f"batch_size must be at most buffer_size ({buffer_size}), got {batch_size!r}")


def parameters_of(func: Any) -> dict[str, inspect.Parameter]:
    """The named parameters of ``func`` (a function or a class's constructor); a class whose constructor passes
    ``**kwargs`` through to its parent's also takes the parent's (as :class:`~sb3_cic.rewards.moss.MOSSReward`
    takes :class:`~sb3_cic.rewards.cic.CICReward`'s).

    :param func: a function or a class
    """
    parameters = dict(inspect.signature(func).parameters)
    passed = [name for name, parameter in parameters.items() if parameter.kind is inspect.Parameter.VAR_KEYWORD]
    if passed and isinstance(func, type):
        parent = next((base for base in func.__mro__[1:] if "__init__" in vars(base)), object)
        if parent is not object:
            del parameters[passed[0]]
            for name, parameter in parameters_of(parent).items():
                parameters.setdefault(name, parameter)
    return parameters


def parameter_default(func: Any, name: str) -> Any:
    """The default value of the parameter ``name`` of ``func`` (a function or a class's constructor, its parent's
    for a parameter it passes through: :func:`parameters_of`), the one place that default is written.

    :param func: a function or a class
    :param name: the parameter's name
    """
    default = parameters_of(func)[name].default
    if default is inspect.Parameter.empty:
        raise ValueError(f"{getattr(func, '__name__', func)}'s {name} has no default")
    return default


def check_ddpg_arguments(args: dict[str, Any]) -> None:
    """``ValueError`` naming the first of :class:`~sb3_cic.ddpg.URLBDDPG`'s arguments that it cannot take.

    :param args: the constructor's arguments by name (its ``locals()``)
    """
    from sb3_cic.buffers import URLBReplayBuffer

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
    check_ranges(args, DDPG_ARGUMENTS)


# the command line ---------------------------------------------------------------------------------
def option_type(name: str) -> Callable[[str], int | float]:
    """The argparse ``type`` of an option whose value has the range of ``name`` in :data:`RANGES`.

    :param name: the name in :data:`RANGES` (``"eval_episodes"`` for ``--eval-episodes``)
    """
    parse = RANGES[name].parse
    kind = "int" if RANGES[name].integer else "float"

    def convert(text: str) -> int | float:
        return parse(text)

    convert.__name__ = kind  # what argparse would name the type in an error of its own
    return convert


def device_type(text: str) -> str:
    """The argparse ``type`` of ``--device``: ``auto`` (SB3's: CUDA when there is one) or a string ``torch.device``
    reads (``cpu``, ``cuda``, ``cuda:1``...); torch is imported only for the latter."""
    if text == "auto":
        return text
    import torch as th

    try:
        th.device(text)
    except RuntimeError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a torch device (auto, cpu, cuda, cuda:1...)") from None
    return text


def check_device_available(device: str) -> None:
    """``ValueError`` when ``device`` asks for CUDA (``cuda``, ``cuda:1``) and torch sees no CUDA device here: SB3 would
    train on the CPU without a word. ``auto`` and ``cpu`` are not checked (torch is not imported for them).

    :param device: a value of ``--device`` (:func:`device_type`)
    """
    if not device.startswith("cuda"):
        return
    import torch as th

    index = th.device(device).index
    if not th.cuda.is_available():
        raise ValueError(f"--device {device}: torch sees no CUDA device on this machine; use --device cpu (or auto)")
    if index is not None and index >= th.cuda.device_count():
        raise ValueError(f"--device {device}: this machine has {th.cuda.device_count()} CUDA device(s)")


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """argparse's help with each option's default after its help text, unless the text already says it
    ("default") or there is none to show (a flag, a default of None: the text says what holds instead)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        nothing = action.default is None or action.default is False or action.default is argparse.SUPPRESS
        if "default" in text or nothing or action.default == [] or not action.option_strings:
            return text
        return super()._get_help_string(action) or text


def argument_parser(prog: str, description: str, **kwargs: Any) -> argparse.ArgumentParser:
    """A parser of the command line: no abbreviated options (``--smal`` is not ``--small``), each option's
    default in ``--help`` (:class:`HelpFormatter`).

    :param prog: the command (``"sb3-cic protocol"``)
    :param description: what it does, as plain text
    :param kwargs: further ``argparse.ArgumentParser`` arguments
    """
    kwargs.setdefault("formatter_class", HelpFormatter)
    return argparse.ArgumentParser(prog=prog, description=description, allow_abbrev=False, **kwargs)
