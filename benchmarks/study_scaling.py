"""The study on Ray: wall time of one tiny study with 1 and 2 runs at a time, and the cost of a checkpoint.

1. The tiny study of ``tests/test_study.py`` (cic and ddpg x walker stand, flip x seeds 0, 1: one
   pre-training and eight fine-tunings; hidden 32, batch 32, 1,000 steps each), run by ``run_study`` on a
   local Ray instance with ``--workers 1`` and ``--workers 2`` (one torch thread per run). The Ray start is
   timed apart from the study.
2. The checkpoint of a CIC pre-training at hidden 256 (batch 256) with a full replay buffer of
   ``--buffer-size`` transitions (250,000; filled with random transitions after one real episode): seconds
   to write it (temporary file + rename), its size, and seconds to load it back, over ``--repeats``.

Prints one table; ``docs/results/study_scaling.md`` holds a run.

    MUJOCO_GL=disable python benchmarks/study_scaling.py
"""

from __future__ import annotations

import argparse
import platform
import tempfile
import time
from pathlib import Path

import numpy as np
import torch as th

from sb3_cic.protocol import Settings

TINY = Settings(
    hidden_dim=32, batch_size=32, learning_starts=500, buffer_size=10_000, pretrain_steps=1000, finetune_steps=1000,
    eval_freq=1000, eval_episodes=1, num_threads=1,
)


def time_study(workers: int, root: Path) -> tuple[float, float, int]:
    """(Ray start seconds, study seconds, runs) of the tiny study with ``workers`` runs at a time."""
    import ray

    from sb3_cic.study.engine import run_study, start_ray

    start = time.perf_counter()
    start_ray(workers=workers)
    ray_s = time.perf_counter() - start
    try:
        start = time.perf_counter()
        runs, statuses = run_study(root / f"workers_{workers}", ["cic", "ddpg"], ["walker"], ["stand", "flip"], [0, 1], TINY,
                                   progress_bar=False)
        study_s = time.perf_counter() - start
    finally:
        ray.shutdown()
    assert all(s["state"] == "done" for s in statuses) and len(statuses) == len(runs)
    return ray_s, study_s, len(runs)


def time_checkpoint(buffer_size: int, hidden_dim: int, repeats: int, root: Path) -> dict[str, float]:
    """Seconds to write and to load a checkpoint of a CIC pre-training with a full buffer, and its MB."""
    from sb3_cic import CIC
    from sb3_cic.protocol import SnapshotCallback
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
    parser.add_argument("--buffer-size", type=int, default=250_000)
    parser.add_argument("--hidden-dim", type=int, default=256)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--skip-study", action="store_true")
    args = parser.parse_args()
    th.set_num_threads(1)
    import ray

    print(f"python {platform.python_version()}, torch {th.__version__}, ray {ray.__version__}, {platform.processor() or platform.machine()}")
    with tempfile.TemporaryDirectory() as tmp:
        if not args.skip_study:
            rows = [(w, *time_study(w, Path(tmp))) for w in args.workers]
            base = rows[0][2]
            print("\nTiny study (cic + ddpg x walker stand, flip x seeds 0, 1; 1 pre-training + 8 fine-tunings of 1,000 steps)")
            print(f"{'workers':>7}  {'runs':>4}  {'Ray start s':>11}  {'study s':>8}  {'speed-up':>8}")
            for workers, ray_s, study_s, runs in rows:
                print(f"{workers:>7}  {runs:>4}  {ray_s:>11.1f}  {study_s:>8.1f}  {base / study_s:>7.2f}x")
        cost = time_checkpoint(args.buffer_size, args.hidden_dim, args.repeats, Path(tmp))
    print(f"\nCheckpoint of a CIC pre-training, hidden {args.hidden_dim}, full buffer of {args.buffer_size:,} transitions "
          f"(buffer arrays {cost['buffer_mb']:.0f} MB), best / worst of {args.repeats}")
    print(f"write {cost['save_s']:.2f} / {cost['save_s_max']:.2f} s, load {cost['load_s']:.2f} / {cost['load_s_max']:.2f} s, "
          f"size {cost['mb']:.0f} MB")


if __name__ == "__main__":
    main()
