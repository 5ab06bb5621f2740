"""sb3-cic: Contrastive Intrinsic Control and the URLB methods for Stable-Baselines3.

Importing the package registers the URLB Gymnasium ids (``URLB/walker-v0``, ``URLB/walker-flip-v0``...).
"""

from __future__ import annotations

import importlib
from typing import Any

from sb3_cic import envs  # noqa: F401  (registers the Gymnasium ids)
from sb3_cic import methods
from sb3_cic.version import __version__

#: each public name (written here once; the methods' in :mod:`sb3_cic.methods`) and its module, imported on first
#: use (``from sb3_cic import CIC`` loads torch; ``import sb3_cic`` alone, as the command line does, does not)
_MODULES: dict[str, str] = {
    **{name: "sb3_cic.methods" for name in methods.__all__ if name not in methods.PARTS},
    "URLBDDPG": "sb3_cic.ddpg",
    "URLBReplayBuffer": "sb3_cic.buffers",
    **dict.fromkeys(
        ("SkillPrior", "UniformSkillPrior", "OneHotSkillPrior", "SphereSkillPrior", "MixtureSkillPrior"), "sb3_cic.skills"
    ),
    **dict.fromkeys(
        ("SkillSelectionCallback", "SkillGridSweepCallback", "FixedSkillCallback", "URLBEvalCallback"), "sb3_cic.callbacks"
    ),
    "EXPERT_SCORES": "sb3_cic.constants",
    "normalized_score": "sb3_cic.constants",
}


def __getattr__(name: str) -> Any:
    if name in _MODULES:
        value = getattr(importlib.import_module(_MODULES[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'sb3_cic' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *_MODULES})


__all__ = list(_MODULES)
