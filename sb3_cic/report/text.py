"""How the reports write a number (three decimals, ``–`` for a missing one, ``mean ± se``) and a study folder."""

from __future__ import annotations

import math
from pathlib import Path


def fmt(value: float | None, digits: int = 3) -> str:
    """``value`` with ``digits`` decimals; ``–`` for None or NaN."""
    return "–" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.{digits}f}"


def pm(mean: float, se: float, digits: int) -> str:
    """``mean ± se`` (the mean alone where the standard error is NaN: one seed)."""
    return fmt(mean, digits) if math.isnan(se) else f"{fmt(mean, digits)} ± {fmt(se, digits)}"


def short_name(study: str | Path) -> str:
    """A study folder's name for the report: its last two path components (``quadruped_reduced/runs``)."""
    return "/".join(Path(study).resolve().parts[-2:])
