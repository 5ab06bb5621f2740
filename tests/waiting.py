"""Waiting for an event of a process the test started, bounded by the work done rather than by the clock.

A fixed wall-clock limit fails on a loaded machine: the processes get a fraction of a core and the event comes late.
:func:`wait_for` gives up when the processes of the test (this one and all its descendants: drivers, Ray nodes, their
workers) have used ``cpu_budget_s`` CPU seconds without the event, when they stall (less than a CPU second in
``stall_s`` wall seconds: a hang, not a slow machine), or when the process to watch ends; the failure names the event.
Linux only (``/proc``), as the tests that use it.
"""

from __future__ import annotations

import os
import subprocess
import time
from pathlib import Path
from typing import Callable

import pytest

_TICKS = os.sysconf("SC_CLK_TCK")


def _stat(pid: str) -> tuple[int, float] | None:
    """(parent pid, CPU seconds of the process and its reaped children) of ``/proc/<pid>/stat``."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    # after the command: state, ppid, ..., utime (14th field of the line), stime, cutime, cstime
    return int(fields[1]), sum(int(value) for value in fields[11:15]) / _TICKS


def tree_cpu_seconds(root: int | None = None) -> float:
    """CPU seconds used so far by ``root`` (default: this process) and all its descendants."""
    root = os.getpid() if root is None else root
    stats = {int(pid): stat for pid in os.listdir("/proc") if pid.isdigit() and (stat := _stat(pid)) is not None}
    children: dict[int, list[int]] = {}
    for pid, (parent, _) in stats.items():
        children.setdefault(parent, []).append(pid)
    total, todo = 0.0, [root]
    while todo:
        pid = todo.pop()
        if pid in stats:
            total += stats[pid][1]
        todo += children.get(pid, [])
    return total


def wait_for(
    condition: Callable[[], bool],
    what: str,
    process: subprocess.Popen | None = None,
    output: Callable[[], str] | None = None,
    cpu_budget_s: float = 900.0,
    stall_s: float = 600.0,
    poll_s: float = 0.1,
) -> None:
    """Wait until ``condition()`` holds; fail, naming ``what``, if ``process`` ends first, if the test's processes
    use ``cpu_budget_s`` CPU seconds without it, or if they stall (see the module docstring).

    :param condition: the event
    :param what: the event in words (``"the first checkpoint of a run"``)
    :param process: the process whose end means the event will not come (None: none)
    :param output: what to show of the processes when failing (their log)
    :param cpu_budget_s: CPU seconds of the test's process tree the event may take
    :param stall_s: wall seconds in which the tree must use at least one CPU second
    :param poll_s: seconds between two looks at the event
    """
    start_cpu = last_cpu = tree_cpu_seconds()
    last_time = time.monotonic()
    while not condition():
        why = None
        if process is not None and process.poll() is not None:
            why = f"the process ended (exit code {process.returncode})"
        else:
            cpu = tree_cpu_seconds()
            if cpu - start_cpu > cpu_budget_s:
                why = f"its processes used {cpu - start_cpu:.0f} CPU seconds (budget {cpu_budget_s:.0f})"
            elif cpu - last_cpu >= 1.0:
                last_cpu, last_time = cpu, time.monotonic()
            elif time.monotonic() - last_time > stall_s:
                why = f"its processes used under a CPU second in {stall_s:.0f} s: stalled"
        if why is not None:
            pytest.fail(f"waited for {what}: {why}" + (f"\n{output()}" if output is not None else ""))
        time.sleep(poll_s)


def run_process(args: list[str], what: str, cpu_budget_s: float = 900.0, **kwargs) -> subprocess.CompletedProcess:
    """``subprocess.run(args, capture_output=True, text=True, **kwargs)`` whose wait is :func:`wait_for`'s (bounded
    by the CPU the process uses, not by the clock); the process is killed if the wait fails.

    :param args: the command
    :param what: the command in words, for a failure (``"sb3-cic --help"``)
    :param cpu_budget_s: CPU seconds it may use
    :param kwargs: further ``subprocess.Popen`` arguments (``env``, ``cwd``)
    """
    import tempfile

    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        process = subprocess.Popen(args, stdout=out, stderr=err, text=True, **kwargs)
        try:
            wait_for(lambda: process.poll() is not None, f"{what} to end", cpu_budget_s=cpu_budget_s)
        finally:
            if process.poll() is None:
                process.kill()
                process.wait()
        out.seek(0)
        err.seek(0)
        return subprocess.CompletedProcess(args, process.returncode, out.read(), err.read())
