"""How a long run shows its progress: SB3's progress bar on a terminal, one line every so often elsewhere (a log
file, a pipe, a batch job's output), where a bar cannot be drawn and a run would otherwise print nothing for hours.
"""

from __future__ import annotations

import sys
import time
from typing import Any, TextIO

from stable_baselines3.common.callbacks import BaseCallback, ProgressBarCallback

#: seconds between two progress lines of :class:`ProgressLineCallback`
PROGRESS_INTERVAL_S = 60.0


def _duration(seconds: float) -> str:
    """``"42 s"``, ``"7 min"``, ``"3.5 h"``."""
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


class ProgressLineCallback(BaseCallback):
    """Print one line of progress (step, share done, speed, time left) every :data:`PROGRESS_INTERVAL_S` seconds,
    and one when training ends.

    :param label: what runs (``"pretrain cic walker seed 0"``), first on each line
    :param total: the step training ends at
    :param interval_s: seconds between lines (default: :data:`PROGRESS_INTERVAL_S`)
    :param file: where the lines go (default: ``sys.stdout``, looked up when printing)
    """

    def __init__(self, label: str, total: int, interval_s: float | None = None, file: TextIO | None = None) -> None:
        super().__init__(verbose=0)
        self.label = label
        self.total = int(total)
        self.interval_s = PROGRESS_INTERVAL_S if interval_s is None else float(interval_s)
        self.file = file

    def _on_training_start(self) -> None:
        self._start_time = self._last_time = time.monotonic()
        self._start_step = self.num_timesteps

    def _print(self) -> None:
        now = time.monotonic()
        done = self.num_timesteps - self._start_step
        rate = done / max(now - self._start_time, 1e-9)
        left = (self.total - self.num_timesteps) / rate if rate > 0 else float("inf")
        text = f"{self.label}: step {self.num_timesteps:,} of {self.total:,} ({100 * self.num_timesteps / self.total:.0f}%)"
        if done:
            text += f", {rate:,.0f} steps/s" + (f", about {_duration(left)} left" if self.num_timesteps < self.total else "")
        print(text, file=self.file or sys.stdout, flush=True)
        self._last_time = now

    def _on_step(self) -> bool:
        if time.monotonic() - self._last_time >= self.interval_s:
            self._print()
        return True

    def _on_training_end(self) -> None:
        self._print()


def progress_callback(label: str, total: int, show: bool) -> BaseCallback | None:
    """The progress display of a run: SB3's progress bar when stdout is a terminal, else
    :class:`ProgressLineCallback`; None when ``show`` is False. A bar left open by an interrupted run is closed by
    :func:`close_progress`.

    :param label: what runs, for the lines
    :param total: the step training ends at
    :param show: whether to show progress at all (``--no-progress``: False)
    """
    if not show:
        return None
    isatty = getattr(sys.stdout, "isatty", None)
    return ProgressBarCallback() if isatty is not None and isatty() else ProgressLineCallback(label, total)


def close_progress(callback: Any) -> None:
    """Close the bar of a :class:`~stable_baselines3.common.callbacks.ProgressBarCallback` that training did not end
    (an exception or Ctrl-C in ``learn``): a bar left open keeps a display thread that fails at interpreter exit.

    :param callback: the callback of :func:`progress_callback` (None, or another kind: nothing to do)
    """
    bar = getattr(callback, "pbar", None) if isinstance(callback, ProgressBarCallback) else None
    if bar is not None:
        bar.close()
