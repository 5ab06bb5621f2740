"""``sb3-cic study`` and ``sb3-cic status``."""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
from typing import Any, Iterator, Sequence

from sb3_cic.common.arguments import argument_parser, check_device_available, option_type
from sb3_cic.parsers import add_pairing_arguments, add_settings_arguments

#: the exit codes of a command ended by a signal (the shell's: 128 + the signal's number)
INTERRUPTED_CODES: dict[int, int] = {signal.SIGINT: 130, signal.SIGTERM: 143}


def build_parser() -> argparse.ArgumentParser:
    """Arguments of ``sb3-cic study``."""
    parser = argument_parser(
        "sb3-cic study",
        "The URLB study on Ray: pre-train each method on each domain, fine-tune on the tasks x seeds; "
        "each run a Ray task, resumed from its last checkpoint when started again.",
    )
    parser.add_argument("study", help="study folder (on a cluster: storage every node sees)")
    parser.add_argument("--methods", nargs="+", default=["all"], help="cic apt ... ddpg, or all")
    parser.add_argument("--domains", nargs="+", default=["all"], help="walker quadruped jaco, or all")
    parser.add_argument("--tasks", nargs="+", default=None, help="tasks (flip or walker_flip; default: each domain's)")
    parser.add_argument("--seeds", nargs="+", type=option_type("seeds"), default=list(range(10)), help="fine-tuning seeds")
    add_pairing_arguments(parser)
    parser.add_argument("--from-snapshot", type=option_type("from_snapshot"), default=None, metavar="STEP",
                        help="fine-tune from the snapshot at this pre-training step (one of --snapshots; default: "
                        "the final one); the runs are <method>@STEP")
    add_settings_arguments(parser)
    parser.add_argument("--address", default=None,
                        help="join a running Ray cluster (auto, ray://host:10001...; default: start a local one)")
    parser.add_argument("--workers", type=option_type("workers"), default=1,
                        help="runs at a time of the local Ray instance (no --address)")
    parser.add_argument("--cpus-per-run", type=option_type("cpus_per_run"), default=1, help="CPUs Ray gives each run")
    parser.add_argument("--gpus-per-run", type=option_type("gpus_per_run"), default=0, help="e.g. 0.25: four runs per GPU")
    parser.add_argument("--max-retries", type=option_type("max_retries"), default=3,
                        help="restarts of a run whose worker died (0: none; no unlimited retries)")
    return parser


class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM during ``sb3-cic study``.

    :param signum: the signal
    """

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


@contextlib.contextmanager
def interruptible() -> Iterator[list[int]]:
    """SIGINT and SIGTERM raise :class:`Interrupted` in this (main) thread while the block runs; the block gets the
    list of the signals received (Ray may re-raise the exception as a plain ``KeyboardInterrupt``)."""
    received: list[int] = []

    def interrupt(signum: int, frame: Any) -> None:
        received.append(signum)
        raise Interrupted(signum)

    previous = {signum: signal.signal(signum, interrupt) for signum in INTERRUPTED_CODES}
    try:
        yield received
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def main(argv: Sequence[str] | None = None) -> int:
    """``sb3-cic study``; returns the exit code: 0 when every run of the command is done.

    Bad input is a ``ValueError`` before anything is written or run (:func:`~sb3_cic.study.engine.run_study`);
    :func:`sb3_cic.cli.main` reports it in one line. SIGINT or SIGTERM stop the runs (no process of the command
    writes afterwards) and end the command with one line that says how to resume, and the exit code 130 or 143,
    whatever error the signal became on its way (an import it cut short, Ray's processes gone with it).
    """
    args = build_parser().parse_args(argv)
    if args.address is None:  # on a cluster, the nodes that run the runs may have the GPUs the driver lacks
        check_device_available(args.device)
    from sb3_cic.protocol import settings_from_args
    from sb3_cic.study.engine import run_study
    from sb3_cic.study.graph import status_report

    settings = settings_from_args(args)
    received: list[int] = []
    try:
        with interruptible() as received:
            runs, statuses = run_study(
                args.study, args.methods, args.domains, args.tasks, args.seeds, settings,
                pretrain_seed=args.pretrain_seed, address=args.address, workers=args.workers,
                cpus_per_run=args.cpus_per_run, gpus_per_run=args.gpus_per_run, max_retries=args.max_retries,
                progress_bar=not args.no_progress, from_snapshot=args.from_snapshot, pairing=args.pairing,
            )
    except BaseException as error:  # a signal may surface as another error (Ray's, an import it cut short)
        if not received and not isinstance(error, KeyboardInterrupt):
            raise
        signum = received[0] if received else getattr(error, "signum", signal.SIGINT)
        print(f"sb3-cic study: interrupted ({signal.Signals(signum).name}); its runs are stopped and keep their last "
              "checkpoint: run the same command to resume", file=sys.stderr)
        return INTERRUPTED_CODES[signum]
    report, finished = status_report(args.study)
    print(report)
    print(f"{len(statuses)} runs ran now; report: sb3-cic report {args.study}")
    return 0 if finished else 1


def status_main(argv: Sequence[str] | None = None) -> int:
    """``sb3-cic status STUDY``; returns the exit code: 0 when every run of the study is done (a ``ValueError`` if
    the folder is no study)."""
    parser = argument_parser("sb3-cic status", "Runs done / running / failed / pending of a study.")
    parser.add_argument("study", help="study folder")
    args = parser.parse_args(argv)
    from sb3_cic.study.graph import status_report

    report, finished = status_report(args.study)
    try:
        print(report, flush=True)
    except BrokenPipeError:  # ``sb3-cic status X | head``: the reader had enough; no traceback at exit either
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return 0 if finished else 1
