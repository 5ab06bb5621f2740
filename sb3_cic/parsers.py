"""The options of ``sb3-cic protocol`` and of the settings ``protocol`` and ``study`` share, apart from the code that
runs them: building these parsers (and printing ``--help``) imports neither torch nor Ray.

Every option's value is checked by its type (:func:`~sb3_cic.common.arguments.option_type`, the ranges of
:data:`~sb3_cic.common.arguments.RANGES`) while the command line is read, before anything is written or run.
"""

from __future__ import annotations

import argparse
from typing import Any

from sb3_cic.envs.tasks import DOMAIN_TASKS
from sb3_cic.common.arguments import argument_parser, device_type, option_type
from sb3_cic.constants import DEFAULT_SNAPSHOTS

#: what ``--small`` sets (of ``protocol``, ``study``, ``train`` and ``finetune``): CPU-sized networks, batches and
#: replay; an option given explicitly wins; the step counts are not changed
SMALL_SETTINGS: dict[str, int] = {"hidden_dim": 32, "batch_size": 32, "learning_starts": 500, "buffer_size": 100_000}


def small_help() -> str:
    """The help text of ``--small`` (from :data:`SMALL_SETTINGS`)."""
    values = ", ".join(f"{key} {value}" for key, value in SMALL_SETTINGS.items())
    return f"CPU-sized: {values} (an explicit option wins); the step counts stay as given or the yaml's"


def build_parser() -> argparse.ArgumentParser:
    """Arguments of ``sb3-cic protocol``."""
    parser = argument_parser(
        "sb3-cic protocol",
        "URLB protocol: pre-train once on URLB/<domain>-v0, fine-tune on the domain's tasks over seeds.",
    )
    parser.add_argument("--method", "--algo", default="cic", help="cic, icm, ..., or ddpg (from scratch)")
    parser.add_argument("--domain", default="walker", choices=sorted(DOMAIN_TASKS), help="URLB domain")
    parser.add_argument("--study", default="runs/urlb", help="study folder")
    parser.add_argument("--tasks", nargs="+", default=None, help="tasks (default: all of the domain)")
    parser.add_argument("--seeds", nargs="+", type=option_type("seeds"), default=list(range(10)),
                        help="fine-tuning seeds")
    add_pairing_arguments(parser)
    parser.add_argument("--snapshot", type=option_type("snapshot"), default=None, metavar="STEP",
                        help="fine-tune from the snapshot at this pre-training step (default: the final one)")
    parser.add_argument("--from-scratch", action="store_true", default=None, help="no pre-training (default for ddpg)")
    parser.add_argument("--conf-file", default=None, help="yaml (default: zoo_configs/<method>.yml)")
    add_settings_arguments(parser)
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
            method, path = methods[0], value
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
    parser.add_argument("--pretrain-seed", type=option_type("pretrain_seed"), default=None,
                        help="the one pre-training seed of --pairing shared (given alone: shared; default 0)")


def add_settings_arguments(parser: argparse.ArgumentParser) -> None:
    """The scale, evaluation and checkpoint options of ``protocol`` and ``study`` (see :class:`~sb3_cic.study.settings.Settings`)."""
    snapshots = " ".join(str(step) for step in DEFAULT_SNAPSHOTS)
    parser.add_argument("--snapshots", nargs="+", type=option_type("snapshots"), default=None, metavar="STEP",
                        help=f"pre-training steps at which a snapshot is saved, at most --pretrain-steps (the final "
                        f"step always is; default: URLB's {snapshots}, those below the pre-training's steps)")
    parser.add_argument("--small", action="store_true", help=small_help())
    parser.add_argument("--hidden-dim", type=option_type("hidden_dim"), default=None,
                        help="hidden width of the networks (default: the yaml's)")
    parser.add_argument("--batch-size", type=option_type("batch_size"), default=None,
                        help="minibatch size, at most --buffer-size (default: the yaml's)")
    parser.add_argument("--learning-starts", type=option_type("learning_starts"), default=None,
                        help="random steps before learning, below the steps of each run; also the fine-tuning "
                        "sweep length (default: the yaml's)")
    parser.add_argument("--buffer-size", type=option_type("buffer_size"), default=None,
                        help="replay capacity (default: the yaml's)")
    parser.add_argument("--pretrain-steps", type=option_type("pretrain_steps"), default=None,
                        help="pre-training steps (default: the yaml's, 2M)")
    parser.add_argument("--finetune-steps", type=option_type("finetune_steps"), default=None,
                        help="fine-tuning steps (default: the yaml's, 100k)")
    parser.add_argument("--eval-freq", type=option_type("eval_freq"), default=10_000, help="steps between evaluations")
    parser.add_argument("--eval-episodes", type=option_type("eval_episodes"), default=10,
                        help="deterministic episodes per evaluation")
    parser.add_argument(
        "--checkpoint-every", nargs="+", type=option_type("checkpoint_every"), default=None, metavar="STEPS",
        help="steps between checkpoints: one value for every run, or two (pre-training, fine-tuning); "
        "default 50000 20000; 0: none",
    )
    parser.add_argument("--device", type=device_type, default="auto", help="torch device (auto: CUDA if any)")
    parser.add_argument("--num-threads", type=option_type("num_threads"), default=None,
                        help="torch threads of each run (default: torch's)")
    parser.add_argument("--compile", action="store_true", help="compile_update=True: each update compiled as one graph")
    parser.add_argument("--tf32", action="store_true", help="TF32 matrix products on CUDA (off by default)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--verbose", type=option_type("verbose"), default=0, help="verbosity of the algorithms")


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
