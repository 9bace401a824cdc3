"""Pictures people would rather look at than read: episode GIFs, trajectories, tracking error."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from ramavt_jax import env as env_lib
from ramavt_jax import network, render
from ramavt_jax.baselines import Policy
from ramavt_jax.figures import pyplot, save_figure
from ramavt_jax.figures.training import plot_training_runs
from ramavt_jax.training.files import replace_atomic


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


def record_episode(
    tracking_env: env_lib.TrackingEnv, policy: Policy, params: env_lib.EnvParams, key: jax.Array, steps: int
) -> EpisodeFrames:
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
            frame = render.render(
                state.target,
                pose.position,
                pose.rotation,
                tracking_env.config.camera,
                tracking_env.lighting(params),
                True,
            )
            out = EpisodeFrames(
                obs=obs,
                rgb=frame.rgb,
                rel_pos=pose.position,
                chaser_pos=state.chaser_pos,
                target_pos=state.target_pos,
                reward=jnp.zeros(()),
                action=action,
                alive=alive,
            )
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


def view_limits(frames: EpisodeFrames, desired_z: float = 5.0) -> tuple[float, float, float]:
    """(half width of x, far end of z, half range of the error) of the trajectory panel: at least the usual
    +-6 m x 15 m view, widened to hold the whole episode's track (a large target is held tens of metres away).
    Fixed over the episode, so the video's axes do not jump."""
    rel = np.asarray(frames.rel_pos, np.float64)[np.asarray(frames.alive, bool)].reshape(-1, 3)
    rel = rel[np.isfinite(rel).all(axis=1)]
    if rel.size == 0:
        return 6.0, 15.0, 6.0
    err = np.abs(rel - np.array([0.0, 0.0, desired_z])).max()
    return (
        max(6.0, 1.1 * np.abs(rel[:, 0]).max()),
        max(15.0, 1.1 * rel[:, 2].max(), 1.5 * desired_z),
        max(6.0, 1.1 * err),
    )


def _trajectory_panel(frames: EpisodeFrames, t: int, size: int, desired_z: float = 5.0) -> np.ndarray:
    """Top view (x-z in the camera frame) of the target track and tracking error up to step t, as uint8 RGB."""
    plt = pyplot()
    fig, (ax_top, ax_err) = plt.subplots(2, 1, figsize=(size / 100, size / 100), dpi=100)
    rel = frames.rel_pos[: t + 1]
    ax_top.plot(rel[:, 0], rel[:, 2], color="tab:blue", lw=1)
    ax_top.scatter([rel[-1, 0]], [rel[-1, 2]], color="tab:red", s=12, zorder=3)
    ax_top.scatter([0], [desired_z], marker="+", color="k", s=40)
    ax_top.scatter([0], [0], marker="^", color="tab:green", s=30)
    half, far, err_range = view_limits(frames, desired_z)
    ax_top.set_xlim(-half, half), ax_top.set_ylim(-1, far)
    ax_top.set_title("target in camera frame (top view)", fontsize=7)
    ax_top.tick_params(labelsize=6)
    err = rel - np.array([0.0, 0.0, desired_z])
    steps = np.arange(err.shape[0])
    for axis, name in enumerate("xyz"):
        ax_err.plot(steps, err[:, axis], lw=1, label=name)
    ax_err.set_xlim(0, max(len(frames.reward), 1)), ax_err.set_ylim(-err_range, err_range)
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
        return replace_atomic(out, lambda tmp: imageio.mimsave(tmp, images, duration=1.0 / fps, loop=0))
    return replace_atomic(out, lambda tmp: imageio.mimsave(tmp, images, fps=fps))


def plot_tracking_error(frames: EpisodeFrames, out: str | Path, desired_z: float = 5.0) -> Path:
    """Tracking error x/y/z over one episode (the paper's Fig. 5b)."""
    plt = pyplot()
    alive = np.asarray(frames.alive)
    rel = np.asarray(frames.rel_pos)[alive]
    err = rel - np.array([0.0, 0.0, desired_z])
    fig, ax = plt.subplots(figsize=(6, 3))
    for axis, name in enumerate("xyz"):
        ax.plot(err[:, axis], label=f"{name} error")
    ax.set_xlabel("step"), ax.set_ylabel("m"), ax.legend(), ax.grid(alpha=0.3)
    fig.tight_layout()
    return save_figure(fig, out, dpi=120)


def plot_trajectory_3d(frames: EpisodeFrames, out: str | Path) -> Path:
    """3-D paths of chaser and target in the Hill frame (the paper's Fig. 5a)."""
    plt = pyplot()
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
    return save_figure(fig, out, dpi=120)


# ============================================================================================ paper figures
def _save(fig, out: str | Path, dpi: int = 120) -> Path:
    return save_figure(fig, out, dpi=dpi)


def _display(image: np.ndarray) -> tuple[np.ndarray, str | None]:
    """[H, W, C] observation -> (image, cmap) for imshow: depth (and the depth of rgbd) in grey, stretched so the
    farthest target pixel is white (depth / far is ~0.25 at the 5 m goal, too dark to see), colour as is."""
    image = np.asarray(image, np.float32)
    if image.shape[-1] in (1, 4):
        depth = image[..., -1]
        return depth / max(float(depth.max()), 1e-6), "gray"
    return np.clip(image, 0, 1), None


def strip_indices(length: int, count: int) -> np.ndarray:
    """`count` steps spread evenly over an episode of `length` steps (first and last included)."""
    if length < 1:
        raise ValueError("empty episode")
    return np.unique(np.linspace(0, length - 1, min(count, length)).round().astype(int))


def plot_frame_strip(frames: EpisodeFrames, out: str | Path, count: int = 8) -> Path:
    """The observations the policy saw at `count` steps across the episode (the paper's Fig. 5c)."""
    plt = pyplot()
    length = max(int(np.asarray(frames.alive).sum()), 1)
    idx = strip_indices(length, count)
    fig, axes = plt.subplots(1, len(idx), figsize=(1.6 * len(idx), 1.9), squeeze=False)
    for ax, t in zip(axes[0], idx):
        image, cmap = _display(np.asarray(frames.obs[t]))
        ax.imshow(image, cmap=cmap, vmin=0, vmax=1, interpolation="nearest")
        ax.set_title(f"step {t}", fontsize=8)
        ax.axis("off")
    fig.tight_layout()
    return _save(fig, out)


def attention_panels(params, network_config, observations: np.ndarray) -> list[dict]:
    """network.attention_maps for each frame of `observations` [K, H, W, C]: a list of {name: [h, w]} dicts."""
    fn = jax.jit(lambda o: network.attention_maps(params, network_config, o))
    return [jax.device_get(fn(jnp.asarray(o))) for o in np.asarray(observations)]


def plot_attention(observations: np.ndarray, maps: list[dict], out: str | Path, alpha: float = 0.55) -> Path:
    """The paper's Fig. 6: per frame (row) the input image, then each conv block's map and the MHA output's map
    (each a softmax over positions, summing to 1), upsampled to the image and overlaid on it."""
    plt = pyplot()
    observations = np.asarray(observations)
    names = list(maps[0])
    rows, cols = len(maps), 1 + len(names)
    fig, axes = plt.subplots(rows, cols, figsize=(1.9 * cols, 2.0 * rows), squeeze=False)
    for r, (obs, m) in enumerate(zip(observations, maps)):
        image, cmap = _display(obs)
        res = image.shape[0]
        axes[r][0].imshow(image, cmap=cmap, vmin=0, vmax=1, interpolation="nearest")
        axes[r][0].set_title("input", fontsize=8)
        for c, name in enumerate(names, start=1):
            a = np.asarray(m[name], np.float32)
            ax = axes[r][c]
            ax.imshow(image, cmap=cmap or None, vmin=0, vmax=1, interpolation="nearest")
            ax.imshow(
                a,
                cmap="jet",
                alpha=alpha,
                extent=(-0.5, res - 0.5, res - 0.5, -0.5),
                interpolation="bilinear",
                vmin=0,
                vmax=max(float(a.max()), 1e-12),
            )
            label = "MHA" if name == "mha" else name.replace("block", "conv block ")
            ax.set_title(f"{label} ({a.shape[0]}x{a.shape[1]})", fontsize=8)
        for ax in axes[r]:
            ax.axis("off")
    fig.tight_layout()
    return _save(fig, out)


def episode_figures(
    tracking_env: env_lib.TrackingEnv,
    policy: Policy,
    params: env_lib.EnvParams,
    key: jax.Array,
    steps: int,
    out_dir: str | Path,
    prefix: str,
    strip: int = 8,
    network=None,
) -> dict[str, str]:
    """Record one episode and write tracking error, 3-D trajectory and frame strip PNGs (and, with
    `network=(network_config, net_params)`, attention maps of 3 frames across the episode). Returns {kind: path}."""
    out_dir = Path(out_dir)
    frames = record_episode(tracking_env, policy, params, key, steps)
    desired = float(np.asarray(params.desired_pos)[2])
    paths = {
        "tracking_error": plot_tracking_error(frames, _mkdir(out_dir) / f"{prefix}_tracking_error.png", desired),
        "trajectory_3d": plot_trajectory_3d(frames, out_dir / f"{prefix}_trajectory_3d.png"),
        "frames": plot_frame_strip(frames, out_dir / f"{prefix}_frames.png", strip),
    }
    if network is not None:
        net_cfg, net_params = network
        length = max(int(np.asarray(frames.alive).sum()), 1)
        obs = np.asarray(frames.obs)[strip_indices(length, 3)]
        paths["attention"] = plot_attention(
            obs, attention_panels(net_params, net_cfg, obs), out_dir / f"{prefix}_attention.png"
        )
    return {k: str(v) for k, v in paths.items()}


def _mkdir(path: Path) -> Path:
    path.mkdir(parents=True, exist_ok=True)
    return path


def slug(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in name).strip("_") or "policy"


def eval_figures(entries, loaded, target: str, out_dir: str | Path, seed: int = 0, steps: int = 1000) -> dict:
    """Figures for `ramavt eval --figures`: one recorded episode on `target` per evaluated policy, attention maps
    of the trained runs and their training curves. Returns {figure: path}."""
    out_dir = Path(out_dir)
    runs = {lr.run_dir: lr for lr in loaded}
    out = {}
    for e in entries:
        config = dataclasses.replace(e.env_config, targets=(target,))
        tracking_env = env_lib.TrackingEnv(config)
        params = tracking_env.eval_params(**e.env_overrides, max_steps=steps)
        lr = runs.get(e.info.get("run_dir"))
        network = (lr.config.network, lr.params) if lr is not None else None
        prefix = slug(f"{e.name}_{config.obs_mode}")
        for k, v in episode_figures(
            tracking_env, e.policy, params, jax.random.PRNGKey(seed), steps, out_dir, prefix, network=network
        ).items():
            out[f"{prefix}/{k}"] = v
    if loaded:
        out["training_curves"] = str(plot_training_runs([lr.run_dir for lr in loaded], out_dir / "training_curves.png"))
    return out
