"""``sb3-cic <command> --help``: fast (no torch, no Ray: the heavy modules load in the command handlers), plain text,
each option's default shown."""

from __future__ import annotations

import argparse
import os
import resource
import sys
from pathlib import Path

import pytest

from sb3_cic.cli import main
from waiting import run_process

ROOT = Path(__file__).resolve().parent.parent
COMMANDS = [
    "demo", "train", "finetune", "enjoy", "record-video", "protocol", "study", "status", "pause", "report", "benchmark-report",
    "skills",
]
#: what a help text must not load
HEAVY = ("torch", "ray", "stable_baselines3", "rl_zoo3", "dm_control")
#: reStructuredText / Sphinx markup that must not reach a help text
MARKUP = ("``", ":class:", ":func:", ":data:", ":mod:", ":meth:", ":param")

SCRIPT = """
import sys
from {module} import main
try:
    main({arguments!r})
except SystemExit as exit_:
    assert exit_.code in (0, None), exit_.code
print("loaded:", sorted(name for name in {heavy!r} if name in sys.modules), file=sys.stderr)
"""


def _help(arguments: list[str], cwd: Path, module: str = "sb3_cic.cli") -> tuple[str, str, float]:
    """Run ``module``'s ``main(arguments)`` (default: ``sb3-cic arguments``) in a fresh interpreter; return its stdout, its stderr and the CPU seconds it used
    (CPU time, not wall time: the measure holds on a machine busy with other work)."""
    env = {**os.environ, "MUJOCO_GL": "disable", "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    process = run_process([sys.executable, "-c", SCRIPT.format(module=module, arguments=arguments, heavy=HEAVY)],
                          f"{module} {arguments}", cwd=cwd, env=env)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    assert process.returncode == 0, process.stderr
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return process.stdout, process.stderr, cpu


@pytest.mark.parametrize("arguments", [[command, "--help"] for command in COMMANDS] + [["--help"]], ids=" ".join)
def test_help_is_fast_plain_and_loads_neither_torch_nor_ray(arguments, tmp_path):
    out, err, cpu = _help(arguments, tmp_path)
    assert err.strip().splitlines()[-1] == "loaded: []", err
    assert cpu < 1.0, f"{cpu:.2f} s of CPU"
    assert out.startswith("usage: sb3-cic"), out
    assert not [mark for mark in MARKUP if mark in out], out
    assert list(tmp_path.iterdir()) == []


def test_the_demo_help_is_fast_too(tmp_path):
    out, err, cpu = _help(["--help"], tmp_path, module="sb3_cic.demo")
    assert err.strip().splitlines()[-1] == "loaded: []", err
    assert cpu < 1.0, f"{cpu:.2f} s of CPU"
    assert "--snapshot" in out and not [mark for mark in MARKUP if mark in out], out
    assert list(tmp_path.iterdir()) == []


class _Parsed(Exception):
    """Raised instead of parsing, to hand the parser a command builds to the test."""

    def __init__(self, parser: argparse.ArgumentParser) -> None:
        super().__init__()
        self.parser = parser


def _parser_of(command: str, monkeypatch: pytest.MonkeyPatch) -> argparse.ArgumentParser:
    """The parser ``sb3-cic command`` reads its arguments with (the first it builds)."""

    def record(self: argparse.ArgumentParser, *args: object, **kwargs: object) -> None:
        raise _Parsed(self)

    monkeypatch.setattr(argparse.ArgumentParser, "parse_known_args", record)
    with pytest.raises(_Parsed) as parsed:
        main([command, "--help"])
    monkeypatch.undo()
    return parsed.value.parser


@pytest.mark.parametrize("command", COMMANDS)
def test_every_option_shows_its_default(command, monkeypatch):
    parser = _parser_of(command, monkeypatch)
    formatter = parser._get_formatter()
    for action in parser._actions:
        if not action.option_strings or action.nargs == 0 or action.required:  # positionals, flags, required
            continue
        text = formatter._get_help_string(action)  # type: ignore[attr-defined]
        assert text and "default" in text, (command, action.option_strings, text)


def test_report_help_names_both_commands_that_write_a_study(tmp_path):
    out, _, _ = _help(["report", "--help"], tmp_path)
    assert "sb3-cic study" in out and "sb3-cic protocol" in out


def test_protocol_help_says_what_small_sets(tmp_path):
    out, _, _ = _help(["protocol", "--help"], tmp_path)
    text = " ".join(out.split())
    assert "hidden_dim 32, batch_size 32, learning_starts 500, buffer_size 100000" in text
    assert "the step counts stay" in text and "(default: 10000)" in text
