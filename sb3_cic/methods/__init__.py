"""The unsupervised RL methods: each is the URLB DDPG base plus a skill prior, a reward module and a
fine-tune choice."""

from sb3_cic.methods.cic import CIC

__all__ = ["CIC"]
