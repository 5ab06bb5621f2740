"""The Fixed baseline (a constant intrinsic reward) as an SB3 algorithm."""

from __future__ import annotations

from typing import Any, ClassVar

from sb3_cic.ddpg import URLBDDPG
from sb3_cic.rewards.fixed import ConstantReward


class Fixed(URLBDDPG):
    """The *Fixed* baseline of the CIC paper's Appendix I (Laskin et al., 2022, https://arxiv.org/abs/2202.00161).

    URLB DDPG (:class:`URLBDDPG`) pre-trained reward-free on an intrinsic reward of 1 at every step
    (:class:`~sb3_cic.rewards.fixed.ConstantReward`), without skills. It sees no extrinsic reward: it measures
    how much of an env's extrinsic signal leaks through its episode ends (early termination rewards the agent
    that stays alive). Fine-tuning keeps the actor and the critic trunk (URLB).

    :param policy: policy (``"MlpPolicy"``, or ``"MultiInputPolicy"`` for a Dict of state vectors)
    :param env: environment id, environment or VecEnv
    :param fixed_reward: the intrinsic reward of every step (default: ConstantReward's, 1)
    :param kwargs: arguments of :class:`URLBDDPG` (``batch_size``, ``policy_kwargs``...)
    """

    # the method ---------------------------------------------------------------------------------
    skill_prior_class = None
    reward_module_class = ConstantReward
    reward_module_args: ClassVar[dict[str, str]] = {"fixed_reward": "value"}
    finetune_skill_choices: ClassVar[dict[str, Any]] = {}
    finetune_critic: ClassVar[str] = "trunk"
