"""A snapshot loaded onto the wrong env, class or skill size says what is wrong and what to do."""

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.callbacks import EvalCallback

from envs import SkillObservationWrapper
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
