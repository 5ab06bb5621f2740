"""Every constructor argument of the eleven classes, and the protocol's settings, checked for type and range before
anything is built: a ``ValueError`` naming the argument. Each range sits beside its owner: ``URLBDDPG.argument_ranges``
(a method's own in the method's), a reward module's or skill prior's ``parameter_ranges``, ``Settings.RANGES``."""

import math

import numpy as np
import pytest

from sb3_cic import APS, APT, CIC, DIAYN, ICM, MOSS, RND, SMM, Disagreement, Fixed, ProtoRL, URLBDDPG, UniformSkillPrior
from sb3_cic.common.arguments import FLAG, Flag, Range, check_argument, ranges_of
from sb3_cic.skills import MAX_SKILL_DIM
from sb3_cic.study.settings import Settings

ALL = [URLBDDPG, CIC, ICM, Disagreement, RND, APT, ProtoRL, DIAYN, SMM, APS, MOSS, Fixed]
SKILLED = [CIC, DIAYN, SMM, APS, MOSS]
SMALL = dict(policy_kwargs={"hidden_dim": 16}, batch_size=16, buffer_size=1000, learning_starts=20, seed=0)


#: URLBDDPG's arguments and their ranges
DDPG_RANGES = URLBDDPG.argument_ranges


def bad_values(name: str, bound: Range | Flag) -> list:
    """Values outside ``bound``, the range of ``name``: below it, of the wrong type, NaN / infinite."""
    if isinstance(bound, Flag):
        return [1, "yes", None]
    below = bound.low if bound.low_open else bound.low - (1 if bound.integer else 0.5)
    if name == "gradient_steps":
        below = -2  # -1: SB3's "as many as env steps"
    values = [below, "1", True, math.nan, math.inf]
    if bound.integer:
        values.append(2.5)
    if math.isfinite(bound.high):
        values.append(bound.high + 1)
    return values


def method_ranges(cls) -> dict[str, Range | Flag]:
    """The range of each of a method's reward-module and skill-prior arguments that has one (its parameter's)."""
    ranges = {}
    for args, owner in ((cls.reward_module_args, cls.reward_module_class), (cls.skill_prior_args, cls.skill_prior_class)):
        owned = ranges_of(owner) if owner is not None else {}
        ranges.update({name: owned[key] for name, key in args.items() if key in owned})
    return ranges


DDPG_CASES = [
    (cls, name, value)
    for cls in ALL
    for name, bound in DDPG_RANGES.items()
    if not (name == "skill_dim" and cls not in SKILLED)  # skill_dim of a method without skills: its own error
    and not (name == "skill_dim" and cls is APS)  # APS's is sf_dim (below)
    for value in bad_values(name, bound)
    if value is not None  # None: the default of an optional argument
]
#: the arguments of a method's own constructor (not of URLBDDPG, its reward module or its prior)
OWN_ARGUMENTS = {APS: ("sf_dim", "regression_step", "regression_max_samples")}
METHOD_CASES = [
    (cls, name, value) for cls in ALL for name, bound in method_ranges(cls).items() for value in bad_values(name, bound)
    if value is not None
] + [(cls, name, value) for cls, names in OWN_ARGUMENTS.items() for name in names
     for value in bad_values(name, ranges_of(cls, "argument_ranges")[name]) if value is not None]


@pytest.mark.parametrize("cls, name, value", DDPG_CASES, ids=lambda x: getattr(x, "__name__", repr(x)))
def test_each_ddpg_argument_out_of_range_names_itself(cls, name, value):
    kwargs = {**SMALL, name: value}
    if name == "buffer_size" and isinstance(value, (int, float)) and not isinstance(value, bool) and value < 1:
        kwargs["batch_size"] = 1
    with pytest.raises(ValueError, match=f"^{name} must be "):
        cls("MlpPolicy", "Pendulum-v1", **kwargs)


@pytest.mark.parametrize("cls, name, value", METHOD_CASES, ids=lambda x: getattr(x, "__name__", repr(x)))
def test_each_method_argument_out_of_range_names_itself(cls, name, value):
    with pytest.raises(ValueError, match=f"^{name} must be "):
        cls("MlpPolicy", "Pendulum-v1", **SMALL, **{name: value})


def test_every_method_argument_has_a_range():
    """A new reward-module argument must be given a range (or be a flag, or a name checked by its module)."""
    checked_elsewhere = {"variant", "knn_source", "skill_mode"}  # strings, each checked against its choices
    for cls in ALL:
        for name, key in {**cls.reward_module_args, **cls.skill_prior_args}.items():
            assert name in method_ranges(cls) or key in checked_elsewhere, (cls.__name__, name)
    assert set(OWN_ARGUMENTS[APS]) <= set(ranges_of(APS, "argument_ranges")) - set(DDPG_RANGES)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"learning_rate": math.inf}, "learning_rate must be a finite number > 0, got inf"),
        ({"temperature": 0}, "temperature must be a finite number > 0, got 0"),
        ({"temperature": math.nan}, "temperature must be a finite number > 0, got nan"),
        ({"batch_size": 1.5}, "batch_size must be an int >= 1, got 1.5"),
        ({"skill_dim": 2.5}, f"skill_dim must be an int in \\[1, {MAX_SKILL_DIM}\\], got 2.5"),
        ({"skill_dim": 100_000}, f"skill_dim must be an int in \\[1, {MAX_SKILL_DIM}\\], got 100000"),
    ],
)
def test_the_reported_python_inputs_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=f"^{message}$"):
        CIC("MlpPolicy", "URLB/walker-v0", **{**SMALL, **kwargs})


def test_numpy_numbers_and_schedules_are_accepted():
    model = CIC("MlpPolicy", "Pendulum-v1", **{**SMALL, "batch_size": np.int64(16), "tau": np.float32(0.01)},
                learning_rate=lambda progress: 1e-4 * progress, skill_dim=np.int64(4), temperature=np.float64(0.5),
                reward_free=False)
    assert model.batch_size == 16 and model.skill_dim == 4 and model.temperature == 0.5


def test_a_skill_prior_refuses_a_fractional_or_huge_size():
    for dim in (2.5, 0, MAX_SKILL_DIM + 1):
        with pytest.raises(ValueError, match="skill dim must be an int in"):
            UniformSkillPrior(dim)
    assert UniformSkillPrior(MAX_SKILL_DIM).dim == MAX_SKILL_DIM


def test_load_checks_the_attributes_it_overrides(tmp_path):
    model = URLBDDPG("MlpPolicy", "Pendulum-v1", **SMALL)
    model.save(tmp_path / "model")
    with pytest.raises(ValueError, match="^batch_size must be an int >= 1, got 0$"):
        URLBDDPG.load(tmp_path / "model", batch_size=0)
    with pytest.raises(ValueError, match="^learning_starts must be an int >= 0, got -5$"):
        URLBDDPG.load_pretrained(tmp_path / "model", "Pendulum-v1", learning_starts=-5)


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"eval_episodes": 0}, "eval_episodes"),
        ({"finetune_steps": 0}, "finetune_steps"),
        ({"pretrain_steps": -5}, "pretrain_steps"),
        ({"hidden_dim": 0}, "hidden_dim"),
        ({"batch_size": 0}, "batch_size"),
        ({"snapshots": (1000, -1)}, "snapshots"),
        ({"eval_freq": 2.5}, "eval_freq"),
        ({"pretrain_checkpoint_every": -1}, "pretrain_checkpoint_every"),
    ],
)
def test_protocol_settings_are_checked(kwargs, name):
    with pytest.raises(ValueError, match=f"^{name} must be "):
        Settings(**kwargs)


def test_range_describes_and_parses():
    assert Range(1, integer=True).describe() == "an int >= 1"
    assert Range(0.0, 1.0).describe() == "a finite number in [0, 1]"
    assert Range(0.0, low_open=True).describe() == "a finite number > 0"
    assert Range(1, integer=True).parse("7") == 7
    for text in ("0", "1.5", "x", "nan"):
        with pytest.raises(Exception, match="must be an int >= 1"):
            Range(1, integer=True).parse(text)
    with pytest.raises(Exception, match="must be a finite number > 0, got 'inf'"):
        Range(0.0, low_open=True).parse("inf")
    assert check_argument("knn_avg", True, FLAG) is True
    with pytest.raises(ValueError, match="^knn_avg must be True or False, got 1$"):
        check_argument("knn_avg", 1, FLAG)
