"""Argument checks: the range an argument takes (:class:`Range`, or :data:`FLAG` for a bool) and the checks that
raise a ``ValueError`` naming the argument in Python, or an argparse error naming the option on the command line (one
line, exit code 2), before anything is written, built or trained.

Each range sits beside what it validates: :class:`~sb3_cic.ddpg.URLBDDPG`'s arguments in its
``argument_ranges`` (a method's own in the method's), a reward module's and a skill prior's parameters in their
``parameter_ranges`` (:func:`ranges_of` merges a class's with its parents'), the protocol settings in
:class:`~sb3_cic.study.settings.Settings`, each command's own options beside the option. This module holds the
shared bounds (:data:`POSITIVE_INT`, :data:`STEPS`, :data:`SEED`...) and imports nothing heavy (no torch, no
gymnasium): the command line (:mod:`sb3_cic.command_line`) builds its parsers and prints ``--help`` with it alone.
"""

from __future__ import annotations

import argparse
import inspect
import math
import numbers
from dataclasses import dataclass
from typing import Any, Iterable

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
#: any finite number
FINITE = Range(-math.inf)


@dataclass(frozen=True)
class Flag:
    """An argument that is a bool (not a number that happens to be true)."""

    def describe(self) -> str:
        """``"True or False"``."""
        return "True or False"

    def accepts(self, value: Any) -> bool:
        """Whether ``value`` is a bool."""
        return isinstance(value, bool)

    def check(self, name: str, value: Any) -> Any:
        """Return ``value``, or raise a ``ValueError`` naming ``name`` when it is not a bool."""
        if not self.accepts(value):
            raise ValueError(f"{name} must be True or False, got {value!r}")
        return value


#: the range of a bool argument
FLAG = Flag()



def ranges_of(cls: type, attribute: str = "parameter_ranges") -> dict[str, Range | Flag]:
    """The ranges a class declares in ``attribute`` (a ``{name: range}`` class attribute), merged with those of its
    parents (a subclass's win).

    :param cls: a reward module, a skill prior (``parameter_ranges``), an algorithm (``argument_ranges``)
    :param attribute: the class attribute
    """
    merged: dict[str, Range | Flag] = {}
    for klass in reversed(cls.__mro__):
        merged.update(vars(klass).get(attribute, {}))
    return merged


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


def check_argument(name: str, value: Any, bound: Range | Flag | None) -> Any:
    """Return ``value``, or a ``ValueError`` naming ``name`` when it is outside ``bound`` (None: not checked).

    :param name: the argument's name for the message
    :param value: the value given
    :param bound: its range
    """
    if bound is not None:
        bound.check(name, value)
    return value


def check_ranges(args: dict[str, Any], ranges: dict[str, Range | Flag], names: Iterable[str] | None = None) -> None:
    """Check the arguments ``names`` found in ``args`` (a constructor's ``locals()``, or a subset) against ``ranges``;
    None is the default of an optional argument and is not checked. A ``learning_rate`` may be a schedule, a
    ``gradient_steps`` -1 (SB3: as many as env steps), a ``train_freq`` a ``(frequency, unit)`` tuple; a
    ``batch_size`` is at most the ``buffer_size``.

    :param args: argument values by name
    :param ranges: the range of each argument by name
    :param names: the names to check (default: those of ``args`` that ``ranges`` knows)
    """
    for name in names if names is not None else [name for name in args if name in ranges]:
        value = args.get(name)
        if value is None:
            continue
        if name == "learning_rate" and callable(value):  # a schedule
            continue
        if name == "gradient_steps" and not isinstance(value, bool) and value == -1:  # SB3: as many as env steps
            continue
        if name == "train_freq" and isinstance(value, tuple):  # (frequency, unit)
            value = value[0]
        check_argument(name, value, ranges.get(name))
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
