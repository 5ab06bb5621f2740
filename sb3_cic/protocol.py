"""The URLB protocol: pre-train a method once on a domain, fine-tune it on the domain's tasks over seeds.

One study lives in one folder::

    <study>/pretrain/<method>_<domain>/snapshot_<steps>.zip, result.json
    <study>/finetune/<label>/<task>/seed_<k>/eval.csv, result.json
    <study>/tensorboard/...

``<label>`` is the method name when fine-tuning from the final snapshot, ``<method>@<steps>`` from
another snapshot; DDPG ("from scratch") has no pre-training. A run whose ``result.json`` exists is
not run again. Hyperparameters come from ``zoo_configs/<method>.yml`` (read with rl_zoo3, see
:func:`sb3_cic.zoo.zoo_hyperparams`), with the small-scale options of :class:`Settings` on top.
Evaluation: :class:`~sb3_cic.callbacks.URLBEvalCallback` (deterministic episodes at step 0 and every
``eval_freq`` steps, plus one at the end if the schedule misses it); the final return is that of
the last evaluation, the normalised score ``return / expert`` (:data:`sb3_cic.constants.EXPERT_SCORES`).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Sequence

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.utils import set_random_seed

from envs.tasks import DOMAIN_TASKS
from sb3_cic import zoo
from sb3_cic.callbacks import SkillGridSweepCallback, SkillSelectionCallback, URLBEvalCallback
from sb3_cic.constants import EXPERT_SCORES

#: URLB's pre-training snapshots
DEFAULT_SNAPSHOTS: tuple[int, ...] = (100_000, 500_000, 1_000_000, 2_000_000)


@dataclass
class Settings:
    """Scale and evaluation settings of a protocol run (None: the yaml's value).

    :param hidden_dim: hidden width of actor, critic (and the reward networks that follow it)
    :param batch_size: minibatch size
    :param learning_starts: random steps before learning; the fine-tuning skill sweep lasts as long
    :param buffer_size: replay capacity
    :param pretrain_steps: pre-training steps (yaml: 2M)
    :param finetune_steps: fine-tuning steps (yaml: 100k)
    :param eval_freq: steps between evaluations (10,000)
    :param eval_episodes: episodes per evaluation (10)
    :param snapshots: pre-training steps at which a snapshot is saved (the final step always is)
    :param device: torch device
    :param num_threads: torch threads (None: torch's default)
    :param progress_bar: show SB3's progress bar
    :param verbose: verbosity of the algorithms
    """

    hidden_dim: int | None = None
    batch_size: int | None = None
    learning_starts: int | None = None
    buffer_size: int | None = None
    pretrain_steps: int | None = None
    finetune_steps: int | None = None
    eval_freq: int = 10_000
    eval_episodes: int = 10
    snapshots: tuple[int, ...] = DEFAULT_SNAPSHOTS
    device: str = "auto"
    num_threads: int | None = None
    progress_bar: bool = False
    verbose: int = 0

    def overrides(self, finetune: bool) -> dict[str, Any]:
        """Hyperparameter overrides for rl-zoo's reading of the yaml."""
        out: dict[str, Any] = {}
        for key in ("batch_size", "learning_starts", "buffer_size"):
            if getattr(self, key) is not None:
                out[key] = getattr(self, key)
        if self.hidden_dim is not None and not finetune:  # a fine-tuned model keeps its saved width
            out["policy_kwargs"] = {"hidden_dim": self.hidden_dim}
        return out


@dataclass
class FinetuneResult:
    """What ``result.json`` of a fine-tuning run holds."""

    method: str
    label: str
    domain: str
    task: str
    env_id: str
    seed: int
    from_scratch: bool
    snapshot_steps: int | None
    finetune_steps: int
    final_return: float
    final_normalized_score: float | None
    expert_score: float | None
    n_evaluations: int
    finetune_skill: list[float] | None
    #: the grid sweep's (candidate c, window return) pairs, when the skill was chosen by a sweep
    skill_sweep: list[list[float]] | None
    wall_time_s: dict[str, float | None] = field(default_factory=dict)
    hyperparams: dict[str, str] = field(default_factory=dict)


def task_name(domain: str, task: str) -> str:
    """URLB task name (``walker_flip``) of a domain and task."""
    return task if task.startswith(f"{domain}_") else f"{domain}_{task}"


def task_env_id(domain: str, task: str) -> str:
    """Gymnasium id of a task (``URLB/walker-flip-v0``)."""
    short = task[len(domain) + 1 :] if task.startswith(f"{domain}_") else task
    if short not in DOMAIN_TASKS[domain]:
        raise ValueError(f"unknown task {task!r} of {domain}; known: {DOMAIN_TASKS[domain]}")
    return f"URLB/{domain}-{short}-v0"


def _write_json(path: Path, data: dict[str, Any]) -> None:
    """Write atomically (``result.json`` marks a finished run)."""
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(data, indent=2, default=float))
    os.replace(tmp, path)


def _describe(hyperparams: dict[str, Any]) -> dict[str, str]:
    return {key: str(value) for key, value in sorted(hyperparams.items())}


def _set_threads(settings: Settings) -> None:
    if settings.num_threads:
        th.set_num_threads(settings.num_threads)


class SnapshotCallback(BaseCallback):
    """Save the model as ``snapshot_<steps>.zip`` when training reaches each of ``steps``.

    :param save_path: folder of the snapshots
    :param steps: the steps to save at
    :param verbose: verbosity
    """

    def __init__(self, save_path: str | Path, steps: Sequence[int], verbose: int = 0) -> None:
        super().__init__(verbose)
        self.save_path = Path(save_path)
        self.pending = sorted(set(int(s) for s in steps))
        self.saved: dict[int, str] = {}

    def _on_step(self) -> bool:
        while self.pending and self.num_timesteps >= self.pending[0]:
            step = self.pending.pop(0)
            path = self.save_path / f"snapshot_{step}.zip"
            self.model.save(path)
            self.saved[step] = path.name
            if self.verbose:
                print(f"Saved snapshot {path}")
        return True


def pretrain(
    study: str | Path,
    method: str,
    domain: str,
    settings: Settings | None = None,
    seed: int = 0,
    config: str | Path | None = None,
) -> dict[str, Any]:
    """Pre-train ``method`` on ``URLB/<domain>-v0`` once (skipped if its ``result.json`` exists).

    :param study: study folder
    :param method: rl-zoo name of an unsupervised method (``cic``...)
    :param domain: URLB domain
    :param settings: scale settings
    :param seed: pre-training seed
    :param config: yaml file (default ``zoo_configs/<method>.yml``)
    :return: the pre-training ``result.json`` content
    """
    settings = settings or Settings()
    run_dir = Path(study) / "pretrain" / f"{method}_{domain}"
    result_file = run_dir / "result.json"
    if result_file.exists():
        return json.loads(result_file.read_text())
    run_dir.mkdir(parents=True, exist_ok=True)
    _set_threads(settings)
    env_id = f"URLB/{domain}-v0"
    hyperparams, _, n_timesteps, _ = zoo.zoo_hyperparams(method, env_id, config, settings.overrides(finetune=False))
    hyperparams.pop("env_wrapper", None)
    steps = int(settings.pretrain_steps or n_timesteps)
    set_random_seed(seed)
    model = zoo.get_algo(method)(
        env=env_id,
        seed=seed,
        device=settings.device,
        verbose=settings.verbose,
        tensorboard_log=str(Path(study) / "tensorboard"),
        **hyperparams,
    )
    snapshots = SnapshotCallback(run_dir, [s for s in settings.snapshots if s < steps] + [steps], settings.verbose)
    start = time.perf_counter()
    model.learn(steps, callback=snapshots, tb_log_name=f"pretrain_{method}_{domain}", progress_bar=settings.progress_bar)
    wall = time.perf_counter() - start
    result = {
        "method": method,
        "domain": domain,
        "env_id": env_id,
        "seed": seed,
        "steps": steps,
        "snapshots": snapshots.saved,
        "wall_time_s": {"pretrain": wall},
        "hyperparams": _describe(hyperparams),
    }
    _write_json(result_file, result)
    return result


def finetune(
    study: str | Path,
    method: str,
    domain: str,
    task: str,
    seed: int,
    settings: Settings | None = None,
    snapshot: int | None = None,
    from_scratch: bool | None = None,
    config: str | Path | None = None,
) -> dict[str, Any]:
    """One fine-tuning run (or a from-scratch run for DDPG), skipped if its ``result.json`` exists.

    :param study: study folder (the pre-training must be done unless ``from_scratch``)
    :param method: rl-zoo name of the method
    :param domain: URLB domain
    :param task: task (``flip`` or ``walker_flip``)
    :param seed: seed of the run
    :param settings: scale and evaluation settings
    :param snapshot: pre-training step of the snapshot to start from (None: the final one)
    :param from_scratch: no pre-training (default: True for ``ddpg``)
    :param config: yaml file (default ``zoo_configs/<method>.yml``)
    :return: the run's ``result.json`` content
    """
    settings = settings or Settings()
    cls = zoo.get_algo(method)
    from_scratch = (not zoo.has_reward_module(cls)) if from_scratch is None else from_scratch
    name, env_id = task_name(domain, task), task_env_id(domain, task)
    pre: dict[str, Any] | None = None
    label = method
    if not from_scratch:
        pre_file = Path(study) / "pretrain" / f"{method}_{domain}" / "result.json"
        if not pre_file.exists():
            raise FileNotFoundError(f"pre-train {method} on {domain} first ({pre_file} is missing)")
        pre = json.loads(pre_file.read_text())
        snapshot = int(pre["steps"]) if snapshot is None else int(snapshot)
        if str(snapshot) not in {str(k) for k in pre["snapshots"]}:
            raise ValueError(f"no snapshot at {snapshot} steps; saved: {sorted(int(k) for k in pre['snapshots'])}")
        if snapshot != int(pre["steps"]):
            label = f"{method}@{snapshot}"
    run_dir = Path(study) / "finetune" / label / name / f"seed_{seed}"
    result_file = run_dir / "result.json"
    if result_file.exists():
        return json.loads(result_file.read_text())
    run_dir.mkdir(parents=True, exist_ok=True)
    _set_threads(settings)

    overrides = settings.overrides(finetune=not from_scratch)
    config = config or zoo.default_config(method)
    # the yaml's callbacks minus its URLBEvalCallback (ours is below), the sweep as long as learning_starts
    overrides = zoo.zoo_overrides(config, env_id, overrides, drop_eval=True)
    hyperparams, callbacks, n_timesteps, _ = zoo.zoo_hyperparams(method, env_id, config, overrides)
    hyperparams.pop("env_wrapper", None)
    steps = int(settings.finetune_steps or n_timesteps)
    common = {"seed": seed, "device": settings.device, "verbose": settings.verbose}
    common["tensorboard_log"] = str(Path(study) / "tensorboard")
    set_random_seed(seed)
    if from_scratch:
        model = cls(env=env_id, **common, **hyperparams)
    else:
        assert pre is not None
        kwargs = {k: v for k, v in hyperparams.items() if k not in ("policy", "policy_kwargs")}
        snapshot_path = Path(study) / "pretrain" / f"{method}_{domain}" / f"snapshot_{snapshot}.zip"
        model = cls.load_pretrained(snapshot_path, env_id, **common, **kwargs)
    if model.skill_prior is not None and not any(isinstance(c, SkillSelectionCallback) for c in callbacks):
        selection = model.make_finetune_callback()  # what learn() would add; kept here to record the sweep
        callbacks = callbacks if selection is None else [selection, *callbacks]
    for callback in callbacks:  # the sweep lasts learning_starts steps (also when the yaml sets neither)
        if isinstance(callback, SkillGridSweepCallback):
            callback.sweep_steps = model.learning_starts

    eval_env = Monitor(gym.make(env_id))
    eval_env.reset(seed=10_000 + seed)
    expert = EXPERT_SCORES.get(name)
    evaluation = URLBEvalCallback(
        eval_env,
        task=name if expert else None,
        n_eval_episodes=settings.eval_episodes,
        eval_freq=settings.eval_freq,
        verbose=0,
    )
    start = time.perf_counter()
    model.learn(
        steps,
        callback=[*callbacks, evaluation],
        tb_log_name=f"finetune_{label}_{name}_seed{seed}",
        progress_bar=settings.progress_bar,
    )
    if not evaluation.history or evaluation.history[-1][0] != model.num_timesteps:
        evaluation._evaluate()  # the final evaluation
    wall = time.perf_counter() - start
    eval_env.close()

    with open(run_dir / "eval.csv", "w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(["timestep", "mean_return", "normalized_score"])
        for step, ret, score in evaluation.history:
            writer.writerow([step, ret, "" if math.isnan(score) else score])
    final_step, final_return, final_score = evaluation.history[-1]
    skill = getattr(model, "finetune_skill", None)
    sweep = next((c.results for c in callbacks if isinstance(c, SkillGridSweepCallback)), None)
    result = FinetuneResult(
        method=method,
        label=label,
        domain=domain,
        task=name,
        env_id=env_id,
        seed=seed,
        from_scratch=from_scratch,
        snapshot_steps=snapshot,
        finetune_steps=steps,
        final_return=float(final_return),
        final_normalized_score=None if math.isnan(final_score) else float(final_score),
        expert_score=expert,
        n_evaluations=len(evaluation.history),
        finetune_skill=None if skill is None else [float(v) for v in np.asarray(skill)],
        skill_sweep=None if sweep is None else [[float(np.mean(z)), float(ret)] for z, ret in sweep],
        wall_time_s={"finetune": wall, "pretrain": None if pre is None else pre["wall_time_s"]["pretrain"]},
        hyperparams=_describe({**hyperparams, "policy_kwargs": model.policy_kwargs}),
    )
    _write_json(result_file, asdict(result))
    return asdict(result)


def run_protocol(
    study: str | Path,
    method: str,
    domain: str,
    tasks: Sequence[str] | None = None,
    seeds: Sequence[int] = tuple(range(10)),
    settings: Settings | None = None,
    snapshot: int | None = None,
    from_scratch: bool | None = None,
    pretrain_seed: int = 0,
    config: str | Path | None = None,
) -> list[dict[str, Any]]:
    """Run the URLB protocol for one method and domain: pre-train once, fine-tune on tasks x seeds.

    Finished runs (``result.json`` present) are not run again, so an interrupted study resumes.

    :param study: study folder
    :param method: rl-zoo name of the method (``ddpg`` trains from scratch)
    :param domain: URLB domain
    :param tasks: tasks (``flip`` or ``walker_flip``; default: all of the domain)
    :param seeds: fine-tuning seeds
    :param settings: scale and evaluation settings
    :param snapshot: snapshot to fine-tune from (default: the final one)
    :param from_scratch: no pre-training (default: True for ``ddpg``)
    :param pretrain_seed: seed of the pre-training
    :param config: yaml file (default ``zoo_configs/<method>.yml``)
    :return: the fine-tuning results
    """
    settings = settings or Settings()
    method = method.lower()
    cls = zoo.get_algo(method)
    from_scratch = (not zoo.has_reward_module(cls)) if from_scratch is None else from_scratch
    if not from_scratch:
        pretrain(study, method, domain, settings, seed=pretrain_seed, config=config)
    results = []
    for task in tasks or DOMAIN_TASKS[domain]:
        for seed in seeds:
            results.append(finetune(study, method, domain, task, seed, settings, snapshot, from_scratch, config))
    return results


def build_parser() -> argparse.ArgumentParser:
    """Arguments of ``sb3-cic protocol``."""
    parser = argparse.ArgumentParser(
        prog="sb3-cic protocol",
        description="URLB protocol: pre-train once on URLB/<domain>-v0, fine-tune on the domain's tasks over seeds.",
    )
    parser.add_argument("--method", "--algo", default="cic", help="cic, icm, ..., or ddpg (from scratch)")
    parser.add_argument("--domain", default="walker", choices=sorted(DOMAIN_TASKS))
    parser.add_argument("--study", default="runs/urlb", help="study folder")
    parser.add_argument("--tasks", nargs="+", default=None, help="tasks (default: all of the domain)")
    parser.add_argument("--seeds", nargs="+", type=int, default=list(range(10)))
    parser.add_argument("--pretrain-seed", type=int, default=0)
    parser.add_argument("--snapshot", type=int, default=None, help="fine-tune from this snapshot (default: final)")
    parser.add_argument("--snapshots", nargs="+", type=int, default=list(DEFAULT_SNAPSHOTS))
    parser.add_argument("--from-scratch", action="store_true", default=None, help="no pre-training (default for ddpg)")
    parser.add_argument("--conf-file", default=None, help="yaml (default zoo_configs/<method>.yml)")
    parser.add_argument("--small", action="store_true", help="hidden 32, batch 32, learning_starts 500, buffer 1e5")
    parser.add_argument("--hidden-dim", type=int, default=None)
    parser.add_argument("--batch-size", type=int, default=None)
    parser.add_argument("--learning-starts", type=int, default=None, help="also the fine-tuning sweep length")
    parser.add_argument("--buffer-size", type=int, default=None)
    parser.add_argument("--pretrain-steps", type=int, default=None, help="default: the yaml's (2M)")
    parser.add_argument("--finetune-steps", type=int, default=None, help="default: the yaml's (100k)")
    parser.add_argument("--eval-freq", type=int, default=10_000)
    parser.add_argument("--eval-episodes", type=int, default=10)
    parser.add_argument("--device", default="auto")
    parser.add_argument("--num-threads", type=int, default=None)
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--verbose", type=int, default=0)
    return parser


def main(argv: Sequence[str] | None = None) -> list[dict[str, Any]]:
    """``sb3-cic protocol``."""
    args = build_parser().parse_args(argv)
    small = {"hidden_dim": 32, "batch_size": 32, "learning_starts": 500, "buffer_size": 100_000} if args.small else {}
    settings = Settings(
        hidden_dim=args.hidden_dim or small.get("hidden_dim"),
        batch_size=args.batch_size or small.get("batch_size"),
        learning_starts=args.learning_starts or small.get("learning_starts"),
        buffer_size=args.buffer_size or small.get("buffer_size"),
        pretrain_steps=args.pretrain_steps,
        finetune_steps=args.finetune_steps,
        eval_freq=args.eval_freq,
        eval_episodes=args.eval_episodes,
        snapshots=tuple(args.snapshots),
        device=args.device,
        num_threads=args.num_threads,
        progress_bar=not args.no_progress,
        verbose=args.verbose,
    )
    results = run_protocol(
        args.study,
        args.method,
        args.domain,
        tasks=args.tasks,
        seeds=args.seeds,
        settings=settings,
        snapshot=args.snapshot,
        from_scratch=args.from_scratch,
        pretrain_seed=args.pretrain_seed,
        config=args.conf_file,
    )
    print(f"{len(results)} fine-tuning runs in {Path(args.study) / 'finetune'}; report: sb3-cic report {args.study}")
    return results
