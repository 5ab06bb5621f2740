"""The study on Ray: wall time of one tiny study with 1 and 2 runs at a time, and the cost of a checkpoint.

1. The tiny study of ``tests/test_study.py`` (cic and ddpg x walker stand, flip x seeds 0, 1: one
   pre-training and eight fine-tunings; hidden 32, batch 32, ``--steps`` 1,000 each), run by ``run_study`` on
   a local Ray instance with ``--workers 1`` and ``--workers 2`` (one torch thread per run), in turns
   ``--rounds`` times. The Ray start is timed apart from the study; the runs' own training seconds, summed,
   over the study's seconds say how many runs went on at once (other work on the machine shows in the load
   average).
2. The checkpoint of a CIC pre-training at hidden 256 (batch 256) with a full replay buffer of
   ``--buffer-size`` transitions (250,000; filled with random transitions after one real episode): seconds
   to write it (temporary file + rename), its size, and seconds to load it back, over ``--repeats``.

Prints one table; ``docs/results/study_scaling.md`` holds a run.

    MUJOCO_GL=disable python benchmarks/study_scaling.py
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch as th

from sb3_cic.study.settings import Settings

TINY = Settings(
    hidden_dim=32, batch_size=32, learning_starts=500, buffer_size=10_000, pretrain_steps=1000, finetune_steps=1000,
    eval_freq=1000, eval_episodes=1, num_threads=1,
)


def time_study(workers: int, root: Path, settings: Settings) -> dict[str, float]:
    """Ray start seconds, study seconds, runs and the runs' summed training seconds of the tiny study with
    ``workers`` runs at a time, and the load average over the study."""
    import ray

    from sb3_cic.study.engine import run_study, start_ray

    start = time.perf_counter()
    start_ray(workers=workers)
    ray_s = time.perf_counter() - start
    folder = root / f"workers_{workers}_{time.monotonic_ns()}"
    try:
        start = time.perf_counter()
        runs, statuses = run_study(
            folder, ["cic", "ddpg"], ["walker"], ["stand", "flip"], [0, 1], settings, progress_bar=False
        )
        study_s = time.perf_counter() - start
        load = os.getloadavg()[0]
    finally:
        ray.shutdown()
    assert all(s["state"] == "done" for s in statuses) and len(statuses) == len(runs)
    busy = sum(next(iter(json.loads(p.read_text())["wall_time_s"].values())) for p in folder.rglob("result.json"))
    return {"workers": workers, "ray_s": ray_s, "study_s": study_s, "runs": len(runs), "busy_s": busy, "load": load}


def time_checkpoint(buffer_size: int, hidden_dim: int, repeats: int, root: Path) -> dict[str, float]:
    """Seconds to write and to load a checkpoint of a CIC pre-training with a full buffer, and its MB."""
    from sb3_cic import CIC
    from sb3_cic.study.snapshots import SnapshotCallback
    from sb3_cic.study.checkpoint import RunFolder

    model = CIC("MlpPolicy", "URLB/walker-v0", buffer_size=buffer_size, batch_size=256, learning_starts=500,
                policy_kwargs={"hidden_dim": hidden_dim}, seed=0, device="cpu")
    model.learn(1000)  # one episode: the checkpoint is taken at its end
    buffer = model.replay_buffer
    rng = np.random.default_rng(0)
    for name in ("observations", "next_observations", "actions", "rewards"):
        array = getattr(buffer, name)
        array[...] = rng.standard_normal(array.shape, dtype=np.float32)
    buffer.pos, buffer.full = 0, True
    folder = RunFolder(root / "checkpoint_run")
    folder.path.mkdir(parents=True)
    callbacks = [SnapshotCallback(folder.path, [2_000_000])]
    save, load, size = [], [], 0
    for _ in range(repeats):
        start = time.perf_counter()
        size = folder.save_checkpoint(model, callbacks, {"elapsed_s": 0.0})
        save.append(time.perf_counter() - start)
        start = time.perf_counter()
        loaded = folder.load_model(CIC, "URLB/walker-v0", device="cpu")
        folder.restore(loaded, callbacks)
        load.append(time.perf_counter() - start)
    return {"save_s": min(save), "save_s_max": max(save), "load_s": min(load), "load_s_max": max(load), "mb": size / 1e6,
            "buffer_mb": buffer.transition_nbytes() * buffer_size / 1e6}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--workers", nargs="+", type=int, default=[1, 2])
    parser.add_argument("--rounds", type=int, default=2, help="the workers settings are timed in turns, this many times")
    parser.add_argument("--steps", type=int, default=1000, help="pre-training and fine-tuning steps of each run")
    parser.add_argument("--buffer-size", type=int, default=250_000)
    parser.add_argument("--hidden-dim", type=int, default=256)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--skip-study", action="store_true")
    args = parser.parse_args()
    th.set_num_threads(1)
    import ray

    cpu = platform.processor() or platform.machine()
    print(f"python {platform.python_version()}, torch {th.__version__}, ray {ray.__version__}, {cpu}, "
          f"{os.cpu_count()} CPUs, load average at start {os.getloadavg()[0]:.2f}")
    settings = replace(TINY, pretrain_steps=args.steps, finetune_steps=args.steps)
    with tempfile.TemporaryDirectory() as tmp:
        if not args.skip_study:
            rows = [time_study(w, Path(tmp), settings) for _ in range(args.rounds) for w in args.workers]
            best = {w: min(r["study_s"] for r in rows if r["workers"] == w) for w in args.workers}
            print(f"\nTiny study (cic + ddpg x walker stand, flip x seeds 0, 1: 1 pre-training + 8 fine-tunings of "
                  f"{args.steps:,} steps, hidden 32, batch 32, one torch thread per run), in turns")
            print("busy s: the runs' own training seconds summed; busy / study: runs going on at once, on average")
            header = [("workers", 7), ("runs", 4), ("Ray start s", 11), ("study s", 8), ("busy s", 7), ("busy/study", 10),
                      ("load", 5)]
            print("  ".join(f"{name:>{width}}" for name, width in header))
            for r in rows:
                print(f"{r['workers']:>7}  {r['runs']:>4}  {r['ray_s']:>11.1f}  {r['study_s']:>8.1f}  {r['busy_s']:>7.1f}  "
                      f"{r['busy_s'] / r['study_s']:>10.2f}  {r['load']:>5.2f}")
            first = args.workers[0]
            print("best study s: " + ", ".join(f"workers {w}: {best[w]:.1f} ({best[first] / best[w]:.2f}x)"
                                               for w in args.workers))
        cost = time_checkpoint(args.buffer_size, args.hidden_dim, args.repeats, Path(tmp))
    print(f"\nCheckpoint of a CIC pre-training, hidden {args.hidden_dim}, full buffer of {args.buffer_size:,} transitions "
          f"(buffer arrays {cost['buffer_mb']:.0f} MB), best / worst of {args.repeats}")
    print(f"write {cost['save_s']:.2f} / {cost['save_s_max']:.2f} s, load + restore {cost['load_s']:.2f} / "
          f"{cost['load_s_max']:.2f} s, size {cost['mb']:.0f} MB")


if __name__ == "__main__":
    main()
