"""``sb3-cic``: the command line of the package.

* ``train``: rl_zoo3's ``train`` with our algorithms and ``--conf-file zoo_configs/<algo>.yml``;
* ``finetune``: rl_zoo3's ``train`` on a task id from a pre-trained model (``-i model.zip``), where the
  algorithm loads with ``load_pretrained`` (see :class:`sb3_cic.zoo.PretrainedLoader`);
* ``enjoy``, ``record-video``: rl_zoo3's scripts with our algorithms registered;
* ``protocol``: the URLB protocol for one method and domain, in this process (:mod:`sb3_cic.study.driver`);
* ``study``, ``status``, ``pause``: the whole study on Ray, its state, and a stop that keeps every run's work
  (:mod:`sb3_cic.study`);
* ``report``: the score report of a study (:mod:`sb3_cic.report`);
* ``benchmark-report``: URLB's 12 tasks over several studies beside the CIC paper's Tables 5 and 6
  (:mod:`sb3_cic.report.benchmark`);
* ``skills``: a pre-trained policy under several skills, as one grid video and a plot (:mod:`sb3_cic.skill_video`).

Options ``train`` and ``finetune`` add to rl-zoo's: ``--small`` (CPU-sized hyperparameters,
:data:`sb3_cic.zoo.SMALL_HYPERPARAMS`); ``--compile`` (``compile_update=True``) and ``--tf32``
(:func:`~sb3_cic.common.fast_update.enable_tf32`); ``--eval-freq`` and ``--eval-episodes`` configure the yaml's
:class:`~sb3_cic.callbacks.URLBEvalCallback` (rl-zoo's own EvalCallback is off, ``--eval-freq -1``);
the grid sweep of the yaml's :class:`~sb3_cic.callbacks.SkillGridSweepCallback` follows ``learning_starts``.

A command that fails on bad input (an unknown method, a snapshot of another domain, a study folder made with
other settings, an unknown option, a folder that cannot be written...) prints one line, ``sb3-cic <command>: error:
<message>``, exits with code 2 and leaves nothing behind (see :data:`USER_ERRORS`, :data:`FILESYSTEM_ERRORS`,
:func:`main`); other errors raise as they are. Ctrl-C is one line that says how to go on (exit code 130), a warning
one line.
Every numeric option is checked for its type and range while the command line is read (each option's range beside
it; rl-zoo's counts too, :data:`ZOO_OPTIONS`), and no option may be abbreviated,
rl-zoo's included (``--smal`` is no ``--small``): an option neither sb3-cic nor rl-zoo knows is refused before
torch loads (:data:`ZOO_SCRIPT_OPTIONS`). ``--help`` shows each option's default and loads neither torch nor
Ray: the heavy modules are imported by the command handlers, after the arguments are read (``--zoo-help`` shows
rl-zoo's own options of ``train``, ``finetune``, ``enjoy`` and ``record-video``).
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import io
import os
import re
import runpy
import shutil
import signal
import sys
import warnings
from pathlib import Path
from typing import Any, Iterator, NoReturn, Sequence

import gymnasium as gym

from sb3_cic.command_line import argument_parser, check_device_available, device_type, option_type
from sb3_cic.common.arguments import POSITIVE_INT, SEED, STEPS, Range
from sb3_cic.study.cli import small_help

USAGE = """usage: sb3-cic {demo,train,finetune,enjoy,record-video,protocol,study,status,pause,report,benchmark-report,
               skills} [options]

  demo          the main job: a shipped CIC snapshot fine-tuned on a task beside DDPG from scratch (make demo)
  train         rl-zoo training (pre-training on URLB/<domain>-v0, or ddpg on a task id)
  finetune      rl-zoo training on a task id from a pre-trained model (-i model.zip)
  enjoy         rl-zoo's enjoy with the sb3-cic algorithms
  record-video  rl-zoo's record_video with the sb3-cic algorithms (needs MUJOCO_GL=egl or glfw)
  protocol      the URLB protocol: pre-train once, fine-tune on tasks x seeds, evaluate
  study         the whole study (methods x domains x tasks x seeds) as Ray tasks, resumable
  status        runs done / running / failed / pending of a study
  pause         the command that drives a study checkpoints its runs at their episode's end and stops
  report        per-task and rliable aggregate scores of a study
  benchmark-report  the 12 tasks over several studies, beside the CIC paper's Tables 5 and 6
  skills        a snapshot's policy under n skills: one grid video and a plot (needs MUJOCO_GL=egl)

Run `sb3-cic <command> --help` for the options of a command (train, finetune, enjoy, record-video: also
--zoo-help for rl-zoo's own)."""

#: the errors that mean bad input: reported in one line with exit code 2 (other exceptions raise as they are)
USER_ERRORS: tuple[type[BaseException], ...] = (ValueError, FileNotFoundError, PermissionError, gym.error.Error)

#: the ``OSError`` numbers of a file system that refuses a path (read-only, full, a file where a folder is needed...):
#: bad input too, reported in one line with exit code 2 by :func:`main`, as ``cannot <verb> <path>: <advice>``
FILESYSTEM_ERRORS: dict[int, tuple[str, str]] = {
    errno.EROFS: ("write", "read-only file system: choose a writable folder"),
    errno.EACCES: ("write", "permission denied: choose a folder you can write"),
    errno.EPERM: ("write", "operation not permitted: choose a folder you can write"),
    errno.ENOSPC: ("write", "no space left on the device"),
    errno.EDQUOT: ("write", "disk quota exceeded"),
    errno.EEXIST: ("use", "a file stands where a folder is needed: choose another path"),
    errno.ENOTDIR: ("use", "a file stands where a folder is needed: choose another path"),
    errno.EISDIR: ("use", "a folder stands where a file is needed: choose another path"),
    errno.ENAMETOOLONG: ("use", "file name too long"),
}

#: what an interrupted command says on how to go on
RESUME_ADVICE: dict[str, str] = {
    "protocol": "each run keeps its last checkpoint: run the same command to resume",
    "train": "run it again to start over (-i <model.zip> continues a saved model)",
    "finetune": "run it again to start over",
}


class UsageError(Exception):
    """A command line argparse refused (an unknown option, a missing argument...): a user error of :func:`main`."""


def _usage_error(parser: argparse.ArgumentParser, message: str) -> NoReturn:
    raise UsageError(message)


@contextlib.contextmanager
def _one_line_usage_errors() -> Iterator[None]:
    """Within the block, argparse's errors (ours and rl-zoo's) raise :class:`UsageError` instead of printing
    the usage and exiting: :func:`main` reports them in one line like the other user errors. rl-zoo's parsers,
    like ours, take no abbreviated option (``--smal`` is not ``--small``)."""
    saved_error, saved_parse = argparse.ArgumentParser.error, argparse.ArgumentParser.parse_known_args

    def parse_known_args(self: argparse.ArgumentParser, *args: Any, **kwargs: Any) -> Any:
        self.allow_abbrev = False
        return saved_parse(self, *args, **kwargs)

    argparse.ArgumentParser.error = _usage_error  # type: ignore[method-assign,assignment]
    argparse.ArgumentParser.parse_known_args = parse_known_args  # type: ignore[method-assign,assignment]
    try:
        yield
    finally:
        argparse.ArgumentParser.error = saved_error  # type: ignore[method-assign]
        argparse.ArgumentParser.parse_known_args = saved_parse  # type: ignore[method-assign]


#: rl-zoo's numeric options (their flags, range and help by name) that sb3-cic checks
#: before passing them on; rl-zoo's defaults hold when they are not given
ZOO_OPTIONS: dict[str, tuple[tuple[str, ...], Range, str]] = {
    "n_timesteps": (("-n", "--n-timesteps"), STEPS, "steps (default: the yaml's n_timesteps; enjoy, record-video: 1000)"),
    "seed": (("--seed",), SEED, "random seed (default: a random one; enjoy, record-video: 0)"),
    "num_threads": (("--num-threads",), POSITIVE_INT, "torch threads (default: torch's)"),
    "n_envs": (("--n-envs",), POSITIVE_INT, "envs (default: 1)"),
    "n_eval_envs": (("--n-eval-envs",), POSITIVE_INT, "rl-zoo's evaluation envs (default: 1)"),
    "save_freq": (("--save-freq",), POSITIVE_INT, "steps between saved checkpoints of the model (default: none)"),
    "log_interval": (("--log-interval",), POSITIVE_INT, "episodes between log outputs (default: the algorithm's)"),
    "exp_id": (("--exp-id",), Range(-1, integer=True), "experiment id (default: 0, the latest; -1: no experiment folder)"),
    "verbose": (("--verbose",), Range(0, 2, integer=True), "verbosity (default: 1)"),
}
#: the :data:`ZOO_OPTIONS` of each command that passes its options to rl-zoo
ZOO_COMMAND_OPTIONS: dict[str, tuple[str, ...]] = {
    "train": ("n_timesteps", "seed", "num_threads", "n_eval_envs", "save_freq", "log_interval", "verbose"),
    "finetune": ("n_timesteps", "seed", "num_threads", "n_eval_envs", "save_freq", "log_interval", "verbose"),
    "enjoy": ("n_timesteps", "seed", "num_threads", "n_envs", "exp_id", "verbose"),
    "record-video": ("n_timesteps", "seed", "n_envs", "exp_id"),
}

#: the options of rl-zoo's own scripts (rl_zoo3 2.9: ``train`` for sb3-cic ``train`` and ``finetune``, ``enjoy``,
#: ``record_video``): an option of a command line that neither sb3-cic nor rl-zoo knows (``--smal``, ``--save-frq``)
#: is refused while the arguments are read, before torch and rl-zoo load (tests/test_first_hour.py compares these
#: lists with rl-zoo's parsers)
ZOO_SCRIPT_OPTIONS: dict[str, frozenset[str]] = {
    "train": frozenset({
        "--algo", "--conf-file", "--device", "--env", "--env-kwargs", "--eval-env-kwargs", "--eval-episodes",
        "--eval-freq", "--gym-packages", "--help", "--hyperparams", "--log-folder", "--log-interval",
        "--max-total-trials", "--n-eval-envs", "--n-evaluations", "--n-jobs", "--n-startup-trials", "--n-timesteps",
        "--n-trials", "--no-optim-plots", "--num-threads", "--optimization-log-path", "--optimize-hyperparameters",
        "--progress", "--pruner", "--sampler", "--save-freq", "--save-replay-buffer", "--seed", "--storage",
        "--study-name", "--tensorboard-log", "--track", "--trained-agent", "--trial-id", "--truncate-last-trajectory",
        "--uuid", "--vec-env", "--verbose", "--wandb-entity", "--wandb-group", "--wandb-project-name", "--wandb-tags",
        "-P", "-conf", "-f", "-h", "-i", "-n", "-optimize", "-params", "-tags", "-tb", "-uuid",
    }),
    "enjoy": frozenset({
        "--algo", "--custom-objects", "--deterministic", "--device", "--env", "--env-kwargs", "--exp-id", "--folder",
        "--gym-packages", "--help", "--load-best", "--load-checkpoint", "--load-last-checkpoint", "--n-envs",
        "--n-timesteps", "--no-render", "--norm-reward", "--num-threads", "--progress", "--reward-log", "--seed",
        "--stochastic", "--verbose", "-P", "-f", "-h", "-n",
    }),
    "record_video": frozenset({
        "--algo", "--custom-objects", "--deterministic", "--env", "--env-kwargs", "--exp-id", "--folder", "--help",
        "--load-best", "--load-checkpoint", "--load-last-checkpoint", "--n-envs", "--n-timesteps", "--no-render",
        "--output-folder", "--seed", "--stochastic", "-f", "-h", "-n", "-o",
    }),
}


def _check_zoo_options(rest: Sequence[str], script: str) -> None:
    """:class:`UsageError` for an option of ``rest`` (what sb3-cic passes on to rl-zoo's ``script``) that rl-zoo does
    not know either (no abbreviation: ``--smal`` is not ``--small``); a negative number is a value, not an option.

    :param rest: the arguments left for rl-zoo
    :param script: ``"train"``, ``"enjoy"`` or ``"record_video"`` (:data:`ZOO_SCRIPT_OPTIONS`)
    """
    unknown = [arg for arg in rest if arg.startswith("-") and not re.fullmatch(r"-\.?\d.*", arg)
               and arg.split("=", 1)[0] not in ZOO_SCRIPT_OPTIONS[script]]
    if unknown:
        raise UsageError(f"unrecognized arguments: {' '.join(unknown)}")


def _add_zoo_options(parser: argparse.ArgumentParser, command: str) -> None:
    """The checked rl-zoo options of ``command`` (:data:`ZOO_COMMAND_OPTIONS`), default None (rl-zoo's)."""
    for name in ZOO_COMMAND_OPTIONS[command]:
        flags, bound, text = ZOO_OPTIONS[name]
        parser.add_argument(*flags, dest=name, type=option_type(bound), default=None, help=text)


def _zoo_options(known: argparse.Namespace, command: str) -> list[str]:
    """The checked rl-zoo options given (:func:`_add_zoo_options`), as rl-zoo arguments."""
    args: list[str] = []
    for name in ZOO_COMMAND_OPTIONS[command]:
        if getattr(known, name) is not None:
            args += [ZOO_OPTIONS[name][0][-1], str(getattr(known, name))]
    return args


def passthrough_parser(command: str) -> argparse.ArgumentParser:
    """The options of ``sb3-cic enjoy`` / ``record-video`` that sb3-cic reads or checks; the others go to rl-zoo's
    script as they are (``--zoo-help`` lists them).

    :param command: ``"enjoy"`` or ``"record-video"``
    """
    parser = argument_parser(
        f"sb3-cic {command}",
        f"rl-zoo's {command.replace('-', '_')} with the sb3-cic algorithms"
        + (" (needs MUJOCO_GL=egl or glfw)" if command == "record-video" else ""),
        epilog=f"Other options are rl-zoo's {command.replace('-', '_')} options, passed on as given: sb3-cic {command} "
        "--zoo-help lists them (it loads torch: a few seconds).",
    )
    parser.add_argument("--zoo-help", action="store_true", help=f"rl-zoo's {command.replace('-', '_')} options")
    parser.add_argument("-f", "--folder", default="logs", help="log folder")
    if command == "enjoy":  # rl-zoo's record_video has no --device
        parser.add_argument("--device", type=device_type, default=None,
                            help="torch device (default: rl-zoo's, auto: CUDA if any); cuda without one is refused")
    _add_zoo_options(parser, command)
    return parser


def _passthrough_args(argv: Sequence[str], command: str) -> list[str]:
    """The rl-zoo arguments of ``sb3-cic enjoy`` / ``record-video`` (``["--help"]`` for ``--zoo-help``)."""
    if "--zoo-help" in argv:
        return ["--help"]
    known, rest = passthrough_parser(command).parse_known_args(list(argv))
    _check_zoo_options(rest, command.replace("-", "_"))
    device = getattr(known, "device", None)
    if device is not None:
        check_device_available(device)
    return ["-f", known.folder, *_zoo_options(known, command), *rest, *(["--device", device] if device else [])]


def zoo_parser(command: str) -> argparse.ArgumentParser:
    """The options of ``sb3-cic train`` / ``finetune`` (``command``) that sb3-cic reads or checks; the others go to
    rl-zoo's ``train`` as they are (``--zoo-help`` lists them).

    :param command: ``"train"`` or ``"finetune"``
    """
    finetune = command == "finetune"
    parser = argument_parser(
        f"sb3-cic {command}",
        "rl-zoo training on a task id from a pre-trained model (-i model.zip, loaded with load_pretrained)"
        if finetune else "rl-zoo training: pre-training on URLB/<domain>-v0, or ddpg on a task id",
        epilog="Other options are rl-zoo's train options, passed on as given: sb3-cic "
        f"{command} --zoo-help lists them (it loads torch: a few seconds).",
    )
    parser.add_argument("--zoo-help", action="store_true", help="rl-zoo's train options")
    parser.add_argument("--algo", default="cic", help="cic, icm, ..., or ddpg")
    parser.add_argument("--env", required=True, help="the task id (URLB/<domain>-<task>-v0)" if finetune
                        else "env id: URLB/<domain>-v0 to pre-train (a method), a task id (ddpg)")
    if finetune:
        parser.add_argument("-i", "--trained-agent", required=True, help="the pre-trained model (.zip)")
    parser.add_argument("-conf", "--conf-file", default=None, help="rl-zoo yaml (default: zoo_configs/<algo>.yml)")
    parser.add_argument("-params", "--hyperparams", nargs="+", default=[],
                        help="rl-zoo's key:value overrides of the yaml (e.g. batch_size:256; default: none)")
    parser.add_argument("--small", action="store_true", help=small_help())
    parser.add_argument("--eval-freq", type=option_type(POSITIVE_INT), default=None,
                        help="steps between the yaml's URLBEvalCallback evaluations (default: the yaml's)")
    parser.add_argument("--eval-episodes", type=option_type(POSITIVE_INT), default=None,
                        help="episodes of each of those evaluations (default: the yaml's)")
    parser.add_argument("-f", "--log-folder", default="logs", help="log folder")
    parser.add_argument("--compile", action="store_true", help="compile_update=True: the update compiled as one graph")
    parser.add_argument("--tf32", action="store_true", help="TF32 matrix products on CUDA")
    parser.add_argument("--device", type=device_type, default=None,
                        help="torch device (default: rl-zoo's, auto: CUDA if any); cuda without one is refused")
    _add_zoo_options(parser, command)
    return parser


def _zoo_args(argv: Sequence[str], finetune: bool) -> tuple[list[str], str, str, str]:
    """Turn our train/finetune arguments into rl-zoo train arguments (``["--help"]`` for ``--zoo-help``)."""
    argv = list(argv)
    if "--zoo-help" in argv:
        return ["--help"], "", "", ""
    known, rest = zoo_parser("finetune" if finetune else "train").parse_known_args(argv)
    _check_zoo_options(rest, "train")  # a typo is refused here, before torch and rl-zoo load
    if finetune and _reward_free(known.env):
        raise ValueError(
            f"{known.env} is a reward-free pre-training env (its reward is 0: the skill sweep would choose on zero "
            "returns and nothing would be learned): fine-tune on a task id, e.g. "
            f"{known.env.replace('-v0', '-<task>-v0')}"
        )
    if known.device is not None:
        check_device_available(known.device)
    from sb3_cic import zoo
    from sb3_cic.common.fast_update import enable_tf32
    from sb3_cic.common.save_util import check_saved_model

    algo = known.algo.lower()
    cls = zoo.get_algo(algo)
    config = known.conf_file or str(zoo.default_config(algo))
    is_task = known.env.removeprefix("URLB/").count("-") >= 2
    if not finetune and is_task and zoo.has_reward_module(cls):
        raise ValueError(
            f"{known.env} is a task: pre-train {algo} on the domain's reward-free id (URLB/<domain>-v0), "
            "then fine-tune with `sb3-cic finetune -i <model.zip>`"
        )
    if finetune:
        rest = ["-i", known.trained_agent, *rest]
    for key in ("-i", "--trained-agent"):  # train -i: rl-zoo continues training a saved model
        if key in rest:
            model = rest[rest.index(key) + 1] if rest.index(key) + 1 < len(rest) else ""
            if not model.endswith(".zip") or not os.path.isfile(model):
                raise ValueError(f"{key} {model}: no saved model (.zip) there")
            check_saved_model(model).check_class(cls)  # before rl-zoo makes its run folder
    overrides = {**(zoo.SMALL_HYPERPARAMS if known.small else {}), **_parse_hyperparams(zoo, known.hyperparams)}
    if known.compile:
        overrides["compile_update"] = True
    if known.tf32:
        enable_tf32()
    overrides = zoo.zoo_overrides(config, known.env, overrides, known.eval_freq, known.eval_episodes)
    args = ["--algo", algo, "--env", known.env, "--conf-file", config, "-f", known.log_folder, "--eval-freq", "-1", *rest]
    args += _zoo_options(known, "finetune" if finetune else "train")
    if known.device is not None:
        args += ["--device", known.device]
    if overrides:
        args += ["--hyperparams", *zoo.format_hyperparams(overrides)]
    return args, algo, known.env, known.log_folder


def _reward_free(env_id: str) -> bool:
    """Whether ``env_id`` is a reward-free pre-training id (``URLB/<domain>-v0``, the gridworld): reward 0."""
    from sb3_cic.envs import DOMAIN_TASKS, OTHER_ENVS

    return env_id in OTHER_ENVS or env_id in {f"URLB/{domain}-v0" for domain in DOMAIN_TASKS}


def _parse_hyperparams(zoo: Any, items: Sequence[str]) -> dict[str, Any]:
    """``--hyperparams key:value ...`` as rl-zoo reads them (:func:`sb3_cic.zoo.parse_hyperparams`); a ``ValueError``
    naming the item whose value is no Python expression (``batch_size:abc``).

    :param zoo: the :mod:`sb3_cic.zoo` module
    :param items: the ``key:value`` strings
    """
    hyperparams: dict[str, Any] = {}
    for item in items:
        if ":" not in item:
            raise ValueError(f"--hyperparams {item}: expected key:value (e.g. batch_size:256)")
        try:
            hyperparams.update(zoo.parse_hyperparams([item]))
        except Exception as error:  # eval of the value: NameError, SyntaxError...
            raise ValueError(
                f"--hyperparams {item}: the value is not a Python expression ({type(error).__name__}: {error}); "
                "quote a string, e.g. key:'text'"
            ) from None
    return hyperparams


class _BuildRecorder:
    """An ``rl_zoo3.ALGOS`` entry that records whether rl-zoo built (or loaded) the model: a user error before
    that removes the run folder rl-zoo made (:func:`_run_zoo_train`); after it, training has begun and the
    folder stays.

    :param entry: the algorithm class (or its :class:`~sb3_cic.zoo.PretrainedLoader`)
    """

    def __init__(self, entry: Any) -> None:
        self.entry = entry
        self.__name__ = entry.__name__
        self.built = False
        #: called once the model is built (:func:`_run_zoo_train` prints what rl-zoo printed until then)
        self.on_built: Any = None

    def _build(self, build: Any, *args: Any, **kwargs: Any) -> Any:
        try:
            model = build(*args, **kwargs)
        except TypeError as error:  # a hyperparameter the algorithm does not take (--hyperparams or the yaml)
            if "unexpected keyword argument" not in str(error):
                raise
            raise ValueError(f"{error}: not a hyperparameter of {self.__name__} (--hyperparams or the yaml)") from None
        self.built = True
        if self.on_built is not None:
            self.on_built()
        return model

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        return self._build(self.entry, *args, **kwargs)

    def load(self, *args: Any, **kwargs: Any) -> Any:
        """The entry's ``load``."""
        return self._build(self.entry.load, *args, **kwargs)


def _remover(folder: Path) -> Any:
    """A function that removes what was made of ``folder`` since this call: the outermost of ``folder`` and its
    parents that did not exist then, or else the entries that appeared in ``folder``.

    :param folder: the folder a command writes into
    """
    missing = [path for path in (*reversed(folder.parents), folder) if not path.exists()]
    before = set(folder.iterdir()) if not missing and folder.is_dir() else set()

    def remove() -> None:
        if missing:
            shutil.rmtree(missing[0], ignore_errors=True)
        elif folder.is_dir():
            for path in set(folder.iterdir()) - before:
                shutil.rmtree(path, ignore_errors=True) if path.is_dir() else path.unlink(missing_ok=True)

    return remove


def _run_zoo_train(args: list[str], algo: str | None = None, log_folder: str | None = None) -> None:
    """rl_zoo3's ``train`` with ``args``; on a user error before the model of ``algo`` is built, the run folder
    it made under ``log_folder/algo`` is removed (see :data:`USER_ERRORS`), and what rl-zoo printed until then (its
    hyperparameters) is not shown: the error is the one line of the command. Once the model is built, that output
    is printed and training prints as it goes."""
    from rl_zoo3 import ALGOS as algos
    from rl_zoo3.train import train

    entry = algos.get(algo or "")
    recorder = _BuildRecorder(entry) if entry is not None and log_folder is not None else None
    remove = _remover(Path(str(log_folder)) / str(algo)) if recorder is not None else None
    if recorder is not None:
        algos[str(algo)] = recorder
    argv, stdout = sys.argv, sys.stdout
    held = io.StringIO()

    def release() -> None:
        if sys.stdout is held:
            sys.stdout = stdout
            stdout.write(held.getvalue())

    if recorder is not None:
        recorder.on_built = release
        sys.stdout = held
    sys.argv = ["rl_zoo3 train", *args]
    try:
        train()
    except (*USER_ERRORS, UsageError, OSError):
        if remove is not None and recorder is not None and not recorder.built:
            remove()
            sys.stdout = stdout  # what rl-zoo printed before the error is dropped
        raise
    finally:
        release()
        sys.argv = argv
        if recorder is not None:
            algos[str(algo)] = entry


def train(argv: Sequence[str]) -> None:
    """``sb3-cic train``: rl_zoo3's train with the sb3-cic algorithms and configs."""
    args, algo, _, log_folder = _zoo_args(argv, finetune=False)
    from sb3_cic import zoo

    zoo.register_algos()
    _run_zoo_train(args, algo, log_folder)


def finetune(argv: Sequence[str]) -> Path | None:
    """``sb3-cic finetune``: rl_zoo3's train from a pre-trained model, loaded with ``load_pretrained``.

    A replay buffer saved beside the pre-trained model is not loaded (URLB fine-tuning starts with an
    empty buffer): the model is read from a temporary copy. After training, the chosen fine-tuning
    skill is written into the run's ``config.yml`` (``env_wrapper`` ``skill``) so that ``enjoy`` and
    ``record-video`` use it. Returns the run folder.
    """
    args, algo, env_id, log_folder = _zoo_args(argv, finetune=True)
    import shutil
    import tempfile

    from huggingface_sb3 import EnvironmentName
    from rl_zoo3.utils import get_latest_run_id

    from sb3_cic import zoo
    from sb3_cic.common.save_util import read_saved_data

    algos = zoo.register_algos()
    if args == ["--help"]:
        _run_zoo_train(args)
        return None
    key = "-i" if "-i" in args else "--trained-agent"
    index = args.index(key) + 1
    pretrained = Path(args[index])
    original = algos[algo]
    with tempfile.TemporaryDirectory() as tmp:
        if (pretrained.parent / "replay_buffer.pkl").exists():
            print(f"Not loading {pretrained.parent / 'replay_buffer.pkl'}: fine-tuning starts with an empty buffer")
            args[index] = str(shutil.copy(pretrained, Path(tmp) / pretrained.name))
        algos[algo] = zoo.PretrainedLoader(original)  # type: ignore[assignment]
        try:
            _run_zoo_train(args, algo, log_folder)
        finally:
            algos[algo] = original
    env_name = EnvironmentName(env_id)
    run = Path(log_folder) / algo / f"{env_name}_{get_latest_run_id(os.path.join(log_folder, algo), env_name)}"
    model = run / f"{env_name}.zip"
    config_file = run / env_name / "config.yml"
    if model.is_file() and config_file.is_file():
        skill = read_saved_data(model).get("finetune_skill")
        if skill is not None:
            _record_skill(config_file, [float(v) for v in skill])
    return run


def _record_skill(config_file: Path, skill: list[float]) -> None:
    """Add ``skill`` to the :func:`sb3_cic.zoo.skill_wrapper` entry of a saved rl-zoo ``config.yml``."""
    import yaml

    with open(config_file) as file:
        config = yaml.load(file, Loader=yaml.UnsafeLoader)
    wrappers = config.get("env_wrapper")
    items = wrappers if isinstance(wrappers, list) else [wrappers]
    for item in items:
        if isinstance(item, dict) and "sb3_cic.zoo.skill_wrapper" in item:
            item["sb3_cic.zoo.skill_wrapper"] = {**(item["sb3_cic.zoo.skill_wrapper"] or {}), "skill": skill}
    with open(config_file, "w") as file:
        yaml.dump(config, file)


@contextlib.contextmanager
def _assertions_as_user_errors() -> Iterator[None]:
    """rl-zoo's ``enjoy`` and ``record_video`` check their input with ``assert`` (a missing folder...): a ``ValueError``."""
    try:
        yield
    except AssertionError as error:
        raise ValueError(str(error) or "rl-zoo refused the arguments") from error


def enjoy(argv: Sequence[str]) -> None:
    """``sb3-cic enjoy``: rl_zoo3's enjoy with the sb3-cic algorithms (default folder ``logs``)."""
    args = _passthrough_args(argv, "enjoy")
    from rl_zoo3.enjoy import enjoy as zoo_enjoy

    from sb3_cic import zoo

    zoo.register_algos()
    saved, sys.argv = sys.argv, ["rl_zoo3 enjoy", *args]
    try:
        with _assertions_as_user_errors():
            zoo_enjoy()
    finally:
        sys.argv = saved


def record_video(argv: Sequence[str]) -> None:
    """``sb3-cic record-video``: rl_zoo3's record_video script with the sb3-cic algorithms."""
    args = _passthrough_args(argv, "record-video")
    from sb3_cic import zoo

    zoo.register_algos()
    saved, sys.argv = sys.argv, ["rl_zoo3 record_video", *args]
    try:
        with _assertions_as_user_errors():
            runpy.run_module("rl_zoo3.record_video", run_name="__main__")
    finally:
        sys.argv = saved


def _run(command: str, argv: list[str]) -> int:
    """Run one command; return its exit code."""
    if command == "demo":
        from sb3_cic.demo import main as demo_main

        demo_main(argv)
    elif command == "train":
        train(argv)
    elif command == "finetune":
        finetune(argv)
    elif command == "enjoy":
        enjoy(argv)
    elif command in ("record-video", "record_video"):
        record_video(argv)
    elif command == "protocol":
        from sb3_cic.study.cli import protocol_parser

        args = protocol_parser().parse_args(argv)  # --help and refused options before the protocol's code (torch) loads
        check_device_available(args.device)
        from sb3_cic.study.cli import interruptible, protocol_main

        with interruptible():  # SIGTERM too: :func:`main` says how to resume
            protocol_main(argv)
    elif command in ("study", "status", "pause"):
        from sb3_cic.study import cli as study_cli

        return {"study": study_cli.main, "status": study_cli.status_main, "pause": study_cli.pause_main}[command](argv)
    elif command == "report":
        from sb3_cic.report.commands import report_main

        report_main(argv)
    elif command == "benchmark-report":
        from sb3_cic.report.commands import benchmark_main

        benchmark_main(argv)
    elif command == "skills":
        from sb3_cic.skill_video import main as skills_main

        skills_main(argv)
    else:
        _fail("sb3-cic", f"unknown command {command!r}", usage=True)
    return 0


@contextlib.contextmanager
def _one_line_warnings(prog: str) -> Iterator[None]:
    """Within the block, a warning prints as one line, ``<prog>: warning: <message>`` (not Python's two lines of
    file, line number and source)."""
    saved = warnings.formatwarning

    def format_warning(message: Any, category: Any, filename: str, lineno: int, line: str | None = None) -> str:
        text = " ".join(part.strip() for part in str(message).splitlines() if part.strip())
        return f"{prog}: warning: {text}\n"

    warnings.formatwarning = format_warning  # type: ignore[assignment]
    try:
        yield
    finally:
        warnings.formatwarning = saved


def _fail(prog: str, message: str, usage: bool = False) -> NoReturn:
    """Print ``<prog>: error: <message>`` as one line on stderr (and, for a refused command line, where the
    help is) and exit with code 2."""
    text = " ".join(line.strip() for line in message.splitlines() if line.strip())
    hint = f" (see {prog} --help)" if usage else ""
    print(f"{prog}: error: {text}{hint}", file=sys.stderr)
    raise SystemExit(2)


def main(argv: Sequence[str] | None = None) -> None:
    """Entry point of ``sb3-cic``.

    Bad input (:data:`USER_ERRORS`, a refused command line, a command's ``SystemExit`` with a message, a file system
    that refuses a write: :data:`FILESYSTEM_ERRORS`) is one line on stderr and exit code 2, with nothing of the
    failed command left behind. Ctrl-C (SIGINT; SIGTERM for ``protocol`` and ``study``) is one line that says how to
    go on (:data:`RESUME_ADVICE`), exit code 130 (143). A warning is one line (:func:`_one_line_warnings`).

    :param argv: arguments (default: ``sys.argv[1:]``)
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(USAGE)
        return
    command, rest = argv[0], argv[1:]
    prog = f"sb3-cic {command}"
    try:
        with _one_line_usage_errors(), _one_line_warnings(prog):
            code = _run(command, rest)
    except UsageError as error:
        _fail(prog, str(error), usage=True)
    except USER_ERRORS as error:
        _fail(prog, str(error) or type(error).__name__)
    except OSError as error:
        if error.errno not in FILESYSTEM_ERRORS:
            raise
        verb, advice = FILESYSTEM_ERRORS[error.errno]
        where = f" {os.fsdecode(error.filename)}" if error.filename is not None else ""
        _fail(prog, f"cannot {verb}{where}: {advice} ({error.strerror})")
    except KeyboardInterrupt as interrupt:
        signum = getattr(interrupt, "signum", signal.SIGINT)
        advice = RESUME_ADVICE.get(command)
        print(f"{prog}: interrupted ({signal.Signals(signum).name})" + (f"; {advice}" if advice else ""), file=sys.stderr)
        raise SystemExit(128 + signum) from None
    except SystemExit as exit_:
        if isinstance(exit_.code, str):  # a command's own message
            _fail(prog, exit_.code)
        raise
    if code:
        raise SystemExit(code)


if __name__ == "__main__":
    main()
