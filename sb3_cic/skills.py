"""Skill priors: what a skill ``z`` is, how it is sampled and how a grid of candidates is made.

A prior is used by :class:`envs.SkillObservationWrapper` (which owns the current skill) and by the
fine-tuning callbacks (which sweep its :meth:`SkillPrior.grid`).
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np


class SkillPrior(ABC):
    """Base class of skill priors.

    :param dim: size of the skill vector
    :param low: lower bound of every skill coordinate (observation space bound)
    :param high: upper bound of every skill coordinate (observation space bound)
    """

    def __init__(self, dim: int, low: float, high: float) -> None:
        if dim < 1:
            raise ValueError(f"skill dim must be >= 1, got {dim}")
        self.dim = int(dim)
        self.low = float(low)
        self.high = float(high)

    @abstractmethod
    def sample(self, rng: np.random.Generator) -> np.ndarray:
        """Draw one skill (float32 vector of size ``dim``)."""

    @abstractmethod
    def grid(self, n: int) -> np.ndarray:
        """Return ``n`` candidate skills, shape ``(n, dim)``, for a fine-tuning sweep."""

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
