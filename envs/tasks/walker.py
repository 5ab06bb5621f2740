"""URLB's walker ``flip`` task, built on the control suite's walker.

The physics, model and observation (orientations, height, velocity: 24 dims) are those of
:mod:`dm_control.suite.walker`; only the reward differs. The walker is rewarded for standing
(as in walker stand) combined with a fast backward-or-forward rotation of its torso subtree, the
rotation speed being measured by the angular momentum of the torso subtree about the world y
axis (the walker moves in the x-z plane):

* ``standing = tolerance(torso_height, (1.2, inf), margin=0.6)``
* ``upright = (1 + torso_zz) / 2``
* ``stand = (3 standing + upright) / 4``
* ``move = tolerance(subtree_angmom_y(torso), (5, inf), margin=5, value_at_margin=0, sigmoid='linear')``
* ``reward = stand * (5 move + 1) / 6``, in [0, 1].

Episodes last 25 s at a control timestep of 0.025 s (1000 steps).
"""

from __future__ import annotations

import numpy as np
from dm_control.rl import control
from dm_control.suite import walker as suite_walker
from dm_control.utils import rewards

#: episode length in seconds
TIME_LIMIT = 25.0
#: seconds between two agent actions
CONTROL_TIMESTEP = 0.025
#: torso height above which ``standing`` is 1
STAND_HEIGHT = 1.2
#: angular momentum (about y) of the torso subtree above which ``move`` is 1
SPIN_SPEED = 5.0


def flip_reward(physics: suite_walker.Physics) -> float:
    """The flip reward of the current state of a walker physics.

    :param physics: a :class:`dm_control.suite.walker.Physics` after a forward pass
    :return: the reward, in [0, 1]
    """
    standing = rewards.tolerance(physics.torso_height(), bounds=(STAND_HEIGHT, float("inf")), margin=STAND_HEIGHT / 2)
    upright = (1.0 + physics.torso_upright()) / 2.0
    stand = (3.0 * standing + upright) / 4.0
    move = rewards.tolerance(
        physics.named.data.subtree_angmom["torso"][1],
        bounds=(SPIN_SPEED, float("inf")),
        margin=SPIN_SPEED,
        value_at_margin=0,
        sigmoid="linear",
    )
    return float(stand * (5.0 * move + 1.0) / 6.0)


class Flip(suite_walker.PlanarWalker):
    """Walker flip: stand and spin the torso about the y axis.

    The episode starts, as in the suite's walker tasks, from random angles of the limited and
    rotational joints (the walker then falls to the floor).

    :param random: a ``numpy.random.RandomState``, an int seed, or None for a random seed
    """

    def __init__(self, random: np.random.RandomState | int | None = None) -> None:
        super().__init__(move_speed=0, random=random)

    def get_reward(self, physics: suite_walker.Physics) -> float:
        """Return the flip reward (see the module docstring).

        :param physics: the walker physics
        """
        return flip_reward(physics)


def flip(seed: np.random.RandomState | int | None = None, time_limit: float = TIME_LIMIT) -> control.Environment:
    """Build the walker flip environment.

    :param seed: the task's random state (an int seed, a ``RandomState`` or None)
    :param time_limit: episode length in seconds
    :return: a ``dm_control.rl.control.Environment``
    """
    physics = suite_walker.Physics.from_xml_string(*suite_walker.get_model_and_assets())
    task = Flip(random=seed)
    return control.Environment(physics, task, time_limit=time_limit, control_timestep=CONTROL_TIMESTEP)
