"""Argument checks: a ``ValueError`` naming the argument, before anything is built."""

from __future__ import annotations

import inspect
from typing import Any

import numpy as np

from sb3_cic.buffers import URLBReplayBuffer

#: URLBDDPG's numeric arguments and their ranges: ``name: (low, high, low_open)``; ``batch_size`` is also at
#: most ``buffer_size``, ``gradient_steps`` may be -1 (SB3: as many as env steps)
RANGES: dict[str, tuple[float, float, bool]] = {
    "learning_rate": (0.0, float("inf"), True),
    "buffer_size": (1, float("inf"), False),
    "batch_size": (1, float("inf"), False),
    "learning_starts": (0, float("inf"), False),
    "tau": (0.0, 1.0, False),
    "gamma": (0.0, 1.0, False),
    "gradient_steps": (0, float("inf"), False),
    "train_freq": (1, float("inf"), False),
    "n_steps": (1, float("inf"), False),
    "exploration_std": (0.0, float("inf"), False),
    "exploration_clip": (0.0, float("inf"), False),
    "stats_window_size": (1, float("inf"), False),
}


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


def check_positive_int(name: str, value: int) -> int:
    """Return ``value``, or raise a ``ValueError`` naming the argument when it is not an int >= 1.

    :param name: argument name for the message
    :param value: the value given
    """
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"{name} must be an int >= 1, got {value!r}")
    return value


def check_ranges(args: dict[str, Any]) -> None:
    """Check the arguments of :data:`RANGES` found in ``args`` (a constructor's ``locals()``).

    :param args: argument values by name
    """
    for name, (low, high, low_open) in RANGES.items():
        value = args[name]
        if name == "learning_rate" and callable(value):  # a schedule
            continue
        if name == "gradient_steps" and value == -1:
            continue
        if name == "train_freq" and isinstance(value, tuple):  # (frequency, unit)
            value = value[0]
        if name == "batch_size":
            high = args["buffer_size"]
        check_range(name, value, low, high, low_open)


def parameter_default(func: Any, name: str) -> Any:
    """The default value of the parameter ``name`` of ``func`` (a function or a class's constructor), the one
    place that default is written.

    :param func: a function or a class
    :param name: the parameter's name
    """
    default = inspect.signature(func).parameters[name].default
    if default is inspect.Parameter.empty:
        raise ValueError(f"{getattr(func, '__name__', func)}'s {name} has no default")
    return default


def check_ddpg_arguments(args: dict[str, Any]) -> None:
    """``ValueError`` naming the first of :class:`~sb3_cic.ddpg.URLBDDPG`'s arguments that it cannot take.

    :param args: the constructor's arguments by name (its ``locals()``)
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
    check_ranges(args)
