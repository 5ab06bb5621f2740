"""The fast path of the update: metrics kept on the device, and the update step compiled.

:meth:`~sb3_cic.ddpg.URLBDDPG.train` runs the model's step (``_step``, the one statement of the math) on each
sampled batch. The step returns 0-d tensors; :class:`UpdateMetrics` sums them on the device and reads them
once, when SB3 dumps its logs, so that an update never waits for the device. With ``compile_update=True``
the same step runs through :func:`compile_step`: ``torch.compile(fullgraph=True)`` of the whole update
(the reward module's update and relabelled reward, critic, actor and target steps, their backward passes and
Adam steps), and on CUDA inductor's CUDA graphs (``mode="reduce-overhead"``); on CUDA the actor acting on one
observation is a CUDA graph too (:class:`GraphedActor`).
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np
import torch as th
from stable_baselines3.common.logger import Logger

from sb3_cic.speed import FusedAdam

Step = Callable[..., dict[str, th.Tensor]]


class UpdateMetrics:
    """Sums of an update's 0-d metric tensors, kept on their device; read and reset by :meth:`record`."""

    def __init__(self) -> None:
        self.sums: dict[str, th.Tensor] = {}
        self.count = 0

    def add(self, metrics: dict[str, th.Tensor]) -> None:
        """Add one update's metrics (no host synchronisation; a new set of keys starts the sums again)."""
        if self.sums.keys() != metrics.keys():
            self.sums = {key: th.zeros((), dtype=th.float64, device=value.device) for key, value in metrics.items()}
            self.count = 0
        th._foreach_add_(list(self.sums.values()), [metrics[key].detach() for key in self.sums])
        self.count += 1

    def record(self, logger: Logger) -> None:
        """Record the mean of each metric since the last call into ``logger`` (one device read), then reset."""
        if self.count == 0:
            return
        means = (th.stack(list(self.sums.values())) / self.count).tolist()
        for key, mean in zip(self.sums, means):
            logger.record(key, mean)
        for total in self.sums.values():
            total.zero_()
        self.count = 0


#: the graphs a process may compile of the update step (models of other classes, sizes or phases)
RECOMPILE_LIMIT = 64


def compile_step(step: Step, device: th.device, options: dict[str, Any] | None = None) -> Step:
    """``step`` compiled as one graph: ``torch.compile(fullgraph=True)`` with the backward passes traced.

    On CUDA the graph is captured and replayed as a CUDA graph (inductor's ``reduce-overhead`` mode); its outputs
    live in the graph's memory until the next replay, so the caller reads them at once (:class:`UpdateMetrics`
    adds them to its sums). A graph break is an error (``fullgraph=True``), never a silent slow path.

    :param step: the update step, a function of a sampled batch returning 0-d tensors
    :param device: the device the step runs on
    :param options: other arguments of ``torch.compile`` (for example ``{"backend": "aot_eager"}`` or
        ``{"mode": "max-autotune"}``); ``fullgraph`` is always True
    """
    options = dict(options or {})
    if "fullgraph" in options and not options["fullgraph"]:
        raise ValueError("compile_update compiles the update as one graph: fullgraph=False is not an option")
    options["fullgraph"] = True
    if th.device(device).type == "cuda":
        options.setdefault("mode", "reduce-overhead")
    compiled = th.compile(step, **options)

    def run(*args: Any) -> dict[str, th.Tensor]:
        # trace loss.backward() into the graph; every model of a process compiles the same method (``_step``), and
        # each (class, sizes, phase) is one more graph of it: more than torch's default of 8
        with th._dynamo.config.patch(trace_autograd_ops=True, recompile_limit=RECOMPILE_LIMIT):
            return compiled(*args)

    return run


def compiled_step(model: Any) -> Step:
    """``model._step`` compiled (:func:`compile_step`, built at the first call and kept as ``model._compiled_step``),
    with the state of the optimisers it steps created and their learning rates copied into the tensors the step
    reads (:meth:`~sb3_cic.speed.FusedAdam.init_state`; call it after SB3 set the rates, as ``train`` does).

    :param model: a :class:`~sb3_cic.ddpg.URLBDDPG` with ``compile_update`` True or a dict of ``torch.compile``
        arguments
    """
    optimizers = [model.actor.optimizer, model.critic.optimizer]
    if model.reward_free and model.reward_module is not None:
        optimizers.append(model.reward_module.optimizer)
    for optimizer in optimizers:
        if not isinstance(optimizer, FusedAdam):
            raise ValueError(f"compile_update needs sb3_cic.speed.FusedAdam optimisers, got {type(optimizer).__name__}")
        optimizer.init_state()
    if model._compiled_step is None:
        options = model.compile_update if isinstance(model.compile_update, dict) else None
        model._compiled_step = compile_step(model._step, model.device, options)
    return model._compiled_step


def enable_tf32() -> None:
    """Let CUDA's float32 matrix products and convolutions use TF32 (``--tf32``; off by default in torch).

    Process-wide. TF32 keeps 10 bits of the mantissa in the products: faster on Ampere and later GPUs, no longer
    equal to float32 results to float rounding. Nothing changes on a CPU.
    """
    th.backends.cuda.matmul.allow_tf32 = True
    th.backends.cudnn.allow_tf32 = True


class GraphedActor:
    """The actor on one observation, captured once as a CUDA graph and replayed at each env step (acting with
    ``compile_update`` on CUDA: one graph launch instead of a launch per layer).

    The graph reads the actor's parameters where they are, so the updates, which write them in place (Adam's
    step, the compiled update's graph, ``load_state_dict``), reach it; :meth:`current` tells when it must be
    captured again (another actor, another observation shape, a parameter replaced or moved). The replay runs the
    kernels the eager forward pass runs, on the same inputs.

    :param actor: the policy's actor, on a CUDA device
    :param shape: the shape of the observations it acts on, ``(n_envs, obs_dim)``
    """

    def __init__(self, actor: th.nn.Module, shape: tuple[int, ...]) -> None:
        self.actor = actor
        self.parameters = list(actor.parameters())
        self.addresses = [p.data_ptr() for p in self.parameters]
        device = self.parameters[0].device
        self.input = th.zeros(shape, device=device)
        # warm up on a side stream (cuBLAS' workspaces and lazy initialisation stay out of the graph), then capture
        stream = th.cuda.Stream(device)
        stream.wait_stream(th.cuda.current_stream(device))
        with th.no_grad(), th.cuda.stream(stream):
            for _ in range(3):
                actor(self.input)
        th.cuda.current_stream(device).wait_stream(stream)
        self.graph = th.cuda.CUDAGraph()
        with th.no_grad(), th.cuda.graph(self.graph):
            self.output = actor(self.input)

    def current(self, actor: th.nn.Module, shape: tuple[int, ...]) -> bool:
        """Whether the captured graph is that of ``actor``'s parameters, as they are now, for ``shape``."""
        if actor is not self.actor or tuple(shape) != tuple(self.input.shape):
            return False
        parameters = list(actor.parameters())
        return len(parameters) == len(self.parameters) and all(
            p is q and p.data_ptr() == address for p, q, address in zip(parameters, self.parameters, self.addresses)
        )

    def __call__(self, observation: np.ndarray) -> np.ndarray:
        """The actor's output for ``observation`` (float32, ``shape``), as a numpy array (waits for the device)."""
        self.input.copy_(th.from_numpy(observation))
        self.graph.replay()
        return self.output.cpu().numpy()
