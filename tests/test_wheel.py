"""The package as a user installs it: a wheel, installed (not editable) into a fresh virtual environment, used from
an empty folder outside the repository.

The wheel is built from this checkout (``pip wheel --no-deps --no-build-isolation``) and installed with
``--no-deps`` into a new virtual environment; that environment reaches the dependencies through a ``.pth`` line
naming the test environment's ``site-packages``, which adds the folder to ``sys.path`` but runs none of its own
``.pth`` files, so the checkout's editable install is not on the path: what runs is what the wheel holds. Each
command runs in an empty folder with a clean ``PYTHONPATH``, and the tests check that ``sb3_cic`` was imported
from the fresh environment.
"""

from __future__ import annotations

import json
import os
import site
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The wheel of this checkout."""
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--quiet", "-w", str(out), str(ROOT)],
        check=True, cwd=out,
    )
    (path,) = out.glob("sb3_cic-*.whl")
    return path


@pytest.fixture(scope="module")
def installed(wheel: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A fresh virtual environment with the wheel installed (not editable); returns its ``bin`` folder."""
    venv = tmp_path_factory.mktemp("venv")
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    python = venv / "bin" / "python"
    purelib = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
        check=True, capture_output=True, text=True,
    ).stdout.strip()
    # the dependencies: this environment's site-packages, whose .pth files (the editable install) are not run
    dependencies = {sysconfig.get_path("purelib"), sysconfig.get_path("platlib"), *site.getsitepackages()}
    Path(purelib, "test_dependencies.pth").write_text("\n".join(sorted(dependencies)) + "\n")
    subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "--no-index", "--quiet", str(wheel)],
        check=True,
    )
    return venv / "bin"


def _run(command: list[str], cwd: Path, timeout: float = 600) -> subprocess.CompletedProcess:
    env = {key: value for key, value in os.environ.items() if key not in ("PYTHONPATH", "PYTHONHOME")}
    env["MUJOCO_GL"] = "disable"
    result = subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert result.returncode == 0, f"{command} -> {result.returncode}\n{result.stdout[-3000:]}\n{result.stderr[-3000:]}"
    return result


def test_the_wheel_carries_the_environments_the_yaml_files_and_the_snapshots(wheel: Path):
    names = zipfile.ZipFile(wheel).namelist()
    tops = {name.split("/")[0] for name in names if not name.split("/")[0].endswith(".dist-info")}
    assert tops == {"sb3_cic"}, f"top-level names other than sb3_cic: {tops}"  # no top-level ``envs``
    shipped = {path.name for path in (ROOT / "zoo_configs").glob("*.yml")}
    assert {name.rpartition("/")[2] for name in names if name.startswith("sb3_cic/zoo_configs/")} >= shipped
    for folder in ("envs", "envs/tasks"):  # every module of the repository's envs/ is in sb3_cic/envs/
        for module in (ROOT / folder).glob("*.py"):
            assert f"sb3_cic/{folder}/{module.name}" in names
    for folder in ("sb3_cic", *(str(p.relative_to(ROOT)) for p in (ROOT / "sb3_cic").iterdir() if p.is_dir())):
        for module in (ROOT / folder).glob("*.py"):
            assert f"{folder}/{module.name}" in names, f"{folder}/{module.name} is not in the wheel"
    for snapshot in (ROOT / "sb3_cic" / "pretrained").glob("*.zip"):
        assert f"sb3_cic/pretrained/{snapshot.name}" in names


def test_the_installed_package_is_the_wheel_and_its_environments_import(installed: Path, tmp_path: Path):
    result = _run([str(installed / "python"), "-c", (
        "import sb3_cic, sb3_cic.envs, gymnasium as gym; from sb3_cic.zoo import CONFIG_DIR; "
        "print(sb3_cic.__file__); print(sb3_cic.envs.__file__); print(CONFIG_DIR); "
        "print(gym.make('URLB/jaco-reach_top_left-v0').reset(seed=0)[0].shape)"
    )], tmp_path)
    package, environments, configs, shape = result.stdout.strip().splitlines()
    venv = installed.parent
    for path in (package, environments, configs):
        assert Path(path).is_relative_to(venv) and not Path(path).is_relative_to(ROOT), path
    assert (Path(configs) / "cic.yml").is_file()
    assert shape == "(55,)"


def test_a_users_own_envs_folder_does_not_shadow_the_environments(installed: Path, tmp_path: Path):
    """A project with a folder ``envs/`` of its own (a common name in RL code) runs a script from there."""
    (tmp_path / "envs").mkdir()
    (tmp_path / "envs" / "__init__.py").write_text("WHOSE = 'the user'\n")
    (tmp_path / "train.py").write_text(
        "import envs\nimport gymnasium as gym\nimport sb3_cic\n"
        "model = sb3_cic.CIC('MlpPolicy', gym.make('URLB/walker-v0'), policy_kwargs={'hidden_dim': 16},\n"
        "                    batch_size=8, learning_starts=20)\n"
        "model.learn(40)\nprint(envs.WHOSE, type(model).__name__, model.num_timesteps)\n"
    )
    result = _run([str(installed / "python"), "train.py"], tmp_path)
    assert result.stdout.strip().splitlines()[-1] == "the user CIC 40"


def test_the_command_line_trains_fine_tunes_runs_the_demo_and_the_protocol_from_an_empty_folder(installed: Path, tmp_path: Path):
    sb3_cic = str(installed / "sb3-cic")
    # jaco: 250-step episodes, so that the evaluation at the fine-tuning's step 0 (10 episodes) stays short
    _run([sb3_cic, "train", "--algo", "cic", "--env", "URLB/jaco-v0", "--small", "-n", "200",
          "--hyperparams", "learning_starts:100"], tmp_path)
    pretrained = tmp_path / "logs" / "cic" / "URLB-jaco-v0_1" / "URLB-jaco-v0.zip"
    assert pretrained.is_file(), sorted(str(p) for p in tmp_path.rglob("*"))
    _run([sb3_cic, "finetune", "--algo", "cic", "--env", "URLB/jaco-reach_top_left-v0", "-i", str(pretrained), "--small",
          "-n", "200", "--hyperparams", "learning_starts:100"], tmp_path)
    assert (tmp_path / "logs" / "cic" / "URLB-jaco-reach_top_left-v0_1" / "URLB-jaco-reach_top_left-v0.zip").is_file()
    _run([sb3_cic, "demo", "--domain", "walker", "--steps", "400", "--learning-starts", "200", "--eval-every", "200",
          "--eval-episodes", "1", "--skills", "0"], tmp_path)
    assert (tmp_path / "demo_output").is_dir() and any((tmp_path / "demo_output").iterdir())
    study = tmp_path / "study"
    _run([sb3_cic, "protocol", "--study", str(study), "--method", "cic", "--domain", "jaco", "--tasks", "reach_top_left",
          "--seeds", "0", "--small", "--pretrain-steps", "300", "--finetune-steps", "300", "--learning-starts", "100",
          "--eval-episodes", "1", "--no-progress"], tmp_path)
    (result,) = study.glob("finetune/cic/jaco_reach_top_left/seed_0/result.json")
    data = json.loads(result.read_text())
    assert data["method"] == "cic" and data["finetune_steps"] == 300 and data["pretrain_seed"] == 0
    assert (result.parent / "eval.csv").is_file()
