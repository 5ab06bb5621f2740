"""URLB actor and twin critic for state observations (``"MlpPolicy"``).

Actor: ``Linear(obs, h) -> LayerNorm -> Tanh -> Linear(h, h) -> ReLU -> Linear(h, act) -> tanh``.
Critic: a shared trunk ``Linear(obs + act, h) -> LayerNorm -> Tanh`` and ``n_critics`` heads (URLB: 2)
``Linear(h, h) -> ReLU -> Linear(h, 1)``. Linear layers use orthogonal init and zero bias.
The observation is the flat ``[state, skill]`` vector; a multi-dimensional Box action is flattened
(``act`` is its number of entries) and reshaped by SB3's ``predict``.

The one width ``h`` is ``hidden_dim`` (URLB: 1024). SB3's ``net_arch`` is accepted where it says the
same: ``[h, h]`` or ``dict(pi=[h, h], qf=[h, h])`` (see :func:`hidden_dim_from_net_arch`).
"""

from __future__ import annotations

from functools import reduce
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import BaseModel, BasePolicy
from stable_baselines3.common.preprocessing import get_action_dim
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule
from stable_baselines3.td3.policies import TD3Policy
from torch import nn

from sb3_cic.common.arguments import check_positive_int
from sb3_cic.speed import FusedAdam, LeanSequential, speed_options


#: Adam's fused implementation, also when ``torch.optim.Adam`` is given: the same update as the per-tensor
#: one (to float rounding), one kernel over all parameters, many times faster on CPU (see
#: benchmarks/throughput.py). The default optimizer class, :class:`~sb3_cic.speed.FusedAdam`, is fused too.
ADAM_KWARGS: dict[str, Any] = {"fused": True}


def hidden_dim_from_net_arch(net_arch: list[int] | dict[str, list[int]]) -> int:
    """The URLB width that SB3's ``net_arch`` describes, or a ``ValueError`` naming ``hidden_dim``.

    URLB's actor and critic have hidden layers of one width ``h`` and a fixed depth: a list of equal
    widths (``[h, h]``) or ``dict(pi=[h, h], qf=[h, h])`` gives ``h`` (the number of entries is not a
    depth here); unequal widths cannot be built.

    :param net_arch: SB3's ``net_arch`` (list of widths, or dict with ``pi`` and ``qf``)
    """
    layers = [*net_arch.get("pi", []), *net_arch.get("qf", [])] if isinstance(net_arch, dict) else list(net_arch)
    extra = set(net_arch) - {"pi", "qf"} if isinstance(net_arch, dict) else set()
    if extra or len(set(layers)) != 1 or any(not isinstance(h, int) or h < 1 for h in layers):
        raise ValueError(
            f"net_arch={net_arch!r} cannot be built: URLB networks have hidden layers of one width; "
            "give policy_kwargs=dict(hidden_dim=h) (or net_arch=[h, h])"
        )
    return int(layers[0])


def min_q(qs: tuple[th.Tensor, ...]) -> th.Tensor:
    """Element-wise minimum over the critic heads' outputs (``th.minimum(q1, q2)`` for the twin critic)."""
    return reduce(th.minimum, qs)


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
    :param normalize_images: SB3's flag, kept for ``save``/``load`` (state observations are never images)
    """

    def __init__(
        self, observation_space: spaces.Box, action_space: spaces.Box, hidden_dim: int = 1024, normalize_images: bool = True
    ) -> None:
        super().__init__(observation_space, action_space, squash_output=True, normalize_images=normalize_images)
        self.hidden_dim = check_positive_int("hidden_dim", hidden_dim)
        obs_dim, act_dim = observation_space.shape[0], get_action_dim(action_space)
        self.trunk = LeanSequential(nn.Linear(obs_dim, hidden_dim), nn.LayerNorm(hidden_dim), nn.Tanh())
        self.policy = LeanSequential(
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
        return self(observation.float())  # type: ignore[union-attr]  # SB3's cast of a float64 Box


class URLBCritic(BaseModel):
    """URLB twin critic: a shared LayerNorm/Tanh trunk and ``n_critics`` Q heads (``q1_net``, ``q2_net``...).

    :param observation_space: flat observation space ``[state, skill]``
    :param action_space: action space
    :param hidden_dim: width of the hidden layers
    :param output_dim: size of each head's output (1 for Q values)
    :param n_critics: number of heads (URLB: 2)
    :param normalize_images: SB3's flag, kept for ``save``/``load`` (state observations are never images)
    """

    def __init__(
        self,
        observation_space: spaces.Box,
        action_space: spaces.Box,
        hidden_dim: int = 1024,
        output_dim: int = 1,
        n_critics: int = 2,
        normalize_images: bool = True,
    ) -> None:
        super().__init__(observation_space, action_space, normalize_images=normalize_images)
        self.hidden_dim = check_positive_int("hidden_dim", hidden_dim)
        self.output_dim = output_dim
        self.n_critics = check_positive_int("n_critics", n_critics)
        in_dim = observation_space.shape[0] + get_action_dim(action_space)
        self.trunk = LeanSequential(nn.Linear(in_dim, hidden_dim), nn.LayerNorm(hidden_dim), nn.Tanh())
        self.q_networks: list[LeanSequential] = []
        for i in range(n_critics):
            head = LeanSequential(nn.Linear(hidden_dim, hidden_dim), nn.ReLU(inplace=True), nn.Linear(hidden_dim, output_dim))
            self.add_module(f"q{i + 1}_net", head)
            self.q_networks.append(head)
        self.apply(orthogonal_init)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(hidden_dim=self.hidden_dim, output_dim=self.output_dim, n_critics=self.n_critics)
        return data

    def forward(self, obs: th.Tensor, actions: th.Tensor) -> tuple[th.Tensor, ...]:
        h = self.trunk(th.cat([obs, actions], dim=1))
        return tuple(q_net(h) for q_net in self.q_networks)

    def q1_forward(self, obs: th.Tensor, actions: th.Tensor) -> th.Tensor:
        return self.q_networks[0](self.trunk(th.cat([obs, actions], dim=1)))

    def reset_heads(self) -> None:
        """Re-initialise the heads (fine-tuning keeps the trunk only, as URLB)."""
        for q_net in self.q_networks:
            q_net.apply(orthogonal_init)


class URLBPolicy(TD3Policy):
    """URLB DDPG policy: :class:`URLBActor` and :class:`URLBCritic` with a critic target.

    URLB has no target actor: the target action comes from the online actor. ``actor_target``
    is therefore the actor itself (kept as an alias so SB3 code that reads it keeps working).

    :param observation_space: flat observation space
    :param action_space: action space
    :param lr_schedule: learning rate schedule (Adam, URLB: 1e-4)
    :param hidden_dim: width of all hidden layers (URLB: 1024)
    :param optimizer_class: optimizer class (default :class:`~sb3_cic.speed.FusedAdam`, Adam with a lean step;
        ``torch.optim.Adam`` gets ``fused=True`` as well)
    :param optimizer_kwargs: extra optimizer arguments (Adam: :data:`ADAM_KWARGS` unless overridden)
    :param n_critics: number of critic heads (URLB: 2)
    :param output_dim: size of each critic head's output (1; APS: the size of ``w``)
    :param net_arch: SB3's form of the width, ``[h, h]`` or ``dict(pi=[h, h], qf=[h, h])``; replaces
        ``hidden_dim`` (see :func:`hidden_dim_from_net_arch`)
    :param normalize_images: SB3's flag, kept for ``save``/``load`` (state observations are never images)
    :param features_extractor_class: not supported (``ValueError``): URLB's networks read the flat state
        with their own first layer; transform observations with a Gymnasium ``ObservationWrapper`` instead
    :param activation_fn: not supported (``ValueError``): URLB's activations are fixed
    :param skill_dim: number of trailing observation entries that hold the skill (set by the model); a
        state-only observation given to :meth:`predict` is then a ``ValueError`` that points to the
        model's ``predict``, which appends the model's skill
    """

    critic_class: type[URLBCritic] = URLBCritic

    def __init__(
        self,
        observation_space: spaces.Box,
        action_space: spaces.Box,
        lr_schedule: Schedule,
        hidden_dim: int = 1024,
        optimizer_class: type[th.optim.Optimizer] = FusedAdam,
        optimizer_kwargs: dict[str, Any] | None = None,
        n_critics: int = 2,
        output_dim: int = 1,
        net_arch: list[int] | dict[str, list[int]] | None = None,
        normalize_images: bool = True,
        features_extractor_class: Any = None,
        features_extractor_kwargs: dict[str, Any] | None = None,
        activation_fn: Any = None,
        skill_dim: int = 0,
    ) -> None:
        self.skill_dim = skill_dim
        wrap_obs = "transform observations with a Gymnasium ObservationWrapper"
        for name, value, alternative in (
            ("features_extractor_class", features_extractor_class, wrap_obs),
            ("features_extractor_kwargs", features_extractor_kwargs, wrap_obs),
            ("activation_fn", activation_fn, "subclass URLBActor/URLBCritic to change the architecture"),
        ):
            if value is not None:
                raise ValueError(
                    f"{name} is not supported: URLB's networks (LayerNorm/Tanh trunk on the flat state) are fixed; "
                    f"{alternative}"
                )
        width = hidden_dim if net_arch is None else hidden_dim_from_net_arch(net_arch)
        self.hidden_dim = check_positive_int("hidden_dim", width)
        self.output_dim = output_dim
        self.n_critics = n_critics
        if optimizer_class is th.optim.Adam:
            optimizer_kwargs = {**ADAM_KWARGS, **(optimizer_kwargs or {})}
        super().__init__(
            observation_space,
            action_space,
            lr_schedule,
            net_arch=[self.hidden_dim],
            normalize_images=normalize_images,
            optimizer_class=optimizer_class,
            optimizer_kwargs=optimizer_kwargs,
            n_critics=n_critics,
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
        return URLBActor(self.observation_space, self.action_space, self.hidden_dim, self.normalize_images).to(self.device)

    def make_critic(self, features_extractor: Any = None) -> URLBCritic:
        critic = self.critic_class(
            self.observation_space, self.action_space, self.hidden_dim, self.output_dim, self.n_critics, self.normalize_images
        )
        return critic.to(self.device)

    def _predict(self, observation: PyTorchObs, deterministic: bool = False) -> th.Tensor:
        return self.actor(observation.float())  # type: ignore[union-attr]  # SB3's cast of a float64 Box

    def obs_to_tensor(self, observation: Any) -> tuple[PyTorchObs, bool]:
        state_dim = self.observation_space.shape[0] - self.skill_dim
        if self.skill_dim and isinstance(observation, np.ndarray) and observation.ndim and observation.shape[-1] == state_dim:
            raise ValueError(
                f"this policy acts on [state, skill] observations ({state_dim} + {self.skill_dim}), got state-only shape "
                f"{observation.shape}: use model.predict (it appends the model's skill) or append a skill"
            )
        return super().obs_to_tensor(observation)

    def set_training_mode(self, mode: bool) -> None:
        """Put actor and critic in training (``mode=True``) or evaluation mode; the critic target stays in evaluation.

        The same flags as SB3's (``nn.Module.train`` on actor and critic), set directly on each
        submodule: SB3 calls this at every ``predict`` and every ``train``, and ``nn.Module.train``
        goes through ``nn.Module.__setattr__`` for each submodule (hidden 256 on this CPU: 94 us per
        call with SB3's, 23 us with this one). With ``speed_options.lean_acting`` the list of submodules
        is kept between calls (rebuilt when ``actor`` or ``critic`` is replaced).
        """
        for module in self._mode_modules():
            module.__dict__["training"] = mode
        self.training = mode

    def _mode_modules(self) -> list[nn.Module]:
        """The modules of actor and critic; with ``speed_options.lean_acting``, listed once per actor and critic."""
        key = (id(self.actor), id(self.critic))
        cached = self.__dict__.get("_mode_modules_cache")
        if not speed_options.lean_acting or cached is None or cached[0] != key:
            cached = (key, [*self.actor.modules(), *self.critic.modules()])
            self.__dict__["_mode_modules_cache"] = cached
        return cached[1]

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        for key in ("net_arch", "activation_fn", "share_features_extractor"):
            data.pop(key, None)
        data.pop("features_extractor_class", None)
        data.pop("features_extractor_kwargs", None)
        data.update(hidden_dim=self.hidden_dim, output_dim=self.output_dim, skill_dim=self.skill_dim)
        return data


MlpPolicy = URLBPolicy


def normalize_policy_kwargs(policy_kwargs: dict[str, Any] | None) -> dict[str, Any]:
    """``policy_kwargs`` in the form a model saves: SB3's ``net_arch`` as ``hidden_dim``, ``n_critics`` set (2).

    :param policy_kwargs: the user's policy arguments
    """
    policy_kwargs = dict(policy_kwargs or {})
    if "net_arch" in policy_kwargs:  # SB3's form of the width
        width = hidden_dim_from_net_arch(policy_kwargs.pop("net_arch"))
        if policy_kwargs.setdefault("hidden_dim", width) != width:
            raise ValueError(f"net_arch says width {width}, hidden_dim {policy_kwargs['hidden_dim']}: give one of them")
    if "hidden_dim" in policy_kwargs:
        check_positive_int("hidden_dim", policy_kwargs["hidden_dim"])
    policy_kwargs.setdefault("n_critics", 2)  # URLB's twin critic (SB3's DDPG would set 1)
    return policy_kwargs
