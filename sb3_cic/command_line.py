"""The command line's own parts, shared by every ``sb3-cic`` command (:mod:`sb3_cic.cli`, the study's
:mod:`sb3_cic.study.cli`, the reports' :mod:`sb3_cic.report.commands`, :mod:`sb3_cic.demo`,
:mod:`sb3_cic.skill_video`): the parser (no abbreviated options, each default in ``--help``), the argparse
``type`` of an option with a range (an error of one line naming the option, exit code 2), ``--device``, and
the exception of a command interrupted by a signal.

The ranges themselves sit beside what they validate (:mod:`sb3_cic.common.arguments`). Nothing heavy is imported
here (torch only to read a ``--device`` other than ``auto``): ``--help`` stays fast.
"""

from __future__ import annotations

import argparse
import signal
from typing import Any, Callable

from sb3_cic.common.arguments import Range


def option_type(bound: Range) -> Callable[[str], int | float]:
    """The argparse ``type`` of an option whose value has the range ``bound``.

    :param bound: the range (:class:`~sb3_cic.common.arguments.Range`)
    """
    parse = bound.parse

    def convert(text: str) -> int | float:
        return parse(text)

    convert.__name__ = "int" if bound.integer else "float"  # what argparse would name the type in an error of its own
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


class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM during a command (``sb3-cic study``, ``protocol``).

    :param signum: the signal
    """

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum
