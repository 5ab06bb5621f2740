"""Speed switches of the update and the acting loop, and the Adam they use.

Each switch changes how a result is computed, not the result: ``tests/test_speed.py`` checks that
every one is bit-identical to its switched-off form, and ``benchmarks/throughput.py`` times the
update with each one switched off in turn. All are on by default; switch one off for the whole process::

    from sb3_cic.speed import speed_options

    speed_options.lean_adam = False              # from now on
    with speed_options.override(knn_partition=False):
        model.train(1, 256)                      # only inside the block

:class:`LeanSequential` is the ``nn.Sequential`` of the policy's and the reward modules' networks that the
``lean_forward`` switch acts on. The update's other speed changes are older and are switched the same way
as before: the model's ``freeze_critic_in_actor_step`` and the reward module's fused ``update_and_reward``.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, fields
from typing import Any, Callable

import numpy as np
import torch as th
from torch import nn
from torch.nn.modules import module as torch_module
from torch.optim import optimizer as torch_optimizer


@dataclass
class SpeedOptions:
    """The switches; see the module docstring.

    :param lean_adam: :class:`FusedAdam` steps with one call of torch's fused Adam kernel and one
        increment of a vector of step counters per parameter group, skipping ``torch.optim``'s per-step
        bookkeeping (a 12-parameter critic at hidden 256 on this project's CPU: 244 us a step instead of
        325-344 us); the same kernel on the same inputs, so the same parameters, bit for bit
    :param knn_partition: on the CPU (float32/float64), the k nearest squared distances of the kNN
        rewards are selected in place with numpy's ``partition``, then sorted (batch 256: 0.38 ms
        instead of 0.87 with ``torch.topk``); the same values in the same order, bit for bit
    :param lean_acting: the policy acts on the pending observation with one forward pass of the actor
        instead of SB3's ``predict`` (which re-checks, converts and reshapes the observation at every
        env step), the policy keeps its list of modules for SB3's mode switches, and ``train`` leaves
        the training mode alone while it is set; the same actions, bit for bit
    :param lean_forward: a :class:`LeanSequential` (the networks of the policy and of the reward
        modules) calls the functions of its linear, LayerNorm, tanh and ReLU layers directly instead of
        calling each layer as a module (``nn.Module.__call__`` costs a few microseconds per layer: one acting
        step at hidden 256 took 170.5 us instead of 185.3 us on this project's CPU); the same kernels on the
        same inputs, so the same outputs, bit for bit. A layer with hooks is still called as a module
    :param lean_loop: the acting loop (``collect_rollouts``) of :class:`~sb3_cic.common.rollout.LeanRolloutMixin`:
        SB3's loop step for step with less work per env step around the actor, the env step and the stored
        transition (``learn()`` without updates, DDPG at hidden 256 on this project's CPU: 0.703 ms a step
        instead of 1.124); the same actions, transitions, callbacks and statistics (``tests/test_rollout.py``)
    """

    lean_adam: bool = True
    knn_partition: bool = True
    lean_acting: bool = True
    lean_forward: bool = True
    lean_loop: bool = True

    @contextmanager
    def override(self, **flags: bool) -> Iterator[SpeedOptions]:
        """Set some switches inside a ``with`` block and restore them after it."""
        names = {f.name for f in fields(self)}
        unknown = set(flags) - names
        if unknown:
            raise ValueError(f"unknown speed option(s) {sorted(unknown)}; known: {sorted(names)}")
        saved = {name: getattr(self, name) for name in flags}
        for name, value in flags.items():
            setattr(self, name, bool(value))
        try:
            yield self
        finally:
            for name, value in saved.items():
                setattr(self, name, value)


#: the process-wide switches
speed_options = SpeedOptions()


class FusedAdam(th.optim.Adam):
    """``torch.optim.Adam(fused=True)`` whose ``step`` calls the fused kernel with little else around it.

    torch's ``step`` spends more time than its kernel at this project's study size (hidden 256): it
    groups the tensors again at each step, increments one step tensor per parameter (a separate
    operator call each on the CPU) and runs the profiler and compiler wrappers. This ``step`` keeps
    the step counters of a group's parameters as the entries of one vector (each parameter's
    ``state["step"]`` is its own 0-d view of it), increments them with one operator call and calls
    ``torch._fused_adam_`` once per group: the same kernel with the same inputs, so the same
    parameters and state. The state dict has torch's format, and torch's own ``step`` still works on
    it. It falls back to torch's ``step`` for anything else: a closure, step hooks, ``amsgrad``,
    ``capturable`` or ``differentiable`` groups, sparse gradients, parameters without state yet (the
    first step creates it), or with ``speed_options.lean_adam`` off.

    :param params: parameters or parameter groups
    :param kwargs: ``torch.optim.Adam``'s arguments (``fused`` defaults to True)
    """

    def __init__(self, params: Any, **kwargs: Any) -> None:
        super().__init__(params, **{"fused": True, **kwargs})

    def _lean_groups(self) -> list[tuple[dict[str, Any], list[th.Tensor], th.Tensor]] | None:
        if (
            not speed_options.lean_adam
            or self._optimizer_step_pre_hooks
            or self._optimizer_step_post_hooks
            or torch_optimizer._global_optimizer_pre_hooks
            or torch_optimizer._global_optimizer_post_hooks
        ):
            return None
        groups = []
        for group in self.param_groups:
            if not group["fused"] or group["amsgrad"] or group["capturable"] or group["differentiable"]:
                return None
            if group.get("decoupled_weight_decay", False):
                return None
            params = [p for p in group["params"] if p.grad is not None]
            if any(p.grad.is_sparse or "step" not in self.state[p] for p in params):  # type: ignore[union-attr]
                return None
            if params:
                steps = [self.state[p]["step"] for p in params]
                base = steps[0]._base
                if base is None or base.shape != (len(steps),) or any(s._base is not base for s in steps):
                    base = th.stack(steps)  # first lean step, a loaded state dict, or another set of gradients
                    for i, p in enumerate(params):
                        self.state[p]["step"] = base[i]
                groups.append((group, params, base))
        return groups

    def init_state(self) -> None:
        """Create the state that torch's first step creates (zero moments, step 0) where a parameter has none, and
        copy each group's learning rate into a tensor that :meth:`_traced_step` reads.

        A compiled update (``compile_update=True``) finds its optimisers' state in place: it cannot create it; and
        a learning rate read as a tensor lets a schedule change it without compiling the update again.
        """
        if len(getattr(self, "_lr_tensors", ())) != len(self.param_groups):
            self._lr_tensors = [th.zeros((), device=group["params"][0].device) for group in self.param_groups]
        #: what the traced step reads, outside the groups (a compiled read of a group would guard on its "lr")
        self._traced_groups = []
        for group, lr in zip(self.param_groups, self._lr_tensors):
            lr.fill_(group["lr"])
            self._traced_groups.append(
                (list(group["params"]), lr, *group["betas"], group["eps"], group["weight_decay"], group["maximize"])
            )
            for p in group["params"]:
                state = self.state[p]
                if "step" not in state:
                    state["step"] = th.zeros((), dtype=th.float32, device=p.device)  # torch's fused Adam's
                    state["exp_avg"] = th.zeros_like(p, memory_format=th.preserve_format)
                    state["exp_avg_sq"] = th.zeros_like(p, memory_format=th.preserve_format)

    def _traced_step(self) -> None:
        """Adam's step in tensor operations that ``torch.compile`` traces (torch's ``step`` breaks the graph).

        torch's single-tensor Adam with the step counter as a tensor on the parameter's device (as ``capturable``
        Adam keeps it) and the learning rate as a tensor: the same update as the fused kernel to float rounding, on
        the same state. Called while compiling; :meth:`init_state` must have run since the rates last changed.
        """
        for params, lr, beta1, beta2, eps, weight_decay, maximize in self._traced_groups:
            for p in params:
                if p.grad is None:
                    continue
                grad = -p.grad if maximize else p.grad
                if weight_decay != 0:
                    grad = grad.add(p, alpha=weight_decay)
                state = self.state[p]
                step, exp_avg, exp_avg_sq = state["step"], state["exp_avg"], state["exp_avg_sq"]
                step.add_(1)
                exp_avg.lerp_(grad, 1 - beta1)
                exp_avg_sq.mul_(beta2).addcmul_(grad, grad, value=1 - beta2)
                denom = (exp_avg_sq.sqrt() / (1 - beta2**step).sqrt()).add_(eps)
                p.sub_(exp_avg / denom * (lr / (1 - beta1**step)))

    @th.no_grad()
    def step(self, closure: Callable[[], float] | None = None) -> float | None:  # type: ignore[override]
        """One Adam step (see the class docstring for when torch's own ``step`` runs instead)."""
        if th.compiler.is_compiling():
            self._traced_step()
            return None
        groups = None if closure is not None else self._lean_groups()
        if groups is None:
            return super().step(closure)
        for group, params, steps in groups:
            states = [self.state[p] for p in params]
            steps.add_(1)
            beta1, beta2 = group["betas"]
            th._fused_adam_(
                params,
                [p.grad for p in params],
                [s["exp_avg"] for s in states],
                [s["exp_avg_sq"] for s in states],
                [],
                [state["step"] for state in states],
                amsgrad=False,
                lr=group["lr"],
                beta1=beta1,
                beta2=beta2,
                weight_decay=group["weight_decay"],
                eps=group["eps"],
                maximize=group["maximize"],
                grad_scale=None,
                found_inf=None,
            )
        return None

    def zero_grad(self, set_to_none: bool = True) -> None:
        """Drop the gradients (``set_to_none``, as torch's default) with a plain loop; else torch's ``zero_grad``."""
        if th.compiler.is_compiling():
            for params, *_ in self._traced_groups:
                for p in params:
                    p.grad = None
            return None
        if not set_to_none or not speed_options.lean_adam:
            return super().zero_grad(set_to_none)
        for group in self.param_groups:
            for p in group["params"]:
                p.grad = None
        return None


def _has_hooks(module: nn.Module) -> bool:
    return bool(module._forward_hooks or module._forward_pre_hooks or module._backward_hooks or module._backward_pre_hooks)


class LeanSequential(nn.Sequential):
    """``nn.Sequential`` that runs its linear, LayerNorm, tanh and ReLU layers as plain function calls.

    With ``speed_options.lean_forward`` (the default) each of these layers is computed by the function
    its module's ``forward`` calls (``F.linear``, ``layer_norm``, ``tanh``, ``relu``/``relu_``), without
    the module call around it; any other layer, a layer with hooks, or every layer while global module
    hooks are registered, is called as a module. The parameters, the ``state_dict`` keys and the outputs
    are those of ``nn.Sequential``.
    """

    def forward(self, x: th.Tensor) -> th.Tensor:  # type: ignore[override]
        if not speed_options.lean_forward or torch_module._global_forward_hooks or torch_module._global_forward_pre_hooks:
            return super().forward(x)
        for layer in self._modules.values():
            kind = type(layer)
            if _has_hooks(layer):  # type: ignore[arg-type]
                x = layer(x)  # type: ignore[misc]
            elif kind is nn.Linear:
                x = th._C._nn.linear(x, layer.weight, layer.bias)
            elif kind is nn.ReLU:
                x = th.relu_(x) if layer.inplace else th.relu(x)
            elif kind is nn.Tanh:
                x = th.tanh(x)
            elif kind is nn.LayerNorm:
                x = th.layer_norm(x, layer.normalized_shape, layer.weight, layer.bias, layer.eps)
            else:
                x = layer(x)  # type: ignore[misc]
        return x


def lean_action(policy: Any, observation: np.ndarray, action_noise: Callable[[], np.ndarray] | None = None) -> tuple[
    np.ndarray, np.ndarray
]:
    """SB3's exploration action of ``policy`` on ``observation`` in one forward pass of the actor (``lean_acting``).

    SB3's ``predict`` checks, converts and reshapes the observation and switches the networks to evaluation mode
    at every env step; URLB's actor has no layer that acts differently in training mode. The same float32 input,
    the same rescaling (SB3's round trip, kept for the same numbers), the same noise: the same action.

    :param policy: the model's policy (``actor``, ``scale_action``, ``unscale_action``)
    :param observation: the pending observations, ``(n_envs, obs_dim)``
    :param action_noise: SB3's action noise (None: none)
    :return: ``(action, buffer_action)`` as ``OffPolicyAlgorithm._sample_action`` returns them
    """
    with th.no_grad():
        mu = policy.actor(th.as_tensor(observation, device=policy.device).float())
    unscaled_action = policy.unscale_action(mu.cpu().numpy().reshape((-1, *policy.action_space.shape)))
    scaled_action = policy.scale_action(unscaled_action)
    if action_noise is not None:
        scaled_action = np.clip(scaled_action + action_noise(), -1, 1)
    return policy.unscale_action(scaled_action), scaled_action
