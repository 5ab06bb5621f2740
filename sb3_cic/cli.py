"""``sb3-cic``: the command line of the package.

* ``train``: rl_zoo3's ``train`` with our algorithms and ``--conf-file zoo_configs/<algo>.yml``;
* ``finetune``: rl_zoo3's ``train`` on a task id from a pre-trained model (``-i model.zip``), where the
  algorithm loads with ``load_pretrained`` (see :class:`sb3_cic.zoo.PretrainedLoader`);
* ``enjoy``, ``record-video``: rl_zoo3's scripts with our algorithms registered;
* ``protocol``: the URLB protocol (:mod:`sb3_cic.protocol`);
* ``study``, ``status``: the whole study on Ray and its state (:mod:`sb3_cic.study`);
* ``report``: the score report of a study (:mod:`sb3_cic.evaluation`);
* ``skills``: a pre-trained policy under several skills, as one grid video and a plot (:mod:`sb3_cic.skill_video`).

Options ``train`` and ``finetune`` add to rl-zoo's: ``--small`` (CPU-sized hyperparameters,
:data:`sb3_cic.zoo.SMALL_HYPERPARAMS`); ``--eval-freq`` and ``--eval-episodes`` configure the yaml's
:class:`~sb3_cic.callbacks.URLBEvalCallback` (rl-zoo's own EvalCallback is off, ``--eval-freq -1``);
the grid sweep of the yaml's :class:`~sb3_cic.callbacks.SkillGridSweepCallback` follows ``learning_starts``.
"""

from __future__ import annotations

import argparse
import os
import runpy
import sys
from pathlib import Path
from typing import Sequence

import yaml

from sb3_cic import zoo

USAGE = """usage: sb3-cic {train,finetune,enjoy,record-video,protocol,study,status,report,skills} [options]

  train         rl-zoo training (pre-training on URLB/<domain>-v0, or ddpg on a task id)
  finetune      rl-zoo training on a task id from a pre-trained model (-i model.zip)
  enjoy         rl-zoo's enjoy with the sb3-cic algorithms
  record-video  rl-zoo's record_video with the sb3-cic algorithms (needs MUJOCO_GL=egl or glfw)
  protocol      the URLB protocol: pre-train once, fine-tune on tasks x seeds, evaluate
  study         the whole study (methods x domains x tasks x seeds) as Ray tasks, resumable
  status        runs done / running / failed / pending of a study
  report        per-task and rliable aggregate scores of a study
  skills        a snapshot's policy under n skills: one grid video and a plot (needs MUJOCO_GL=egl)

Run `sb3-cic <command> --help` for the options (train/finetune/enjoy show rl-zoo's)."""


def _zoo_args(argv: Sequence[str], finetune: bool) -> tuple[list[str], str, str, str]:
    """Turn our train/finetune arguments into rl-zoo train arguments."""
    parser = argparse.ArgumentParser(add_help=False)
    parser.add_argument("--algo", default="cic")
    parser.add_argument("--env", default=None)
    parser.add_argument("-conf", "--conf-file", default=None)
    parser.add_argument("-params", "--hyperparams", nargs="+", default=[])
    parser.add_argument("--small", action="store_true")
    parser.add_argument("--eval-freq", type=int, default=None)
    parser.add_argument("--eval-episodes", type=int, default=None)
    parser.add_argument("-f", "--log-folder", default="logs")
    known, rest = parser.parse_known_args(list(argv))
    if known.env is None or "-h" in rest or "--help" in rest:
        print(
            "sb3-cic options: --small (CPU-sized hyperparameters), --eval-freq N and --eval-episodes N (the yaml's "
            "URLBEvalCallback), --conf-file (default zoo_configs/<algo>.yml), -f/--log-folder (default logs)"
            + (", -i <pre-trained model.zip> (required)" if finetune else "")
            + ". rl-zoo's train options follow.\n"
        )
        return ["--help"], known.algo, "", known.log_folder
    algo = known.algo.lower()
    cls = zoo.get_algo(algo)
    config = known.conf_file or str(zoo.default_config(algo))
    is_task = known.env.removeprefix("URLB/").count("-") >= 2
    if not finetune and is_task and zoo.has_reward_module(cls):
        raise SystemExit(
            f"{known.env} is a task: pre-train {algo} on the domain's reward-free id (URLB/<domain>-v0), "
            "then fine-tune with `sb3-cic finetune -i <model.zip>`"
        )
    if finetune and not any(arg in rest for arg in ("-i", "--trained-agent")):
        raise SystemExit("sb3-cic finetune needs the pre-trained model: -i <model.zip>")
    overrides = {**(zoo.SMALL_HYPERPARAMS if known.small else {}), **zoo.parse_hyperparams(known.hyperparams)}
    overrides = zoo.zoo_overrides(config, known.env, overrides, known.eval_freq, known.eval_episodes)
    args = ["--algo", algo, "--env", known.env, "--conf-file", config, "-f", known.log_folder, "--eval-freq", "-1", *rest]
    if overrides:
        args += ["--hyperparams", *zoo.format_hyperparams(overrides)]
    return args, algo, known.env, known.log_folder


def _run_zoo_train(args: list[str]) -> None:
    from rl_zoo3.train import train

    argv = sys.argv
    sys.argv = ["rl_zoo3 train", *args]
    try:
        train()
    finally:
        sys.argv = argv


def train(argv: Sequence[str]) -> None:
    """``sb3-cic train``: rl_zoo3's train with the sb3-cic algorithms and configs."""
    zoo.register_algos()
    args, _, _, _ = _zoo_args(argv, finetune=False)
    _run_zoo_train(args)


def finetune(argv: Sequence[str]) -> Path | None:
    """``sb3-cic finetune``: rl_zoo3's train from a pre-trained model, loaded with ``load_pretrained``.

    A replay buffer saved beside the pre-trained model is not loaded (URLB fine-tuning starts with an
    empty buffer): the model is read from a temporary copy. After training, the chosen fine-tuning
    skill is written into the run's ``config.yml`` (``env_wrapper`` ``skill``) so that ``enjoy`` and
    ``record-video`` use it. Returns the run folder.
    """
    import shutil
    import tempfile

    from huggingface_sb3 import EnvironmentName
    from rl_zoo3.utils import get_latest_run_id
    from sb3_cic.common.save_util import read_saved_data

    algos = zoo.register_algos()
    args, algo, env_id, log_folder = _zoo_args(argv, finetune=True)
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
            _run_zoo_train(args)
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
    with open(config_file) as file:
        config = yaml.load(file, Loader=yaml.UnsafeLoader)
    wrappers = config.get("env_wrapper")
    items = wrappers if isinstance(wrappers, list) else [wrappers]
    for item in items:
        if isinstance(item, dict) and "sb3_cic.zoo.skill_wrapper" in item:
            item["sb3_cic.zoo.skill_wrapper"] = {**(item["sb3_cic.zoo.skill_wrapper"] or {}), "skill": skill}
    with open(config_file, "w") as file:
        yaml.dump(config, file)


def _with_default_folder(argv: Sequence[str]) -> list[str]:
    argv = list(argv)
    if not any(arg in argv for arg in ("-f", "--folder")):
        argv = ["-f", "logs", *argv]
    return argv


def enjoy(argv: Sequence[str]) -> None:
    """``sb3-cic enjoy``: rl_zoo3's enjoy with the sb3-cic algorithms (default folder ``logs``)."""
    from rl_zoo3.enjoy import enjoy as zoo_enjoy

    zoo.register_algos()
    saved, sys.argv = sys.argv, ["rl_zoo3 enjoy", *_with_default_folder(argv)]
    try:
        zoo_enjoy()
    finally:
        sys.argv = saved


def record_video(argv: Sequence[str]) -> None:
    """``sb3-cic record-video``: rl_zoo3's record_video script with the sb3-cic algorithms."""
    zoo.register_algos()
    saved, sys.argv = sys.argv, ["rl_zoo3 record_video", *_with_default_folder(argv)]
    try:
        runpy.run_module("rl_zoo3.record_video", run_name="__main__")
    finally:
        sys.argv = saved


def main(argv: Sequence[str] | None = None) -> None:
    """Entry point of ``sb3-cic``.

    :param argv: arguments (default: ``sys.argv[1:]``)
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(USAGE)
        return
    command, rest = argv[0], argv[1:]
    if command == "train":
        train(rest)
    elif command == "finetune":
        finetune(rest)
    elif command == "enjoy":
        enjoy(rest)
    elif command in ("record-video", "record_video"):
        record_video(rest)
    elif command == "protocol":
        from sb3_cic.protocol import main as protocol_main

        protocol_main(rest)
    elif command in ("study", "status"):
        from sb3_cic.study import cli as study_cli

        code = (study_cli.main if command == "study" else study_cli.status_main)(rest)
        if code:
            raise SystemExit(code)
    elif command == "report":
        from sb3_cic.evaluation import main as report_main

        report_main(rest)
    elif command == "skills":
        from sb3_cic.skill_video import main as skills_main

        skills_main(rest)
    else:
        raise SystemExit(f"unknown command {command!r}\n{USAGE}")


if __name__ == "__main__":
    main()
