"""The CIC paper's Appendix G (Figure 7): skill spaces that are too small, on a 10 x 10 gridworld.

The appendix's argument: with 4 discrete skills, I(tau; z) is largest when each skill goes to its own cell
near the start, so a skill-conditioned policy that maximises it explores 4 of the 100 cells; with 100 skills
it can map skills one-to-one onto cells; CIC answers with a large continuous skill space (64-d) and an explicit
entropy term. This script pre-trains, on ``URLB/gridworld-v0`` (start (5, 5), 20-step episodes, no reward):

* ``diayn4``: DIAYN with 4 one-hot skills (the appendix's case);
* ``diayn100``: DIAYN with 100 one-hot skills;
* ``cic``: CIC with its 64-d skills ``z ~ U[0, 1]^64``;

for ``--seeds`` seeds each, then measures the trained skill-conditioned policy, acting deterministically (its
mean action) from the start for one episode per skill (the env and the policy are deterministic, so one episode
is the skill's whole behaviour):

* ``cells_visited``: distinct cells on the trajectories of all the method's skills (DIAYN: each of its 4 or 100
  skills; CIC: the first 4, 100 and ``--cic-skills`` (1,000) skills drawn from its prior); ``cells_final``:
  distinct cells where those trajectories end;
* the discriminator's accuracy, an estimate of I(tau; z) (chance in brackets):
  DIAYN: the share of the trajectories' states ``s_t`` (t = 1..20, all skills) whose most likely skill under
  ``q(z | s_t)`` is the skill that produced them (chance ``1/K``), and the lower bound
  ``I(s; z) >= E[log q(z | s)] + log K`` in nats (at most ``log K``);
  CIC: top-1 accuracy of matching each skill to its own transition embedding among those of a batch of
  ``batch_size`` skills drawn from the prior, as CIC's training accuracy is computed: the query ``g2(z)``
  against the keys ``pred(g1(s_t), g1(s_{t+3}))`` of every skill's deterministic trajectory (3 = the n-step
  transition the discriminator trains on), averaged over t (chance ``1/batch_size``); and the InfoNCE bound
  ``log batch_size - contrastive loss`` in nats;
* ``cells_in_replay``: distinct cells among the stored transitions (exploration during pre-training, random
  warm-up included).

Settings (small networks, chosen here; the appendix publishes none): hidden 64 for actor, critic and
discriminator, batch 128, learning rate 1e-3 everywhere, one update per env step after 1,000 random steps,
replay as large as the run, skills resampled at each episode (20 steps < the 50-step period), everything else
URLB's (3-step returns, tau 0.01, exploration noise 0.2). Outputs, under ``--out``: ``<method>_seed<k>.json``
per run (with its wall-clock and CPU seconds) and ``<method>_seed<k>_trajectories.npy`` (its skills' cells),
``results.json`` (every run and the per-method means), ``gridworld_skills_seed<k>.png`` per seed (Figure 7:
per-skill visitation of the grid, one row per method) and a printed table. A run whose two files exist with the
same settings is kept, not run again: a killed call resumes where it stopped.

    MUJOCO_GL=disable OMP_NUM_THREADS=1 python benchmarks/gridworld_skills.py --steps 30000 --seeds 0 1 2 \\
        --out docs/results/gridworld_skills
    python benchmarks/gridworld_skills.py --steps 2000 --seeds 0 --out /tmp/gridworld_smoke   # a smoke run
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import time
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch as th  # noqa: E402

import sb3_cic  # noqa: E402,F401  (registers the ids)
from sb3_cic.envs.gridworld import GridWorldEnv  # noqa: E402
from sb3_cic import CIC, DIAYN, URLBDDPG  # noqa: E402

ENV_ID = "URLB/gridworld-v0"
#: the compared methods: ``name: (class, constructor arguments)``
METHODS: dict[str, tuple[type[URLBDDPG], dict[str, Any]]] = {
    "diayn4": (DIAYN, {"skill_dim": 4}),
    "diayn100": (DIAYN, {"skill_dim": 100}),
    "cic": (CIC, {"skill_dim": 64}),
}
#: panels per method in the figure (the first skills), besides the "all skills" panel
PANELS = 8


def make_model(name: str, args: argparse.Namespace, seed: int) -> URLBDDPG:
    """The method ``name`` at this benchmark's settings (see the module docstring).

    :param name: a key of :data:`METHODS`
    :param args: the command line
    :param seed: the run's seed
    """
    cls, kwargs = METHODS[name]
    prefix = "diayn" if cls is DIAYN else "cic"
    return cls(
        "MlpPolicy", ENV_ID, policy_kwargs={"hidden_dim": args.hidden_dim}, batch_size=args.batch_size,
        buffer_size=max(args.steps, 1), learning_starts=args.learning_starts, train_freq=1, learning_rate=args.lr,
        seed=seed, **{f"{prefix}_lr": args.lr}, **kwargs,
    )


def rollout(model: URLBDDPG, env: GridWorldEnv, skills: np.ndarray) -> np.ndarray:
    """The deterministic trajectory of each skill from the start: cells ``(n_skills, episode_length + 1, 2)``.

    All skills step together (one actor pass per time step).

    :param model: a trained skill-based model
    :param env: the gridworld (its dynamics, vectorised)
    :param skills: skills of the model's prior, ``(n_skills, skill_dim)``
    """
    cells = np.repeat(env.start[None], len(skills), axis=0)
    trajectory = [cells]
    for _ in range(env.episode_length):
        obs = np.concatenate([env.observe(cells), skills], axis=1).astype(np.float32)
        actions, _ = model.predict(obs, deterministic=True)
        cells = np.clip(cells + env.move(actions), 0, env.size - 1)
        trajectory.append(cells)
    return np.stack(trajectory, axis=1)


def coverage(trajectories: np.ndarray) -> dict[str, int]:
    """Distinct cells on the trajectories (``cells_visited``, the start included) and at their ends (``cells_final``).

    :param trajectories: ``(n_skills, T + 1, 2)`` cells
    """
    return {
        "cells_visited": len(np.unique(trajectories.reshape(-1, 2), axis=0)),
        "cells_final": len(np.unique(trajectories[:, -1], axis=0)),
    }


@th.no_grad()
def diayn_discrimination(model: DIAYN, env: GridWorldEnv, trajectories: np.ndarray) -> dict[str, float]:
    """DIAYN's discriminator on the trajectories of its K skills: accuracy of ``argmax q(z | s_t)`` and the bound
    ``E[log q(z | s_t)] + log K`` (nats), over t = 1..T.

    :param model: the trained DIAYN model
    :param env: the gridworld
    :param trajectories: ``(K, T + 1, 2)``, row k the trajectory of skill k
    """
    k, steps = trajectories.shape[0], trajectories.shape[1] - 1
    states = th.as_tensor(env.observe(trajectories[:, 1:]).reshape(-1, 2), device=model.device)
    log_q = th.log_softmax(model.reward_module.discriminator(states), dim=1)
    skill = th.arange(k, device=model.device).repeat_interleave(steps)
    return {
        "disc_accuracy": float((log_q.argmax(dim=1) == skill).float().mean()),
        "disc_chance": 1.0 / k,
        "mi_lower_bound_nats": float(log_q.gather(1, skill[:, None]).mean()) + math.log(k),
        "mi_max_nats": math.log(k),
    }


@th.no_grad()
def cic_discrimination(model: CIC, env: GridWorldEnv, skills: np.ndarray) -> dict[str, float]:
    """CIC's discriminator on a batch of skills: top-1 accuracy of matching each skill's query to its own key among
    the batch's, and the InfoNCE bound ``log B - loss`` (nats), averaged over the n-step transitions of the skills'
    deterministic trajectories.

    :param model: the trained CIC model
    :param env: the gridworld
    :param skills: ``B`` skills of the prior, ``(B, skill_dim)``
    """
    module, n = model.reward_module, model.n_steps
    states = th.as_tensor(env.observe(rollout(model, env, skills)), device=model.device)  # (B, T + 1, 2)
    query = module.skill_net(th.as_tensor(skills, dtype=th.float32, device=model.device))
    accuracies, losses = [], []
    for t in range(states.shape[1] - n):
        key = module.pred_net(th.cat([module.state_net(states[:, t]), module.state_net(states[:, t + n])], dim=1))
        loss, accuracy = module.loss_of_logits(module.logits(query, key), "paper")
        accuracies.append(float(accuracy))
        losses.append(float(loss))
    batch = len(skills)
    return {
        "disc_accuracy": float(np.mean(accuracies)),
        "disc_chance": 1.0 / batch,
        "mi_lower_bound_nats": math.log(batch) - float(np.mean(losses)),
        "mi_max_nats": math.log(batch),
    }


def evaluate(name: str, model: URLBDDPG, args: argparse.Namespace, seed: int) -> tuple[dict[str, Any], np.ndarray]:
    """The run's measures (module docstring) and the trajectories drawn in the figure.

    :param name: the method's key
    :param model: the trained model
    :param args: the command line
    :param seed: the run's seed (CIC's skills are drawn with it)
    """
    env = GridWorldEnv()
    prior = model.skill_prior
    buffer = model.replay_buffer
    stored = buffer.observations[: buffer.size(), 0, :2]
    result: dict[str, Any] = {"cells_in_replay": len(np.unique(env.cell_of(np.asarray(stored)), axis=0))}
    if isinstance(model, DIAYN):
        trajectories = rollout(model, env, prior.grid())
        result.update(coverage(trajectories), n_skills=len(trajectories))
        result.update(diayn_discrimination(model, env, trajectories))
    else:
        rng = np.random.default_rng(seed)
        skills = np.stack([prior.sample(rng) for _ in range(args.cic_skills)])
        trajectories = rollout(model, env, skills)
        for count in sorted({4, 100, args.cic_skills}):
            result[f"skills_{count}"] = coverage(trajectories[:count])
        result.update(result[f"skills_{args.cic_skills}"], n_skills=args.cic_skills)
        result.update(cic_discrimination(model, env, skills[: args.batch_size]))
    result["final_cells"] = trajectories[:, -1].tolist() if len(trajectories) <= 100 else None
    return result, trajectories


def plot_seed(runs: dict[str, np.ndarray], results: dict[str, dict[str, Any]], path: Path, seed: int) -> None:
    """Figure 7 for one seed: per method, the first :data:`PANELS` skills' visitation of the grid (steps spent in
    each cell, the trajectory drawn, its end marked) and the number of skills ending in each cell.

    :param runs: trajectories by method
    :param results: measures by method
    :param path: the png to write
    :param seed: the seed (for the title)
    """
    size = GridWorldEnv().size
    fig, axes = plt.subplots(len(runs), PANELS + 1, figsize=(1.6 * (PANELS + 1), 1.9 * len(runs)), squeeze=False)
    for row, (name, trajectories) in zip(axes, runs.items()):
        for k, ax in enumerate(row[:PANELS]):
            if k < len(trajectories):
                visits = np.zeros((size, size))
                np.add.at(visits, (trajectories[k, :, 1], trajectories[k, :, 0]), 1)
                ax.imshow(visits, origin="lower", cmap="Blues", vmin=0, vmax=trajectories.shape[1])
                ax.plot(trajectories[k, :, 0], trajectories[k, :, 1], color="tab:orange", lw=1)
                ax.plot(*trajectories[k, -1], marker="*", color="tab:red", ms=8)
                ax.set_title(f"skill {k}", fontsize=8)
                ax.plot(size // 2, size // 2, marker="s", mfc="none", color="black", ms=5)  # the start
            elif k:
                ax.axis("off")  # fewer skills than panels
            ax.set_xticks([])
            ax.set_yticks([])
        ends = np.zeros((size, size))
        np.add.at(ends, (trajectories[:, -1, 1], trajectories[:, -1, 0]), 1)
        row[-1].imshow(ends, origin="lower", cmap="Reds")
        row[-1].set_title(f"ends of {len(trajectories)} skills", fontsize=8)
        row[-1].set_xticks([])
        row[-1].set_yticks([])
        measures = results[name]
        row[0].set_ylabel(
            f"{name}\n{measures['cells_visited']} cells, {measures['cells_final']} ends\n"
            f"acc {measures['disc_accuracy']:.2f} ({measures['disc_chance']:.2g})",
            fontsize=8,
        )
        row[-1].plot(size // 2, size // 2, marker="s", mfc="none", color="black", ms=5)
    fig.suptitle(f"Gridworld skills (seed {seed}): deterministic episode of each skill from the start (square)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def summary(rows: list[dict[str, Any]]) -> dict[str, dict[str, float]]:
    """Mean and standard deviation over seeds of each method's measures.

    :param rows: one dict per run (``method`` and its measures)
    """
    keys = ("cells_visited", "cells_final", "disc_accuracy", "mi_lower_bound_nats", "wall_s", "cpu_s")
    out: dict[str, dict[str, float]] = {}
    for method in dict.fromkeys(row["method"] for row in rows):
        values = {key: [row[key] for row in rows if row["method"] == method] for key in keys}
        stats = (("mean", np.mean), ("std", np.std))
        out[method] = {f"{key}_{stat}": float(f(v)) for key, v in values.items() for stat, f in stats}
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=30_000, help="pre-training env steps per run")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    parser.add_argument("--hidden-dim", type=int, default=64)
    parser.add_argument("--batch-size", type=int, default=128)
    parser.add_argument("--lr", type=float, default=1e-3)
    parser.add_argument("--learning-starts", type=int, default=1000)
    parser.add_argument("--cic-skills", type=int, default=1000, help="skills drawn from CIC's prior for its coverage")
    parser.add_argument("--out", default="gridworld_skills")
    args = parser.parse_args(argv)
    th.set_num_threads(1)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    settings = {k: v for k, v in vars(args).items() if k not in ("seeds", "methods", "out")}
    machine = {"torch": th.__version__, "python": platform.python_version(), "cpus": os.cpu_count()}  # provenance
    for seed in args.seeds:
        trajectories: dict[str, np.ndarray] = {}
        results: dict[str, dict[str, Any]] = {}
        for name in args.methods:
            done, path = out / f"{name}_seed{seed}.json", out / f"{name}_seed{seed}_trajectories.npy"
            kept = json.loads(done.read_text()) if done.exists() and path.exists() else None
            if kept is not None and kept["settings"] == settings:  # finished by an earlier call with these settings
                results[name], trajectories[name] = kept, np.load(path)
                rows.append(kept)
                print(f"{name} seed {seed}: kept from {done}", flush=True)
                continue
            start, cpu_start = time.perf_counter(), time.process_time()
            model = make_model(name, args, seed)
            model.learn(args.steps)
            wall, cpu = time.perf_counter() - start, time.process_time() - cpu_start
            results[name], trajectories[name] = evaluate(name, model, args, seed)
            run = {"method": name, "seed": seed, "steps": args.steps, "wall_s": wall, "cpu_s": cpu, **results[name],
                   "settings": settings, "machine": machine}
            np.save(path, trajectories[name])
            done.write_text(json.dumps(run, indent=1))
            rows.append(run)
            print(f"{name} seed {seed}: {wall:.0f} s ({cpu:.0f} s of CPU)", flush=True)
        plot_seed(trajectories, results, out / f"gridworld_skills_seed{seed}.png", seed)
    (out / "results.json").write_text(json.dumps({"runs": rows, "summary": summary(rows)}, indent=1))
    print(f"\n| method | seed | skills | cells visited | cells at the end | disc. accuracy (chance) | I bound / max (nats) | "
          f"cells in replay | wall / CPU s |\n|---|---|---|---|---|---|---|---|---|")
    for row in rows:
        print(f"| {row['method']} | {row['seed']} | {row['n_skills']} | {row['cells_visited']} | {row['cells_final']} | "
              f"{row['disc_accuracy']:.3f} ({row['disc_chance']:.3g}) | {row['mi_lower_bound_nats']:.2f} / "
              f"{row['mi_max_nats']:.2f} | {row['cells_in_replay']} | {row['wall_s']:.0f} / {row['cpu_s']:.0f} |")
    cic = [row for row in rows if row["method"] == "cic"]
    if cic:
        print("\nCIC with as many sampled skills as DIAYN has (cells visited / at the end):")
        for row in cic:
            print(f"  seed {row['seed']}: " + ", ".join(
                f"{k.split('_')[1]} skills {v['cells_visited']} / {v['cells_final']}" for k, v in row.items()
                if k.startswith("skills_")))
    print(f"\nwrote {out}/")


if __name__ == "__main__":
    main()
