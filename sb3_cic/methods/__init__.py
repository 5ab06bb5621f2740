"""The unsupervised RL methods: each is the URLB DDPG base plus a skill prior, a reward module and a
fine-tune choice."""

from sb3_cic.methods.apt import APT
from sb3_cic.methods.aps import APS, APSCritic, APSPolicy, APSRegressionCallback
from sb3_cic.methods.cic import CIC
from sb3_cic.methods.diayn import DIAYN
from sb3_cic.methods.disagreement import Disagreement
from sb3_cic.methods.fixed import Fixed
from sb3_cic.methods.icm import ICM
from sb3_cic.methods.moss import MOSS
from sb3_cic.methods.proto import ProtoRL
from sb3_cic.methods.rnd import RND
from sb3_cic.methods.smm import SMM

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
    "APSPolicy",
    "APSCritic",
    "APSRegressionCallback",
]
