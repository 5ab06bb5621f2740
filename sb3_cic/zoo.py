"""RL Baselines3 Zoo integration: our algorithms in ``rl_zoo3.ALGOS``, the URLB ids, and the yaml helpers.

Nothing of rl_zoo3 is copied: ``sb3-cic train`` / ``enjoy`` / ``record-video`` call rl_zoo3's own entry
points after :func:`register_algos`, and ``sb3-cic finetune`` is rl_zoo3's ``train`` with a trained agent
(``-i``) where the algorithm's ``load`` is the method's :meth:`~sb3_cic.ddpg.URLBDDPG.load_pretrained`
(:class:`PretrainedLoader`). The protocol runner reads the same yaml files through rl_zoo3's
:class:`~rl_zoo3.exp_manager.ExperimentManager` (:func:`zoo_hyperparams`).

Skill-based methods observe ``[state, skill]``: their yaml entries wrap the env with
:func:`skill_wrapper` (rl-zoo's ``env_wrapper`` key), so that the training, evaluation and ``enjoy``
envs all carry the skill.
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import importlib.resources
import io
from pathlib import Path
from typing import Any, Sequence

import gymnasium as gym
import numpy as np
import yaml
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.type_aliases import GymEnv

from sb3_cic import envs  # noqa: F401  (registers the URLB ids)
from sb3_cic.envs.skill_wrapper import SkillObservationWrapper
from sb3_cic.constants import METHOD_VARIANTS, SMALL_SETTINGS
from sb3_cic.ddpg import URLBDDPG

#: folder of the rl-zoo yaml files (``zoo_configs/<algo>.yml`` of the repository, installed as the package
#: ``sb3_cic.zoo_configs``: found through the package, in a checkout and from a wheel alike)
CONFIG_DIR = Path(str(importlib.resources.files("sb3_cic.zoo_configs")))

#: CPU-sized hyperparameters (``sb3-cic train --small``): :data:`sb3_cic.constants.SMALL_SETTINGS` as rl-zoo overrides
SMALL_HYPERPARAMS: dict[str, Any] = {
    **{key: value for key, value in SMALL_SETTINGS.items() if key != "hidden_dim"},
    "policy_kwargs": f"dict(hidden_dim={SMALL_SETTINGS['hidden_dim']})",
}

#: algorithms that ``--methods all`` of a study leaves out (name them to run them): ``fixed``, the CIC paper's
#: Appendix I baseline (a constant intrinsic reward), not one of URLB's methods
BASELINES_BY_NAME_ONLY: tuple[str, ...] = ("fixed",)


def algorithms() -> dict[str, type[URLBDDPG]]:
    """The algorithms of this package by rl-zoo name: ``ddpg``/``urlbddpg`` (:class:`URLBDDPG`), every
    :class:`URLBDDPG` subclass of ``sb3_cic.methods.__all__``, lower-cased (``cic``, ``icm``...), and the
    variants (:data:`~sb3_cic.constants.METHOD_VARIANTS`: ``cic_code``, CIC as the reference code runs it)."""
    import sb3_cic.methods as methods

    algos: dict[str, type[URLBDDPG]] = {"ddpg": URLBDDPG, "urlbddpg": URLBDDPG}
    for name in methods.__all__:
        cls = getattr(methods, name)
        if isinstance(cls, type) and issubclass(cls, URLBDDPG):
            algos[name.lower()] = cls
    algos.update({name: algos[method] for name, method in METHOD_VARIANTS.items()})
    return algos


def get_algo(name: str) -> type[URLBDDPG]:
    """The algorithm class of an rl-zoo name (case-insensitive).

    :param name: ``cic``, ``ddpg``, ``icm``...
    """
    algos = algorithms()
    if name.lower() not in algos:
        raise ValueError(f"unknown algorithm {name!r}; known: {sorted(algos)}")
    return algos[name.lower()]


def has_reward_module(cls: type[URLBDDPG]) -> bool:
    """Whether ``cls`` is an unsupervised method (it defines an intrinsic reward), i.e. is pre-trained."""
    return cls.reward_module_class is not None


def register_algos() -> dict[str, Any]:
    """Put our algorithms into ``rl_zoo3.ALGOS`` (in this process; ``ddpg`` becomes :class:`URLBDDPG`,
    replacing SB3's DDPG) and return that dict."""
    from rl_zoo3 import ALGOS

    ALGOS.update(algorithms())
    return ALGOS


class PretrainedLoader:
    """The algorithm rl_zoo3's ``train`` sees in ``sb3-cic finetune``.

    rl-zoo continues a trained agent (``-i model.zip``) with ``ALGOS[algo].load(path, env=..., **hyperparams)``;
    here that ``load`` is the method's :meth:`~sb3_cic.ddpg.URLBDDPG.load_pretrained` (actor, critic trunk
    and reward module kept, extrinsic reward, empty buffer, step 0), and the yaml's hyperparameters of the
    task id (``batch_size``, ``learning_starts``...) override the saved ones.

    :param cls: the method
    """

    def __init__(self, cls: type[URLBDDPG]) -> None:
        self.cls = cls
        self.__name__ = cls.__name__

    def __call__(self, *args: Any, **kwargs: Any) -> URLBDDPG:
        raise RuntimeError("fine-tuning starts from a pre-trained model: pass it with -i / --trained-agent")

    def load(self, path: str, env: GymEnv | None = None, **kwargs: Any) -> URLBDDPG:
        """:meth:`~sb3_cic.ddpg.URLBDDPG.load_pretrained` with rl-zoo's arguments."""
        if env is None:
            raise ValueError("fine-tuning needs the task environment")
        return self.cls.load_pretrained(path, env, **kwargs)


# skills ------------------------------------------------------------------------------------------
def skill_prior_of(algo: str, **algo_kwargs: Any) -> tuple[Any, int | None]:
    """The skill prior and resampling period an algorithm builds from its constructor arguments.

    The algorithm is constructed without env and without networks (``_init_setup_model=False``),
    which is cheap, and its ``skill_prior`` read.

    :param algo: rl-zoo name of the algorithm
    :param algo_kwargs: constructor arguments that define the prior (``skill_dim``, ``sf_dim``...)
    :return: ``(prior or None, skill_resample_every)``
    """
    probe = get_algo(algo)("MlpPolicy", None, _init_setup_model=False, **algo_kwargs)  # type: ignore[arg-type]
    return probe.skill_prior, probe.skill_resample_every


def skill_wrapper(
    env: gym.Env, algo: str, skill: Sequence[float] | None = None, resample_every: int | None = -1, **algo_kwargs: Any
) -> gym.Env:
    """rl-zoo ``env_wrapper`` of the skill-based methods: :class:`~sb3_cic.envs.SkillObservationWrapper` with the
    prior of ``algo``.

    In a yaml entry::

        env_wrapper:
          - sb3_cic.zoo.skill_wrapper: {algo: cic, skill_dim: 64}

    The prior is built as the algorithm builds it (:func:`skill_prior_of`), so the prior arguments
    (``skill_dim``...) must agree with the algorithm's; a mismatch in size is a ``ValueError`` when the
    model is created. Algorithms without skills get the env back unchanged.

    :param env: the environment
    :param algo: rl-zoo name of the algorithm
    :param skill: a skill to fix (``sb3-cic finetune`` records the chosen one here for ``enjoy``)
    :param resample_every: resampling period (-1: the algorithm's)
    :param algo_kwargs: the algorithm's prior arguments
    """
    prior, period = skill_prior_of(algo, **algo_kwargs)
    if prior is None:
        return env
    wrapped = SkillObservationWrapper(env, prior, resample_every=period if resample_every == -1 else resample_every)
    if skill is not None:
        wrapped.set_skill(np.asarray(skill, dtype=np.float32), fixed=True)
    return wrapped


# yaml helpers ------------------------------------------------------------------------------------
def default_config(algo: str) -> Path:
    """``zoo_configs/<algo>.yml`` (``urlbddpg`` uses ``ddpg.yml``)."""
    name = "ddpg" if algo.lower() == "urlbddpg" else algo.lower()
    for folder in (CONFIG_DIR, Path.cwd() / "zoo_configs"):
        if (folder / f"{name}.yml").is_file():
            return folder / f"{name}.yml"
    raise FileNotFoundError(f"no rl-zoo config {name}.yml in {CONFIG_DIR}")


def read_entry(config: str | Path, env_id: str) -> dict[str, Any]:
    """The raw yaml entry of ``env_id`` (or ``default``) in an rl-zoo config file, ``{}`` if none."""
    with open(config) as file:
        table = yaml.safe_load(file) or {}
    entry = table.get(env_id, table.get("default", {}))
    return copy.deepcopy(entry) if isinstance(entry, dict) else {}


def _callback_items(spec: Any) -> list[tuple[str, dict[str, Any]]]:
    items = spec if isinstance(spec, list) else [] if spec is None else [spec]
    out = []
    for item in items:
        if isinstance(item, dict):
            ((name, kwargs),) = item.items()
            out.append((name, dict(kwargs or {})))
        else:
            out.append((item, {}))
    return out


def adjust_callbacks(
    spec: Any,
    learning_starts: int | None = None,
    eval_freq: int | None = None,
    eval_episodes: int | None = None,
    drop_eval: bool = False,
) -> list[dict[str, dict[str, Any]]]:
    """Rewrite an rl-zoo ``callback`` spec: the grid sweep lasts ``learning_starts`` steps, evaluation settings.

    :param spec: the yaml ``callback`` value (a name, ``{name: kwargs}`` or a list of them)
    :param learning_starts: set ``sweep_steps`` of :class:`~sb3_cic.callbacks.SkillGridSweepCallback` to it
    :param eval_freq: set ``eval_freq`` of :class:`~sb3_cic.callbacks.URLBEvalCallback`
    :param eval_episodes: set ``n_eval_episodes`` of :class:`~sb3_cic.callbacks.URLBEvalCallback`
    :param drop_eval: remove :class:`~sb3_cic.callbacks.URLBEvalCallback` entries
    :return: the spec as a list of ``{name: kwargs}``
    """
    out = []
    for name, kwargs in _callback_items(spec):
        short = name.rsplit(".", 1)[-1]
        if short == "SkillGridSweepCallback" and learning_starts is not None:
            kwargs["sweep_steps"] = int(learning_starts)
        if short == "URLBEvalCallback":
            if drop_eval:
                continue
            if eval_freq is not None:
                kwargs["eval_freq"] = int(eval_freq)
            if eval_episodes is not None:
                kwargs["n_eval_episodes"] = int(eval_episodes)
        out.append({name: kwargs})
    return out


def zoo_overrides(
    config: str | Path,
    env_id: str,
    overrides: dict[str, Any] | None = None,
    eval_freq: int | None = None,
    eval_episodes: int | None = None,
    drop_eval: bool = False,
) -> dict[str, Any]:
    """Hyperparameter overrides for rl-zoo, with the yaml's ``callback`` list kept consistent.

    Returns ``overrides`` plus, unless it sets ``callback`` itself, the entry's callback list with the
    sweep length set to the effective ``learning_starts`` and the evaluation settings applied.

    :param config: rl-zoo yaml file
    :param env_id: environment id (the yaml key)
    :param overrides: hyperparameters to override (``--hyperparams``)
    :param eval_freq: evaluation period of :class:`~sb3_cic.callbacks.URLBEvalCallback`
    :param eval_episodes: evaluation episodes of :class:`~sb3_cic.callbacks.URLBEvalCallback`
    :param drop_eval: remove :class:`~sb3_cic.callbacks.URLBEvalCallback` entries
    """
    result = dict(overrides or {})
    entry = read_entry(config, env_id)
    if "callback" not in result and entry.get("callback"):
        learning_starts = result.get("learning_starts", entry.get("learning_starts"))
        callbacks = adjust_callbacks(entry["callback"], learning_starts, eval_freq, eval_episodes, drop_eval)
        if callbacks != adjust_callbacks(entry["callback"]):
            result["callback"] = callbacks
    return result


def zoo_hyperparams(
    algo: str,
    env_id: str,
    config: str | Path | None = None,
    overrides: dict[str, Any] | None = None,
    verbose: int = 0,
) -> tuple[dict[str, Any], list[BaseCallback], int, dict[str, Any]]:
    """Read and pre-process the hyperparameters of ``env_id`` with rl_zoo3's ExperimentManager.

    Uses ``ExperimentManager.read_hyperparameters`` (yaml lookup, overrides) and its
    ``_preprocess_hyperparams`` (schedules, ``policy_kwargs`` strings, ``callback`` instantiation),
    so a yaml file means the same to ``sb3-cic train`` and to the protocol runner.

    :param algo: rl-zoo name of the algorithm
    :param env_id: environment id (the yaml key)
    :param config: yaml file (default: ``zoo_configs/<algo>.yml``)
    :param overrides: hyperparameters to override
    :param verbose: print rl-zoo's messages
    :return: ``(constructor kwargs, callbacks, n_timesteps, saved hyperparameters)``; ``env_wrapper``
        is dropped (the algorithms wrap a plain env themselves)
    """
    from rl_zoo3.exp_manager import ExperimentManager

    manager = ExperimentManager(
        argparse.Namespace(),
        algo,
        env_id,
        log_folder="",
        hyperparams=dict(overrides) if overrides else None,
        config=str(config or default_config(algo)),
        verbose=verbose,
    )
    out = contextlib.nullcontext() if verbose else contextlib.redirect_stdout(io.StringIO())
    with out:
        raw, saved = manager.read_hyperparameters()
        hyperparams, _, callbacks, _ = manager._preprocess_hyperparams(raw)
    return hyperparams, callbacks, int(manager.n_timesteps), dict(saved)


def parse_hyperparams(items: Sequence[str]) -> dict[str, Any]:
    """Parse ``key:value`` strings as rl-zoo's ``--hyperparams`` does (the value is evaluated as Python)."""
    from rl_zoo3.utils import StoreDict

    namespace = argparse.Namespace()
    StoreDict(option_strings=[], dest="hyperparams")(argparse.ArgumentParser(), namespace, list(items))
    return namespace.hyperparams


def format_hyperparams(hyperparams: dict[str, Any]) -> list[str]:
    """Inverse of :func:`parse_hyperparams` (``key:repr(value)``)."""
    return [f"{key}:{value!r}" for key, value in hyperparams.items()]
