"""One declaration per method: the four parts in the method's own class body, each default in one place (the
yaml files list the code's values), and the two safeguards of the base (a pre-training that ignores an env's
reward says so; a non-finite observation or reward never reaches the replay buffer)."""

from __future__ import annotations

import ast
import inspect
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch as th
import yaml

import sb3_cic.methods as methods
from sb3_cic import CIC, URLBDDPG, URLBEvalCallback, zoo
from sb3_cic.common.arguments import parameter_default, parameters_of
from sb3_cic.common.method import MethodMixin

from method_classes import METHODS

#: the four parts a method declares (:class:`~sb3_cic.common.method.MethodMixin`)
PARTS = ("skill_prior_class", "reward_module_class", "reward_module_args", "finetune_skill_choices", "finetune_critic")
#: yaml values that differ from the code's default on purpose, ``{(yaml file, key): reason}``: a variant's yaml
OVERRIDES: dict[tuple[str, str], str] = {
    ("cic_code.yml", "cic_variant"): "CIC as the reference code runs it: its loss, reward normalisation and k",
    ("cic_code.yml", "finetune_skill_choice"): "the reference code's skill fixed at 0.5",
}


def test_every_method_declares_its_four_parts_in_its_own_file():
    assert len(METHODS) == 11  # URLB's nine, MOSS, Fixed
    for cls in METHODS:
        tree = ast.parse(inspect.getsource(cls))
        declared = {
            target.id if isinstance(target, ast.Name) else target.target.id
            for target in (n.targets[0] if isinstance(n, ast.Assign) else n for n in tree.body[0].body
                           if isinstance(n, (ast.Assign, ast.AnnAssign)))
        }
        assert set(PARTS) <= declared, (cls.__name__, set(PARTS) - declared)
        assert cls.reward_module_class is not None and cls.finetune_critic in ("trunk", "all", "none")
        module_parameters = parameters_of(cls.reward_module_class)
        assert set(cls.reward_module_args.values()) <= set(module_parameters), cls.__name__
        # no method writes a hook of its own for a part
        assert not {"make_reward_module", "make_finetune_callback", "_make_skill_prior"} & set(vars(cls)), cls.__name__
    assert all(getattr(URLBDDPG, part) == getattr(MethodMixin, part) for part in PARTS)


def test_reward_defaults_are_the_reward_modules():
    for cls in METHODS:
        probe = cls("MlpPolicy", None, _init_setup_model=False)
        for name, parameter in cls.reward_module_args.items():
            if parameter == "hidden_dim":
                assert getattr(probe, name) is None  # the policy's width
            elif not (issubclass(cls, methods.CIC) and name == "knn_k"):  # the variant's
                assert getattr(probe, name) == parameter_default(cls.reward_module_class, parameter), (cls, name)
    code = CIC("MlpPolicy", None, cic_variant="code", _init_setup_model=False)
    assert (CIC("MlpPolicy", None, _init_setup_model=False).knn_k, code.knn_k) == (12, 16)


def _compare(name: str, key: str, listed, default, mismatches: list[str]) -> None:
    if listed != default and (name, key) not in OVERRIDES:
        mismatches.append(f"{name}: {key} is {listed!r} in the yaml, {default!r} in the code")


@pytest.mark.parametrize("config", sorted(zoo.CONFIG_DIR.glob("*.yml")), ids=lambda p: p.stem)
def test_the_yaml_lists_the_code_defaults(config: Path):
    cls = zoo.get_algo(config.stem)
    probe = cls("MlpPolicy", None, _init_setup_model=False)
    mismatches: list[str] = []
    entries = yaml.safe_load(config.read_text())
    assert entries
    for env_id, entry in entries.items():
        for key, value in entry.items():
            if key in ("n_timesteps", "policy"):
                assert key != "policy" or value == "MlpPolicy"
            elif key == "policy_kwargs":
                for arg, width in eval(value, {"dict": dict}).items():
                    _compare(config.name, f"policy_kwargs {arg}", width, probe.hidden_dim if arg == "hidden_dim"
                             else probe.policy_kwargs.get(arg), mismatches)
            elif key == "env_wrapper":
                for item in value:
                    ((_, kwargs),) = item.items()
                    assert kwargs["algo"] == config.stem
                    if "skill_dim" in kwargs:
                        _compare(config.name, "env_wrapper skill_dim", kwargs["skill_dim"], probe.skill_dim, mismatches)
            elif key == "callback":
                for item in value:
                    ((path, kwargs),) = item.items()
                    short = path.rsplit(".", 1)[-1]
                    if short == "URLBEvalCallback":
                        assert kwargs["eval_env"] == env_id
                        for arg in ("n_eval_episodes", "eval_freq"):
                            _compare(config.name, f"{short} {arg}", kwargs[arg], parameter_default(URLBEvalCallback, arg),
                                     mismatches)
                        continue
                    selection = probe.make_finetune_callback()
                    assert type(selection).__name__ == short, (config.name, short)
                    for arg, listed in kwargs.items():
                        _compare(config.name, f"{short} {arg}", listed, getattr(selection, arg), mismatches)
            else:
                _compare(config.name, key, value, getattr(probe, key), mismatches)
    assert not mismatches, mismatches


def test_pretraining_on_an_env_with_its_own_reward_warns_once(tiny):
    for env_id in ("Pendulum-v1", "URLB/point_mass-reach-v0"):
        with pytest.warns(UserWarning) as record:
            model = CIC("MlpPolicy", env_id, **tiny)
        said = [w for w in record if "reward is ignored" in str(w.message)]
        assert len(said) == 1 and env_id in str(said[0].message) and "reward_free=False" in str(said[0].message)
        assert said[0].filename == __file__  # it points at the line that built the model
        model.learn(10)  # no second word while training
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*reward is ignored")
        CIC("MlpPolicy", "URLB/point_mass-v0", **tiny)  # URLB's reward-free pre-training env: nothing to say
        CIC("MlpPolicy", "Pendulum-v1", reward_free=False, **tiny)
        URLBDDPG("MlpPolicy", "Pendulum-v1", **tiny)


class NonFinite(gym.Wrapper):
    """Returns a NaN (or inf) observation or reward at step ``at`` of the first episode."""

    def __init__(self, env: gym.Env, at: int, what: str, value: float = np.nan) -> None:
        super().__init__(env)
        self.at, self.what, self.value, self.steps = at, what, value, 0

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.steps += 1
        if self.steps == self.at:
            if self.what == "observation":
                obs = np.array(obs, copy=True)
                obs[0] = self.value
            else:
                reward = self.value
        return obs, reward, terminated, truncated, info


@pytest.mark.parametrize("cls, what, value", [(URLBDDPG, "observation", np.nan), (CIC, "observation", np.inf),
                                              (URLBDDPG, "reward", np.nan)])
def test_a_non_finite_transition_is_an_error_before_it_is_stored(cls, what, value, tiny):
    env = NonFinite(gym.make("URLB/point_mass-reach-v0"), at=250, what=what, value=value)
    model = cls("MlpPolicy", env, reward_free=False, **tiny)
    with pytest.raises(ValueError, match=f"non-finite {what} at step 250"):
        model.learn(400)
    assert model.replay_buffer.pos == 249  # the first 249 transitions; not the 250th
    assert np.isfinite(model.replay_buffer.observations[:249]).all() and np.isfinite(model.replay_buffer.rewards).all()
    assert all(th.isfinite(p).all() for p in model.policy.parameters())


def test_moss_reward_passes_cic_reward_parameters_through():
    """MOSSReward lists only what it adds or sets otherwise; CICReward's other parameters and defaults come through."""
    from sb3_cic.rewards.cic import CICReward
    from sb3_cic.rewards.moss import MOSSReward

    cic, moss = parameters_of(CICReward), parameters_of(MOSSReward)
    assert set(cic) < set(moss) and {"minus_mean", "knn_source", "skill_mode"} <= set(moss)
    assert (parameter_default(MOSSReward, "skill_dim"), parameter_default(MOSSReward, "variant")) == (32, "code")
    assert all(parameter_default(MOSSReward, name) == parameter_default(CICReward, name)
               for name in ("hidden_dim", "embed_dim", "lr", "temperature", "knn_k", "knn_clip", "knn_avg", "knn_rms"))
    module = MOSSReward(4, 2, hidden_dim=8, lr=3e-4, knn_k=5)
    assert module.particle.center and module.knn_source == "state" and module.variant == "code"
    with pytest.raises(TypeError):
        MOSSReward(4, 2, not_a_parameter=1)
