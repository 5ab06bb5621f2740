"""Proto-RL as an SB3 algorithm."""

from __future__ import annotations

from typing import Any, ClassVar

from stable_baselines3.common.type_aliases import GymEnv

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
    :param pred_dim: embedding size (128)
    :param proj_dim: hidden width of the projector (512)
    :param num_protos: number of prototypes (512)
    :param queue_size: candidate queue length (2048)
    :param topk: the reward is the distance to the topk-th nearest candidate (3)
    :param proto_temperature: softmax temperature (0.1)
    :param proto_target_tau: EMA coefficient of the target predictor (0.05)
    :param proto_lr: learning rate of predictor, projector and prototypes (1e-4)
    :param kwargs: arguments of :class:`URLBDDPG` (``batch_size``, ``policy_kwargs``...)
    """

    finetune_critic: ClassVar[str] = "all"

    def __init__(
        self,
        policy: str | type,
        env: GymEnv | str,
        pred_dim: int = 128,
        proj_dim: int = 512,
        num_protos: int = 512,
        queue_size: int = 2048,
        topk: int = 3,
        proto_temperature: float = 0.1,
        proto_target_tau: float = 0.05,
        proto_lr: float = 1e-4,
        **kwargs: Any,
    ) -> None:
        self.pred_dim = pred_dim
        self.proj_dim = proj_dim
        self.num_protos = num_protos
        self.queue_size = queue_size
        self.topk = topk
        self.proto_temperature = proto_temperature
        self.proto_target_tau = proto_target_tau
        self.proto_lr = proto_lr
        super().__init__(policy, env, **kwargs)

    def _make_reward_module(self) -> ProtoReward:
        return ProtoReward(
            self.state_dim,
            self.action_dim,
            pred_dim=self.pred_dim,
            proj_dim=self.proj_dim,
            num_protos=self.num_protos,
            queue_size=self.queue_size,
            topk=self.topk,
            temperature=self.proto_temperature,
            target_tau=self.proto_target_tau,
            lr=self.proto_lr,
        )
