"""URLB's jaco ``reach_*`` tasks: bring the Kinova Jaco hand to a Duplo brick at a fixed place.

A dm_control composer task built on the public pieces of :mod:`dm_control.manipulation`
(the standard arena, the Jaco arm and hand, a Duplo 2x4 brick, the tool-centre-point and
prop initialisers and the "perfect features" observation settings), with the brick at a fixed
position per task instead of a random one:

======================  ===============
task                    brick (x, y)
======================  ===============
``reach_top_left``      (-0.09, 0.09)
``reach_top_right``     (0.09, 0.09)
``reach_bottom_left``   (-0.09, -0.09)
``reach_bottom_right``  (0.09, -0.09)
======================  ===============

Each episode the brick is put at z = 0.001 with a uniformly random rotation about z and left to
settle; the hand's tool centre point (its pinch site) is put, pointing down, at a uniform point of
[-0.1, 0.1]^2 x [0.2, 0.4], with a random closure of the grasp.

``reward = tolerance(|tcp - brick|, (0, 0.05), margin=0.05)`` where ``brick`` is the brick body's
origin (the observed ``duplo2x4/position`` is a site 0.0119 m above it). Episodes last 10 s at a
control timestep of 0.04 s (250 steps) and a physics timestep of 0.002 s.

The observation has 55 dims (arm joint sin/cos 12, arm torques 6, arm velocities 6, hand joint
positions 3 and velocities 3, pinch site position 3 and rotation 9, brick angular velocity 3,
linear velocity 3, orientation 4 and position 3) and the action 9.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np
from dm_control import composer, mjcf
from dm_control.composer import initializers
from dm_control.composer.observation import observable
from dm_control.composer.variation import distributions
from dm_control.entities import props
from dm_control.entities.manipulators import base as manipulator_base
from dm_control.manipulation.shared import arenas, cameras, observations, robots, workspaces
from dm_control.utils import rewards

#: brick (x, y) of each task
TARGETS: dict[str, tuple[float, float]] = {
    "reach_top_left": (-0.09, 0.09),
    "reach_top_right": (0.09, 0.09),
    "reach_bottom_left": (-0.09, -0.09),
    "reach_bottom_right": (0.09, -0.09),
}
#: the brick starts this high so that it does not touch the table before settling
PROP_Z = 0.001
#: where the tool centre point starts, uniformly: (lower, upper) corners
TCP_BOX = workspaces.BoundingBox(lower=(-0.1, -0.1, 0.2), upper=(0.1, 0.1, 0.4))
#: distance below which the reward is 1 (and the margin of the tolerance)
TARGET_RADIUS = 0.05
#: episode length in seconds
TIME_LIMIT = 10.0
#: seconds between two agent actions
CONTROL_TIMESTEP = 0.04
#: seconds of one physics step
PHYSICS_TIMESTEP = 0.002


class ReachBrick(composer.Task):
    """Move the Jaco hand's tool centre point to a Duplo brick lying at a fixed place.

    :param target_xy: (x, y) of the brick on the table
    :param obs_settings: observation settings (``observations.PERFECT_FEATURES`` for URLB)
    :param control_timestep: seconds between two agent actions
    :param physics_timestep: seconds of one physics step
    """

    def __init__(
        self,
        target_xy: tuple[float, float],
        obs_settings: observations.ObservationSettings = observations.PERFECT_FEATURES,
        control_timestep: float = CONTROL_TIMESTEP,
        physics_timestep: float = PHYSICS_TIMESTEP,
    ) -> None:
        self._arena = arenas.Standard()
        self._arm = robots.make_arm(obs_settings=obs_settings)
        self._hand = robots.make_hand(obs_settings=obs_settings)
        self._arm.attach(self._hand)
        self._arena.attach_offset(self._arm, offset=robots.ARM_OFFSET)
        self._brick = props.Duplo(
            observable_options=observations.make_options(obs_settings, observations.FREEPROP_OBSERVABLES)
        )
        # the attachment frame of the free brick: its xpos is the brick body's origin
        self._brick_frame = self._arena.add_free_entity(self._brick)
        self.target_position = np.array([target_xy[0], target_xy[1], PROP_Z])

        self._tcp_initializer = initializers.ToolCenterPointInitializer(
            self._hand,
            self._arm,
            position=distributions.Uniform(*TCP_BOX),
            quaternion=workspaces.DOWN_QUATERNION,
        )
        self._brick_placer = initializers.PropPlacer(
            props=[self._brick],
            position=self.target_position,
            quaternion=workspaces.uniform_z_rotation,
            settle_physics=True,
        )
        # a front camera for rendering (its image observable is disabled with feature observations)
        self._task_observables: OrderedDict[str, observable.Observable] = cameras.add_camera_observables(
            self._arena, obs_settings, cameras.FRONT_CLOSE
        )
        workspaces.add_bbox_site(
            body=self._arena.mjcf_model.worldbody,
            lower=TCP_BOX.lower,
            upper=TCP_BOX.upper,
            name="tcp_spawn_area",
        )
        self.set_timesteps(control_timestep=control_timestep, physics_timestep=physics_timestep)

    @property
    def root_entity(self) -> composer.Entity:
        """The arena, root of the model."""
        return self._arena

    @property
    def arm(self) -> manipulator_base.RobotArm:
        """The Jaco arm."""
        return self._arm

    @property
    def hand(self) -> manipulator_base.RobotHand:
        """The Jaco hand."""
        return self._hand

    @property
    def brick(self) -> props.Duplo:
        """The Duplo brick to reach."""
        return self._brick

    @property
    def brick_frame(self) -> mjcf.Element:
        """The brick's free attachment frame (a body whose origin is the brick's)."""
        return self._brick_frame

    @property
    def task_observables(self) -> OrderedDict[str, observable.Observable]:
        """The task's own observables (the disabled front camera)."""
        return self._task_observables

    def distance(self, physics: mjcf.Physics) -> float:
        """Distance from the tool centre point to the brick body's origin.

        :param physics: the task's physics
        """
        tcp = physics.bind(self._hand.tool_center_point).xpos
        brick = physics.bind(self._brick_frame).xpos
        return float(np.linalg.norm(tcp - brick))

    def get_reward(self, physics: mjcf.Physics) -> float:
        """``tolerance(distance, (0, 0.05), margin=0.05)``, in [0, 1].

        :param physics: the task's physics
        """
        return float(rewards.tolerance(self.distance(physics), bounds=(0.0, TARGET_RADIUS), margin=TARGET_RADIUS))

    def initialize_episode(self, physics: mjcf.Physics, random_state: np.random.RandomState) -> None:
        """Random grasp closure, random tool centre point, brick at its place with a random yaw.

        :param physics: the task's physics
        :param random_state: the environment's random state
        """
        self._hand.set_grasp(physics, close_factors=random_state.uniform())
        self._tcp_initializer(physics, random_state)
        self._brick_placer(physics, random_state)


def make(task: str, seed: np.random.RandomState | int | None = None, time_limit: float = TIME_LIMIT) -> composer.Environment:
    """Build a jaco reach environment.

    :param task: ``reach_top_left``, ``reach_top_right``, ``reach_bottom_left`` or ``reach_bottom_right``
    :param seed: the environment's random state (an int seed, a ``RandomState`` or None)
    :param time_limit: episode length in seconds
    :return: a ``dm_control.composer.Environment`` with flat (unbuffered) observations
    """
    if task not in TARGETS:
        raise ValueError(f"unknown jaco task {task!r}; known: {sorted(TARGETS)}")
    return composer.Environment(
        ReachBrick(TARGETS[task]),
        time_limit=time_limit,
        random_state=seed,
        strip_singleton_obs_buffer_dim=True,
    )
