"""What a run checkpoint saves of the library's objects beyond SB3's ``save``: the callbacks' state
(:class:`ResumableCallback`) and each env layer's state (:func:`env_state`). The checkpoint itself is the
study's (:mod:`sb3_cic.study.checkpoint`)."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
from stable_baselines3.common.callbacks import BaseCallback


class ResumableCallback(BaseCallback):
    """A callback whose state a checkpoint saves (its ``n_calls`` and :meth:`get_checkpoint_state`).

    After :meth:`set_checkpoint_state` the callback is :attr:`resumed`: its ``_on_training_start`` must
    continue, not start over (no step-0 evaluation, no new skill sweep...).

    :param verbose: verbosity
    """

    #: set when the state came from a checkpoint
    resumed: bool = False

    def get_checkpoint_state(self) -> dict[str, Any]:
        """The callback's state beyond ``n_calls`` (none by default)."""
        return {}

    def set_checkpoint_state(self, state: dict[str, Any]) -> None:
        """Restore what :meth:`get_checkpoint_state` returned.

        :param state: the saved state
        """


def has_method(obj: Any, name: str) -> bool:
    """Whether ``obj``'s class defines a method ``name`` (gymnasium wrappers do not forward attributes).

    :param obj: an env, a wrapper or a VecEnv wrapper
    :param name: the method's name
    """
    return callable(getattr(type(obj), name, None))


def env_layers(env: gym.Env) -> list[gym.Env]:
    """``env`` and every env it wraps, outermost first.

    :param env: a gymnasium env and its wrappers
    """
    layers = [env]
    while isinstance(env, gym.Wrapper):
        env = env.env
        layers.append(env)
    return layers


def env_state(env: gym.Env) -> list[Any]:
    """The checkpoint state of each layer of ``env`` (its ``get_checkpoint_state``, None for a layer without).

    Taken just after a reset: :class:`~sb3_cic.envs.dmc.DMCEnv` saves the random state its episode started from.

    :param env: a gymnasium env and its wrappers
    """
    return [layer.get_checkpoint_state() if has_method(layer, "get_checkpoint_state") else None for layer in env_layers(env)]


def set_env_state(env: gym.Env, state: list[Any]) -> list[Any]:
    """Reset ``env`` (the wrappers' bookkeeping), then restore each layer's state; return what the layers returned.

    :param env: an env built as the one :func:`env_state` read
    :param state: what :func:`env_state` returned
    """
    layers = env_layers(env)
    if len(layers) != len(state):
        raise ValueError(f"the env has {len(layers)} layers, the checkpoint {len(state)}: not the same env")
    env.reset()
    return [layer.set_checkpoint_state(saved) for layer, saved in zip(layers, state) if saved is not None]
