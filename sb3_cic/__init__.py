"""sb3-cic: Contrastive Intrinsic Control and the URLB methods for Stable-Baselines3.

Importing the package registers the URLB Gymnasium ids (``URLB/walker-v0``, ``URLB/walker-flip-v0``...).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from sb3_cic import envs  # noqa: F401  (registers the Gymnasium ids)
from sb3_cic.version import __version__

if TYPE_CHECKING:
    from sb3_cic.buffers import URLBReplayBuffer
    from sb3_cic.callbacks import FixedSkillCallback, SkillGridSweepCallback, SkillSelectionCallback, URLBEvalCallback
    from sb3_cic.constants import EXPERT_SCORES, normalized_score
    from sb3_cic.ddpg import URLBDDPG
    from sb3_cic.methods import (
        APS, APT, CIC, DIAYN, ICM, MOSS, RND, SMM, APSRegressionCallback, Disagreement, Fixed, ProtoRL,
    )
    from sb3_cic.skills import MixtureSkillPrior, OneHotSkillPrior, SkillPrior, SphereSkillPrior, UniformSkillPrior

#: the module of each public name, imported on first use (``from sb3_cic import CIC`` loads torch; ``import sb3_cic``
#: alone, as the command line does, does not)
_MODULES: dict[str, str] = {
    **dict.fromkeys(
        ("CIC", "ICM", "Disagreement", "RND", "APT", "ProtoRL", "DIAYN", "SMM", "APS", "MOSS", "Fixed", "APSRegressionCallback"),
        "sb3_cic.methods",
    ),
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


__all__ = [
    "CIC",
    "ICM",
    "Disagreement",
    "RND",
    "APT",
    "ProtoRL",
    "DIAYN",
    "SMM",
    "APS",
    "MOSS",
    "Fixed",
    "APSRegressionCallback",
    "URLBDDPG",
    "URLBReplayBuffer",
    "SkillPrior",
    "UniformSkillPrior",
    "OneHotSkillPrior",
    "SphereSkillPrior",
    "MixtureSkillPrior",
    "SkillSelectionCallback",
    "SkillGridSweepCallback",
    "FixedSkillCallback",
    "URLBEvalCallback",
    "EXPERT_SCORES",
    "normalized_score",
]
