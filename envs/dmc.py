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
        # physics bounds of exactly [-1, 1] (walker, quadruped, point mass): the rescaling is the identity
        self._act_unit_range = bool(np.all(self._act_low == -1.0) and np.all(self._act_high == 1.0))
        # array operands: cheaper in ufuncs than Python scalars
        self._act_ones = np.ones(act_spec.shape, dtype=np.float64)
        self._act_minus_ones = -self._act_ones

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
        time_step = self._env.reset()
        return self._flatten(time_step.observation), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        # clip to [-1, 1] in float64 and rescale to the physics bounds (``mid + a * half_range``; nothing
        # to do for [-1, 1] bounds), in place on one new array: np.clip and temporaries cost twice as much
        scaled = np.maximum(action, self._act_minus_ones, dtype=np.float64)
        np.minimum(scaled, self._act_ones, out=scaled)
        if not self._act_unit_range:
            scaled *= self._act_half_range
            scaled += self._act_mid
        time_step = self._env.step(scaled)
        task_reward = float(time_step.reward or 0.0)
        last = time_step.step_type == dm_env.StepType.LAST
        terminated = bool(last and time_step.discount == 0.0)
        truncated = bool(last and not terminated)
        reward = 0.0 if self.reward_free else task_reward
        return self._flatten(time_step.observation), reward, terminated, truncated, {"task_reward": task_reward}

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            return None
        try:
            return self.physics.render(*self.render_size, camera_id=self.camera_id)
        except Exception as error:  # no usable OpenGL backend
            raise RuntimeError(
                "MuJoCo could not render: no OpenGL backend is available. Set MUJOCO_GL=egl "
                f"(or glfw with a display) before importing dm_control. Original error: {error!r}"
            ) from error

    def close(self) -> None:
        if not getattr(self, "_closed", False):
            self._closed = True
            self._env.close()
