"""URLB's quadruped ``stand`` and ``jump`` tasks, built on the control suite's quadruped.

The model is the suite's quadruped with a 10 m floor and no walls, ball, terrain or
rangefinders; the observation is the suite's egocentric state observation (egocentric state,
torso velocity, torso upright, IMU, toe force/torque: 78 dims) and the action has 12 dims.
Each episode starts from a uniformly random orientation of the root (a normalised ``randn(4)``
quaternion) dropped to the lowest height at which nothing touches.

* ``upright = tolerance(torso_zz, (1, inf), margin=2, value_at_margin=0, sigmoid='linear')``
* stand: ``reward = upright``
* jump: ``reward = upright * tolerance(com_z(torso subtree), (1, inf), margin=1, value_at_margin=0.5,
  sigmoid='linear')``

Episodes last 20 s at a control timestep of 0.02 s (1000 steps).
"""

from __future__ import annotations

import numpy as np
from dm_control.rl import control
from dm_control.suite import common
from dm_control.suite import quadruped as suite_quadruped
from dm_control.utils import rewards

#: episode length in seconds
TIME_LIMIT = 20.0
#: seconds between two agent actions
CONTROL_TIMESTEP = 0.02
#: half side of the square floor, in metres
FLOOR_SIZE = 10
#: height of the torso subtree's centre of mass above which the jump term is 1
JUMP_HEIGHT = 1.0


def upright_reward(physics: suite_quadruped.Physics) -> float:
    """1 with the torso upright, falling linearly to 0 upside down.

    :param physics: a :class:`dm_control.suite.quadruped.Physics` after a forward pass
    """
    return float(
        rewards.tolerance(
            physics.torso_upright(), bounds=(1.0, float("inf")), margin=2.0, value_at_margin=0, sigmoid="linear"
        )
    )


def jump_reward(physics: suite_quadruped.Physics) -> float:
    """Upright reward times a linear reward on the height of the torso subtree's centre of mass.

    :param physics: a :class:`dm_control.suite.quadruped.Physics` after a forward pass
    """
    jump = rewards.tolerance(
        physics.named.data.subtree_com["torso"][2],
        bounds=(JUMP_HEIGHT, float("inf")),
        margin=JUMP_HEIGHT,
        value_at_margin=0.5,
        sigmoid="linear",
    )
    return float(upright_reward(physics) * jump)


class _QuadrupedTask(suite_quadruped.Move):
    """Common base: the suite's ``Move`` start state (random orientation, non-contacting drop) and
    observation; subclasses define the reward.

    :param random: a ``numpy.random.RandomState``, an int seed, or None for a random seed
    """

    def __init__(self, random: np.random.RandomState | int | None = None) -> None:
        super().__init__(desired_speed=0.0, random=random)


class Stand(_QuadrupedTask):
    """Quadruped stand: keep the torso upright."""

    def get_reward(self, physics: suite_quadruped.Physics) -> float:
        """Return :func:`upright_reward`.

        :param physics: the quadruped physics
        """
        return upright_reward(physics)


class Jump(_QuadrupedTask):
    """Quadruped jump: keep the torso upright and its centre of mass high."""

    def get_reward(self, physics: suite_quadruped.Physics) -> float:
        """Return :func:`jump_reward`.

        :param physics: the quadruped physics
        """
        return jump_reward(physics)


def make_physics() -> suite_quadruped.Physics:
    """The quadruped physics of the URLB tasks (10 m floor; no walls, ball, terrain, rangefinders)."""
    xml = suite_quadruped.make_model(floor_size=FLOOR_SIZE, terrain=False, rangefinders=False, walls_and_ball=False)
    return suite_quadruped.Physics.from_xml_string(xml, common.ASSETS)


def _environment(task: _QuadrupedTask, time_limit: float) -> control.Environment:
    return control.Environment(make_physics(), task, time_limit=time_limit, control_timestep=CONTROL_TIMESTEP)


def stand(seed: np.random.RandomState | int | None = None, time_limit: float = TIME_LIMIT) -> control.Environment:
    """Build the quadruped stand environment.

    :param seed: the task's random state (an int seed, a ``RandomState`` or None)
    :param time_limit: episode length in seconds
    :return: a ``dm_control.rl.control.Environment``
    """
    return _environment(Stand(random=seed), time_limit)


def jump(seed: np.random.RandomState | int | None = None, time_limit: float = TIME_LIMIT) -> control.Environment:
    """Build the quadruped jump environment.

    :param seed: the task's random state (an int seed, a ``RandomState`` or None)
    :param time_limit: episode length in seconds
    :return: a ``dm_control.rl.control.Environment``
    """
    return _environment(Jump(random=seed), time_limit)
