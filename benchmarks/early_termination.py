"""The CIC paper's Appendix I (Figure 3): early termination leaks the extrinsic signal (Gym against DMC hopper).

Gym's locomotion episodes end when the agent falls, so a reward-free agent that prolongs its episodes learns to
balance; DMC's episodes have a fixed length (1,000 steps), so balance brings no intrinsic gain there. The appendix
pre-trains DIAYN, ICM and a *Fixed* baseline (an intrinsic reward of 1 per step: :class:`sb3_cic.Fixed`) on
hopper in both, reward-free, and records the extrinsic reward. This script does that:

* ``gym``: Gymnasium's ``Hopper-v5`` (terminates when unhealthy, time limit 1,000 steps; its reward: healthy 1
  + forward velocity - control cost), wrapped with :class:`sb3_cic.envs.RewardFree` (reward 0, the env's reward in
  ``info["task_reward"]``) for pre-training; the plain ``Hopper-v5`` for evaluation;
* ``dmc``: ``URLB/hopper-v0`` (dm_control's hopper hop through this project's adapter, reward 0, the hop reward
  in ``info["task_reward"]``, 1,000 steps, never terminated) for pre-training; ``URLB/hopper-hop-v0`` for
  evaluation.

Each (env, method, seed) run pre-trains for ``--steps`` env steps at the CPU size (hidden 256, batch 256;
everything else URLB's: lr 1e-4, 4,000 random steps, one update per 2 steps, 3-step returns; replay as large as
the run). The extrinsic reward is never learnt from: the pre-training env returns 0 (and the methods relabel every
batch with their intrinsic reward anyway). Recorded, by :class:`ExtrinsicRecorder`:

* the extrinsic return and length of every pre-training episode (with exploration noise, skills as sampled);
* every ``--eval-freq`` steps and at step 0, ``--eval-episodes`` deterministic episodes (actor mean) on the
  evaluation env; a skill-based method (DIAYN) runs episode j with skill j of a fixed list drawn from its prior
  with the run's seed, kept for the whole episode;
* wall-clock times: the random warm-up, the training steps after it, the evaluations.

Outputs under ``--out``: per run ``<env>_<method>_seed<k>.json`` (settings, timings, both records),
``..._episodes.csv`` and ``..._evals.csv`` (a run whose JSON exists with the same settings is kept, not run
again: a killed call resumes where it stopped); ``early_termination.png`` (Figure 3: per env, per method, the
training episodes' extrinsic return and length and the evaluations' return over pre-training, mean over seeds with
the seeds' range shaded); a printed table. ``--project-steps`` prints the cost of the whole experiment (3 methods
x 2 envs x the seeds) at that budget, from the rates measured in this invocation's runs.

    MUJOCO_GL=disable OMP_NUM_THREADS=1 python benchmarks/early_termination.py --steps 200000 --seeds 0 1 2 \\
        --out docs/results/early_termination
    python benchmarks/early_termination.py --steps 6000 --seeds 0 --eval-freq 2000 --eval-episodes 1 \\
        --out /tmp/early_termination_smoke --project-steps 200000   # time a short run of each
    python benchmarks/early_termination.py --plot-only --out docs/results/early_termination   # redraw the figure
"""

from __future__ import annotations

import argparse
import csv
import json
import time
import warnings
from pathlib import Path
from typing import Any

import gymnasium as gym
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch as th  # noqa: E402
from stable_baselines3.common.callbacks import BaseCallback  # noqa: E402

import sb3_cic  # noqa: E402,F401  (registers the ids)
from sb3_cic.envs import RewardFree  # noqa: E402
from sb3_cic.envs.skill_wrapper import SkillObservationWrapper  # noqa: E402
from sb3_cic import DIAYN, ICM, URLBDDPG, Fixed  # noqa: E402
from sb3_cic.common.env_util import find_skill_wrapper  # noqa: E402

METHODS: dict[str, type[URLBDDPG]] = {"diayn": DIAYN, "icm": ICM, "fixed": Fixed}
#: ``env: (pre-training env factory, evaluation env id, label)``
ENVS: dict[str, tuple[Any, str, str]] = {
    "gym": (lambda: RewardFree(gym.make("Hopper-v5")), "Hopper-v5", "Gym Hopper-v5 (early termination)"),
    "dmc": (lambda: gym.make("URLB/hopper-v0"), "URLB/hopper-hop-v0", "DMC hopper hop (1,000 fixed steps)"),
}


def clocks() -> np.ndarray:
    """Wall-clock time and this process's CPU time (seconds)."""
    return np.array([time.perf_counter(), time.process_time()])


class ExtrinsicRecorder(BaseCallback):
    """Records the extrinsic return of each pre-training episode (``info["task_reward"]``, never learnt from) and of
    deterministic evaluations every ``eval_freq`` steps, with wall-clock times.

    :param eval_env_id: the evaluation env (its own, extrinsic reward)
    :param eval_freq: env steps between evaluations (also one at step 0)
    :param n_eval_episodes: episodes per evaluation
    :param seed: seeds the evaluation resets and the skills of a skill-based model
    """

    def __init__(self, eval_env_id: str, eval_freq: int, n_eval_episodes: int, seed: int) -> None:
        super().__init__()
        self.eval_env_id, self.eval_freq, self.n_eval_episodes, self.seed = eval_env_id, eval_freq, n_eval_episodes, seed
        self.episodes: list[dict[str, float]] = []
        self.evals: list[dict[str, Any]] = []
        #: wall-clock (``*_s``) and this process's CPU time (``*_cpu_s``: the core-seconds it used) of each part
        self.times: dict[str, float] = {"eval_s": 0.0, "eval_cpu_s": 0.0, "eval_steps": 0}
        self._return = self._length = 0.0

    def _on_training_start(self) -> None:
        self.eval_env = self.model.wrap_env(gym.make(self.eval_env_id))
        prior = self.model.skill_prior
        rng = np.random.default_rng(self.seed)
        self.skills = [None if prior is None else prior.sample(rng) for _ in range(self.n_eval_episodes)]
        self._start = clocks()
        self._evaluate()

    def _on_step(self) -> bool:
        (info,) = self.locals["infos"]
        self._return += info["task_reward"]
        self._length += 1
        if self.locals["dones"][0]:
            terminated = not info.get("TimeLimit.truncated", False)
            self.episodes.append({"step": self.num_timesteps, "return": self._return, "length": self._length,
                                  "terminated": terminated})
            self._return = self._length = 0.0
        if self.num_timesteps == self.model.learning_starts:
            self._since_start("warmup", minus="eval")
        if self.num_timesteps % self.eval_freq == 0:
            self._evaluate()
        return True

    def _on_training_end(self) -> None:
        self._since_start("total")
        for suffix in ("_s", "_cpu_s"):
            self.times[f"train{suffix}"] = self.times[f"total{suffix}"] - self.times[f"eval{suffix}"] - self.times.get(
                f"warmup{suffix}", 0.0)

    def _since_start(self, name: str, minus: str | None = None) -> None:
        """Record the wall and CPU time since training started as ``name``, less the part ``minus``."""
        for suffix, value in zip(("_s", "_cpu_s"), clocks() - self._start):
            self.times[f"{name}{suffix}"] = value - (self.times[f"{minus}{suffix}"] if minus else 0.0)

    def _evaluate(self) -> None:
        start = clocks()
        wrapper: SkillObservationWrapper | None = find_skill_wrapper(self.eval_env)
        returns, lengths = [], []
        for episode, skill in enumerate(self.skills):
            if skill is not None and wrapper is not None:
                wrapper.set_skill(skill, fixed=True)
            obs, _ = self.eval_env.reset(seed=10_000 + self.seed if episode == 0 else None)
            total, length, done = 0.0, 0, False
            while not done:
                action, _ = self.model.predict(obs, deterministic=True)
                obs, reward, terminated, truncated, _ = self.eval_env.step(action)
                total, length, done = total + float(reward), length + 1, terminated or truncated
            returns.append(total)
            lengths.append(length)
            self.times["eval_steps"] += length
        self.evals.append({"step": self.num_timesteps, "mean": float(np.mean(returns)), "max": float(np.max(returns)),
                           "returns": returns, "lengths": lengths})
        elapsed = clocks() - start
        self.times["eval_s"] += elapsed[0]
        self.times["eval_cpu_s"] += elapsed[1]


def run(env_name: str, method: str, seed: int, args: argparse.Namespace) -> dict[str, Any]:
    """One pre-training run with its records (see the module docstring).

    :param env_name: a key of :data:`ENVS`
    :param method: a key of :data:`METHODS`
    :param seed: the seed
    :param args: the command line
    """
    make_env, eval_id, _ = ENVS[env_name]
    model = METHODS[method](
        "MlpPolicy", make_env(), policy_kwargs={"hidden_dim": args.hidden_dim}, batch_size=args.batch_size,
        buffer_size=min(args.steps, 1_000_000), seed=seed, reward_free=True,
    )
    recorder = ExtrinsicRecorder(eval_id, args.eval_freq, args.eval_episodes, seed)
    model.learn(args.steps, callback=recorder)
    updates = max(model._n_updates, 1)
    times: dict[str, float] = {**recorder.times, "updates": model._n_updates}
    for clock in ("", "_cpu"):  # wall-clock and CPU rates
        part = {name: recorder.times.get(f"{name}{clock}_s", 0.0) for name in ("train", "warmup", "eval")}
        times[f"train{clock}_ms_per_step"] = 1000 * part["train"] / max(args.steps - model.learning_starts, 1)
        times[f"train{clock}_ms_per_update"] = 1000 * part["train"] / updates
        times[f"warmup{clock}_ms_per_step"] = 1000 * part["warmup"] / model.learning_starts
        times[f"eval{clock}_ms_per_step"] = 1000 * part["eval"] / max(recorder.times["eval_steps"], 1)
    return {"env": env_name, "env_id": eval_id, "method": method, "seed": seed, **settings_of(args),
            "learning_starts": model.learning_starts, "threads": th.get_num_threads(), "torch": th.__version__,
            "times": times, "episodes": recorder.episodes, "evals": recorder.evals}


def settings_of(args: argparse.Namespace) -> dict[str, int]:
    """The settings a run's JSON records and a later call compares (a run with the same ones is kept)."""
    return {"steps": args.steps, "hidden_dim": args.hidden_dim, "batch_size": args.batch_size,
            "eval_freq": args.eval_freq, "eval_episodes": args.eval_episodes}


def write_run(result: dict[str, Any], out: Path) -> None:
    """The run's JSON and its two CSV files.

    :param result: :func:`run`'s result
    :param out: the output folder
    """
    stem = f"{result['env']}_{result['method']}_seed{result['seed']}"
    (out / f"{stem}.json").write_text(json.dumps(result, indent=1))
    with open(out / f"{stem}_episodes.csv", "w", newline="") as file:
        writer = csv.DictWriter(file, ["step", "return", "length", "terminated"])
        writer.writeheader()
        writer.writerows(result["episodes"])
    with open(out / f"{stem}_evals.csv", "w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(["step", "mean", "max", "mean_length"])
        writer.writerows([e["step"], e["mean"], e["max"], float(np.mean(e["lengths"]))] for e in result["evals"])


def binned(episodes: list[dict[str, float]], key: str, edges: np.ndarray) -> np.ndarray:
    """Mean of ``key`` over the episodes that end in each bin of ``edges`` (NaN for an empty bin).

    :param episodes: the run's training episodes
    :param key: ``return`` or ``length``
    :param edges: bin edges in env steps
    """
    steps = np.array([e["step"] for e in episodes], dtype=float)
    values = np.array([e[key] for e in episodes], dtype=float)
    index = np.digitize(steps, edges[1:-1])
    sums = np.bincount(index, weights=values, minlength=len(edges) - 1)
    counts = np.bincount(index, minlength=len(edges) - 1)
    with np.errstate(invalid="ignore"):
        return sums / counts


def plot(results: list[dict[str, Any]], path: Path) -> None:
    """Figure 3: per env (columns) the training episodes' extrinsic return and length, and the deterministic
    evaluations' return, over pre-training; per method the mean over seeds, the seeds' range shaded.

    :param results: the runs
    :param path: the png to write
    """
    envs = [e for e in ENVS if any(r["env"] == e for r in results)]
    rows = [("return", "training episodes' extrinsic return"), ("length", "training episodes' length"),
            ("eval", "deterministic evaluation: extrinsic return")]
    fig, axes = plt.subplots(len(rows), len(envs), figsize=(5.5 * len(envs), 8.5), squeeze=False, sharex="col")
    for col, env in enumerate(envs):
        steps = max(r["steps"] for r in results if r["env"] == env)
        edges = np.linspace(0, steps, 21)
        centres = (edges[:-1] + edges[1:]) / 2
        for method, color in zip(METHODS, ("tab:blue", "tab:orange", "tab:green")):
            runs = [r for r in results if r["env"] == env and r["method"] == method]
            if not runs:
                continue
            for row, (key, label) in enumerate(rows):
                ax = axes[row, col]
                if key == "eval":
                    x = np.array([e["step"] for e in runs[0]["evals"]])
                    n = min(len(r["evals"]) for r in runs)
                    curves = np.array([[e["mean"] for e in r["evals"][:n]] for r in runs])
                    x = x[:n]
                else:
                    x, curves = centres, np.array([binned(r["episodes"], key, edges) for r in runs])
                with warnings.catch_warnings():  # a bin without episodes in every seed: NaN, not a warning
                    warnings.simplefilter("ignore", RuntimeWarning)
                    mean, low, high = np.nanmean(curves, 0), np.nanmin(curves, 0), np.nanmax(curves, 0)
                ok = np.isfinite(mean)  # bins where no episode ended (short runs of 1,000-step episodes) are left out
                ax.plot(x[ok], mean[ok], color=color, marker="." if ok.sum() < 5 else None,
                        label=f"{method} ({len(runs)} seed{'s' * (len(runs) > 1)})")
                ax.fill_between(x[ok], low[ok], high[ok], color=color, alpha=0.2)
                ax.set_ylabel(label, fontsize=8)
        axes[0, col].set_title(ENVS[env][2], fontsize=10)
        axes[-1, col].set_xlabel("pre-training env steps")
        axes[-1, col].xaxis.set_major_formatter(lambda value, _: f"{value / 1000:g}k" if value else "0")
        axes[0, col].legend(fontsize=8)
    fig.suptitle("Reward-free pre-training on hopper\n(extrinsic reward recorded, never learnt from)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def project(results: list[dict[str, Any]], steps: int, n_seeds: int, eval_freq: int, eval_episodes: int) -> list[str]:
    """The projected cost of the whole experiment at ``steps`` per run, from the rates measured in CPU time (core
    seconds; the wall-clock rates of a busy machine overstate it): the warm-up and training steps at their measured
    cost, the evaluations at their measured cost per step with every episode at its longest (1,000 steps: an upper
    bound for Gym, whose episodes end sooner while the hopper falls).

    :param results: the measured runs (the last of each env and method counts)
    :param steps: the projected budget per run
    :param n_seeds: seeds per (env, method)
    :param eval_freq: evaluation period of the projected runs
    :param eval_episodes: episodes per evaluation of the projected runs
    """
    lines, total = [], 0.0
    rates = {(r["env"], r["method"]): r for r in results}
    for (env, method), r in sorted(rates.items()):
        t, warmup = r["times"], r["learning_starts"]
        train = (t["warmup_cpu_ms_per_step"] * warmup + t["train_cpu_ms_per_step"] * (steps - warmup)) / 1000
        evals = t["eval_cpu_ms_per_step"] * 1000 * eval_episodes * (steps // eval_freq + 1) / 1000
        total += (train + evals) * n_seeds
        lines.append(f"  {env} {method}: {t['train_cpu_ms_per_step']:.1f} CPU ms per training step "
                     f"({t['train_cpu_ms_per_update']:.1f} per update; wall {t['train_ms_per_step']:.1f}), "
                     f"{(train + evals) / 3600:.2f} core-hours per run (evaluations at most {evals / 60:.0f} min)")
    lines.append(f"  all {len(rates)} (env, method) x {n_seeds} seeds at {steps} steps: {total / 3600:.1f} core-hours")
    return lines


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=200_000, help="pre-training env steps per run")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    parser.add_argument("--envs", nargs="+", default=list(ENVS), choices=list(ENVS))
    parser.add_argument("--hidden-dim", type=int, default=256)
    parser.add_argument("--batch-size", type=int, default=256)
    parser.add_argument("--eval-freq", type=int, default=10_000)
    parser.add_argument("--eval-episodes", type=int, default=5)
    parser.add_argument("--project-steps", type=int, default=None, help="print the whole experiment's cost at this budget")
    parser.add_argument("--plot-only", action="store_true", help="redraw the figure from the runs' JSON in --out")
    parser.add_argument("--out", default="early_termination")
    args = parser.parse_args(argv)
    th.set_num_threads(1)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.plot_only:
        results = [json.loads(p.read_text()) for p in sorted(out.glob("*_seed*.json"))]
    else:
        results = []
        for seed in args.seeds:
            for env in args.envs:
                for method in args.methods:
                    done = out / f"{env}_{method}_seed{seed}.json"
                    kept = json.loads(done.read_text()) if done.exists() else None
                    if kept is not None and all(kept[key] == value for key, value in settings_of(args).items()):
                        results.append(kept)  # finished by an earlier call with the same settings
                        print(f"{env} {method} seed {seed}: kept from {done}", flush=True)
                        continue
                    result = run(env, method, seed, args)
                    write_run(result, out)
                    results.append(result)
                    print(f"{env} {method} seed {seed}: {result['times']['total_s']:.0f} s", flush=True)
    plot(results, out / "early_termination.png")
    print("\n| env | method | seed | training episodes | mean return, first / last fifth | mean length, first / last fifth | "
          "eval return, step 0 / last | ms per training step, wall / CPU |\n|---|---|---|---|---|---|---|---|")
    for r in results:
        episodes = r["episodes"]
        fifth = max(len(episodes) // 5, 1)
        first, last = episodes[:fifth], episodes[-fifth:]

        def mean(items: list[dict[str, Any]], key: str) -> float:
            return float(np.mean([e[key] for e in items])) if items else float("nan")

        print(f"| {r['env']} | {r['method']} | {r['seed']} | {len(episodes)} | {mean(first, 'return'):.1f} / "
              f"{mean(last, 'return'):.1f} | {mean(first, 'length'):.0f} / {mean(last, 'length'):.0f} | "
              f"{r['evals'][0]['mean']:.1f} / {r['evals'][-1]['mean']:.1f} | {r['times']['train_ms_per_step']:.1f} / "
              f"{r['times']['train_cpu_ms_per_step']:.1f} |")
    if args.project_steps:
        print(f"\nprojected at {args.project_steps} steps per run (eval every {args.eval_freq}, "
              f"{args.eval_episodes} episodes):")
        print("\n".join(project(results, args.project_steps, 3, args.eval_freq, args.eval_episodes)))
    print(f"\nwrote {out}/")


if __name__ == "__main__":
    main()
