"""The snapshots of a pre-training: the steps it saves them at (:func:`snapshot_steps`), the callback that saves
them (:class:`SnapshotCallback`), and the check that ties a fine-tuning to the snapshot its pre-training saved
(:func:`check_pretraining`, by sha256: :func:`file_sha256`)."""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any, Sequence

from sb3_cic.common.resumable import ResumableCallback
from sb3_cic.common.save_util import networks_only
from sb3_cic.study.layout import check_snapshot, snapshot_file
from sb3_cic.study.settings import Settings


def file_sha256(path: str | Path) -> str:
    """The sha256 of a file's content (a snapshot's: what ties a fine-tuning to the pre-training it loaded)."""
    digest = hashlib.sha256()
    with open(path, "rb") as file:
        for block in iter(lambda: file.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def snapshot_steps(settings: Settings, steps: int) -> list[int]:
    """The steps at which a pre-training of ``steps`` steps saves a snapshot: the earlier of ``settings.snapshots``
    and the final step.

    :param settings: the run's settings
    :param steps: the pre-training's steps
    """
    return sorted({s for s in settings.snapshots if s < steps} | {steps})


class SnapshotCallback(ResumableCallback):
    """Save the model as ``snapshot_<steps>.zip`` when training reaches each of ``steps``, networks only
    (:func:`~sb3_cic.common.save_util.networks_only`: no optimiser states, replay buffer or local TensorBoard path),
    the file a study can share as it is: a fine-tuning starts with fresh optimisers (the run resumes from its
    checkpoint, not from a snapshot).

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
            path = snapshot_file(self.save_path, step)
            self.model.save(path)
            networks_only(path)
            self.saved[step] = path.name
            if self.verbose:
                print(f"Saved snapshot {path}")
        return True

    def get_checkpoint_state(self) -> dict[str, Any]:
        return {"pending": list(self.pending), "saved": dict(self.saved)}

    def set_checkpoint_state(self, state: dict[str, Any]) -> None:
        self.pending, self.saved = list(state["pending"]), dict(state["saved"])


def check_pretraining(folder: Path, pre: dict[str, Any], step: int, seed: int | None) -> str:
    """The sha256 of the snapshot at ``step`` of the pre-training in ``folder`` (its ``result.json``: ``pre``), which
    a fine-tuning is about to load; a one-line ``ValueError`` when the snapshot is unreadable, when its content is
    not the one the pre-training recorded (a snapshot copied over it), or when the pre-training is not of ``seed``.

    :param folder: the pre-training folder
    :param pre: its ``result.json``
    :param step: the snapshot's step
    :param seed: the pre-training seed the fine-tuning must start from (None: the study's shared one, not checked)
    """
    path = snapshot_file(folder, step)
    check_snapshot(path)
    if seed is not None and int(pre["seed"]) != seed:
        raise ValueError(f"{folder / 'result.json'} is the pre-training of seed {pre['seed']}, not of seed {seed}: it was "
                         f"copied; delete {folder} to pre-train seed {seed} again")
    digest = file_sha256(path)
    recorded = (pre.get("snapshot_sha256") or {}).get(str(step))
    if recorded is not None and recorded != digest:
        raise ValueError(f"the snapshot {path} is not the one its pre-training saved (sha256 {digest[:12]}..., "
                         f"{folder / 'result.json'} records {recorded[:12]}...): it was replaced; restore it, or delete "
                         f"{folder} to pre-train again")
    return digest
