"""A study's labels for a method's fine-tuning skill choice (``cic+fixed``, ``cic+sweep``: one pre-training serves
both) and for CIC as the reference code runs it (``cic_code``: its own yaml, the ``code`` variant, the skill fixed)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from sb3_cic import zoo
from sb3_cic.methods import CIC
from sb3_cic.study.graph import build_graph
from sb3_cic.study.layout import parse_label, run_label
from sb3_cic.study.record import Pairing
from sb3_cic.study.run import Run
from sb3_cic.study.results import study_results
from test_driver import FLAGS
from test_study_folder import _exit, _refused  # a command's exit code and output, run in process


@pytest.mark.parametrize(
    "method, snapshot, choice, label",
    [("cic", None, None, "cic"), ("cic", 100000, None, "cic@100000"), ("cic_code", None, "fixed", "cic_code+fixed"),
     ("aps", 500, "regression", "aps@500+regression")],
)
def test_a_label_says_its_method_snapshot_and_skill_choice(method, snapshot, choice, label):
    assert run_label(method, snapshot, choice) == label
    assert parse_label(label) == (method, snapshot, choice)


@pytest.mark.parametrize("label", ["cic@", "cic@01", "cic+", "cic+a b", "@500", "cic@x+fixed"])
def test_a_label_the_layout_does_not_make_is_refused(label):
    with pytest.raises(ValueError, match="no label of a study's runs"):
        parse_label(label)


def test_two_skill_choices_share_one_pretraining_per_seed():
    runs = build_graph(["cic_code+fixed", "cic_code+sweep"], ["walker"], ["flip"], [0, 1])
    assert [str(run) for run in runs if run.task is None] == ["pretrain cic_code walker seed 0",
                                                              "pretrain cic_code walker seed 1"]
    finetunes = [run for run in runs if run.task is not None]
    assert sorted({run.label for run in finetunes}) == ["cic_code+fixed", "cic_code+sweep"]
    assert all(run.dependency() == Run("cic_code", "walker", None, run.seed) for run in finetunes)
    assert Run.of_row(finetunes[0].row(), Pairing("paired")) == finetunes[0]  # study.json's row keeps the choice
    assert finetunes[0].row() == ["cic_code", "walker", "walker_flip", 0, None, "fixed"]


@pytest.mark.parametrize(
    "method, message",
    [("cic+nope", "cic fine-tunes with one of the skill choices ['fixed', 'sweep']"),
     ("ddpg+fixed", "ddpg fine-tunes without a skill to choose"), ("apt+sweep", "apt fine-tunes without a skill")],
)
def test_a_skill_choice_the_method_lacks_is_refused(method, message, tmp_path: Path, capsys: pytest.CaptureFixture):
    line = _refused(["study", str(tmp_path / "study"), "--methods", method, "--domains", "walker", "--tasks", "flip",
                     "--seeds", "0", *FLAGS], capsys)
    assert message in line, line
    assert not (tmp_path / "study").exists()


def test_cic_code_is_cic_with_its_own_yaml():
    assert zoo.get_algo("cic_code") is CIC
    hyperparams, _, _, _ = zoo.zoo_hyperparams("cic_code", "URLB/walker-v0")
    assert hyperparams["cic_variant"] == "code"
    hyperparams, callbacks, _, _ = zoo.zoo_hyperparams("cic_code", "URLB/walker-flip-v0")
    assert hyperparams["finetune_skill_choice"] == "fixed"
    assert not any(type(callback).__name__ == "SkillGridSweepCallback" for callback in callbacks)


def test_a_study_fine_tunes_one_pretraining_with_both_choices(tmp_path: Path, capsys: pytest.CaptureFixture):
    """``protocol`` with ``cic_code+fixed`` then ``cic_code+sweep``: the second reuses the first's pre-training; each
    ``result.json`` records the variant and the skill choice, the skill fixed at 0.5 or found by the sweep; the
    study's reader checks the choice against the label."""
    study = tmp_path / "study"
    for method in ("cic_code+fixed", "cic_code+sweep"):
        code, out, err = _exit(["protocol", "--method", method, "--domain", "walker", "--study", str(study),
                                "--tasks", "flip", "--seeds", "0", *FLAGS], capsys)
        assert code == 0, err
    pretraining = json.loads((study / "pretrain" / "cic_code_walker" / "result.json").read_text())
    assert pretraining["hyperparams"]["cic_variant"] == "code"
    results = {}
    for choice in ("fixed", "sweep"):
        results[choice] = json.loads((study / "finetune" / f"cic_code+{choice}" / "walker_flip" / "seed_0" /
                                      "result.json").read_text())
        assert results[choice]["label"] == f"cic_code+{choice}" and results[choice]["method"] == "cic_code"
        assert results[choice]["finetune_skill_choice"] == choice and results[choice]["cic_variant"] == "code"
        assert results[choice]["pretrain_seed"] == 0
    assert np.allclose(results["fixed"]["finetune_skill"], 0.5) and results["fixed"]["skill_sweep"] is None
    assert results["sweep"]["skill_sweep"]  # the sweep's candidates and their returns
    rows = json.loads((study / "study.json").read_text())["runs"]
    assert sum(row[2] is None for row in rows) == 1  # one pre-training
    assert sorted(result["label"] for result in study_results(study).results) == ["cic_code+fixed", "cic_code+sweep"]

    path = study / "finetune" / "cic_code+fixed" / "walker_flip" / "seed_0" / "result.json"
    path.write_text(json.dumps({**results["fixed"], "finetune_skill_choice": "sweep"}))
    with pytest.warns(UserWarning, match="finetune_skill_choice 'sweep' but its place in the study says 'fixed'"):
        assert [result["label"] for result in study_results(study).results] == ["cic_code+sweep"]
