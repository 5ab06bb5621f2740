"""One study driver for ``sb3-cic protocol`` and ``sb3-cic study``: the same runs give the same files, and
``study`` takes a ``--conf-file`` that its study records and holds to, as ``protocol`` does."""

from __future__ import annotations

import io
import json
import shutil
import zipfile
from pathlib import Path

import pytest

from sb3_cic.study.cli import conf_files_of
from sb3_cic.study.driver import check_conf_files
from sb3_cic.study.run import Run
from test_study_folder import _exit, _refused  # a command's exit code and output, run in process

ROOT = Path(__file__).resolve().parents[1]
#: a tiny study: CIC pre-trained 600 steps (snapshot at 500), fine-tuned 600; DDPG from scratch 600
FLAGS = ["--hidden-dim", "32", "--batch-size", "32", "--learning-starts", "500", "--buffer-size", "10000",
         "--pretrain-steps", "600", "--finetune-steps", "600", "--snapshots", "500", "--eval-freq", "300",
         "--eval-episodes", "1", "--num-threads", "1", "--checkpoint-every", "0", "--no-progress"]
#: what differs between two runs of the same study: the seconds a run took, and the snapshots' sha256 (a zip
#: records the time its ``data`` entry was written; their networks are compared entry by entry)
VOLATILE = ("wall_time_s", "snapshot_sha256")


def _files(study: Path) -> dict[str, object]:
    """Every record of ``study`` by its path: ``eval.csv`` as bytes, ``study.json``, ``result.json`` and
    ``settings.json`` as data without :data:`VOLATILE`, each snapshot's entries but ``data`` as bytes."""
    files: dict[str, object] = {}
    for path in sorted(study.rglob("*")):
        name = str(path.relative_to(study))
        if path.name == "eval.csv":
            files[name] = path.read_bytes()
        elif path.name in ("result.json", "settings.json", "study.json"):
            data = json.loads(path.read_text())
            files[name] = {key: value for key, value in data.items() if key not in VOLATILE}
        elif path.name.startswith("snapshot_") and path.suffix == ".zip":
            with zipfile.ZipFile(io.BytesIO(path.read_bytes())) as archive:
                files[name] = {entry: archive.read(entry) for entry in archive.namelist() if entry != "data"}
    return files


def _yaml(tmp_path: Path, tau: float) -> Path:
    """DDPG's yaml with another ``tau``."""
    path = tmp_path / "ddpg_tuned.yml"
    path.write_text((ROOT / "zoo_configs" / "ddpg.yml").read_text().replace("  tau: 0.01\n", f"  tau: {tau}\n", 1))
    return path


def test_protocol_and_study_give_the_same_files(tmp_path: Path, capsys: pytest.CaptureFixture):
    """The same tiny study (CIC pre-trained and fine-tuned, DDPG from scratch with a tuned yaml) run by
    ``protocol`` in this process and by ``study`` on Ray: the same ``eval.csv`` bytes, the same results and run
    settings, the same snapshots' networks; ``study --conf-file`` is read, recorded, and refused once changed."""
    yaml_file = _yaml(tmp_path, 0.02)
    one, two = tmp_path / "protocol", tmp_path / "study"
    common = ["--tasks", "stand", "--seeds", "0", *FLAGS]
    for method in ("cic", "ddpg"):
        conf = ["--conf-file", str(yaml_file)] if method == "ddpg" else []
        code, _, err = _exit(["protocol", "--method", method, "--domain", "walker", "--study", str(one), *common, *conf],
                             capsys)
        assert code == 0, err
    code, out, err = _exit(["study", str(two), "--methods", "cic", "ddpg", "--domains", "walker", *common,
                            "--conf-file", f"ddpg={yaml_file}"], capsys)
    assert code == 0 and "3 runs ran now" in out, err

    first, second = _files(one), _files(two)
    assert sorted(first) == sorted(second)
    assert sum(name.endswith("eval.csv") for name in first) == 2 and sum(".zip" in name for name in first) == 2
    for name in first:
        assert first[name] == second[name], name
    result = json.loads((two / "finetune" / "ddpg" / "walker_stand" / "seed_0" / "result.json").read_text())
    assert result["hyperparams"]["tau"] == "0.02"  # the tuned yaml ran
    recorded = json.loads((two / "study.json").read_text())["conf_files"]
    assert recorded["ddpg"]["file"] == str(yaml_file) and recorded["cic"]["file"] is None

    code, out, _ = _exit(["study", str(two), "--methods", "cic", "ddpg", "--domains", "walker", *common,
                          "--conf-file", f"ddpg={yaml_file}"], capsys)
    assert code == 0 and "0 runs ran now" in out  # the same yaml: nothing to do
    _yaml(tmp_path, 0.03)
    line = _refused(["study", str(two), "--methods", "ddpg", "--domains", "walker", *common, "--conf-file",
                     str(yaml_file)], capsys)
    assert "other settings" in line and "conf_file of ddpg (entries " in line and "URLB/walker-stand-v0" in line, line
    line = _refused(["protocol", "--method", "ddpg", "--domain", "walker", "--study", str(two), *common,
                     "--conf-file", str(yaml_file)], capsys)
    assert "conf_file of ddpg (entries " in line, line
    shutil.rmtree(tmp_path / "protocol")


@pytest.mark.parametrize(
    "values, methods, message",
    [
        (["a.yml"], ["cic", "ddpg"], "give METHOD=FILE"),
        (["a.yml"], ["all"], "give METHOD=FILE"),
        (["cic=a.yml", "CIC=b.yml"], ["cic"], "names cic twice"),
    ],
)
def test_a_conf_file_names_its_method(values, methods, message):
    with pytest.raises(ValueError, match=message):
        conf_files_of(values, methods)


def test_conf_files_are_read_per_method(tmp_path: Path):
    assert conf_files_of(["dir/a.yml"], ["cic"]) == {"cic": "dir/a.yml"}
    assert conf_files_of(["ddpg=a.yml", "cic=b=c.yml"], ["all"]) == {"ddpg": "a.yml", "cic": "b=c.yml"}
    runs = [Run("ddpg", "walker", "walker_stand", 0)]
    with pytest.raises(ValueError, match="--conf-file for cic, which is not among the methods \\['ddpg'\\]"):
        check_conf_files(runs, {"cic": None})
    with pytest.raises(ValueError, match="no yaml file"):
        check_conf_files(runs, {"ddpg": tmp_path / "missing.yml"})
    assert check_conf_files(runs, {}) == {"ddpg": None}


def test_the_final_snapshot_is_the_default_and_others_must_be_saved(tmp_path: Path):
    """``--snapshot`` / ``--from-snapshot`` at the pre-training's last step is its final snapshot (``cic``, not
    ``cic@600``); a step the pre-training does not save is refused before anything is written, for both commands."""
    from sb3_cic.study.driver import check_run_inputs
    from sb3_cic.study.graph import build_graph
    from sb3_cic.study.settings import Settings

    settings = Settings(pretrain_steps=600, snapshots=(500,))
    runs = build_graph(["cic"], ["walker"], ["stand"], [0], from_snapshot=600)
    assert [run.label for run in check_run_inputs(tmp_path, runs, settings, {}, 600)] == ["cic", "cic"]
    runs = build_graph(["cic"], ["walker"], ["stand"], [0], from_snapshot=500)
    assert [run.label for run in check_run_inputs(tmp_path, runs, settings, {}, 500)] == ["cic", "cic@500"]
    with pytest.raises(ValueError, match=r"no snapshot at 700 steps: the pre-training saves \[500, 600\]"):
        check_run_inputs(tmp_path, build_graph(["cic"], ["walker"], ["stand"], [0], from_snapshot=700), settings, {}, 700)


def test_a_pretraining_method_is_not_run_from_scratch(tmp_path: Path, capsys: pytest.CaptureFixture):
    """``--from-scratch`` is the default of a method without pre-training; a method that pre-trains is refused in one
    line (its runs from scratch would take the folders of its fine-tunings)."""
    line = _refused(["protocol", "--method", "cic", "--domain", "walker", "--from-scratch", "--study",
                     str(tmp_path / "study"), *FLAGS], capsys)
    assert "--from-scratch: cic pre-trains" in line
    assert not (tmp_path / "study").exists()
