"""A snapshot loaded onto the wrong env, class or skill size, or a file that is no readable snapshot, says what is
wrong and what to do."""

import re

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.callbacks import EvalCallback

from sb3_cic.envs import SkillObservationWrapper
from sb3_cic import APT, CIC, UniformSkillPrior, URLBDDPG, __version__


@pytest.fixture
def cic_snapshot(tmp_path, tiny):
    model = CIC("MlpPolicy", "URLB/walker-v0", seed=0, **tiny)
    model.save(tmp_path / "cic")
    return model, tmp_path / "cic.zip"


def test_the_snapshot_records_env_class_and_version(cic_snapshot):
    model, _ = cic_snapshot
    assert (model.env_id, model.algorithm, model.package_version) == ("URLB/walker-v0", "CIC", __version__)


def test_a_fine_tuned_model_records_its_task_and_this_version(tmp_path, cic_snapshot):
    model, _ = cic_snapshot
    model.package_version = "0.0.1"
    model.save(tmp_path / "old_version")
    tuned = CIC.load_pretrained(tmp_path / "old_version.zip", env="URLB/walker-flip-v0")
    assert (tuned.env_id, tuned.algorithm, tuned.package_version) == ("URLB/walker-flip-v0", "CIC", __version__)


def test_snapshot_of_another_domain(cic_snapshot):
    with pytest.raises(ValueError) as error:
        CIC.load_pretrained(cic_snapshot[1], env="URLB/quadruped-walk-v0")
    message = str(error.value)
    assert "pre-trained on URLB/walker-v0: state 24 + skill 64, action 6" in message
    assert "cannot act on URLB/quadruped-walk-v0 (state 78, action 12)" in message
    assert "Observation spaces do not match" not in message


def test_snapshot_of_another_method(cic_snapshot):
    with pytest.raises(ValueError, match="is a CIC model: use CIC.load_pretrained"):
        APT.load_pretrained(cic_snapshot[1], env="URLB/walker-flip-v0")
    with pytest.raises(ValueError, match="is a CIC model"):
        URLBDDPG.load(cic_snapshot[1])


def test_snapshot_on_an_env_with_another_skill_size(cic_snapshot):
    env = SkillObservationWrapper(gym.make("URLB/walker-flip-v0"), UniformSkillPrior(16))
    with pytest.raises(ValueError, match="skill 64.*skill_dim.*pass the plain env"):
        CIC.load_pretrained(cic_snapshot[1], env=env)


def test_snapshot_of_an_older_version_without_the_records(tmp_path, cic_snapshot):
    """A snapshot saved before the class was recorded: the state-dict error says what else it may be."""
    model, _ = cic_snapshot
    del model.algorithm, model.package_version
    model.save(tmp_path / "old")
    with pytest.raises(ValueError) as error:
        APT.load_pretrained(tmp_path / "old.zip", env="URLB/walker-flip-v0")
    message = str(error.value)
    assert "does not fit APT" in message and "saved by an earlier sb3-cic" in message


def test_the_version_is_named_when_it_differs(tmp_path, cic_snapshot):
    model, _ = cic_snapshot
    model.package_version = "0.0.1"
    model.save(tmp_path / "versioned")
    with pytest.raises(ValueError, match=rf"saved by sb3-cic 0.0.1; this is sb3-cic {__version__}"):
        CIC.load_pretrained(tmp_path / "versioned.zip", env="URLB/quadruped-walk-v0")


def test_predict_on_an_observation_of_another_domain_names_wrap_env(cic_snapshot):
    model, _ = cic_snapshot
    with pytest.raises(ValueError, match=r"state 24 \+ skill 64 \(env URLB/walker-v0\).*model.wrap_env"):
        model.predict(np.zeros(78, dtype=np.float32))


def test_wrap_env_for_sb3_eval_callback(tmp_path, cic_snapshot, tiny):
    _, path = cic_snapshot
    model = CIC.load_pretrained(path, env="URLB/walker-flip-v0", learning_starts=40)
    model.batch_size = 16
    eval_env = model.wrap_env("URLB/walker-flip-v0")
    assert isinstance(eval_env, SkillObservationWrapper) and eval_env.observation_space.shape == (24 + 64,)
    callback = EvalCallback(eval_env, n_eval_episodes=1, eval_freq=60, log_path=str(tmp_path), warn=False)
    model.learn(60, callback=callback)
    assert callback.evaluations_results and len(callback.evaluations_results[0]) == 1
    # once fine-tuning has chosen its skill, a wrapped env acts with it, fixed
    assert model.finetune_skill is not None
    wrapped = model.wrap_env(gym.make("URLB/walker-flip-v0"))
    wrapped.reset(seed=0)
    assert np.array_equal(wrapped.get_skill(), model.finetune_skill) and wrapped.fixed


def _bad_snapshots(folder, good):
    """Damaged copies of the saved model ``good`` and a stock SB3 DDPG model, in ``folder``: ``{kind: path}``."""
    import zipfile

    from stable_baselines3 import DDPG

    raw = good.read_bytes()
    paths = {kind: folder / f"{kind}.zip" for kind in ("not_a_zip", "truncated", "bad_json", "garbage_policy", "sb3_ddpg")}
    paths["not_a_zip"].write_bytes(b"this is no zip file")
    paths["truncated"].write_bytes(raw[: len(raw) // 2])
    with zipfile.ZipFile(good) as archive:
        entries = {name: archive.read(name) for name in archive.namelist()}
    for kind, name, content in (("bad_json", "data", b'{"policy_class": '), ("garbage_policy", "policy.pth", b"\x80garbage")):
        with zipfile.ZipFile(paths[kind], "w") as archive:
            for entry, data in entries.items():
                archive.writestr(entry, content if entry == name else data)
    DDPG("MlpPolicy", "Pendulum-v1", policy_kwargs={"net_arch": [8, 8]}, buffer_size=100).save(paths["sb3_ddpg"])
    return paths


#: what each damaged file is said to be
UNREADABLE = {
    "not_a_zip": "is not a readable zip file \\(File is not a zip file\\)",
    "truncated": "(is not a readable zip file|holds no saved model data)",
    "bad_json": "its 'data' entry is not valid JSON",
    "garbage_policy": "its policy.pth entry holds no tensors torch reads safely",
    "sb3_ddpg": "is not an sb3-cic model: its policy is stable_baselines3.td3.policies.TD3Policy",
}


@pytest.fixture
def bad_snapshots(tmp_path, cic_snapshot):
    folder = tmp_path / "bad"
    folder.mkdir()
    return _bad_snapshots(folder, cic_snapshot[1])


@pytest.mark.parametrize("kind", sorted(UNREADABLE))
@pytest.mark.parametrize("how", ["load", "load_pretrained"])
def test_an_unreadable_snapshot_is_named_with_what_is_wrong(bad_snapshots, kind, how):
    path = bad_snapshots[kind]
    with pytest.raises(ValueError) as info:
        if how == "load":
            CIC.load(path)
        else:
            CIC.load_pretrained(path, "URLB/walker-flip-v0")
    message = str(info.value)
    assert str(path) in message and len(message.splitlines()) == 1
    assert re.search(UNREADABLE[kind], message), message
    # torch's advice to unpickle the file is nowhere in what the user sees, the chained errors included
    chain, error = [], info.value
    while error is not None:
        chain.append(str(error))
        error = None if error.__suppress_context__ else (error.__cause__ or error.__context__)
    assert not any("weights_only" in text for text in chain), chain


@pytest.mark.parametrize("kind", sorted(UNREADABLE))
def test_an_unreadable_snapshot_on_the_command_line(bad_snapshots, kind, tmp_path, monkeypatch, capsys):
    """``finetune`` reads the snapshot before rl-zoo makes its run folder; ``skills`` names the file."""
    from sb3_cic.cli import main

    monkeypatch.chdir(tmp_path)
    path = str(bad_snapshots[kind])
    for arguments in (["finetune", "--algo", "cic", "--env", "URLB/walker-flip-v0", "-i", path, "-n", "100"],
                      ["skills", path, "--no-video", "--plot", "p.png"]):
        capsys.readouterr()
        with pytest.raises(SystemExit) as exit_info:
            main(arguments)
        err = capsys.readouterr().err
        assert exit_info.value.code == 2 and len(err.strip().splitlines()) == 1, err
        assert path in err and re.search(UNREADABLE[kind], err), err
        assert "weights_only" not in err and "Error: Error" not in err
        assert sorted(p.name for p in tmp_path.iterdir()) == ["bad", "cic.zip"]  # no logs/, no plot
