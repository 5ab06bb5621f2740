"""MOSS: the mode schedule of its skills, the sign of its reward per mode, its update against CIC's where every
skill explores, its fine-tuning sweep, save/load, and the rl-zoo and protocol paths."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import numpy as np
import pytest
import torch as th
import yaml
from stable_baselines3.common.type_aliases import ReplayBufferSamples

from sb3_cic.envs.skill_wrapper import SkillSchedule
from sb3_cic import CIC, MOSS, MixtureSkillPrior, SkillGridSweepCallback
from sb3_cic.cli import main
from sb3_cic.study.driver import run_protocol
from sb3_cic.study.settings import Settings
from sb3_cic.rewards.base import RewardModule
from sb3_cic.rewards.cic import CICReward
from sb3_cic.rewards.moss import MOSSReward
from sb3_cic.skills import control_mask

STATE, ACT, SKILL = 5, 3, 6
SMALL = dict(batch_size=32, learning_starts=200, buffer_size=5000, policy_kwargs={"hidden_dim": 32}, seed=0)


def skills_of_an_episode(prior: MixtureSkillPrior, steps: int, resample_every: int = 10, seed: int = 0) -> np.ndarray:
    """The skill each step of an episode acts with, from a schedule reset at step 0."""
    schedule = SkillSchedule(prior, resample_every)
    schedule.reset(seed)
    skills = []
    for _ in range(steps):
        skills.append(schedule.skill)
        schedule.step()
    return np.stack(skills)


def make_batch(skill: th.Tensor, seed: int = 0) -> ReplayBufferSamples:
    g = th.Generator().manual_seed(seed)
    n = skill.shape[0]
    obs = th.cat([th.randn(n, STATE, generator=g), skill], 1)
    next_obs = th.cat([th.randn(n, STATE, generator=g), skill], 1)
    zeros = th.zeros(n, 1)
    return ReplayBufferSamples(obs, th.rand(n, ACT, generator=g) * 2 - 1, next_obs, zeros, zeros, th.ones(n, 1))


def explore_skills(n: int, dim: int = SKILL, seed: int = 1) -> th.Tensor:
    z = th.rand(n, dim, generator=th.Generator().manual_seed(seed))
    z[:, dim - dim // 2 :] = 0
    return z


def as_control(explore: th.Tensor) -> th.Tensor:
    """The control skills of the same draws ([0, U] instead of [U, 0], half mode)."""
    dim = explore.shape[1]
    return th.cat([th.zeros(len(explore), dim // 2), explore[:, : dim - dim // 2]], 1)


# the skills and their modes -------------------------------------------------------------------------
def test_half_mode_two_partitions_first_half_explores_second_controls():
    skills = skills_of_an_episode(MixtureSkillPrior(SKILL, partitions=2, episode_length=100), 100)
    explore, control = skills[:50], skills[50:]
    assert (explore[:, 3:] == 0).all() and ((explore[:, :3] > 0) & (explore[:, :3] < 1)).all()
    assert (control[:, :3] == 0).all() and ((control[:, 3:] > 0) & (control[:, 3:] < 1)).all()
    # resampled every 10 steps, constant in between
    assert all(len(np.unique(skills[i : i + 10], axis=0)) == 1 for i in range(0, 100, 10))
    assert len(np.unique(skills, axis=0)) == 10
    mask = control_mask(th.as_tensor(skills), "half").squeeze(1).numpy()
    assert (mask == (np.arange(100) >= 50)).all()


def test_a_new_episode_explores_again_even_after_an_early_reset():
    prior = MixtureSkillPrior(SKILL, episode_length=100)
    schedule = SkillSchedule(prior, 10)
    schedule.reset(0)
    for _ in range(70):
        schedule.step()
    assert control_mask(th.as_tensor(schedule.skill)[None], "half").item()
    schedule.reset()  # an episode that ended at step 70
    assert not control_mask(th.as_tensor(schedule.skill)[None], "half").item()
    state = schedule.get_state()
    assert state["episode_steps"] == 0


def test_sign_mode_with_fractional_partitions():
    """MOSS's jaco example: 1.5 partitions, the part length ``100 // 1.5 = 66``: the skill drawn at step 60
    still explores (and acts until step 70), the one drawn at 70 controls."""
    skills = skills_of_an_episode(MixtureSkillPrior(4, partitions=1.5, skill_mode="sign", episode_length=100), 100)
    assert (skills[:70] > 0).all() and (skills[70:] < 0).all()
    assert (control_mask(th.as_tensor(skills), "sign").squeeze(1).numpy() == (np.arange(100) >= 70)).all()


def test_checkpointed_schedule_resumes_the_episode_step():
    prior = MixtureSkillPrior(SKILL, episode_length=100)
    schedule = SkillSchedule(prior, 10)
    schedule.reset(0)
    for _ in range(45):
        schedule.step()
    resumed = SkillSchedule(prior, 10)
    resumed.set_state(schedule.get_state())
    for a in (schedule, resumed):
        for _ in range(10):
            a.step()
    np.testing.assert_array_equal(schedule.skill, resumed.skill)
    assert control_mask(th.as_tensor(resumed.skill)[None], "half").item()  # drawn at step 50


@pytest.mark.parametrize(
    "kwargs, message",
    [({"skill_mode": "both"}, "skill_mode"), ({"dim": 1}, "at least 2"), ({"partitions": 0}, "partitions"),
     ({"partitions": 2000}, "partitions")],
)
def test_bad_prior_arguments_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        MixtureSkillPrior(**kwargs)


def test_the_reward_module_refuses_an_unknown_skill_mode():
    with pytest.raises(ValueError, match="skill_mode must be one of"):
        MOSSReward(STATE, ACT, skill_dim=SKILL, hidden_dim=16, skill_mode="both")


def test_the_sweep_grid_is_moss_grid_search():
    grid = MixtureSkillPrior(4).grid(80)
    assert grid.shape == (80, 4) and (grid == grid[:, :1]).all()
    np.testing.assert_allclose(grid[:, 0], np.linspace(-1, 0, 80), rtol=0, atol=1e-7)
    for z in grid[[0, -1]]:  # the prior's bounds admit the grid's ends
        np.testing.assert_array_equal(MixtureSkillPrior(4).validate(z), z)


# the reward --------------------------------------------------------------------------------------
def test_a_control_skill_negates_the_reward_of_the_same_transition():
    module = MOSSReward(STATE, ACT, skill_dim=SKILL, hidden_dim=16)
    explore = explore_skills(32)
    control = as_control(explore)
    r_explore = copy.deepcopy(module).reward(make_batch(explore))
    r_control = copy.deepcopy(module).reward(make_batch(control))
    assert r_explore.shape == (32, 1) and (r_explore != 0).any()
    th.testing.assert_close(r_control, -r_explore)
    mixed = th.where(th.arange(32)[:, None] % 2 == 0, explore, control)
    r_mixed = copy.deepcopy(module).reward(make_batch(mixed))
    th.testing.assert_close(r_mixed[0::2], r_explore[0::2])
    th.testing.assert_close(r_mixed[1::2], -r_explore[1::2])


def test_reward_formula_state_against_next_state_minus_mean_over_var():
    """MOSS's particle reward by hand: kNN of each g1(s) among the batch's g1(s'), ``(d - mean) / var`` with the
    running statistics of all k distances, clipped, averaged, ``log(1 + x)``."""
    k, clip = 4, 0.0005
    module = MOSSReward(STATE, ACT, skill_dim=SKILL, hidden_dim=16, knn_k=k, knn_clip=clip)
    batch = make_batch(explore_skills(24))
    with th.no_grad():
        source = module.state_net(batch.observations[:, :STATE])
        target = module.state_net(batch.next_observations[:, :STATE])
        reward = module.reward(batch)
    d = th.cdist(source.double(), target.double()).sort(dim=1).values[:, :k]
    values, count = d.reshape(-1), 1e-4
    mean = values.mean() * len(values) / (count + len(values))
    var = (1.0 * count + values.var() * len(values) + values.mean() ** 2 * count * len(values) / (count + len(values)))
    var = var / (count + len(values))
    expected = th.log1p(((d - mean) / var - clip).clamp_min(0).mean(dim=1, keepdim=True))
    th.testing.assert_close(reward.double(), expected, rtol=1e-4, atol=1e-5)
    assert module.particle.rms.mean.item() == pytest.approx(mean.item(), rel=1e-5)


def test_fused_update_equals_reward_then_update():
    fused = MOSSReward(STATE, ACT, skill_dim=SKILL, hidden_dim=16)
    plain = copy.deepcopy(fused)
    batch = make_batch(th.where(th.arange(32)[:, None] < 16, explore_skills(32), as_control(explore_skills(32))))
    r_fused, m_fused = fused.update_and_reward(batch)
    r_plain, m_plain = RewardModule.update_and_reward(plain, batch)
    th.testing.assert_close(r_fused, r_plain, atol=1e-6, rtol=1e-5)
    th.testing.assert_close(m_fused["contrastive_loss"], m_plain["contrastive_loss"])
    for a, b in zip(fused.state_dict().values(), plain.state_dict().values()):
        th.testing.assert_close(a, b, atol=1e-6, rtol=1e-5)


def test_explore_mode_update_equals_cics():
    """With CIC's kNN source and normalisation, a batch of explore skills gets exactly CIC's update (same
    networks, same batch, same noise): the mode and the sign are all MOSS adds."""
    env = "URLB/point_mass-v0"
    cic = CIC("MlpPolicy", env, cic_variant="code", skill_dim=SKILL, **SMALL)
    moss = MOSS("MlpPolicy", env, minus_mean=False, knn_source="next_state", skill_dim=SKILL, **SMALL)
    moss.policy.load_state_dict(cic.policy.state_dict())
    moss.reward_module.load_state_dict(cic.reward_module.state_dict())
    state_dim = cic.state_dim
    g = th.Generator().manual_seed(0)
    n = 32
    skill = explore_skills(n)
    obs = th.cat([th.randn(n, state_dim, generator=g), skill], 1)
    next_obs = th.cat([th.randn(n, state_dim, generator=g), skill], 1)
    batch = ReplayBufferSamples(obs, th.rand(n, cic.action_dim, generator=g) * 2 - 1, next_obs, th.zeros(n, 1),
                                th.zeros(n, 1), th.full((n, 1), 0.99**3))
    metrics = {}
    for name, model in (("cic", cic), ("moss", moss)):
        th.manual_seed(0)
        metrics[name] = {key: value.item() for key, value in model._step(batch).items()}
    assert metrics["cic"] == metrics["moss"] and metrics["cic"]["reward/contrastive_loss"] > 0
    for module in ("policy", "reward_module"):
        for (key, a), b in zip(getattr(cic, module).state_dict().items(), getattr(moss, module).state_dict().values()):
            assert th.equal(a, b), (module, key)
    # the same transitions with control skills: the opposite reward
    means = []
    for data in (batch, make_control_batch(batch, state_dim)):
        copied = copy.deepcopy(moss)
        copied._install_relabel()  # a copied buffer drops its hook (it holds the model)
        means.append(copied._step(data)["reward/intrinsic_reward_mean"].item())
    assert means[1] == pytest.approx(-means[0], rel=1e-6) and means[0] != 0


def make_control_batch(batch: ReplayBufferSamples, state_dim: int) -> ReplayBufferSamples:
    control = as_control(batch.observations[:, state_dim:])
    return batch._replace(
        observations=th.cat([batch.observations[:, :state_dim], control], 1),
        next_observations=th.cat([batch.next_observations[:, :state_dim], control], 1),
    )


# the model -------------------------------------------------------------------------------------------
def test_defaults_are_moss_code():
    model = MOSS("MlpPolicy", "URLB/quadruped-v0", **SMALL)
    assert model.skill_prior == MixtureSkillPrior(32, partitions=2, skill_mode="half", episode_length=1000)
    rm = model.reward_module
    assert (model.knn_k, rm.particle.k, rm.variant, rm.particle.divide_by, rm.particle.center) == (16, 16, "code", "var", True)
    assert (rm.knn_source, rm.skill_mode, rm.temperature, model.skill_resample_every) == ("state", "half", 0.5, 50)
    assert isinstance(rm, CICReward) and model.finetune_skill_choice == "sweep"
    callback = model.make_finetune_callback()
    assert isinstance(callback, SkillGridSweepCallback) and (callback.sweep_steps, callback.window) == (200, 50)
    sign = MOSS("MlpPolicy", "URLB/quadruped-v0", skill_mode="sign", partitions=1.5, **SMALL)
    assert sign.skill_prior == MixtureSkillPrior(32, partitions=1.5, skill_mode="sign")
    assert sign.reward_module.skill_mode == "sign"


def test_learn_save_load_and_fine_tune(tmp_path: Path):
    model = MOSS("MlpPolicy", "URLB/point_mass-v0", **SMALL)
    model.learn(1200)
    skills = model.replay_buffer.observations[:1000, 0, model.state_dim :]
    control = control_mask(th.as_tensor(skills), "half").squeeze(1).numpy()
    assert (control == (np.arange(1000) >= 500)).all()  # the first episode: half explore, half control
    path = tmp_path / "moss.zip"
    model.save(path)
    loaded = MOSS.load(path)
    assert loaded.skill_prior == model.skill_prior and loaded.partitions == 2
    for a, b in zip(model.reward_module.state_dict().values(), loaded.reward_module.state_dict().values()):
        assert th.equal(a, b)
    obs = model.observation_space.sample()
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])

    tuned = MOSS.load_pretrained(path, "URLB/point_mass-reach-v0", learning_starts=200, batch_size=32)
    tuned.learn(300)
    skill = tuned.get_env().env_method("get_skill")[0]
    grid = MixtureSkillPrior(32).grid(4)
    assert any(np.array_equal(skill, z) for z in grid) and tuned.get_env().get_attr("fixed") == [True]


def test_rl_zoo_train_finetune_and_the_protocol(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    threads = th.get_num_threads()
    monkeypatch.chdir(tmp_path)
    small = ["--small", "--seed", "0", "--num-threads", "1", "--verbose", "0"]
    main(["train", "--algo", "moss", "--env", "URLB/point_mass-v0", "-n", "600", *small, "--hyperparams", "learning_starts:300"])
    pretrained = tmp_path / "logs" / "moss" / "URLB-point_mass-v0_1" / "URLB-point_mass-v0.zip"
    main(["finetune", "--algo", "moss", "--env", "URLB/point_mass-reach-v0", "-i", str(pretrained), "-n", "400",
          "--eval-freq", "400", "--eval-episodes", "1", *small, "--hyperparams", "learning_starts:200"])
    run = tmp_path / "logs" / "moss" / "URLB-point_mass-reach-v0_1"
    config = yaml.load((run / "URLB-point_mass-reach-v0" / "config.yml").read_text(), Loader=yaml.UnsafeLoader)
    assert config["finetune_skill_choice"] == "sweep"  # learn's sweep: learning_starts (200) steps, windows of 50
    chosen = config["env_wrapper"][0]["sb3_cic.zoo.skill_wrapper"]["skill"]
    assert any(np.allclose(chosen, z) for z in MixtureSkillPrior(32).grid(4))

    settings = Settings(hidden_dim=32, batch_size=32, learning_starts=200, buffer_size=5000, pretrain_steps=600,
                        finetune_steps=400, eval_freq=400, eval_episodes=1, num_threads=1)
    study = tmp_path / "study"
    run_protocol(study, "moss", "walker", tasks=("stand",), seeds=(0,), settings=settings)
    result = json.loads((study / "finetune" / "moss" / "walker_stand" / "seed_0" / "result.json").read_text())
    assert result["method"] == "moss" and (study / "pretrain" / "moss_walker" / "snapshot_600.zip").exists()
    th.set_num_threads(threads)
