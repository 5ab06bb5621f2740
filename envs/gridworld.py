"""A reward-free gridworld: the CIC paper's Appendix G setting (skill spaces that are too small).

``URLB/gridworld-v0`` is :class:`GridWorldEnv` with its defaults: a 10 x 10 grid, the agent starts at the
centre cell, four moves and staying, 20 steps per episode, reward 0. ``benchmarks/gridworld_skills.py``
pre-trains DIAYN and CIC on it and counts the cells their skills reach.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

#: the moves of the action's axes and signs, as ``(dx, dy)``: index ``2 * axis + (component > 0)``
MOVES = np.array([[-1, 0], [1, 0], [0, -1], [0, 1]], dtype=np.int64)
#: steps per episode of ``URLB/gridworld-v0`` (why 20: see :class:`GridWorldEnv`)
GRID_EPISODE_LENGTH = 20


class GridWorldEnv(gym.Env):
    """A ``size`` x ``size`` grid of cells ``(x, y)``, ``0 <= x, y < size``, with no reward.

    * Start: the centre cell ``(size // 2, size // 2)``; for an even size there is no single centre, and this is
      the upper of the four middle cells, ``(5, 5)`` on the 10 x 10 grid.
    * Action: a continuous ``Box([-1, 1]^2)``, so that every method here (URLB's DDPG) can act on it. The
      component of larger magnitude picks the axis (``a[0]``: x, ``a[1]``: y; a tie picks x) and its sign the
      direction (negative: -1, positive: +1); when both magnitudes are below ``dead_zone`` the agent stays. A move
      into the wall leaves the agent where it is. With ``dead_zone=0.5`` a uniformly random action stays with
      probability 1/4 and takes each move with probability 3/16.
    * Observation: the cell as float32 coordinates normalised to [-1, 1], ``2 * (x, y) / (size - 1) - 1``
      (``(0.111, 0.111)`` at the start of the 10 x 10 grid). :meth:`cell_of` maps an observation back to its cell.
    * Episodes: ``episode_length`` steps, then a truncation (never a termination), as URLB's fixed-length
      episodes. The default, 20, is twice the longest shortest path from the start (10 moves, to the corner
      ``(0, 0)``): every cell is reachable within an episode, with time to stay there, and an episode is one skill
      (the skill wrapper resamples skills at each reset and every 50 steps).
    * Reward: 0 at every step (reward-free: the methods' intrinsic rewards are the only signal); ``info["cell"]``
      is the cell after the step.

    :param size: cells per side (10)
    :param episode_length: steps per episode (20)
    :param dead_zone: both action components below this magnitude: stay (0.5)
    """

    metadata = {"render_modes": []}

    def __init__(self, size: int = 10, episode_length: int = GRID_EPISODE_LENGTH, dead_zone: float = 0.5) -> None:
        if size < 2 or episode_length < 1 or not 0.0 <= dead_zone < 1.0:
            raise ValueError(
                f"size must be >= 2, episode_length >= 1 and dead_zone in [0, 1), got {size}, {episode_length}, {dead_zone}"
            )
        self.size = int(size)
        self.episode_length = int(episode_length)
        self.dead_zone = float(dead_zone)
        self.start = np.array([self.size // 2, self.size // 2], dtype=np.int64)
        self.observation_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        self.cell = self.start.copy()
        self.steps = 0

    def observe(self, cell: np.ndarray) -> np.ndarray:
        """The observation of ``cell`` (or of an array of cells, shape ``(..., 2)``).

        :param cell: ``(x, y)`` integer coordinates
        """
        return (2.0 * np.asarray(cell, dtype=np.float32) / (self.size - 1) - 1.0).astype(np.float32)

    def cell_of(self, observation: np.ndarray) -> np.ndarray:
        """The cells of observations (shape ``(..., 2)``, the state part of ``[state, skill]`` observations).

        :param observation: observations of this env
        """
        return np.rint((np.asarray(observation)[..., :2] + 1.0) * (self.size - 1) / 2.0).astype(np.int64)

    def move(self, action: np.ndarray) -> np.ndarray:
        """The move ``(dx, dy)`` of an action (of an array of actions, shape ``(..., 2)``), before the walls.

        :param action: actions in [-1, 1]^2
        """
        action = np.asarray(action, dtype=np.float64)
        magnitude = np.abs(action)
        axis = (magnitude[..., 1] > magnitude[..., 0]).astype(np.int64)
        component = np.take_along_axis(action, axis[..., None], axis=-1)[..., 0]
        moves = MOVES[2 * axis + (component > 0)]
        stay = magnitude.max(axis=-1) < self.dead_zone
        return np.where(stay[..., None], 0, moves)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self.cell = self.start.copy()
        self.steps = 0
        return self.observe(self.cell), {"cell": self.cell.copy()}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        """Move by the action's move, staying inside the grid.

        :param action: an action in [-1, 1]^2 (see the class docstring)
        :return: observation, reward 0, terminated False, truncated at ``episode_length`` steps, ``{"cell": (x, y)}``
        """
        self.cell = np.clip(self.cell + self.move(action), 0, self.size - 1)
        self.steps += 1
        return self.observe(self.cell), 0.0, False, self.steps >= self.episode_length, {"cell": self.cell.copy()}
