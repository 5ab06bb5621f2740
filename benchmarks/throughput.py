"""Update throughput of every method against the time of its own matrix products.

For each method and size (``full``: hidden 1024, batch 1024, URLB; ``small``: hidden 256, batch 256,
the size of this project's studies) one fresh process (so that its peak memory is its own) builds
the model on ``URLB/walker-v0`` (DDPG: ``URLB/walker-stand-v0``), fills the replay buffer with random
steps, and measures, timed in turns (see :func:`best_times`), the fastest of ``--repeats``:

* ``matmul ms``: the update's own matrix products (every ``mm``/``addmm``/``bmm`` one update calls,
  recorded with their shapes and strides and replayed on tensors of the same layout): the time the
  update would take if everything but its matrix products were free;
* ``after ms``: one update (``model.train(1, batch)``: sampling, the reward module's update and
  relabelling, critic and actor steps, target update) with every switch of
  :data:`sb3_cic.speed.speed_options` on (the default), and ``x``: after / matmul;
* ``before ms``: the same update with all of them off, and ``x``;
* one column per switch: the update with only that switch off (``-``: the switch does not touch
  this method's update);
* ``GFLOP``: the update's floating-point operations in its matrix products
  (``torch.utils.flop_counter.FlopCounterMode``, forward and backward), and ``GFLOP/s`` at ``after``;
* ``loop %`` before and after: the time of a ``learn()`` (one update every 2 env steps) outside
  ``model.train`` and the VecEnv's ``step`` (both timed inside it; env steps include the skill
  wrapper and Monitor), over the time inside them: what SB3's loop adds, action selection and
  buffer insertion included; ``lean_acting`` and ``lean_forward`` are the switches that act on it;
* ``learn steps/s`` (after) and ``2M h``: the hours a 2M-step pre-training takes at that rate;
* ``peak MiB``: the process's peak resident memory (CPU) or ``torch.cuda.max_memory_allocated``.

A plain-PyTorch CIC (the same networks, losses and reward on batches drawn from tensors, no SB3)
runs beside them as ``cic (plain torch)``. ``--ablations`` times the CIC update with each older
speed change undone (fused reward, frozen critic in the actor step, foreach lerp, fused Adam) and
the kNN reward of a batch. ``--profile`` prints where the time of five updates of each method goes
(``torch.profiler``, by operator). ``--compile MODE`` adds rows with the update's loss computations
under ``torch.compile`` (``critic_loss``, ``actor_loss`` and the reward module's networks;
``reduce-overhead`` adds CUDA graphs on a GPU); the package itself runs eagerly.

``--loop`` measures the acting loop instead (DDPG and CIC of ``--methods``, hidden 256 and 1024 or
``--loop-hidden``; one fresh process each), per env step, fastest of ``--repeats`` chunks of ``--loop-steps``
steps timed in turns: ``env`` the underlying gymnasium env's own ``step`` (``URLB/walker-stand-v0`` or
``URLB/walker-v0``, no wrapper, reset at episode ends) replaying the trajectory of the latest ``lean`` chunk (its
episode start from the env's checkpoint, its actions; checked to give the observations that ``learn()`` stored,
bit for bit), ``env rnd`` the same env on uniform random actions (another trajectory, so another cost of the
physics: the bound of earlier runs), ``actor`` one forward pass of the actor for one observation (``no_grad``), and
``learn()`` with ``gradient_steps=0`` and ``learning_starts=0`` (the policy acts, with its noise, at every step;
warmed up first) with ``speed_options.lean_loop`` on (``lean``) and off (``sb3``), and their ratios to
``env + actor``; ``pair`` is the actor and the env in turn with nothing else (each acting on the other's last
output), a floor of any acting loop. ``--loop-steps`` is a multiple of the episode length, so that each chunk
starts at an episode start.

``--fast`` puts each method's eager update beside ``compile_update=True`` (one fresh process per method and
size): update ms, ``learn()`` env steps/s over ``--learn-steps`` (one update every 2 env steps), hours per 2M
steps, the first compiled update's time (compiling included) and peak memory; on a GPU, the command of the GPU
figures (``docs/results/throughput_gpu.md``) came from ``python benchmarks/throughput.py --device cuda --sizes full
--fast --learn-steps 20000 --repeats 10`` (``benchmarks/gpu_check.sh`` runs it, at 10,000 steps, after the
CUDA-only tests, and says how to bundle the dependencies for a GPU machine without a registry).

Usage::

    MUJOCO_GL=disable python benchmarks/throughput.py --threads 1 --sizes small   # the study size, one thread
    MUJOCO_GL=disable python benchmarks/throughput.py --methods cic ddpg --sizes full --ablations
    MUJOCO_GL=disable python benchmarks/throughput.py --device cuda         # where a GPU exists
    MUJOCO_GL=disable python benchmarks/throughput.py --methods cic --sizes small --profile
    OMP_NUM_THREADS=1 MUJOCO_GL=disable python benchmarks/throughput.py --threads 1 --methods ddpg cic --loop
"""

from __future__ import annotations

import argparse
import concurrent.futures as futures
import dataclasses
import multiprocessing
import os
import resource
import sys
import time
from typing import Any, Callable

os.environ.setdefault("MUJOCO_GL", "disable")
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import torch as th  # noqa: E402
import torch.nn.functional as F  # noqa: E402
from torch import nn  # noqa: E402
from torch.utils._python_dispatch import TorchDispatchMode  # noqa: E402
from torch.utils.flop_counter import FlopCounterMode  # noqa: E402

SIZES = {"full": (1024, 1024), "small": (256, 256)}
METHODS = ["ddpg", "cic", "icm", "disagreement", "rnd", "apt", "protorl", "diayn", "smm", "aps"]


def _sync(device: th.device) -> None:
    if device.type == "cuda":
        th.cuda.synchronize(device)


def best_times(fns: dict[str, Callable[[], Any]], device: th.device, repeats: int, warmup: int = 2) -> dict[str, float]:
    """Fastest wall time (seconds) of each of ``fns``, called in turn ``repeats`` times after warm-up.

    This machine's speed drifts by tens of percent while other work shares its cores; the turns
    expose every function to the same spells of load, and the fastest call of each is its least
    disturbed one, so that ratios between them (update / matmul, variant / shipped) hold.
    """
    for fn in fns.values():
        for _ in range(warmup):
            fn()
    _sync(device)
    best = {name: float("inf") for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            start = time.perf_counter()
            fn()
            _sync(device)
            best[name] = min(best[name], time.perf_counter() - start)
    return best


def count_flops(fn: Callable[[], Any]) -> int:
    """Floating-point operations of the matrix products of one call of ``fn``."""
    with FlopCounterMode(display=False) as counter:
        fn()
    return int(counter.get_total_flops())


def peak_memory_mib(device: th.device) -> float:
    if device.type == "cuda":
        return th.cuda.max_memory_allocated(device) / 2**20
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux


MATMULS = {th.ops.aten.mm.default, th.ops.aten.addmm.default, th.ops.aten.bmm.default, th.ops.aten.baddbmm.default}


class _RecordMatmuls(TorchDispatchMode):
    """Records each matrix product's operator, argument layouts (shape, stride) and keyword arguments."""

    def __init__(self) -> None:
        super().__init__()
        self.calls: list[tuple[Any, list[Any], dict[str, Any]]] = []

    def __torch_dispatch__(self, func: Any, types: Any, args: tuple = (), kwargs: dict | None = None) -> Any:
        kwargs = kwargs or {}
        if func in MATMULS:
            layouts = [(a.shape, a.stride(), a.dtype) if isinstance(a, th.Tensor) else a for a in args]
            self.calls.append((func, layouts, dict(kwargs)))
        return func(*args, **kwargs)


def matmul_replay(step: Callable[[], Any], device: th.device) -> tuple[Callable[[], None], int]:
    """A function that runs the matrix products of one call of ``step`` on fresh tensors of the same layouts.

    The products see inputs of the same shapes and strides (transposed views stay transposed), so
    MKL/cuBLAS pick the same kernels; their values are random (products' time does not depend on them).
    Returns the function and the number of products.
    """
    recorder = _RecordMatmuls()
    with recorder:
        step()
    def like(shape: th.Size, stride: tuple[int, ...], dtype: th.dtype) -> th.Tensor:  # broadcast views too
        storage = 1 + sum((n - 1) * s for n, s in zip(shape, stride))
        return th.randn(storage, dtype=dtype, device=device).as_strided(shape, stride)

    calls = [
        (func, [like(*a) if isinstance(a, tuple) else a for a in layouts], kwargs) for func, layouts, kwargs in recorder.calls
    ]

    def replay() -> None:
        for func, args, kwargs in calls:
            func(*args, **kwargs)

    return replay, len(calls)


def time_against_bound(step: Callable[[], Any], hidden: int, device: th.device, repeats: int) -> dict[str, float]:
    """The fastest time of ``step`` (one update) in turns with its own matrix products, and its FLOP."""
    replay, _ = matmul_replay(step, device)
    best = best_times({"update": step, "matmul": replay}, device, repeats)
    flops = count_flops(step)
    return {"update_ms": best["update"] * 1e3, "gflop": flops / 1e9, "bound_ms": best["matmul"] * 1e3}


# ----------------------------------------------------------------------------------------------
# the package's methods
def fill_steps(batch: int) -> int:
    """Random steps put in the buffer before the first timed update."""
    return max(2 * batch, 2000)


def build(
    method: str, hidden: int, batch: int, device: str, buffer_size: int = 10_000, seed: int = 0, compile_mode: str = "",
    compile_update: bool = False,
) -> Any:
    """A model of ``method`` whose buffer holds :func:`fill_steps` random steps (no update taken yet).

    ``compile_update`` is the model's argument (the whole step compiled, at its first update).

    With ``compile_mode``, ``critic_loss``, ``actor_loss`` and each network of the reward module go
    through ``torch.compile(mode=compile_mode)`` (compiled during the warm-up updates).
    """
    from sb3_cic.zoo import get_algo

    cls = get_algo(method)
    env_id = "URLB/walker-stand-v0" if method == "ddpg" else "URLB/walker-v0"
    model = cls(
        "MlpPolicy",
        env_id,
        policy_kwargs={"hidden_dim": hidden},
        batch_size=batch,
        buffer_size=buffer_size,
        learning_starts=fill_steps(batch),
        device=device,
        seed=seed,
        compile_update=compile_update,
    )
    if compile_mode:
        model.critic_loss = th.compile(model.critic_loss, mode=compile_mode)
        model.actor_loss = th.compile(model.actor_loss, mode=compile_mode)
        for network in (model.reward_module.children() if model.reward_module is not None else ()):
            if next(network.parameters(), None) is not None:
                network.compile(mode=compile_mode)
    model.learn(fill_steps(batch))  # random actions only: SB3 trains once num_timesteps > learning_starts
    return model


def timed_learn(model: Any, steps: int, device: th.device) -> tuple[float, float, float]:
    """``learn(steps)`` with its updates and env steps timed inside it: ``(total, train, env)`` seconds.

    ``train`` is the time in ``model.train`` (sampling, reward module, critic, actor, target), ``env``
    the time in the VecEnv's ``step`` (the env, skill wrapper and Monitor); the rest is SB3's loop
    (action selection, buffer insertion, callbacks, logging).
    """
    spent = {"train": 0.0, "env": 0.0}

    def timed(fn: Callable, key: str) -> Callable:
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            start = time.perf_counter()
            out = fn(*args, **kwargs)
            _sync(device)
            spent[key] += time.perf_counter() - start
            return out

        return wrapper

    model.train = timed(model.train, "train")
    model.env.step = timed(model.env.step, "env")
    try:
        start = time.perf_counter()
        model.learn(steps, reset_num_timesteps=False)
        _sync(device)
        total = time.perf_counter() - start
    finally:
        del model.train, model.env.step  # the instance attributes: back to the methods
    return total, spent["train"], spent["env"]


#: methods whose update computes k-nearest-neighbour distances (the ``knn_partition`` switch)
KNN_METHODS = {"cic", "apt", "aps", "protorl"}


def measure_method(
    method: str, size: str, device_name: str, repeats: int, learn_steps: int, threads: int, compile_mode: str = ""
) -> dict:
    """One row of the table (run in a fresh process)."""
    from sb3_cic.speed import SpeedOptions, speed_options

    th.set_num_threads(threads)
    device = th.device(device_name)
    hidden, batch = SIZES[size]
    model = build(method, hidden, batch, device_name, fill_steps(batch) + 2 * learn_steps + 1000, compile_mode=compile_mode)
    every = [f.name for f in dataclasses.fields(SpeedOptions)]

    def update(**off: bool) -> Callable[[], None]:
        def run() -> None:
            with speed_options.override(**off):
                model.train(1, batch)

        return run

    replay, n_matmuls = matmul_replay(update(), device)
    variants = {"after": update(), "before": update(**dict.fromkeys(every, False)), "matmul": replay}
    switches = ["lean_adam", "lean_forward", *(["knn_partition"] if method in KNN_METHODS else [])]
    variants.update({name: update(**{name: False}) for name in switches})
    best = best_times(variants, device, repeats)
    loop_pct, steps_per_s = {}, 0.0
    for label, acting in (("before", False), ("after", True)):
        with speed_options.override(lean_acting=acting, lean_forward=acting):
            total, train, env = timed_learn(model, learn_steps, device)
        loop_pct[label], steps_per_s = 100 * (total - train - env) / (train + env), learn_steps / total
    flops = count_flops(update())
    return {
        "name": method + (f" ({compile_mode})" if compile_mode else ""),
        "size": size,
        "ms": {k: v * 1e3 for k, v in best.items()},
        "n_matmuls": n_matmuls,
        "gflop": flops / 1e9,
        "loop_before": loop_pct["before"],
        "loop_after": loop_pct["after"],
        "steps_per_s": steps_per_s,
        "peak_mib": peak_memory_mib(device),
    }


# ----------------------------------------------------------------------------------------------
# the acting loop against the env and the actor
LOOP_METHODS = ("ddpg", "cic")


def measure_loop(method: str, hidden: int, repeats: int, steps: int, threads: int) -> dict[str, float]:
    """Per-step times (ms) of the raw env, the actor and ``learn()`` without updates, lean loop on and off."""
    import numpy as np

    from sb3_cic.speed import speed_options
    from sb3_cic.zoo import get_algo

    th.set_num_threads(threads)
    env_id = "URLB/walker-stand-v0" if method == "ddpg" else "URLB/walker-v0"
    model = get_algo(method)(
        "MlpPolicy", env_id, policy_kwargs={"hidden_dim": hidden}, learning_starts=0, gradient_steps=0,
        buffer_size=100_000, seed=0,
    )
    raw_env = model.env.envs[0].unwrapped  # the gymnasium env below the skill wrapper and Monitor
    raw_env.reset(seed=1)
    random_actions = np.random.default_rng(0).uniform(-1, 1, (steps, *raw_env.action_space.shape)).astype(np.float32)
    obs = model.observation_space.sample()[None]
    buffer = model.replay_buffer
    state_dim = raw_env.observation_space.shape[0]
    lean_run: dict[str, Any] = {}  # the episode start and the actions of the latest lean learn() chunk

    def replay(actions: np.ndarray) -> np.ndarray:
        """The raw env's steps on ``actions`` (reset at episode ends); the observations."""
        observations = np.empty((len(actions), state_dim), np.float32)
        for i, action in enumerate(actions):
            observations[i], _, terminated, truncated, _ = raw_env.step(action)
            if terminated or truncated:
                raw_env.reset()
        return observations

    def at_episode_start(fn: Callable[[], None]) -> Callable[[], None]:
        """``fn``, after which the env is put back at the episode start it was at (learn() goes on from there)."""

        def run() -> None:
            start = raw_env.get_checkpoint_state()
            try:
                fn()
            finally:
                raw_env.set_checkpoint_state(start)

        return run

    def env_steps() -> None:  # the trajectory of the latest lean learn() chunk, replayed
        raw_env.set_checkpoint_state(lean_run["start"])
        lean_run["replayed"] = replay(lean_run["actions"])

    def env_random_actions() -> None:
        replay(random_actions)

    def actor_steps() -> None:
        actor = model.policy.actor
        with th.no_grad():
            for _ in range(steps):
                actor(th.as_tensor(obs))

    def alternating() -> None:  # the two in turn, each step acting on the env's last state
        actor, state = model.policy.actor, obs.copy()
        with th.no_grad():
            for _ in range(steps):
                action = actor(th.as_tensor(state)).numpy()[0]
                next_state, _, terminated, truncated, _ = raw_env.step(action)
                if terminated or truncated:
                    next_state, _ = raw_env.reset()
                state[0, : len(next_state)] = next_state

    def learn(lean: bool) -> Callable[[], None]:
        def run() -> None:
            start, first = raw_env.get_checkpoint_state(), buffer.pos
            with speed_options.override(lean_loop=lean):
                model.learn(steps, reset_num_timesteps=False)
            if lean:
                rows = np.arange(first, first + steps) % buffer.buffer_size
                actions = model.policy.unscale_action(buffer.actions[rows, 0])  # what the env was given
                lean_run.update(start=start, actions=actions, next_obs=buffer.next_observations[rows, 0])

        return run

    # chunks of whole episodes: each learn() chunk starts at an episode start, where the env's checkpoint replays it
    if steps % int(raw_env.dm_env._step_limit):
        raise ValueError(f"--loop-steps must be a multiple of the episode length, got {steps}")
    best = best_times(
        {
            "lean": learn(True), "sb3": learn(False), "env": at_episode_start(env_steps),
            "env_random": at_episode_start(env_random_actions), "actor": actor_steps,
            "pair": at_episode_start(alternating),
        },
        th.device("cpu"),
        repeats,
    )
    # the replay is the lean chunk's trajectory: the same observations as learn() stored (truncated episode ends:
    # the stored next observation is the terminal one, as the replay's)
    gap = float(np.abs(lean_run["replayed"] - lean_run["next_obs"][:, :state_dim]).max())
    if gap > 0:
        raise RuntimeError(f"the raw env's replay left learn()'s trajectory (observations differ by up to {gap})")
    return {name: seconds * 1e3 / steps for name, seconds in best.items()}


# ----------------------------------------------------------------------------------------------
# eager against compile_update=True
def measure_fast(method: str, size: str, device_name: str, repeats: int, learn_steps: int, threads: int) -> dict:
    """One method at one size, eager and ``compile_update=True`` side by side (``--fast``).

    Per path: the first compiled update (``compile s``: compiling included), one update (``update ms``, the fastest
    of ``repeats`` turns of 10 updates, the two paths in turn), ``learn()`` env steps/s over ``learn_steps`` steps
    with one update every 2 (after the warm-up above), the hours of a 2M-step pre-training at that rate, and the
    peak memory (CUDA: ``max_memory_allocated``; CPU: the process's peak resident memory, both paths together).
    """
    th.set_num_threads(threads)
    device = th.device(device_name)
    hidden, batch = SIZES[size]
    out: dict[str, Any] = {}
    models = {}
    for fast in (False, True):
        model = build(method, hidden, batch, device, compile_update=fast)
        start = time.perf_counter()
        model.train(1, batch)
        _sync(device)
        out[f"compile s {fast}"] = time.perf_counter() - start
        models[fast] = model
    times = best_times({fast: (lambda m=m: m.train(10, batch)) for fast, m in models.items()}, device, repeats)
    for fast, model in models.items():
        if device.type == "cuda":
            th.cuda.reset_peak_memory_stats(device)
        start = time.perf_counter()
        model.learn(learn_steps, reset_num_timesteps=False)
        _sync(device)
        rate = learn_steps / (time.perf_counter() - start)
        out[f"update ms {fast}"] = times[fast] * 100.0
        out[f"steps/s {fast}"] = rate
        out[f"2M h {fast}"] = 2e6 / rate / 3600
        out[f"peak MiB {fast}"] = peak_memory_mib(device)
    return out


def print_fast_table(args: argparse.Namespace) -> None:
    """The ``--fast`` table: each method eager and compiled, side by side."""
    print(f"torch {th.__version__}, {args.device}, {args.threads} threads; update: fastest of {args.repeats} turns of 10; "
          f"learn(): {args.learn_steps} env steps after the warm-up")
    columns = ["update ms", "x", "steps/s", "x", "2M h", "compile s", "peak MiB"]
    header = f"{'method':<14}{'size':<6}{'path':<9}" + "".join(f"{name:>11}" for name in columns)
    print(header + "\n" + "-" * len(header))
    for size in args.sizes:
        for method in args.methods:
            r = _in_fresh_process(measure_fast, method, size, args.device, args.repeats, args.learn_steps, args.threads)
            for fast in (False, True):
                speedup = r[f"update ms {False}"] / r[f"update ms {fast}"]
                rate_up = r[f"steps/s {fast}"] / r[f"steps/s {False}"]
                print(
                    f"{method:<14}{size:<6}{'compiled' if fast else 'eager':<9}{r[f'update ms {fast}']:>11.2f}{speedup:>10.2f}x"
                    f"{r[f'steps/s {fast}']:>11.1f}{rate_up:>10.2f}x{r[f'2M h {fast}']:>11.2f}"
                    f"{r[f'compile s {fast}'] if fast else float('nan'):>11.1f}{r[f'peak MiB {fast}']:>11.0f}",
                    flush=True,
                )


# ----------------------------------------------------------------------------------------------
# the same CIC update in plain PyTorch
class PlainCIC:
    """CIC (URLB networks, contrastive loss, particle reward, DDPG update) on tensors, without SB3.

    Written as a user would write it in plain PyTorch: one Adam per network, batches indexed from
    tensors that live on the device, the same mathematics as :class:`sb3_cic.CIC`.
    """

    def __init__(self, state_dim: int, action_dim: int, skill_dim: int, hidden: int, device: th.device) -> None:
        obs_dim = state_dim + skill_dim
        self.state_dim, self.skill_dim, self.device = state_dim, skill_dim, device

        def mlp(i: int, o: int) -> nn.Sequential:
            return nn.Sequential(nn.Linear(i, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, o))

        def head() -> nn.Sequential:
            return nn.Sequential(nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, 1))

        self.actor = nn.Sequential(
            nn.Linear(obs_dim, hidden), nn.LayerNorm(hidden), nn.Tanh(),
            nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, action_dim), nn.Tanh(),
        ).to(device)
        self.critic = nn.ModuleDict({
            "trunk": nn.Sequential(nn.Linear(obs_dim + action_dim, hidden), nn.LayerNorm(hidden), nn.Tanh()),
            "q1": head(), "q2": head(),
        }).to(device)
        self.critic_target = nn.ModuleDict({
            "trunk": nn.Sequential(nn.Linear(obs_dim + action_dim, hidden), nn.LayerNorm(hidden), nn.Tanh()),
            "q1": head(), "q2": head(),
        }).to(device)
        self.critic_target.load_state_dict(self.critic.state_dict())
        self.cic = nn.ModuleDict({
            "state_net": mlp(state_dim, skill_dim), "pred_net": mlp(2 * skill_dim, skill_dim),
            "skill_net": mlp(skill_dim, skill_dim),
        }).to(device)
        self.actor_opt = th.optim.Adam(self.actor.parameters(), lr=1e-4)
        self.critic_opt = th.optim.Adam(self.critic.parameters(), lr=1e-4)
        self.cic_opt = th.optim.Adam(self.cic.parameters(), lr=1e-4)
        self.rms_mean, self.rms_count = th.zeros((), device=device), 1e-4

    def q(self, critic: nn.ModuleDict, obs: th.Tensor, action: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        h = critic["trunk"](th.cat([obs, action], 1))
        return critic["q1"](h), critic["q2"](h)

    def noisy(self, mu: th.Tensor) -> th.Tensor:
        return (mu + (0.2 * th.randn_like(mu)).clamp(-0.3, 0.3)).clamp(-1, 1)

    def update(self, obs: th.Tensor, action: th.Tensor, next_obs: th.Tensor, discount: th.Tensor) -> None:
        state, skill, next_state = obs[:, : self.state_dim], obs[:, self.state_dim :], next_obs[:, : self.state_dim]
        # CIC discriminator and reward
        embedding = self.cic["state_net"](th.cat([state, next_state]))
        key = self.cic["pred_net"](th.cat(embedding.chunk(2), 1))
        logits = F.normalize(self.cic["skill_net"](skill), dim=1) @ F.normalize(key, dim=1).T / 0.5
        loss = F.cross_entropy(logits, th.arange(len(obs), device=self.device))
        with th.no_grad():
            source = embedding[len(obs) :]
            dist = th.cdist(source, source).topk(12, dim=1, largest=False).values
            n = dist.numel()
            self.rms_mean = self.rms_mean + (dist.mean() - self.rms_mean) * n / (self.rms_count + n)
            self.rms_count += n
            reward = th.log(1 + (dist.mean(1, keepdim=True) / self.rms_mean - 0.0005).clamp_min(0))
        self.cic_opt.zero_grad()
        loss.backward()
        self.cic_opt.step()
        # critic
        with th.no_grad():
            target = reward + discount * th.min(*self.q(self.critic_target, next_obs, self.noisy(self.actor(next_obs))))
        q1, q2 = self.q(self.critic, obs, action)
        critic_loss = F.mse_loss(q1, target) + F.mse_loss(q2, target)
        self.critic_opt.zero_grad()
        critic_loss.backward()
        self.critic_opt.step()
        # actor
        actor_loss = -th.min(*self.q(self.critic, obs, self.noisy(self.actor(obs)))).mean()
        self.actor_opt.zero_grad()
        actor_loss.backward()
        self.actor_opt.step()
        with th.no_grad():
            for p, tp in zip(self.critic.parameters(), self.critic_target.parameters()):
                tp.lerp_(p, 0.01)


def measure_plain_cic(size: str, device_name: str, repeats: int, threads: int) -> dict:
    th.set_num_threads(threads)
    device = th.device(device_name)
    hidden, batch = SIZES[size]
    state_dim, action_dim, skill_dim, capacity = 24, 6, 64, 10_000
    agent = PlainCIC(state_dim, action_dim, skill_dim, hidden, device)
    obs = th.rand(capacity, state_dim + skill_dim, device=device)
    actions = th.rand(capacity, action_dim, device=device) * 2 - 1
    next_obs = th.rand(capacity, state_dim + skill_dim, device=device)
    discounts = th.full((capacity, 1), 0.99**3, device=device)

    def step() -> None:
        idx = th.randint(capacity, (batch,), device=device)
        agent.update(obs[idx], actions[idx], next_obs[idx], discounts[idx])

    timing = time_against_bound(step, hidden, device, repeats)
    return {
        "name": "cic (plain torch)",
        "size": size,
        "ms": {"after": timing["update_ms"], "matmul": timing["bound_ms"]},
        "gflop": timing["gflop"],
        "loop_before": float("nan"),
        "loop_after": float("nan"),
        "steps_per_s": float("nan"),
        "peak_mib": peak_memory_mib(device),
    }


# ----------------------------------------------------------------------------------------------
# ablations: each speed change of the package undone
def measure_ablations(size: str, device_name: str, repeats: int, threads: int) -> list[tuple[str, float]]:
    """CIC update time (ms) as shipped, with each older speed change undone and with two changes tried and not
    adopted (in turns); kNN reward time."""
    from contextlib import contextmanager, nullcontext

    from stable_baselines3.common.utils import polyak_update

    from sb3_cic.policies import URLBCritic
    from sb3_cic.rewards.base import RewardModule
    from sb3_cic.rewards.particle import ParticleEntropy

    th.set_num_threads(threads)
    device = th.device(device_name)
    hidden, batch = SIZES[size]
    model = build("cic", hidden, batch, device_name)
    module = model.reward_module

    @contextmanager
    def unfused_reward():  # reward and discriminator update with separate state_net passes
        module.update_and_reward = lambda data: RewardModule.update_and_reward(module, data)
        yield
        del module.update_and_reward

    @contextmanager
    def critic_weight_gradients():  # critic weight gradients computed during the actor step
        model.freeze_critic_in_actor_step = False
        yield
        model.freeze_critic_in_actor_step = True

    @contextmanager
    def polyak_loop():  # SB3's polyak_update (a Python loop over parameters) instead of one foreach lerp
        foreach_lerp = th._foreach_lerp_
        th._foreach_lerp_ = lambda targets, sources, tau: polyak_update(sources, targets, tau)
        yield
        th._foreach_lerp_ = foreach_lerp

    owners = [model.actor, model.critic, module]
    per_tensor = [th.optim.Adam(o.optimizer.param_groups[0]["params"], lr=1e-4, foreach=False) for o in owners]

    @contextmanager
    def per_tensor_adam():  # torch's per-tensor Adam (its CPU default) instead of the fused one
        fused = [o.optimizer for o in owners]
        for owner, optimizer in zip(owners, per_tensor):
            owner.optimizer = optimizer
        yield
        for owner, optimizer in zip(owners, fused):
            owner.optimizer = optimizer

    @contextmanager
    def heads_as_one_product():  # tried, not adopted: each layer of the twin heads as one product
        def forward(critic: URLBCritic, obs: th.Tensor, actions: th.Tensor) -> tuple[th.Tensor, ...]:
            h = critic.trunk(th.cat([obs, actions], dim=1))
            first, last = [q[0] for q in critic.q_networks], [q[2] for q in critic.q_networks]
            hidden = F.relu(F.linear(h, th.cat([lin.weight for lin in first]), th.cat([lin.bias for lin in first])))
            out = F.linear(hidden, th.block_diag(*[lin.weight for lin in last]), th.cat([lin.bias for lin in last]))
            return out.split(critic.output_dim, dim=1)

        original, URLBCritic.forward = URLBCritic.forward, forward
        yield
        URLBCritic.forward = original

    class SigmoidTanh(th.autograd.Function):  # tanh(x) = 2 sigmoid(2x) - 1 (absolute error ~1.8e-7)
        @staticmethod
        def forward(ctx: Any, x: th.Tensor) -> th.Tensor:
            y = th.sigmoid(x * 2).mul_(2).sub_(1)
            ctx.save_for_backward(y)
            return y

        @staticmethod
        def backward(ctx: Any, grad: th.Tensor) -> th.Tensor:
            return th.ops.aten.tanh_backward(grad, ctx.saved_tensors[0])

    class FastTanh(nn.Module):
        def forward(self, x: th.Tensor) -> th.Tensor:
            return SigmoidTanh.apply(x)

    @contextmanager
    def sigmoid_tanh():  # tried, not adopted: the trunks' tanh through the (3.5x faster alone) sigmoid
        trunks = [model.actor.trunk, model.critic.trunk, model.critic_target.trunk]
        for trunk in trunks:
            trunk[2] = FastTanh()
        yield
        for trunk in trunks:
            trunk[2] = nn.Tanh()

    def under(change: Callable) -> Callable[[], Any]:
        def run() -> None:
            with change():
                model.train(1, batch)

        return run

    variants = {
        "CIC update as shipped": under(nullcontext),
        "  reward not fused with the discriminator update": under(unfused_reward),
        "  critic weight gradients in the actor step": under(critic_weight_gradients),
        "  polyak_update loop for the target critic": under(polyak_loop),
        "  per-tensor Adam instead of fused Adam": under(per_tensor_adam),
        "  tried, not adopted: twin heads as one product": under(heads_as_one_product),
        "  tried, not adopted: tanh as 2 sigmoid(2x) - 1": under(sigmoid_tanh),
    }
    rows = list(best_times(variants, device, repeats).items())

    particle = ParticleEntropy().to(device)
    embedding = th.randn(batch, 64, device=device)
    knn = {
        f"kNN particle reward of a {batch} batch (matrix products + topk)": lambda: particle(embedding),
        "  same with B x B x D broadcast differences": lambda: (embedding[:, None] - embedding[None])
        .norm(dim=-1)
        .topk(12, dim=1, largest=False),
    }
    rows += list(best_times(knn, device, 5 * repeats).items())
    return [(name, seconds * 1e3) for name, seconds in rows]


def profile_method(method: str, size: str, device_name: str, threads: int, updates: int = 5, rows: int = 8) -> str:
    """The top operators of ``updates`` updates of ``method`` by own time (``torch.profiler``), and the products' share.

    Also the time the update's matrix products take inside it (their own time in the profile) against
    the same products replayed alone (:func:`matmul_replay`, fastest of 20): what the rest of the
    update costs them (caches, memory).
    """
    from torch.profiler import ProfilerActivity, profile

    th.set_num_threads(threads)
    hidden, batch = SIZES[size]
    model = build(method, hidden, batch, device_name)
    for _ in range(2):
        model.train(1, batch)
    replay, _ = matmul_replay(lambda: model.train(1, batch), th.device(device_name))
    replayed = best_times({"matmul": replay}, th.device(device_name), 20)["matmul"] * 1e3
    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if device_name.startswith("cuda") else [])
    with profile(activities=activities) as prof:
        for _ in range(updates):
            model.train(1, batch)
        _sync(th.device(device_name))
    events = prof.key_averages()
    key = "self_device_time_total" if device_name.startswith("cuda") else "self_cpu_time_total"
    total = sum(getattr(e, key) for e in events)
    products = sum(getattr(e, key) for e in events if e.key in ("aten::mm", "aten::addmm", "aten::bmm", "aten::baddbmm"))
    calls = sum(e.count for e in events if e.key.startswith("aten::")) / updates
    top = sorted(events, key=lambda e: -getattr(e, key))[:rows]
    share = 100 * products / total
    lines = [
        f"{method} ({size}): {calls:.0f} aten calls per update; matrix products {share:.1f}% of own time, "
        f"{products / updates / 1e3:.2f} ms per update (replayed alone: {replayed:.2f} ms)"
    ]
    for e in top:
        own = getattr(e, key)
        per_update = own / updates / 1e3
        lines.append(f"    {e.key[:48]:<48}{per_update:>8.3f} ms{e.count / updates:>7.1f} calls{100 * own / total:>7.1f}%")
    return "\n".join(lines)


# ----------------------------------------------------------------------------------------------
def _in_fresh_process(fn: Callable, *args: Any) -> Any:
    context = multiprocessing.get_context("spawn")
    with futures.ProcessPoolExecutor(max_workers=1, mp_context=context) as pool:
        return pool.submit(fn, *args).result()


def print_loop_table(args: argparse.Namespace) -> None:
    """The ``--loop`` table: ms per env step, and ``learn`` over ``env + actor``."""
    print(f"torch {th.__version__}, cpu, {args.threads} threads; ms per env step, fastest of {args.repeats} turns of "
          f"{args.loop_steps} steps; x: over env + actor")
    columns = ["env", "env rnd", "actor", "pair", "sb3", "lean", "pair x", "sb3 x", "lean x"]
    header = f"{'method':<8}{'hidden':>7}" + "".join(f"{name:>8}" for name in columns)
    print(header + "\n" + "-" * len(header))
    for method in [m for m in args.methods if m in LOOP_METHODS]:
        for hidden in args.loop_hidden:
            r = _in_fresh_process(measure_loop, method, hidden, args.repeats, args.loop_steps, args.threads)
            bound = r["env"] + r["actor"]
            times = "".join(f"{r[name]:>8.3f}" for name in ("env", "env_random", "actor", "pair", "sb3", "lean"))
            ratios = "".join(f"{r[name] / bound:>7.2f}x" for name in ("pair", "sb3", "lean"))
            print(f"{method:<8}{hidden:>7}{times}{ratios}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--methods", nargs="+", default=METHODS, choices=METHODS)
    parser.add_argument("--sizes", nargs="+", default=["full", "small"], choices=list(SIZES))
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--repeats", type=int, default=10, help="timed updates per row (the fastest counts)")
    parser.add_argument("--learn-steps", type=int, default=200, help="env steps of the timed learn()")
    parser.add_argument("--threads", type=int, default=th.get_num_threads())
    parser.add_argument("--no-plain", action="store_true", help="skip the plain-PyTorch CIC")
    parser.add_argument("--ablations", action="store_true", help="time the CIC update with each speed change undone")
    parser.add_argument(
        "--compile",
        default="",
        metavar="MODE",
        help="also time each method with its losses and reward networks under torch.compile(mode=MODE)",
    )
    parser.add_argument("--profile", action="store_true", help="where the time of each method's update goes, by operator")
    parser.add_argument("--loop", action="store_true", help="time the acting loop against the raw env and the actor")
    parser.add_argument("--loop-hidden", nargs="+", type=int, default=[256, 1024], help="hidden sizes of --loop")
    parser.add_argument("--loop-steps", type=int, default=1000, help="env steps per timed chunk of --loop")
    parser.add_argument("--fast", action="store_true", help="each method eager and with compile_update=True, side by side")
    args = parser.parse_args()
    if args.loop:
        print_loop_table(args)
        return
    if args.fast:
        print_fast_table(args)
        return

    print(f"torch {th.__version__}, device {args.device}, {args.threads} threads")
    header = (
        f"{'method':<20}{'size':>6}{'matmul ms':>10}{'after ms':>10}{'x':>7}{'before ms':>10}{'x':>7}"
        f"{'-lean_adam':>11}{'-lean_fwd':>10}{'-knn_part':>10}{'GFLOP':>7}{'GFLOP/s':>8}{'loop% b/a':>12}"
        f"{'steps/s':>9}{'2M h':>7}{'MiB':>6}"
    )
    print(header + "\n" + "-" * len(header))

    def cell(ms: dict[str, float], key: str, width: int, ratio: bool = False) -> str:
        if key not in ms:
            return f"{'-':>{width}}" + (f"{'':>7}" if ratio else "")
        text = f"{ms[key]:>{width}.2f}"
        return text + (f"{ms[key] / ms['matmul']:>6.2f}x" if ratio else "")

    for size in args.sizes:
        modes = ["", args.compile] if args.compile else [""]
        jobs = [
            (measure_method, m, size, args.device, args.repeats, args.learn_steps, args.threads, mode)
            for m in args.methods
            for mode in modes
        ]
        if not args.no_plain:
            jobs.append((measure_plain_cic, size, args.device, args.repeats, args.threads))
        for fn, *fn_args in jobs:
            r = _in_fresh_process(fn, *fn_args)
            ms = r["ms"]
            gflops = r["gflop"] * 1e3 / ms["after"]
            print(
                f"{r['name']:<20}{r['size']:>6}{ms['matmul']:>10.2f}{cell(ms, 'after', 10, True)}"
                f"{cell(ms, 'before', 10, True)}{cell(ms, 'lean_adam', 11)}{cell(ms, 'lean_forward', 10)}"
                f"{cell(ms, 'knn_partition', 10)}"
                f"{r['gflop']:>7.2f}{gflops:>8.0f}{r['loop_before']:>6.1f}/{r['loop_after']:>4.1f}%"
                f"{r['steps_per_s']:>9.1f}{2e6 / r['steps_per_s'] / 3600:>7.1f}{r['peak_mib']:>6.0f}",
                flush=True,
            )
    if args.ablations:
        for size in args.sizes:
            print(f"\nCIC speed changes undone ({size}: hidden {SIZES[size][0]}, batch {SIZES[size][1]}), fastest ms in turns")
            for name, ms in _in_fresh_process(measure_ablations, size, args.device, args.repeats, args.threads):
                print(f"{name:<55}{ms:>10.2f}")
    if args.profile:
        for size in args.sizes:
            print(f"\nTop operators of 5 updates ({size}: hidden {SIZES[size][0]}, batch {SIZES[size][1]}), per update")
            for method in args.methods:
                print(_in_fresh_process(profile_method, method, size, args.device, args.threads), flush=True)


if __name__ == "__main__":
    main()
