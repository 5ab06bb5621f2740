"""Proto-RL as an SB3 algorithm."""

from __future__ import annotations

from typing import Any, ClassVar

from sb3_cic.ddpg import URLBDDPG
from sb3_cic.rewards.proto import ProtoReward


class ProtoRL(URLBDDPG):
    """Proto-RL (Yarats et al., 2021, https://arxiv.org/abs/2102.11271), URLB's state-based version.

    Reference implementation: https://github.com/rll-research/url_benchmark (``agent/proto.py``).
    A data-based method without skills: URLB DDPG (:class:`URLBDDPG`) with the prototypical
    representation and kNN novelty reward of :class:`~sb3_cic.rewards.proto.ProtoReward`.
    Fine-tuning keeps the actor and the whole pre-trained critic (``finetune_critic = "all"``, as
    the reference's ``init_from``).

    :param policy: policy (``"MlpPolicy"``)
    :param env: environment id, environment or VecEnv
    :param pred_dim: embedding size (default: ProtoReward's)
    :param proj_dim: hidden width of the projector (default: ProtoReward's)
    :param num_protos: number of prototypes (default: ProtoReward's)
    :param queue_size: candidate queue length (default: ProtoReward's)
    :param topk: the reward is the distance to the topk-th nearest candidate (default: ProtoReward's)
    :param proto_temperature: softmax temperature (default: ProtoReward's)
    :param proto_target_tau: EMA coefficient of the target predictor (default: ProtoReward's)
    :param proto_lr: learning rate of predictor, projector and prototypes (default: ProtoReward's)
    :param kwargs: arguments of :class:`URLBDDPG` (``batch_size``, ``policy_kwargs``...)
    """

    # the method ---------------------------------------------------------------------------------
    skill_prior_class = None
    reward_module_class = ProtoReward
    reward_module_args: ClassVar[dict[str, str]] = {
        "pred_dim": "pred_dim",
        "proj_dim": "proj_dim",
        "num_protos": "num_protos",
        "queue_size": "queue_size",
        "topk": "topk",
        "proto_temperature": "temperature",
        "proto_target_tau": "target_tau",
        "proto_lr": "lr",
    }
    finetune_skill_choices: ClassVar[dict[str, Any]] = {}
    finetune_critic: ClassVar[str] = "all"
