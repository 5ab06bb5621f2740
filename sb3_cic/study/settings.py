"""The settings of a study: the scale, evaluation and checkpoint settings of ``sb3-cic protocol`` and ``sb3-cic study``
(:class:`Settings`), each checked against its range (:attr:`Settings.RANGES`) when made. What a study folder records of
them is :mod:`sb3_cic.study.settings_record`. This module imports nothing heavy: the command line reads the ranges
of its options here.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, ClassVar

from sb3_cic.common.arguments import NON_NEGATIVE_INT, POSITIVE_INT, STEPS, Range, check_argument
from sb3_cic.constants import DEFAULT_SNAPSHOTS


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
    :param compile_update: compile each run's update step (``compile_update=True``; the same math to float rounding)
    :param tf32: TF32 matrix products on CUDA (:func:`~sb3_cic.common.fast_update.enable_tf32`)
    :param progress_bar: show progress: SB3's progress bar on a terminal, a line a minute elsewhere
    :param verbose: verbosity of the algorithms
    :param pretrain_checkpoint_every: steps between the checkpoints of a pre-training (0: none)
    :param finetune_checkpoint_every: steps between the checkpoints of a fine-tuning (0: none)
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
    compile_update: bool = False
    tf32: bool = False
    progress_bar: bool = False
    verbose: int = 0
    pretrain_checkpoint_every: int = 50_000
    finetune_checkpoint_every: int = 20_000

    #: the range of each numeric setting (``snapshots``: of each step)
    RANGES: ClassVar[dict[str, Range]] = {
        "hidden_dim": POSITIVE_INT, "batch_size": POSITIVE_INT, "learning_starts": NON_NEGATIVE_INT,
        "buffer_size": POSITIVE_INT, "pretrain_steps": STEPS, "finetune_steps": STEPS, "eval_freq": POSITIVE_INT,
        "eval_episodes": POSITIVE_INT, "snapshots": STEPS, "num_threads": POSITIVE_INT, "verbose": Range(0, 2, integer=True),
        "pretrain_checkpoint_every": NON_NEGATIVE_INT, "finetune_checkpoint_every": NON_NEGATIVE_INT,
    }
    #: the settings that make a study's results (recorded in ``study.json``); the others only say how it runs
    STUDY_KEYS: ClassVar[tuple[str, ...]] = (
        "hidden_dim", "batch_size", "learning_starts", "buffer_size", "pretrain_steps", "finetune_steps",
        "eval_freq", "eval_episodes", "snapshots",
    )
    #: the study settings only a pre-training (and the fine-tunings from it) uses; a run from scratch does not
    PRETRAIN_KEYS: ClassVar[tuple[str, ...]] = ("pretrain_steps", "snapshots")

    def __post_init__(self) -> None:
        """A ``ValueError`` naming the first setting out of its range (:attr:`RANGES`)."""
        for key, value in asdict(self).items():
            for item in value if key == "snapshots" else [value]:
                if item is not None:
                    check_argument(key, item, self.RANGES.get(key))

    def study_settings(self, pretrained: bool = True) -> dict[str, Any]:
        """The settings recorded in ``study.json`` (:attr:`STUDY_KEYS`), as JSON values.

        :param pretrained: whether the runs pre-train (False: runs from scratch, without :attr:`PRETRAIN_KEYS`)
        """
        return {key: list(value) if isinstance(value, tuple) else value for key, value in asdict(self).items()
                if key in self.STUDY_KEYS and (pretrained or key not in self.PRETRAIN_KEYS)}

    def overrides(self, finetune: bool) -> dict[str, Any]:
        """Hyperparameter overrides for rl-zoo's reading of the yaml."""
        out: dict[str, Any] = {}
        for key in ("batch_size", "learning_starts", "buffer_size"):
            if getattr(self, key) is not None:
                out[key] = getattr(self, key)
        if self.hidden_dim is not None and not finetune:  # a fine-tuned model keeps its saved width
            out["policy_kwargs"] = {"hidden_dim": self.hidden_dim}
        if self.compile_update:
            out["compile_update"] = True
        return out
