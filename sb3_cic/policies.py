"""URLB actor and twin critic for state observations (``"MlpPolicy"``).

Actor: ``Linear(obs, h) -> LayerNorm -> Tanh -> Linear(h, h) -> ReLU -> Linear(h, act) -> tanh``.
Critic: a shared trunk ``Linear(obs + act, h) -> LayerNorm -> Tanh`` and two heads
``Linear(h, h) -> ReLU -> Linear(h, 1)``. Linear layers use orthogonal init and zero bias.
The observation is the flat ``[state, skill]`` vector.
"""

from __future__ import annotations

from typing import Any

import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import BaseModel, BasePolicy
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule
from stable_baselines3.td3.policies import TD3Policy
from torch import nn


#: Adam's fused implementation by default: the same update as the per-tensor one (to float rounding),
#: one kernel over all parameters, many times faster on CPU (see benchmarks/throughput.py)
ADAM_KWARGS: dict[str, Any] = {"fused": True}


def orthogonal_init(module: nn.Module) -> None:
    """URLB weight init: orthogonal weights and zero bias for every linear layer."""
    if isinstance(module, nn.Linear):
        nn.init.orthogonal_(module.weight.data)
        if module.bias is not None:
            module.bias.data.fill_(0.0)


class URLBActor(BasePolicy):
    """Deterministic URLB actor: returns the mean action ``mu`` in [-1, 1].

    :param observation_space: flat observation space ``[state, skill]``
    :param action_space: action space, [-1, 1]
    :param hidden_dim: width of the hidden layers
    """

    def __init__(self, observation_space: spaces.Box, action_space: spaces.Box, hidden_dim: int = 1024) -> None:
        super().__init__(observation_space, action_space, squash_output=True)
        self.hidden_dim = hidden_dim
        obs_dim, act_dim = observation_space.shape[0], action_space.shape[0]
        self.trunk = nn.Sequential(nn.Linear(obs_dim, hidden_dim), nn.LayerNorm(hidden_dim), nn.Tanh())
        self.policy = nn.Sequential(
            nn.Linear(hidden_dim, hidden_dim), nn.ReLU(inplace=True), nn.Linear(hidden_dim, act_dim), nn.Tanh()
        )
        self.apply(orthogonal_init)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(hidden_dim=self.hidden_dim)
        return data

    def forward(self, obs: th.Tensor) -> th.Tensor:
        return self.policy(self.trunk(obs))

    def _predict(self, observation: PyTorchObs, deterministic: bool = False) -> th.Tensor:
        return self(observation)


class URLBCritic(BaseModel):
    """URLB twin critic: a shared LayerNorm/Tanh trunk and two Q heads.

    :param observation_space: flat observation space ``[state, skill]``
    :param action_space: action space
    :param hidden_dim: width of the hidden layers
    :param output_dim: size of each head's output (1 for Q values)
    """

    def __init__(
        self, observation_space: spaces.Box, action_space: spaces.Box, hidden_dim: int = 1024, output_dim: int = 1
    ) -> None:
        super().__init__(observation_space, action_space)
        in_dim = observation_space.shape[0] + action_space.shape[0]
        self.trunk = nn.Sequential(nn.Linear(in_dim, hidden_dim), nn.LayerNorm(hidden_dim), nn.Tanh())

        def head() -> nn.Sequential:
            return nn.Sequential(nn.Linear(hidden_dim, hidden_dim), nn.ReLU(inplace=True), nn.Linear(hidden_dim, output_dim))

        self.q1_net, self.q2_net = head(), head()
        self.q_networks = [self.q1_net, self.q2_net]
        self.n_critics = 2
        self.apply(orthogonal_init)

    def forward(self, obs: th.Tensor, actions: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        h = self.trunk(th.cat([obs, actions], dim=1))
        return self.q1_net(h), self.q2_net(h)

    def q1_forward(self, obs: th.Tensor, actions: th.Tensor) -> th.Tensor:
        return self.q1_net(self.trunk(th.cat([obs, actions], dim=1)))

    def reset_heads(self) -> None:
        """Re-initialise the two heads (fine-tuning keeps the trunk only, as URLB)."""
        self.q1_net.apply(orthogonal_init)
        self.q2_net.apply(orthogonal_init)


class URLBPolicy(TD3Policy):
    """URLB DDPG policy: :class:`URLBActor` and :class:`URLBCritic` with a critic target.

    URLB has no target actor: the target action comes from the online actor. ``actor_target``
    is therefore the actor itself (kept as an alias so SB3 code that reads it keeps working).

    :param observation_space: flat observation space
    :param action_space: action space
    :param lr_schedule: learning rate schedule (Adam, URLB: 1e-4)
    :param hidden_dim: width of all hidden layers (URLB: 1024)
    :param optimizer_class: optimizer class
    :param optimizer_kwargs: extra optimizer arguments (Adam: :data:`ADAM_KWARGS` unless overridden)
    """

    critic_class: type[URLBCritic] = URLBCritic

    def __init__(
        self,
        observation_space: spaces.Box,
        action_space: spaces.Box,
        lr_schedule: Schedule,
        hidden_dim: int = 1024,
        optimizer_class: type[th.optim.Optimizer] = th.optim.Adam,
        optimizer_kwargs: dict[str, Any] | None = None,
        **critic_kwargs: Any,
    ) -> None:
        self.hidden_dim = hidden_dim
        self.critic_extra_kwargs = critic_kwargs
        if optimizer_class is th.optim.Adam:
            optimizer_kwargs = {**ADAM_KWARGS, **(optimizer_kwargs or {})}
        super().__init__(
            observation_space,
            action_space,
            lr_schedule,
            net_arch=[hidden_dim],
            optimizer_class=optimizer_class,
            optimizer_kwargs=optimizer_kwargs,
        )

    def _build(self, lr_schedule: Schedule) -> None:
        self.actor = self.make_actor()
        self.actor_target = self.actor
        self.actor.optimizer = self.optimizer_class(self.actor.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)
        self.critic = self.make_critic()
        self.critic_target = self.make_critic()
        self.critic_target.load_state_dict(self.critic.state_dict())
        self.critic_target.set_training_mode(False)
        self.critic.optimizer = self.optimizer_class(self.critic.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)

    def make_actor(self, features_extractor: Any = None) -> URLBActor:
        return URLBActor(self.observation_space, self.action_space, self.hidden_dim).to(self.device)

    def make_critic(self, features_extractor: Any = None) -> URLBCritic:
        return self.critic_class(self.observation_space, self.action_space, self.hidden_dim, **self.critic_extra_kwargs).to(
            self.device
        )

    def set_training_mode(self, mode: bool) -> None:
        """Put actor and critic in training (``mode=True``) or evaluation mode; the critic target stays in evaluation.

        The same flags as SB3's (``nn.Module.train`` on actor and critic), set directly on each
        submodule: SB3 calls this at every ``predict`` and every ``train``, and ``nn.Module.train``
        goes through ``nn.Module.__setattr__`` for each submodule (hidden 256 on this CPU: 94 us per
        call with SB3's, 23 us with this one).
        """
        for module in (*self.actor.modules(), *self.critic.modules()):
            module.__dict__["training"] = mode
        self.training = mode

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        for key in ("net_arch", "activation_fn", "n_critics", "share_features_extractor"):
            data.pop(key, None)
        data.pop("features_extractor_class", None)
        data.pop("features_extractor_kwargs", None)
        data.update(hidden_dim=self.hidden_dim, **self.critic_extra_kwargs)
        return data


MlpPolicy = URLBPolicy
