"""Dict observations of state vectors (shimmy's ``dm_control/<domain>-<task>-v0``) as one flat Box.

URLB's networks and the n-step replay buffer take one flat float32 state; SB3's convention for a Dict
observation is a ``MultiInputPolicy``. The methods here take ``"MultiInputPolicy"`` for a Dict of state entries and
keep the URLB networks on the flat vector: :class:`StateDictLayout` is the one statement of how a Dict observation
is that vector and how an action in [-1, 1] is the env's action. :class:`FlatStateDict` applies it to an env,
:class:`~sb3_cic.envs.vec_dict_obs.VecFlatStateDict` to a VecEnv (:func:`~sb3_cic.common.env_util.prepare_env`
picks), and the model's ``predict`` to the Dict observations it is given (an env's own, single or from a VecEnv).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

#: the entries a Dict of states may hold besides 1-D and scalar Boxes (one-hot, or 0/1, as SB3's preprocessing)
ONE_HOT_ENTRIES = (spaces.Discrete, spaces.MultiDiscrete, spaces.MultiBinary)


def state_dict_keys(space: spaces.Dict) -> list[str]:
    """The keys of a Dict of state entries in the order :class:`StateDictLayout` concatenates them: the Dict's own
    key order. Gymnasium sorts the keys of a ``Dict`` built from a plain ``dict`` alphabetically, so for shimmy's
    dm_control envs this is the alphabetical order, not dm_control's own (``flat_observation=True``, the URLB order
    of ``URLB/<domain>-...`` ids): walker's is ``height, orientations, velocity``, dm_control's
    ``orientations, height, velocity``.

    An entry is a 1-D or 0-d Box, a ``Discrete``, a ``MultiDiscrete`` or a ``MultiBinary``; any other (an image, a
    nested Dict) is a one-line ``ValueError``.

    :param space: a Dict observation space
    """
    for key, entry in space.spaces.items():
        if isinstance(entry, ONE_HOT_ENTRIES) or (isinstance(entry, spaces.Box) and len(entry.shape) <= 1):
            continue
        kind = "an image" if isinstance(entry, spaces.Box) and len(entry.shape) == 3 else "not a state vector"
        raise ValueError(
            f"MultiInputPolicy takes a Dict of 1-D or scalar Boxes, Discrete, MultiDiscrete and MultiBinary entries "
            f"(state vectors); entry {key!r} is {entry} ({kind}): image and other entries are not supported "
            "(the URLB methods are state-based)"
        )
    return list(space.spaces)


class StateDictLayout:
    """How a Dict observation of state entries is one flat float32 vector, and an action in [-1, 1] the env's.

    * Observation: gymnasium's ``spaces.flatten`` of the Dict, cast to float32: the entries in
      :func:`state_dict_keys` order, a Box raveled (a 0-d entry is one value), a ``Discrete`` one-hot (of
      ``x - start``), a ``MultiDiscrete`` the one-hots of its entries, a ``MultiBinary`` its 0/1 values: SB3's
      ``preprocess_obs`` of a ``MultiInputPolicy``, concatenated as its ``CombinedExtractor`` does.
    * Action: a Box in [-1, 1] of the same shape, float32, mapped linearly to the env's bounds,
      ``low + (a + 1) / 2 * (high - low)`` after clipping to [-1, 1], in the env's dtype (shimmy's action spaces are
      dm_control's physics bounds; URLB's actor acts in [-1, 1]). An action Box not bounded on both sides is kept.

    :param observation_space: the env's Dict observation space (``ValueError`` for entries :func:`state_dict_keys`
        refuses)
    :param action_space: the env's action space (``ValueError`` unless a Box)
    """

    def __init__(self, observation_space: spaces.Dict, action_space: spaces.Space) -> None:
        if not isinstance(observation_space, spaces.Dict):
            raise ValueError(f"a Dict observation space is needed, got {observation_space}")
        if not isinstance(action_space, spaces.Box):
            raise ValueError(f"URLB agents need a continuous (Box) action space, got {action_space}")
        self.keys = state_dict_keys(observation_space)
        self.dict_space = observation_space
        self.env_action_space = action_space
        flat = spaces.flatten_space(observation_space)
        self.observation_space = spaces.Box(flat.low.astype(np.float32), flat.high.astype(np.float32), dtype=np.float32)
        sizes = [spaces.flatdim(observation_space[key]) for key in self.keys]
        #: each entry's place in the flat vector
        self.slices = {key: slice(int(end - size), int(end)) for key, size, end in zip(self.keys, sizes, np.cumsum(sizes))}
        self.rescale = bool(action_space.is_bounded("both"))
        self.action_space = spaces.Box(-1.0, 1.0, action_space.shape, np.float32) if self.rescale else action_space

    def is_batch(self, observation: dict[str, Any]) -> bool:
        """Whether ``observation`` holds several observations (a VecEnv's): its first entry has a leading axis.

        :param observation: a Dict observation, single or batched
        """
        key = self.keys[0]
        return bool(np.ndim(observation[key]) > len(self.dict_space[key].shape))

    def flatten(self, observation: dict[str, Any], batch: bool | None = None) -> np.ndarray:
        """The flat float32 observation(s) of a Dict observation: shape ``(dim,)``, or ``(n, dim)`` for a batch.

        :param observation: a Dict observation of this layout's space, single or batched (a leading axis per entry)
        :param batch: whether it is batched (None: :meth:`is_batch`)
        """
        missing = set(self.keys) - set(observation)
        if missing:
            raise ValueError(f"the Dict observation lacks {sorted(missing)}: this model's keys are {self.keys}")
        if not (self.is_batch(observation) if batch is None else batch):
            return spaces.flatten(self.dict_space, observation).astype(np.float32, copy=False)
        n = len(observation[self.keys[0]])
        rows = [spaces.flatten(self.dict_space, {key: observation[key][i] for key in self.keys}) for i in range(n)]
        return np.stack(rows).astype(np.float32, copy=False).reshape(n, -1)

    def env_action(self, action: np.ndarray) -> np.ndarray:
        """The env's action(s) of action(s) in [-1, 1] (any leading axes are kept).

        :param action: action(s) of this layout's :attr:`action_space`
        """
        if not self.rescale:
            return action
        space = self.env_action_space
        unit = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        low = space.low.astype(np.float64)
        return (low + (unit + 1.0) * 0.5 * (space.high.astype(np.float64) - low)).astype(space.dtype, copy=False)


class FlatStateDict(gym.Wrapper):
    """A Dict of state entries as one flat float32 Box, and actions in [-1, 1] (the rule: :class:`StateDictLayout`).

    :param env: an env whose observation space is a Dict of state entries (``ValueError`` otherwise)
    """

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        if not isinstance(env.observation_space, spaces.Dict):
            raise ValueError(f"FlatStateDict needs a Dict observation space, got {env.observation_space}")
        self.layout = StateDictLayout(env.observation_space, env.action_space)
        self.keys = self.layout.keys
        self.observation_space = self.layout.observation_space
        self.action_space = self.layout.action_space

    def observation(self, observation: dict[str, Any]) -> np.ndarray:
        """The flat float32 observation of a Dict observation.

        :param observation: an observation of the wrapped env
        """
        return self.layout.flatten(observation, batch=False)

    def action(self, action: np.ndarray) -> np.ndarray:
        """The wrapped env's action of an action in [-1, 1].

        :param action: an action of this wrapper's space
        """
        return self.layout.env_action(action)

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict[str, Any]]:
        observation, info = self.env.reset(**kwargs)
        return self.observation(observation), info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, Any, bool, bool, dict[str, Any]]:
        observation, reward, terminated, truncated, info = self.env.step(self.action(action))
        return self.observation(observation), reward, terminated, truncated, info
