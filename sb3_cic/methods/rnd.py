"""Random Network Distillation (RND) as an SB3 algorithm."""

from __future__ import annotations

from typing import Any, ClassVar

from sb3_cic.ddpg import URLBDDPG
from sb3_cic.rewards.rnd import RNDReward


class RND(URLBDDPG):
    """Random Network Distillation (Burda et al., 2019, https://arxiv.org/abs/1810.12894), URLB's version.

    Reference implementation: https://github.com/rll-research/url_benchmark (``agent/rnd.py``).
    A knowledge-based method without skills: URLB DDPG (:class:`URLBDDPG`) with the normalised
    prediction-error reward of :class:`~sb3_cic.rewards.rnd.RNDReward`. Fine-tuning keeps the actor
    and the critic trunk (URLB).

    Deliberate deviation from the reference code: the reward scores the next state ``s'`` of the
    transition (the code scores ``s``).

    :param policy: policy (``"MlpPolicy"``)
    :param env: environment id, environment or VecEnv
    :param rnd_hidden_dim: hidden width of predictor and target (default: the policy's)
    :param rnd_rep_dim: output size of predictor and target (default: RNDReward's)
    :param rnd_lr: learning rate of the predictor (default: RNDReward's)
    :param rnd_scale: reward scale (default: RNDReward's)
    :param kwargs: arguments of :class:`URLBDDPG` (``batch_size``, ``policy_kwargs``...)
    """

    # the method ---------------------------------------------------------------------------------
    skill_prior_class = None
    reward_module_class = RNDReward
    reward_module_args: ClassVar[dict[str, str]] = {
        "rnd_hidden_dim": "hidden_dim",
        "rnd_rep_dim": "rep_dim",
        "rnd_lr": "lr",
        "rnd_scale": "scale",
    }
    finetune_skill_choices: ClassVar[dict[str, Any]] = {}
    finetune_critic: ClassVar[str] = "trunk"
