"""``sb3-cic protocol``, ``sb3-cic study``, ``sb3-cic status`` and ``sb3-cic pause``: the command lines of the study driver
(:mod:`sb3_cic.study.driver`). Both run commands take the same settings (:func:`add_settings_arguments`), pairing
(:func:`add_pairing_arguments`) and ``--conf-file``.

Every option's value is checked by its type and range while the command line is read, before anything is written or
run: a setting's range is :attr:`Settings.RANGES <sb3_cic.study.settings.Settings.RANGES>`, an option's own is
:data:`OPTION_RANGES`. Building these parsers (and printing ``--help``) imports neither torch nor Ray: the code that
runs the commands is imported by the handlers, after the arguments are read.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
from pathlib import Path
from typing import Any, Iterator, Sequence

from sb3_cic.common.arguments import (
    NON_NEGATIVE,
    NON_NEGATIVE_INT,
    POSITIVE,
    POSITIVE_INT,
    SEED,
    STEPS,
    Range,
)
from sb3_cic.command_line import Interrupted, argument_parser, check_device_available, device_type, option_type
from sb3_cic.constants import DEFAULT_SNAPSHOTS, SMALL_SETTINGS
from sb3_cic.envs.tasks import DOMAIN_TASKS
from sb3_cic.study.settings import Settings

#: the ranges of the settings' options (``--hidden-dim``...)
SETTINGS: dict[str, Range] = Settings.RANGES
#: the ranges of the options of ``protocol`` and ``study`` that are no setting
OPTION_RANGES: dict[str, Range] = {
    "seeds": SEED,
    "pretrain_seed": SEED,
    "snapshot": STEPS,
    "from_snapshot": STEPS,
    "checkpoint_every": NON_NEGATIVE_INT,
    "workers": POSITIVE_INT,
    "cpus_per_run": POSITIVE,
    "gpus_per_run": NON_NEGATIVE,
    "max_retries": NON_NEGATIVE_INT,
}

#: the exit codes of a command ended by a signal (the shell's: 128 + the signal's number)
INTERRUPTED_CODES: dict[int, int] = {signal.SIGINT: 130, signal.SIGTERM: 143}
#: the exit code of ``study`` and ``protocol`` ended by ``sb3-cic pause`` (sysexits' EX_TEMPFAIL: run it again)
PAUSED_CODE = 75
#: what a paused command says after its name
PAUSED_ADVICE = "paused (sb3-cic pause): its runs stopped at their checkpoints; run the same command to resume"


def small_help() -> str:
    """The help text of ``--small`` (from :data:`SMALL_SETTINGS`)."""
    values = ", ".join(f"{key} {value}" for key, value in SMALL_SETTINGS.items())
    return f"CPU-sized: {values} (an explicit option wins); the step counts stay as given or the yaml's"


def protocol_parser() -> argparse.ArgumentParser:
    """Arguments of ``sb3-cic protocol``."""
    parser = argument_parser(
        "sb3-cic protocol",
        "URLB protocol: pre-train once on URLB/<domain>-v0, fine-tune on the domain's tasks over seeds.",
    )
    parser.add_argument("--method", "--algo", default="cic", help="cic, icm, ..., or ddpg (from scratch); cic+fixed: fine-tuned with the method's skill choice fixed")
    parser.add_argument("--domain", default="walker", choices=sorted(DOMAIN_TASKS), help="URLB domain")
    parser.add_argument("--study", default="runs/urlb", help="study folder")
    parser.add_argument("--tasks", nargs="+", default=None, help="tasks (default: all of the domain)")
    parser.add_argument("--seeds", nargs="+", type=option_type(OPTION_RANGES["seeds"]), default=list(range(10)),
                        help="fine-tuning seeds")
    add_pairing_arguments(parser)
    parser.add_argument("--snapshot", type=option_type(OPTION_RANGES["snapshot"]), default=None, metavar="STEP",
                        help="fine-tune from the snapshot at this pre-training step (default: the final one)")
    parser.add_argument("--from-scratch", action="store_true", default=None, help="no pre-training (default for ddpg)")
    parser.add_argument("--conf-file", default=None, help="yaml (default: zoo_configs/<method>.yml)")
    add_settings_arguments(parser)
    return parser


def build_parser() -> argparse.ArgumentParser:
    """Arguments of ``sb3-cic study``."""
    parser = argument_parser(
        "sb3-cic study",
        "The URLB study on Ray: pre-train each method on each domain, fine-tune on the tasks x seeds; "
        "each run a Ray task, resumed from its last checkpoint when started again.",
    )
    parser.add_argument("study", help="study folder (on a cluster: storage every node sees)")
    parser.add_argument("--methods", nargs="+", default=["all"], help="cic apt ... ddpg, or all; cic+fixed, cic+sweep: fine-tuned with that skill choice of the method "
                        "(one pre-training serves both)")
    parser.add_argument("--domains", nargs="+", default=["all"], help="walker quadruped jaco, or all")
    parser.add_argument("--tasks", nargs="+", default=None, help="tasks (flip or walker_flip; default: each domain's)")
    parser.add_argument("--seeds", nargs="+", type=option_type(OPTION_RANGES["seeds"]), default=list(range(10)), help="fine-tuning seeds")
    add_pairing_arguments(parser)
    parser.add_argument("--from-snapshot", type=option_type(OPTION_RANGES["from_snapshot"]), default=None, metavar="STEP",
                        help="fine-tune from the snapshot at this pre-training step (one of --snapshots; default: "
                        "the final one); the runs are <method>@STEP")
    parser.add_argument("--conf-file", nargs="+", default=None, metavar="[METHOD=]FILE",
                        help="each method's yaml, METHOD=FILE (FILE alone with one of --methods; default: "
                        "zoo_configs/<method>.yml), recorded in study.json: a study keeps its yaml")
    add_settings_arguments(parser)
    parser.add_argument("--address", default=None,
                        help="join a running Ray cluster (auto, ray://host:10001...; default: start a local one)")
    parser.add_argument("--workers", type=option_type(OPTION_RANGES["workers"]), default=1,
                        help="runs at a time of the local Ray instance (no --address)")
    parser.add_argument("--cpus-per-run", type=option_type(OPTION_RANGES["cpus_per_run"]), default=1, help="CPUs Ray gives each run")
    parser.add_argument("--gpus-per-run", type=option_type(OPTION_RANGES["gpus_per_run"]), default=0, help="e.g. 0.25: four runs per GPU")
    parser.add_argument("--max-retries", type=option_type(OPTION_RANGES["max_retries"]), default=3,
                        help="restarts of a run whose worker died (0: none; no unlimited retries)")
    return parser


def conf_files_of(values: list[str] | None, methods: list[str]) -> dict[str, str]:
    """The yaml of each method that ``sb3-cic study --conf-file`` gives: ``METHOD=FILE`` entries, or one ``FILE``
    when ``--methods`` names one method; a ``ValueError`` for a bare file with several methods or a method twice.

    :param values: the ``--conf-file`` values (None: none given)
    :param methods: the ``--methods`` values
    """
    out: dict[str, str] = {}
    for value in values or ():
        method, _, path = value.partition("=")
        if not path or "/" in method or "." in method:  # a file name, not METHOD=FILE
            if len(methods) != 1 or methods == ["all"] or len(values or ()) != 1:
                raise ValueError(f"--conf-file {value}: give METHOD=FILE for each method's yaml when --methods names "
                                 "several (or all)")
            method, path = methods[0].partition("+")[0], value  # cic+fixed: cic's yaml
        method = method.lower()
        if method in out:
            raise ValueError(f"--conf-file names {method} twice")
        out[method] = path
    return out


def add_pairing_arguments(parser: argparse.ArgumentParser) -> None:
    """``--pairing`` and ``--pretrain-seed`` of ``protocol`` and ``study`` (:class:`~sb3_cic.study.record.Pairing`)."""
    parser.add_argument(
        "--pairing", choices=("paired", "shared"), default=None,
        help="paired: pre-train once per seed and fine-tune seed s from pre-training seed s (URLB's protocol; the "
        "default of a new study); shared: pre-train once, with --pretrain-seed, and fine-tune every seed from it "
        "(the CIC code's). Default: the study folder's pairing (a study made before this option: shared)",
    )
    parser.add_argument("--pretrain-seed", type=option_type(OPTION_RANGES["pretrain_seed"]), default=None,
                        help="the one pre-training seed of --pairing shared (given alone: shared; default 0)")


def add_settings_arguments(parser: argparse.ArgumentParser) -> None:
    """The scale, evaluation and checkpoint options of ``protocol`` and ``study`` (see :class:`~sb3_cic.study.settings.Settings`)."""
    snapshots = " ".join(str(step) for step in DEFAULT_SNAPSHOTS)
    parser.add_argument("--snapshots", nargs="+", type=option_type(SETTINGS["snapshots"]), default=None, metavar="STEP",
                        help=f"pre-training steps at which a snapshot is saved, at most --pretrain-steps (the final "
                        f"step always is; default: URLB's {snapshots}, those below the pre-training's steps)")
    parser.add_argument("--small", action="store_true", help=small_help())
    parser.add_argument("--hidden-dim", type=option_type(SETTINGS["hidden_dim"]), default=None,
                        help="hidden width of the networks (default: the yaml's)")
    parser.add_argument("--batch-size", type=option_type(SETTINGS["batch_size"]), default=None,
                        help="minibatch size, at most --buffer-size (default: the yaml's)")
    parser.add_argument("--learning-starts", type=option_type(SETTINGS["learning_starts"]), default=None,
                        help="random steps before learning, below the steps of each run; also the fine-tuning "
                        "sweep length (default: the yaml's)")
    parser.add_argument("--buffer-size", type=option_type(SETTINGS["buffer_size"]), default=None,
                        help="replay capacity (default: the yaml's)")
    parser.add_argument("--pretrain-steps", type=option_type(SETTINGS["pretrain_steps"]), default=None,
                        help="pre-training steps (default: the yaml's, 2M)")
    parser.add_argument("--finetune-steps", type=option_type(SETTINGS["finetune_steps"]), default=None,
                        help="fine-tuning steps (default: the yaml's, 100k)")
    parser.add_argument("--eval-freq", type=option_type(SETTINGS["eval_freq"]), default=10_000, help="steps between evaluations")
    parser.add_argument("--eval-episodes", type=option_type(SETTINGS["eval_episodes"]), default=10,
                        help="deterministic episodes per evaluation")
    parser.add_argument(
        "--checkpoint-every", nargs="+", type=option_type(OPTION_RANGES["checkpoint_every"]), default=None, metavar="STEPS",
        help="steps between checkpoints: one value for every run, or two (pre-training, fine-tuning); "
        "default 50000 20000; 0: none",
    )
    parser.add_argument("--device", type=device_type, default="auto", help="torch device (auto: CUDA if any)")
    parser.add_argument("--num-threads", type=option_type(SETTINGS["num_threads"]), default=None,
                        help="torch threads of each run (default: torch's)")
    parser.add_argument("--compile", action="store_true", help="compile_update=True: each update compiled as one graph")
    parser.add_argument("--tf32", action="store_true", help="TF32 matrix products on CUDA (off by default)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--verbose", type=option_type(SETTINGS["verbose"]), default=0, help="verbosity of the algorithms")


def settings_values(args: argparse.Namespace) -> dict[str, Any]:
    """The values of :class:`~sb3_cic.study.settings.Settings` that the options of :func:`add_settings_arguments` give
    (``--small`` filled in, ``--checkpoint-every`` split), checked together: a ``ValueError`` naming the options for
    a batch above the replay capacity, a snapshot above the pre-training steps or more than two checkpoint periods.

    :param args: the parsed command line
    """
    small = SMALL_SETTINGS if args.small else {}
    values: dict[str, Any] = {
        key: small.get(key) if getattr(args, key) is None else getattr(args, key) for key in SMALL_SETTINGS
    }
    if values["batch_size"] is not None and values["buffer_size"] is not None and values["batch_size"] > values["buffer_size"]:
        raise ValueError(f"--batch-size {values['batch_size']} is above --buffer-size {values['buffer_size']}")
    if args.snapshots is not None and args.pretrain_steps is not None:
        beyond = [step for step in args.snapshots if step > args.pretrain_steps]
        if beyond:
            raise ValueError(f"--snapshots {beyond} above the {args.pretrain_steps} pre-training steps (--pretrain-steps)")
    if args.checkpoint_every is not None and len(args.checkpoint_every) > 2:
        raise ValueError(f"--checkpoint-every takes one or two values >= 0, got {args.checkpoint_every}")
    values.update(
        pretrain_steps=args.pretrain_steps,
        finetune_steps=args.finetune_steps,
        eval_freq=args.eval_freq,
        eval_episodes=args.eval_episodes,
        snapshots=tuple(DEFAULT_SNAPSHOTS if args.snapshots is None else args.snapshots),
        device=args.device,
        num_threads=args.num_threads,
        compile_update=args.compile,
        tf32=args.tf32,
        progress_bar=not args.no_progress,
        verbose=args.verbose,
    )
    if args.checkpoint_every is not None:
        values.update(pretrain_checkpoint_every=args.checkpoint_every[0], finetune_checkpoint_every=args.checkpoint_every[-1])
    return values


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
    """``sb3-cic study``; returns the exit code: 0 when every run of the command is done, :data:`PAUSED_CODE` when
    it was paused (``sb3-cic pause``: its runs stopped at their checkpoints), 1 otherwise.

    Bad input is a ``ValueError`` before anything is written or run (:func:`~sb3_cic.study.engine.run_study`);
    :func:`sb3_cic.cli.main` reports it in one line. SIGINT or SIGTERM stop the runs (no process of the command
    writes afterwards) and end the command with one line that says how to resume, and the exit code 130 or 143,
    whatever error the signal became on its way (an import it cut short, Ray's processes gone with it).
    """
    args = build_parser().parse_args(argv)
    if args.address is None:  # on a cluster, the nodes that run the runs may have the GPUs the driver lacks
        check_device_available(args.device)
    conf_files = conf_files_of(args.conf_file, args.methods)
    settings = settings_from_args(args)
    from sb3_cic.study.engine import run_study
    from sb3_cic.study.graph import status_report

    received: list[int] = []
    try:
        with interruptible() as received:
            runs, statuses = run_study(
                args.study, args.methods, args.domains, args.tasks, args.seeds, settings,
                pretrain_seed=args.pretrain_seed, address=args.address, workers=args.workers,
                cpus_per_run=args.cpus_per_run, gpus_per_run=args.gpus_per_run, max_retries=args.max_retries,
                progress_bar=not args.no_progress, from_snapshot=args.from_snapshot, pairing=args.pairing,
                conf_files=conf_files,
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
    if any(status["state"] == "paused" for status in statuses):
        print(f"sb3-cic study: {PAUSED_ADVICE}", file=sys.stderr)
        return PAUSED_CODE
    return 0 if finished else 1


def settings_from_args(args: argparse.Namespace) -> Settings:
    """The :class:`~sb3_cic.study.settings.Settings` of the options of :func:`add_settings_arguments` (a
    ``ValueError`` naming the options that do not go together, see :func:`settings_values`)."""
    return Settings(**settings_values(args))


def protocol_main(argv: Sequence[str] | None = None) -> list[dict[str, Any]]:
    """``sb3-cic protocol``: the runs of one method and domain, in this process
    (:func:`~sb3_cic.study.driver.run_protocol`); returns the fine-tunings' results."""
    args = protocol_parser().parse_args(argv)
    settings = settings_from_args(args)
    from sb3_cic.common.resumable import RunPaused
    from sb3_cic.study import driver

    try:
        results = driver.run_protocol(
            args.study, args.method, args.domain, tasks=args.tasks, seeds=args.seeds, settings=settings,
            snapshot=args.snapshot, from_scratch=args.from_scratch, pretrain_seed=args.pretrain_seed,
            config=args.conf_file, pairing=args.pairing,
        )
    except RunPaused:
        print(f"sb3-cic protocol: {PAUSED_ADVICE}", file=sys.stderr)
        raise SystemExit(PAUSED_CODE) from None
    print(f"{len(results)} fine-tuning runs in {Path(args.study) / 'finetune'}; report: sb3-cic report {args.study}")
    return results


def status_main(argv: Sequence[str] | None = None) -> int:
    """``sb3-cic status STUDY``; returns the exit code: 0 when every run of the study is done (a ``ValueError`` if
    the folder is no study)."""
    parser = argument_parser("sb3-cic status",
                             "Runs done / running / failed / pending of a study, and the time the unfinished ones need.")
    parser.add_argument("study", help="study folder")
    args = parser.parse_args(argv)
    from sb3_cic.study.graph import status_report

    report, finished = status_report(args.study)
    try:
        print(report, flush=True)
    except BrokenPipeError:  # ``sb3-cic status X | head``: the reader had enough; no traceback at exit either
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return 0 if finished else 1


def pause_main(argv: Sequence[str] | None = None) -> int:
    """``sb3-cic pause STUDY``: ask the command that drives the study to pause
    (:func:`~sb3_cic.study.record.request_pause`); returns 0 (a ``ValueError`` when no command drives it)."""
    parser = argument_parser(
        "sb3-cic pause",
        "Ask the command that drives a study (sb3-cic study or protocol) to pause: each running run checkpoints at "
        "its next episode end and stops, no other run starts, and the command ends with exit code "
        f"{PAUSED_CODE}; the same command resumes every run from there. For a machine about to be taken away (a "
        "cluster job's time limit, a shutdown): a signal keeps only each run's last periodic checkpoint.",
    )
    parser.add_argument("study", help="study folder")
    args = parser.parse_args(argv)
    from sb3_cic.study.record import request_pause

    holder = request_pause(args.study)
    print(f"asked the command that drives {args.study} ({holder}) to pause: each running run checkpoints at its next "
          f"episode end and stops (seconds to a minute); the command then ends with exit code {PAUSED_CODE} "
          f"(sb3-cic status {args.study} shows the runs' checkpoints)")
    return 0
