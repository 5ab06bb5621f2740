"""Dict observations of state vectors (shimmy's ``dm_control/<domain>-<task>-v0``) as one flat Box.

URLB's networks and the n-step replay buffer take one flat float32 state; SB3's convention for a Dict
observation is a ``MultiInputPolicy``. The methods here take ``"MultiInputPolicy"`` for a Dict of 1-D or scalar
(0-d) Boxes and wrap the env with :class:`FlatStateDict` (:func:`~sb3_cic.common.env_util.prepare_env`), then
use the URLB networks on the flat vector.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces


def state_dict_keys(space: spaces.Dict) -> list[str]:
    """The keys of a Dict of state vectors in the order :class:`FlatStateDict` concatenates them: the Dict's own
    key order. Gymnasium sorts the keys of a ``Dict`` built from a plain ``dict`` alphabetically, so for shimmy's
    dm_control envs this is the alphabetical order, not dm_control's own (``flat_observation=True``, the URLB order
    of ``URLB/<domain>-...`` ids): walker's is ``height, orientations, velocity``, dm_control's
    ``orientations, height, velocity``.

    ``ValueError`` (one line) for an entry that is not a 1-D or 0-d Box (an image, a nested Dict, a discrete entry).

    :param space: a Dict observation space
    """
    for key, entry in space.spaces.items():
        if not isinstance(entry, spaces.Box) or len(entry.shape) > 1:
            kind = "an image" if isinstance(entry, spaces.Box) and len(entry.shape) == 3 else "not a state vector"
            raise ValueError(
                f"MultiInputPolicy takes a Dict of 1-D or scalar Boxes (state vectors); entry {key!r} is {entry} "
                f"({kind}): image and other entries are not supported"
            )
    return list(space.spaces)


class FlatStateDict(gym.Wrapper):
    """A Dict of state vectors as one flat float32 Box, and actions in [-1, 1].

    * Observation: the entries concatenated in :func:`state_dict_keys` order (the Dict's own key order, which is
      alphabetical for shimmy's dm_control envs), a 0-d entry as one value, cast to float32 (shimmy's are float64).
    * Action: a Box in [-1, 1] of the same shape, float32, mapped linearly to the env's bounds,
      ``low + (a + 1) / 2 * (high - low)`` after clipping to [-1, 1] (shimmy's action spaces are dm_control's
      physics bounds, which need not be [-1, 1]; URLB's actor acts in [-1, 1]). An env whose action Box is not
      bounded on both sides keeps its actions as they are.

    :param env: an env whose observation space is a Dict of 1-D or 0-d Boxes (``ValueError`` otherwise)
    """

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        space = env.observation_space
        if not isinstance(space, spaces.Dict):
            raise ValueError(f"FlatStateDict needs a Dict observation space, got {space}")
        self.keys = state_dict_keys(space)
        entries = [space.spaces[key] for key in self.keys]
        low = np.concatenate([np.ravel(entry.low) for entry in entries]).astype(np.float32)
        high = np.concatenate([np.ravel(entry.high) for entry in entries]).astype(np.float32)
        self.observation_space = spaces.Box(low, high, dtype=np.float32)
        action_space = env.action_space
        if not isinstance(action_space, spaces.Box):
            raise ValueError(f"URLB agents need a continuous (Box) action space, got {action_space}")
        self._rescale = bool(action_space.is_bounded("both"))
        if self._rescale:
            self._low = action_space.low.astype(np.float64)
            self._half_range = 0.5 * (action_space.high.astype(np.float64) - self._low)
            self.action_space = spaces.Box(-1.0, 1.0, shape=action_space.shape, dtype=np.float32)

    def observation(self, observation: dict[str, Any]) -> np.ndarray:
        """The flat float32 observation of a Dict observation.

        :param observation: an observation of the wrapped env
        """
        return np.concatenate([np.ravel(observation[key]) for key in self.keys]).astype(np.float32, copy=False)

    def action(self, action: np.ndarray) -> np.ndarray:
        """The wrapped env's action of an action in [-1, 1].

        :param action: an action of this wrapper's space
        """
        if not self._rescale:
            return action
        unit = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        return (self._low + (unit + 1.0) * self._half_range).astype(self.env.action_space.dtype, copy=False)

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict[str, Any]]:
        observation, info = self.env.reset(**kwargs)
        return self.observation(observation), info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, Any, bool, bool, dict[str, Any]]:
        observation, reward, terminated, truncated, info = self.env.step(self.action(action))
        return self.observation(observation), reward, terminated, truncated, info
