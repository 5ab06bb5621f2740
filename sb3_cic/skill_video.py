"""``sb3-cic skills``: what a pre-trained policy does under several skills, as one grid video and a plot.

Each skill gets its own copy of the pre-training env (same seed, so the same start); the policy acts
deterministically with the skill fixed, every tile is labelled with its skill, and the tiles are
written side by side as one video (``.mp4`` through imageio's ffmpeg plugin, ``.gif`` through
Pillow). The plot shows where each skill takes the body: the position of the robot's root body over
time (walker, quadruped, jaco: forward position and height), or the path in the plane (point mass).
Rendering needs an OpenGL backend: run headless with ``MUJOCO_GL=egl``.

Usage::

    MUJOCO_GL=egl sb3-cic skills SNAPSHOT.zip --n 9 --steps 250 --out skills.mp4 --plot skills.png
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import gymnasium as gym
import numpy as np

from sb3_cic.command_line import argument_parser, option_type
from sb3_cic.common.arguments import POSITIVE_INT, SEED, Range

if TYPE_CHECKING:  # torch loads with the snapshot, not with ``sb3-cic skills --help``
    from sb3_cic.ddpg import URLBDDPG


def load_snapshot(path: str | Path, device: str = "cpu") -> URLBDDPG:
    """Load a saved model with the class that saved it (``model.algorithm``; URLBDDPG for older snapshots).

    :param path: saved model (``.zip``)
    :param device: torch device
    """
    from sb3_cic.common.save_util import check_saved_model
    from sb3_cic.zoo import get_algo

    cls = get_algo(check_saved_model(path).algorithm or "ddpg")  # a damaged file: a ValueError naming it
    return cls.load(path, device=device)


def skill_label(skill: np.ndarray, index: int) -> str:
    """A short label: the one-hot index of a discrete skill, else the index and the skill's mean."""
    if np.isin(skill, (0.0, 1.0)).all() and skill.sum() == 1:
        return f"skill {int(np.argmax(skill))}"
    return f"z{index}  mean {float(skill.mean()):.2f}"


def root_position(env: gym.Env) -> np.ndarray:
    """World position of the robot's root body (body 1 of the MuJoCo model), (x, y, z)."""
    return np.array(env.unwrapped.physics.data.xpos[1], dtype=np.float64)


def rollout_skills(
    model: URLBDDPG,
    skills: np.ndarray,
    steps: int,
    env_id: str | None = None,
    size: int = 160,
    seed: int = 0,
    render: bool = True,
) -> tuple[np.ndarray | None, np.ndarray]:
    """Act with ``model`` under each skill for ``steps`` steps from the same start.

    :param model: a model with a skill prior
    :param skills: ``(n, skill_dim)`` skills
    :param steps: env steps per skill
    :param env_id: env id (default: the model's own, ``model.env_id``)
    :param size: rendered tile height and width (pixels)
    :param seed: reset seed of every env
    :param render: render frames (else only the positions)
    :return: frames ``(steps + 1, n, size, size, 3)`` uint8 (None without ``render``) and root positions
        ``(n, steps + 1, 3)``
    """
    if model.skill_prior is None:
        raise ValueError(f"{type(model).__name__} has no skills to show")
    env_id = env_id or model.env_id
    if env_id is None:
        raise ValueError("the snapshot does not record its env: give env_id")
    frames: list[list[np.ndarray]] = [[] for _ in range(steps + 1)]
    positions = np.zeros((len(skills), steps + 1, 3))
    kwargs: dict[str, Any] = {"render_mode": "rgb_array", "render_size": (size, size)} if render else {}
    from sb3_cic.envs import SkillObservationWrapper

    for i, skill in enumerate(skills):
        env = SkillObservationWrapper(gym.make(env_id, **kwargs), model.skill_prior, resample_every=None)
        obs, _ = env.reset(seed=seed)
        env.set_skill(skill, fixed=True)
        obs[-model.skill_dim :] = skill
        for t in range(steps + 1):
            positions[i, t] = root_position(env)
            if render:
                frames[t].append(env.render())
            if t < steps:
                action, _ = model.predict(obs, deterministic=True)
                obs, _, terminated, truncated, _ = env.step(action)
                if terminated or truncated:
                    obs, _ = env.reset(seed=seed)
        env.close()
    return (np.asarray(frames, dtype=np.uint8) if render else None), positions


def grid_frames(frames: np.ndarray, labels: Sequence[str], columns: int | None = None) -> np.ndarray:
    """Tile ``(T, n, H, W, 3)`` frames into ``(T, rows * H, columns * W, 3)`` with each tile's label drawn on it."""
    from PIL import Image, ImageDraw

    steps, n, height, width, _ = frames.shape
    columns = columns or int(np.ceil(np.sqrt(n)))
    rows = int(np.ceil(n / columns))
    # the labels are drawn once, as a mask, and stamped on every frame
    masks = np.zeros((n, height, width), dtype=bool)
    for i, label in enumerate(labels):
        image = Image.new("L", (width, height))
        ImageDraw.Draw(image).text((4, 2), label, fill=255)
        masks[i] = np.asarray(image) > 127
    out = np.zeros((steps, rows * height, columns * width, 3), dtype=np.uint8)
    for i in range(n):
        r, c = divmod(i, columns)
        tile = frames[:, i].copy()
        tile[:, masks[i]] = 255
        out[:, r * height : (r + 1) * height, c * width : (c + 1) * width] = tile
    return out


def write_video(frames: np.ndarray, path: str | Path, fps: int = 30) -> None:
    """Write ``(T, H, W, 3)`` uint8 frames: ``.gif`` with Pillow, anything else (``.mp4``) with imageio's ffmpeg."""
    import imageio.v2 as imageio

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() == ".gif":
        imageio.mimsave(path, list(frames), duration=1000 / fps, loop=0)
    else:
        imageio.mimsave(path, list(frames), fps=fps, macro_block_size=1)


def plot_positions(positions: np.ndarray, labels: Sequence[str], path: str | Path, env_id: str, dt: float) -> None:
    """Where each skill goes: the plane path (point mass) or forward position and height over time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    planar = "point_mass" in env_id
    fig, axes = plt.subplots(1, 1 if planar else 2, figsize=(5 if planar else 10, 4), squeeze=False)
    time = np.arange(positions.shape[1]) * dt
    for pos, label in zip(positions, labels):
        if planar:
            axes[0, 0].plot(pos[:, 0], pos[:, 1], label=label)
            axes[0, 0].plot(pos[0, 0], pos[0, 1], "k.")
        else:
            axes[0, 0].plot(time, pos[:, 0], label=label)
            axes[0, 1].plot(time, pos[:, 2], label=label)
    if planar:
        axes[0, 0].set(xlabel="x", ylabel="y", title=f"{env_id}: path of each skill", aspect="equal")
    else:
        axes[0, 0].set(xlabel="time (s)", ylabel="root x (forward)", title=f"{env_id}: where each skill goes")
        axes[0, 1].set(xlabel="time (s)", ylabel="root z (height)")
    axes[0, -1].legend(fontsize=7, loc="best")
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def show_skills(
    snapshot: str | Path,
    n: int = 9,
    steps: int = 250,
    out: str | Path | None = "skills.mp4",
    plot: str | Path | None = None,
    env_id: str | None = None,
    size: int = 160,
    seed: int = 0,
    grid: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Render ``n`` skills of a snapshot side by side into ``out`` and plot where they go into ``plot``.

    :param snapshot: saved skill model
    :param n: number of skills
    :param steps: env steps per skill
    :param out: video path (``.mp4`` or ``.gif``); None for no video
    :param plot: PNG path of the positions plot; None for no plot
    :param env_id: env to act in (default: the snapshot's)
    :param size: tile size in pixels
    :param seed: seed of the skills drawn from the prior and of the env resets
    :param grid: use the prior's fine-tuning grid instead of skills drawn from the prior
    :return: the skills ``(n, skill_dim)`` and the root positions ``(n, steps + 1, 3)``
    """
    if n < 1 or steps < 1 or size < 16:
        raise ValueError(f"need n >= 1, steps >= 1 and size >= 16, got n={n}, steps={steps}, size={size}")
    model = load_snapshot(snapshot)
    if model.skill_prior is None:
        raise ValueError(f"{snapshot} is a {type(model).__name__} model, which has no skills")
    prior = model.skill_prior
    rng = np.random.default_rng(seed)
    skills = prior.grid(n)[:n] if grid else np.stack([prior.sample(rng) for _ in range(n)])
    labels = [skill_label(z, i) for i, z in enumerate(skills)]
    frames, positions = rollout_skills(model, skills, steps, env_id, size, seed, render=out is not None)
    env_id = env_id or model.env_id or ""
    if out is not None:
        assert frames is not None
        write_video(grid_frames(frames, labels), out)
    if plot is not None:
        dt = gym.make(env_id).unwrapped.dm_env.control_timestep()
        plot_positions(positions, labels, plot, env_id, dt)
    return skills, positions


def main(argv: Sequence[str] | None = None) -> None:
    """``sb3-cic skills``."""
    parser = argument_parser(
        "sb3-cic skills",
        "What a pre-trained policy does under several skills: one grid video (each tile a skill) and a plot of where "
        "each skill takes the body. Rendering needs an OpenGL backend (headless: MUJOCO_GL=egl).",
    )
    parser.add_argument("snapshot", type=Path, help="saved skill model (.zip)")
    parser.add_argument("--n", type=option_type(POSITIVE_INT), default=9, help="number of skills (tiles)")
    parser.add_argument("--steps", type=option_type(POSITIVE_INT), default=250, help="env steps per skill")
    parser.add_argument("--out", default="skills.mp4", help="video file (.mp4 or .gif)")
    parser.add_argument("--plot", default=None, help="PNG of where each skill goes (default: no plot)")
    parser.add_argument("--no-video", action="store_true", help="only the plot: nothing rendered, no OpenGL needed")
    parser.add_argument("--env", default=None, help="env id (default: the snapshot's pre-training env)")
    parser.add_argument("--size", type=option_type(Range(16, 1024, integer=True)), default=160, help="tile size in pixels")
    parser.add_argument("--seed", type=option_type(SEED), default=0, help="seed of the envs (the same start for each skill)")
    parser.add_argument("--grid", action="store_true", help="the prior's fine-tuning grid instead of random skills")
    args = parser.parse_args(argv)
    if not args.snapshot.exists():
        raise SystemExit(f"no snapshot at {args.snapshot}")
    if args.no_video and not args.plot:
        raise SystemExit("--no-video leaves only the plot: give --plot PNG")
    out = None if args.no_video else args.out
    show_skills(args.snapshot, args.n, args.steps, out, args.plot, args.env, args.size, args.seed, args.grid)
    print("wrote " + " and ".join(str(f) for f in (out, args.plot) if f))
