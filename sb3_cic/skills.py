"""Skill priors: what a skill ``z`` is, how it is sampled and how a grid of candidates is made.

A prior is used by :class:`sb3_cic.envs.SkillObservationWrapper` (which owns the current skill) and by the
fine-tuning callbacks (which sweep its :meth:`SkillPrior.grid`).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import ClassVar

import numpy as np
import torch as th

from sb3_cic.common.arguments import POSITIVE, POSITIVE_INT, Flag, Range

#: the largest skill a method takes (``skill_dim``): the URLB methods use 4 to 64; a prior of thousands of
#: dimensions makes every update slow (the skill is part of every network's input) and a grid sweep meaningless
MAX_SKILL_DIM = 1024
#: the size of a skill
SKILL_DIM = Range(1, MAX_SKILL_DIM, integer=True)


class SkillPrior(ABC):
    """Base class of skill priors.

    :param dim: size of the skill vector
    :param low: lower bound of every skill coordinate (observation space bound)
    :param high: upper bound of every skill coordinate (observation space bound)
    """

    #: the range of each numeric parameter (a subclass adds its own: :func:`~sb3_cic.common.arguments.ranges_of`)
    parameter_ranges: ClassVar[dict[str, Range | Flag]] = {"dim": SKILL_DIM}

    def __init__(self, dim: int, low: float, high: float) -> None:
        self.dim = int(SKILL_DIM.check("skill dim", dim))
        self.low = float(low)
        self.high = float(high)

    @abstractmethod
    def sample(self, rng: np.random.Generator) -> np.ndarray:
        """Draw one skill (float32 vector of size ``dim``)."""

    @abstractmethod
    def grid(self, n: int) -> np.ndarray:
        """Return ``n`` candidate skills, shape ``(n, dim)``, for a fine-tuning sweep."""

    def sample_at(self, rng: np.random.Generator, episode_step: int) -> np.ndarray:
        """Draw the skill of step ``episode_step`` of an episode (0 at reset): :meth:`sample`, whatever the step,
        but for a prior whose skills depend on the part of the episode (:class:`MixtureSkillPrior`).

        :param rng: random generator
        :param episode_step: steps since the episode's reset
        """
        return self.sample(rng)

    def validate(self, skill: np.ndarray) -> np.ndarray:
        """Return ``skill`` as a float32 vector, or raise ``ValueError`` if it is not in the prior's support.

        :param skill: candidate skill
        """
        z = np.asarray(skill, dtype=np.float32)
        if z.shape != (self.dim,):
            raise ValueError(f"{type(self).__name__}: skill must have shape ({self.dim},), got {z.shape}")
        if not np.all(np.isfinite(z)) or z.min() < self.low - 1e-6 or z.max() > self.high + 1e-6:
            raise ValueError(f"{type(self).__name__}: skill values must lie in [{self.low}, {self.high}], got {z}")
        return z

    def __repr__(self) -> str:
        return f"{type(self).__name__}(dim={self.dim})"

    def __eq__(self, other: object) -> bool:
        return type(self) is type(other) and vars(self) == vars(other)


class UniformSkillPrior(SkillPrior):
    """Continuous skills ``z ~ U[low, high]^dim`` (CIC: U[0, 1]^64).

    The grid is the paper's sweep of constant skills ``c * 1`` for ``c`` evenly spaced in [low, high].

    :param dim: skill size
    :param low: lower bound
    :param high: upper bound
    """

    def __init__(self, dim: int = 64, low: float = 0.0, high: float = 1.0) -> None:
        super().__init__(dim, low, high)

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        return rng.uniform(self.low, self.high, size=self.dim).astype(np.float32)

    def grid(self, n: int) -> np.ndarray:
        values = np.linspace(self.low, self.high, n, dtype=np.float32)
        return np.repeat(values[:, None], self.dim, axis=1)


class OneHotSkillPrior(SkillPrior):
    """Discrete skills as one-hot vectors (DIAYN: 16, SMM: 4); the grid is every skill.

    :param dim: number of skills
    """

    def __init__(self, dim: int = 16) -> None:
        super().__init__(dim, 0.0, 1.0)

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        z = np.zeros(self.dim, dtype=np.float32)
        z[rng.integers(self.dim)] = 1.0
        return z

    def grid(self, n: int | None = None) -> np.ndarray:
        return np.eye(self.dim, dtype=np.float32)

    def validate(self, skill: np.ndarray) -> np.ndarray:
        z = super().validate(skill)
        if not (np.isin(z, (0.0, 1.0)).all() and z.sum() == 1.0):
            raise ValueError(f"OneHotSkillPrior: skill must be one-hot, got {z}")
        return z


class SphereSkillPrior(SkillPrior):
    """Skills on the unit sphere: a normalised gaussian (APS task vectors ``w``, 10-d).

    :param dim: skill size
    """

    def __init__(self, dim: int = 10) -> None:
        super().__init__(dim, -1.0, 1.0)

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        z = rng.standard_normal(self.dim)
        return (z / np.linalg.norm(z)).astype(np.float32)

    def grid(self, n: int) -> np.ndarray:
        rng = np.random.default_rng(0)
        return np.stack([self.sample(rng) for _ in range(n)])

    def validate(self, skill: np.ndarray) -> np.ndarray:
        z = super().validate(skill)
        if abs(float(np.linalg.norm(z)) - 1.0) > 1e-3:
            raise ValueError(f"SphereSkillPrior: skill must have unit norm, got norm {np.linalg.norm(z):.4f}")
        return z


#: MOSS's ways of carrying the mode in the skill (:class:`MixtureSkillPrior`)
MOSS_SKILL_MODES = ("half", "sign")


def check_skill_mode(skill_mode: str) -> str:
    """Return ``skill_mode``, or raise ``ValueError`` if it is not one of :data:`MOSS_SKILL_MODES`."""
    if skill_mode not in MOSS_SKILL_MODES:
        raise ValueError(f"skill_mode must be one of {MOSS_SKILL_MODES}, got {skill_mode!r}")
    return skill_mode


def control_mask(skills: th.Tensor, skill_mode: str) -> th.Tensor:
    """Which skills of a batch ``(B, dim)`` are control skills of :class:`MixtureSkillPrior` (``(B, 1)`` bool).

    ``"half"``: the first ``dim // 2`` coordinates are zero (an explore skill draws them from U[0, 1]);
    ``"sign"``: the coordinates are negative.

    :param skills: skills of the prior
    :param skill_mode: the prior's ``skill_mode``
    """
    if skill_mode == "half":
        return (skills[:, : skills.shape[1] // 2] == 0).all(dim=1, keepdim=True)
    return skills.sum(dim=1, keepdim=True) < 0


class MixtureSkillPrior(SkillPrior):
    """MOSS's skills (Zhao et al., 2022): each part of an episode either explores or controls, and the skill says which.

    The episode of ``episode_length`` steps is cut into parts of ``episode_length // partitions`` steps; a skill drawn
    in an even part (the first included) is an *explore* skill, in an odd part a *control* skill (MOSS's
    defaults: 2 partitions, the first half of an episode explores, the second controls; their jaco example: 1.5,
    the first 666 steps explore). With ``skill_mode="half"`` (MOSS's default) an explore skill is
    ``[U[0, 1]^(dim - dim // 2), 0^(dim // 2)]`` and a control skill ``[0^(dim // 2), U[0, 1]^(dim - dim // 2)]``;
    with ``"sign"`` an explore skill is ``U[0, 1]^dim`` and a control skill its negative. :func:`control_mask`
    reads the mode back from a skill.

    The grid of a fine-tuning sweep is MOSS's: constant skills ``c * 1`` for ``c`` evenly spaced in [-1, 0]
    (their ``grid_search``), which the bounds [-1, 1] admit.

    :param dim: skill size (MOSS: 32)
    :param partitions: parts of an episode, alternately explore and control (2)
    :param skill_mode: "half" or "sign" (see above)
    :param episode_length: steps of an episode (URLB's 1,000)
    """

    parameter_ranges: ClassVar[dict[str, Range | Flag]] = {"partitions": POSITIVE, "episode_length": POSITIVE_INT}

    def __init__(self, dim: int = 32, partitions: float = 2, skill_mode: str = "half", episode_length: int = 1000) -> None:
        super().__init__(dim, -1.0, 1.0)
        if check_skill_mode(skill_mode) == "half" and dim < 2:
            raise ValueError(f"skill_mode 'half' needs a skill of at least 2 coordinates, got dim {dim}")
        if not partitions > 0 or episode_length // partitions < 1:
            raise ValueError(f"partitions must be > 0 and at most episode_length ({episode_length}), got {partitions}")
        self.partitions = partitions
        self.skill_mode = skill_mode
        self.episode_length = int(episode_length)

    def is_control_step(self, episode_step: int) -> bool:
        """Whether a skill drawn at ``episode_step`` is a control skill."""
        return bool(int(episode_step // (self.episode_length // self.partitions)) % 2)

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        """An explore skill (the mode of an episode's first step)."""
        return self.sample_at(rng, 0)

    def sample_at(self, rng: np.random.Generator, episode_step: int) -> np.ndarray:
        control = self.is_control_step(episode_step)
        if self.skill_mode == "sign":
            z = rng.uniform(0.0, 1.0, size=self.dim)
            return (-z if control else z).astype(np.float32)
        zeros, drawn = self.dim // 2, self.dim - self.dim // 2
        uniform = rng.uniform(0.0, 1.0, size=drawn)
        parts = (np.zeros(zeros), uniform) if control else (uniform, np.zeros(zeros))
        return np.concatenate(parts).astype(np.float32)

    def grid(self, n: int) -> np.ndarray:
        values = np.linspace(-1.0, 0.0, n, dtype=np.float32)
        return np.repeat(values[:, None], self.dim, axis=1)
