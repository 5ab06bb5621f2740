"""dm_control -> Gymnasium adapter used by every URLB environment.

The adapter talks to a ``dm_env.Environment`` (a control-suite or a composer environment) directly
instead of going through shimmy's Dict environment plus ``FlattenObservation``:

* the observation is one flat float32 vector in dm_control's own key order (the URLB order);
  a gymnasium ``Dict`` space would sort the keys alphabetically and give another order;
* actions are float32 in [-1, 1], rescaled to the physics bounds;
* episodes end by truncation at the time limit (``truncated=True``), never by termination,
  unless the task itself returns a zero discount;
* ``reset(seed=...)`` re-seeds the task's random state in place, so the same seed and actions
  give identical trajectories.

``benchmarks/env_speed.py`` measures this adapter against raw dm_control and against shimmy.
"""

from __future__ import annotations

from typing import Any, Callable

import dm_env
import gymnasium as gym
import numpy as np
from gymnasium import spaces

_LAST = dm_env.StepType.LAST
#: MuJoCo's ``mjDSBL_CLAMPCTRL`` disable flag (controls of ``ctrllimited`` actuators are not clamped)
_DISABLE_CLAMPCTRL = 1 << 8


class RenderError(gym.error.Error, RuntimeError):
    """MuJoCo cannot render here (no OpenGL backend, or ``MUJOCO_GL=disable``): a ``gymnasium.error.Error`` (the
    command line reports it in one line) and a ``RuntimeError``."""


class DMCEnv(gym.Env):
    """A dm_control environment as a Gymnasium environment with a flat float32 observation.

    :param loader: callable ``loader(seed) -> dm_env.Environment`` that builds the dm_control env
    :param reward_free: if True the returned reward is 0 and the task reward goes to
        ``info["task_reward"]`` (URLB pre-training); otherwise the task reward is returned
        (and also reported in ``info["task_reward"]``)
    :param render_mode: ``None`` or ``"rgb_array"``
    :param render_size: (height, width) of rendered frames
    :param camera_id: camera used for rendering
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(
        self,
        loader: Callable[[int | None], dm_env.Environment],
        reward_free: bool = False,
        render_mode: str | None = None,
        render_size: tuple[int, int] = (256, 256),
        camera_id: int = 0,
    ) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self._env = loader(None)
        self.reward_free = reward_free
        self.render_mode = render_mode
        self.render_size = render_size
        self.camera_id = camera_id

        # (key, slice of the flat observation, needs ravel) in dm_control's key order
        self._obs_slices: list[tuple[str, slice, bool]] = []
        dim = 0
        for key, spec in self._env.observation_spec().items():
            size = int(np.prod(spec.shape))
            self._obs_slices.append((key, slice(dim, dim + size), len(spec.shape) > 1))
            dim += size
        self._obs_dim = dim
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(dim,), dtype=np.float32)
        act_spec = self._env.action_spec()
        self._act_low = act_spec.minimum.astype(np.float64)
        self._act_high = act_spec.maximum.astype(np.float64)
        self.action_space = spaces.Box(-1.0, 1.0, shape=act_spec.shape, dtype=np.float32)
        # ``a`` in [-1, 1] -> ``mid + a * half_range``, from ``low`` to ``high``
        self._act_half_range = 0.5 * (self._act_high - self._act_low)
        self._act_mid = 0.5 * (self._act_high + self._act_low)
        # physics bounds of exactly [-1, 1] (walker, point mass): the rescaling is the identity
        self._act_unit_range = bool(np.all(self._act_low == -1.0) and np.all(self._act_high == 1.0))
        self._physics_clamps = self._physics_clamps_controls()
        # array operands: cheaper in ufuncs than Python scalars
        self._act_ones = np.ones(act_spec.shape, dtype=np.float64)
        self._act_minus_ones = -self._act_ones
        #: the task's random state as the last reset found it (see :meth:`get_checkpoint_state`)
        self._reset_random_state: tuple | dict | None = None

    def _physics_clamps_controls(self) -> bool:
        """Whether MuJoCo itself clamps every control to exactly the action spec's bounds.

        Then ``mid + a * half_range`` needs no clip of ``a`` to [-1, 1] first: the affine map is
        increasing, so clamping its result to ``[low, high]`` (MuJoCo, for ``ctrllimited`` actuators
        unless ``clampctrl`` is disabled) applies the same control as clipping ``a``.
        """
        model = self.physics.model
        ranges = np.asarray(model.actuator_ctrlrange, dtype=np.float64)
        return bool(
            model.nu == self._act_low.size
            and np.all(model.actuator_ctrllimited)
            and not model.opt.disableflags & _DISABLE_CLAMPCTRL
            and np.array_equal(ranges[:, 0], self._act_low.ravel())
            and np.array_equal(ranges[:, 1], self._act_high.ravel())
        )

    # dm_control objects --------------------------------------------------------------------
    @property
    def dm_env(self) -> dm_env.Environment:
        """The wrapped dm_control environment."""
        return self._env

    @property
    def physics(self) -> Any:
        """The MuJoCo physics of the wrapped environment."""
        return self._env.physics

    def _random_state(self) -> np.random.RandomState:
        task = getattr(self._env, "task", None)
        if hasattr(self._env, "random_state"):  # composer
            return self._env.random_state
        return task.random  # control suite

    # Gymnasium API -------------------------------------------------------------------------
    def _flatten(self, observation: dict[str, np.ndarray]) -> np.ndarray:
        # a new array per step (callers keep observations); scalars and vectors are assigned as they are
        out = np.empty(self._obs_dim, dtype=np.float32)
        for key, where, ravel in self._obs_slices:
            out[where] = observation[key].ravel() if ravel else observation[key]
        return out

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        if seed is not None:
            self._random_state().seed(seed)
        self._reset_random_state = self._random_state().get_state()
        time_step = self._env.reset()
        return self._flatten(time_step.observation), {}

    # checkpoints ---------------------------------------------------------------------------
    def get_checkpoint_state(self) -> dict[str, Any]:
        """What a checkpoint taken just after a reset (at an episode boundary) needs of this env.

        The episode's start is a function of the task's random state alone (the physics is reset
        and re-initialised from it), so the random state the last reset started from is enough:
        :meth:`set_checkpoint_state` replays that reset.
        """
        if self._reset_random_state is None:
            raise ValueError("the environment was never reset: there is no episode start to checkpoint")
        return {"reset_random_state": self._reset_random_state}

    def set_checkpoint_state(self, state: dict[str, Any]) -> np.ndarray:
        """Put the env back at the episode start of :meth:`get_checkpoint_state`; return its observation.

        :param state: what :meth:`get_checkpoint_state` returned
        """
        self._random_state().set_state(state["reset_random_state"])
        self._reset_random_state = state["reset_random_state"]
        return self._flatten(self._env.reset().observation)

    def _control(self, action: np.ndarray) -> np.ndarray:
        """The physics control of ``action``: clipped to [-1, 1], then ``mid + a * half_range``.

        When MuJoCo clamps the controls to the bounds itself (:meth:`_physics_clamps_controls`), the
        clip is left to it, and with [-1, 1] bounds the action goes through as it is (MuJoCo copies
        it into float64 ``ctrl``). Otherwise the clip and the rescaling run in place on one new
        float64 array (np.clip and temporaries cost twice as much).
        """
        if self._physics_clamps:
            if self._act_unit_range:
                return action
            scaled = action * self._act_half_range  # float64, as the half range
        else:
            scaled = np.maximum(action, self._act_minus_ones, dtype=np.float64)
            np.minimum(scaled, self._act_ones, out=scaled)
            if self._act_unit_range:
                return scaled
            scaled *= self._act_half_range
        scaled += self._act_mid
        return scaled

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        """Step the physics with ``action`` (in [-1, 1], rescaled to the control bounds).

        :param action: the action
        :return: observation, reward (0 when ``reward_free``), terminated (dm_control's discount 0),
            truncated (the time limit), and ``info`` with the task reward under ``"task_reward"``
        """
        time_step = self._env.step(self._control(action))
        task_reward = float(time_step.reward or 0.0)
        terminated = truncated = False
        if time_step.step_type is _LAST:
            terminated = bool(time_step.discount == 0.0)
            truncated = not terminated
        reward = 0.0 if self.reward_free else task_reward
        return self._flatten(time_step.observation), reward, terminated, truncated, {"task_reward": task_reward}

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            return None
        try:
            return self.physics.render(*self.render_size, camera_id=self.camera_id)
        except Exception as error:  # no usable OpenGL backend
            raise RenderError(
                "MuJoCo could not render: no OpenGL backend is available. Set MUJOCO_GL=egl "
                f"(or glfw with a display) before importing dm_control. Original error: {error!r}"
            ) from error

    def close(self) -> None:
        if not getattr(self, "_closed", False):
            self._closed = True
            self._env.close()
