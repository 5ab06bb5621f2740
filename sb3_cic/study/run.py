"""One run of a study (:class:`Run`): what it is, where its folder lies and which pre-training it starts from.

The job graph (:mod:`sb3_cic.study.graph`), the study's records (:mod:`sb3_cic.study.results`) and the engine
use it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

from sb3_cic import zoo
from sb3_cic.study.layout import finetune_dir, pretrain_dir, run_label
from sb3_cic.study.record import Pairing


@dataclass(frozen=True)
class Run:
    """One run of a study: a pre-training (``task`` None) or a fine-tuning of ``method`` on ``domain``.

    :param method: rl-zoo name of the method (``cic``...; ``ddpg`` fine-tunes from scratch)
    :param domain: URLB domain
    :param task: URLB task name (``walker_flip``), None for a pre-training
    :param seed: the run's seed (a pre-training's: its pre-training seed)
    :param snapshot: pre-training step of the snapshot a fine-tuning starts from (None: the final one)
    :param pretrain_seed: the seed of the pre-training a fine-tuning starts from (None: a pre-training, or a run
        from scratch)
    :param shared: a run of a study with shared pre-training (:class:`~sb3_cic.study.record.Pairing`): its
        pre-training folder has no seed in its name (:func:`~sb3_cic.study.layout.pretrain_dir`)
    :param skill_choice: how a fine-tuning chooses its skill, one of the method's ``finetune_skill_choices``
        (``fixed``, ``sweep``...; None: the yaml's ``finetune_skill_choice``)

    ``study.json`` lists the first five fields and the skill choice, when there is one (:meth:`row`); the pairing
    is the study's.
    """

    method: str
    domain: str
    task: str | None
    seed: int
    snapshot: int | None = None
    pretrain_seed: int | None = None
    shared: bool = False
    skill_choice: str | None = None

    @classmethod
    def of_row(cls, row: Sequence[Any], pairing: Pairing | None) -> Run:
        """The run of a ``study.json`` row (4 to 6 fields) in a study with ``pairing`` (None: none pre-trained)."""
        method, domain, task, seed, *rest = row
        run = cls(method, domain, task, seed, rest[0] if rest else None, skill_choice=rest[1] if len(rest) > 1 else None)
        shared = pairing is not None and not pairing.paired
        if run.task is None:
            return dataclasses.replace(run, shared=shared)
        if run.from_scratch or pairing is None:
            return run
        return dataclasses.replace(run, pretrain_seed=pairing.pretrain_seed(run.seed), shared=shared)

    def row(self) -> list[Any]:
        """The run as ``study.json`` lists it: ``[method, domain, task or None, seed, snapshot or None]``, and the
        skill choice when there is one."""
        row = [self.method, self.domain, self.task, self.seed, self.snapshot]
        return row if self.skill_choice is None else [*row, self.skill_choice]

    @property
    def kind(self) -> str:
        """``pretrain`` or ``finetune``."""
        return "pretrain" if self.task is None else "finetune"

    @property
    def from_scratch(self) -> bool:
        """A fine-tuning without pre-training (``ddpg``)."""
        return not zoo.has_reward_module(zoo.get_algo(self.method))

    def folder(self, study: str | Path) -> Path:
        """The run's folder in ``study`` (:mod:`sb3_cic.study.layout`: ``cic@100000`` for a fine-tuning from the
        snapshot at 100,000 steps)."""
        if self.task is None:
            return pretrain_dir(study, self.method, self.domain, None if self.shared else self.seed)
        return finetune_dir(study, self.label, self.task, self.seed)

    @property
    def label(self) -> str:
        """The method's name in the study's folders and reports (``cic``, ``cic@100000``, ``cic+fixed``)."""
        return run_label(self.method, self.snapshot, self.skill_choice)

    def dependency(self) -> Run | None:
        """The pre-training a fine-tuning starts from (None for a pre-training or a run from scratch)."""
        if self.task is None or self.pretrain_seed is None:
            return None
        return Run(self.method, self.domain, None, self.pretrain_seed, shared=self.shared)

    def __str__(self) -> str:
        if self.task is None:
            return f"pretrain {self.method} {self.domain}" + ("" if self.shared else f" seed {self.seed}")
        return f"{self.label} {self.task} seed {self.seed}"
