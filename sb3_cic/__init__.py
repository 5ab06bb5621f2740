"""sb3-cic: Contrastive Intrinsic Control and the URLB methods for Stable-Baselines3.

Importing the package registers the URLB Gymnasium ids (``URLB/walker-v0``, ``URLB/walker-flip-v0``...).
"""

import envs  # noqa: F401  (registers the Gymnasium ids)
from sb3_cic.buffers import URLBReplayBuffer
from sb3_cic.callbacks import FixedSkillCallback, SkillGridSweepCallback, SkillSelectionCallback, URLBEvalCallback
from sb3_cic.constants import EXPERT_SCORES, normalized_score
from sb3_cic.ddpg import URLBDDPG
from sb3_cic.methods import (
    APS, APT, CIC, DIAYN, ICM, MOSS, RND, SMM, APSRegressionCallback, Disagreement, Fixed, ProtoRL,
)
from sb3_cic.skills import MixtureSkillPrior, OneHotSkillPrior, SkillPrior, SphereSkillPrior, UniformSkillPrior
from sb3_cic.version import __version__

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
