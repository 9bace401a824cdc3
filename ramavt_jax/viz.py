"""Pictures people would rather look at than read: episode GIFs, trajectories, tracking error."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from ramavt_jax import env as env_lib
from ramavt_jax import render
from ramavt_jax.baselines import Policy


@struct.dataclass
class EpisodeFrames:
    """One recorded episode, [T, ...]: what the camera saw and where everything was."""

    obs: jax.Array  # [T, H, W, C] observation given to the policy
    rgb: jax.Array  # [T, H, W, 3] colour view of the same camera
    rel_pos: jax.Array  # [T, 3] target centre in the camera frame
    chaser_pos: jax.Array  # [T, 3] Hill frame
    target_pos: jax.Array  # [T, 3] Hill frame
    reward: jax.Array  # [T]
    action: jax.Array  # [T]
    alive: jax.Array  # [T] bool, step belongs to the episode


def record_episode(tracking_env: env_lib.TrackingEnv, policy: Policy, params: env_lib.EnvParams, key: jax.Array,
                   steps: int) -> EpisodeFrames:
    """Run one episode (no auto-reset) and keep every frame. jit-compiled."""

    @jax.jit
    def run(key):
        k_reset, k_pol, k_loop = jax.random.split(key, 3)
        obs, state = tracking_env.reset(k_reset, params)
        pstate = policy.init(k_pol)

        def body(carry, step_key):
            obs, state, pstate, alive = carry
            k_act, k_env = jax.random.split(step_key)
            action, pstate = policy.act(k_act, pstate, obs, state, params)
            pose = tracking_env.pose(state, params)
            frame = render.render(state.target, pose.position, pose.rotation, tracking_env.config.camera,
                                  tracking_env.lighting(params), True)
            out = EpisodeFrames(obs=obs, rgb=frame.rgb, rel_pos=pose.position, chaser_pos=state.chaser_pos,
                                target_pos=state.target_pos, reward=jnp.zeros(()), action=action, alive=alive)
            obs, state, reward, terminated, truncated, _ = tracking_env.step_env(k_env, state, action, params)
            out = out.replace(reward=reward)
            return (obs, state, pstate, alive & ~(terminated | truncated)), out

        _, frames = jax.lax.scan(body, (obs, state, pstate, jnp.ones((), bool)), jax.random.split(k_loop, steps))
        return frames

    return jax.device_get(run(key))


def _to_uint8(image: np.ndarray, size: int) -> np.ndarray:
    """[H, W, C] float in [0, 1] (C = 1, 3 or 4) -> [size, size, 3] uint8, nearest-neighbour upscaled."""
    if image.shape[-1] == 1:
        image = np.repeat(image, 3, axis=-1)
    elif image.shape[-1] == 4:  # rgbd: show the depth channel
        image = np.repeat(image[..., 3:], 3, axis=-1)
    scale = max(1, size // image.shape[0])
    image = np.kron(image, np.ones((scale, scale, 1)))
    return (np.clip(image, 0, 1) * 255).astype(np.uint8)


def _trajectory_panel(frames: EpisodeFrames, t: int, size: int, desired_z: float = 5.0) -> np.ndarray:
    """Top view (x-z in the camera frame) of the target track and tracking error up to step t, as uint8 RGB."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_top, ax_err) = plt.subplots(2, 1, figsize=(size / 100, size / 100), dpi=100)
    rel = frames.rel_pos[: t + 1]
    ax_top.plot(rel[:, 0], rel[:, 2], color="tab:blue", lw=1)
    ax_top.scatter([rel[-1, 0]], [rel[-1, 2]], color="tab:red", s=12, zorder=3)
    ax_top.scatter([0], [desired_z], marker="+", color="k", s=40)
    ax_top.scatter([0], [0], marker="^", color="tab:green", s=30)
    ax_top.set_xlim(-6, 6), ax_top.set_ylim(-1, 15)
    ax_top.set_title("target in camera frame (top view)", fontsize=7)
    ax_top.tick_params(labelsize=6)
    err = rel - np.array([0.0, 0.0, desired_z])
    steps = np.arange(err.shape[0])
    for axis, name in enumerate("xyz"):
        ax_err.plot(steps, err[:, axis], lw=1, label=name)
    ax_err.set_xlim(0, max(len(frames.reward), 1)), ax_err.set_ylim(-6, 6)
    ax_err.legend(fontsize=6, loc="upper right"), ax_err.tick_params(labelsize=6)
    ax_err.set_title("tracking error (m)", fontsize=7)
    fig.tight_layout()
    fig.canvas.draw()
    image = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
    plt.close(fig)
    return image


def episode_video(frames: EpisodeFrames, out: str | Path, size: int = 256, fps: int = 10, every: int = 1) -> Path:
    """Write a GIF/MP4 (by suffix): camera colour view | observation | trajectory and error panel."""
    import imageio.v2 as imageio

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    alive = np.asarray(frames.alive)
    last = int(alive.sum())
    images = []
    for t in range(0, max(last, 1), every):
        left = _to_uint8(np.asarray(frames.rgb[t]), size)
        middle = _to_uint8(np.asarray(frames.obs[t]), size)
        right = _trajectory_panel(frames, t, size)
        right = right[: left.shape[0], : left.shape[0]]
        if right.shape[0] < left.shape[0] or right.shape[1] < left.shape[0]:
            pad = np.full((left.shape[0], left.shape[0], 3), 255, np.uint8)
            pad[: right.shape[0], : right.shape[1]] = right
            right = pad
        images.append(np.concatenate([left, middle, right], axis=1))
    if out.suffix.lower() == ".gif":
        imageio.mimsave(out, images, duration=1.0 / fps, loop=0)
    else:
        imageio.mimsave(out, images, fps=fps)
    return out


def plot_tracking_error(frames: EpisodeFrames, out: str | Path, desired_z: float = 5.0) -> Path:
    """Tracking error x/y/z over one episode (the paper's Fig. 5b)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    alive = np.asarray(frames.alive)
    rel = np.asarray(frames.rel_pos)[alive]
    err = rel - np.array([0.0, 0.0, desired_z])
    fig, ax = plt.subplots(figsize=(6, 3))
    for axis, name in enumerate("xyz"):
        ax.plot(err[:, axis], label=f"{name} error")
    ax.set_xlabel("step"), ax.set_ylabel("m"), ax.legend(), ax.grid(alpha=0.3)
    fig.tight_layout()
    out = Path(out)
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out


def plot_trajectory_3d(frames: EpisodeFrames, out: str | Path) -> Path:
    """3-D paths of chaser and target in the Hill frame (the paper's Fig. 5a)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    alive = np.asarray(frames.alive)
    chaser = np.asarray(frames.chaser_pos)[alive]
    target = np.asarray(frames.target_pos)[alive]
    fig = plt.figure(figsize=(5, 5))
    ax = fig.add_subplot(projection="3d")
    ax.plot(*chaser.T, label="chaser")
    ax.plot(*target.T, label="target")
    ax.set_xlabel("radial x (m)"), ax.set_ylabel("along-track y (m)"), ax.set_zlabel("cross-track z (m)")
    ax.legend()
    fig.tight_layout()
    out = Path(out)
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out
