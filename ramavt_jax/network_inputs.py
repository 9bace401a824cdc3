"""What the encoder's first layer sees besides the raw frame, and per-frame statistics read beside its features:
the hit mask, CoordConv planes, the depth rescaled to metres from the stand-off, the silhouette's statistics, and
two inputs over time (each frame's change, a long exposure). Pure array functions without parameters, on single
frames [N, H, W, C] or sequences [B, T, H, W, C]; network.Encoder and QNetwork apply them as NetworkConfig asks."""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = [
    "hit_mask",
    "with_hit_mask",
    "with_depth_rescaled",
    "coordinate_planes",
    "with_coordinates",
    "silhouette_stats",
    "STATS_DEPTH_CENTRE",
    "STATS_DEPTH_GAIN",
    "frame_changes",
    "long_exposure",
]


def hit_mask(x: jax.Array) -> jax.Array:
    """[N, H, W, C] -> [N, H, W, 1]: 1 where any channel > 0 (the background is 0 in every observation mode)."""
    return (jnp.max(x, axis=-1, keepdims=True) > 0).astype(x.dtype)


def with_hit_mask(x: jax.Array) -> jax.Array:
    """[N, H, W, C] -> [N, H, W, C + 1]: the frame and its hit mask."""
    return jnp.concatenate([x, hit_mask(x)], axis=-1)


def with_depth_rescaled(x: jax.Array, hit: jax.Array, centre: float, gain: float) -> jax.Array:
    """[N, H, W, C] -> the same with the depth channel (the last; C = 1 'depth' or 4 'rgbd') of the hit pixels
    (hit [N, H, W, 1], 1 on the target) mapped to (depth - centre) * gain; the background stays 0."""
    if x.shape[-1] not in (1, 4):
        raise ValueError(
            f"depth_centre / depth_gain need a depth channel (1 'depth' or 4 'rgbd' channels), got "
            f"{x.shape[-1]} channels"
        )
    depth = (x[..., -1:] - centre) * gain * hit
    return jnp.concatenate([x[..., :-1], depth], axis=-1)


def coordinate_planes(h: int, w: int, dtype=jnp.float32) -> jax.Array:
    """[H, W, 2]: the column and the row coordinate of each pixel in [-1, 1] (CoordConv)."""
    cols = jnp.broadcast_to(jnp.linspace(-1.0, 1.0, w, dtype=dtype)[None, :], (h, w))
    rows = jnp.broadcast_to(jnp.linspace(-1.0, 1.0, h, dtype=dtype)[:, None], (h, w))
    return jnp.stack([cols, rows], axis=-1)


def with_coordinates(x: jax.Array) -> jax.Array:
    """[N, H, W, C] -> [N, H, W, C + 3]: the frame, its hit mask and the coordinate planes, as the encoder's
    first conv sees them (coord_channels). The mask and the coordinates do not scale with the depth values, so a
    conv over all channels followed by a per-frame norm still tells a near small target from a far large one, and
    where in the image it is."""
    planes = coordinate_planes(*x.shape[1:3], x.dtype)
    return jnp.concatenate([with_hit_mask(x), jnp.broadcast_to(planes, (*x.shape[:3], 2))], axis=-1)


# Depth observations are depth / far with far = 20 m (the default camera): 0.25 is the 5 m stand-off, and 20 turns
# observation units into metres (NetworkConfig.depth_centre / depth_gain say why the raw units are too small). A
# resized target is rendered in stand-off units (env: depths divided by its scale k), so these read metres / k.
STATS_DEPTH_CENTRE, STATS_DEPTH_GAIN = 0.25, 20.0


def silhouette_stats(x: jax.Array) -> jax.Array:
    """[N, H, W, C] single raw frames (depth last: C = 1 'depth' or 4 'rgbd'; not frame stacks) -> [N, 8] float32
    statistics of the hit pixels: sqrt(count) (a linear size, px); centroid column and row and their standard
    deviations (the coordinate planes' [-1, 1] times half the image size: px from the centre, to within
    W / (W - 1)); mean, nearest and standard deviation of depth (STATS_DEPTH_*: metres from the 5 m stand-off, in
    stand-off units for a resized target). The statistics have the observation's precision (a uint8 replay stores
    depth in 20 m / 255 steps). Every statistic is 0 in a frame without a hit pixel."""
    if x.shape[-1] not in (1, 4):
        raise ValueError(f"silhouette_stats needs a depth channel (1 'depth' or 4 'rgbd' channels), got {x.shape[-1]}")
    x = x.astype(jnp.float32)
    hit = hit_mask(x)[..., 0]  # [N, H, W]
    depth = x[..., -1]
    h, w = hit.shape[1:]
    planes = coordinate_planes(h, w) * jnp.array([w / 2.0, h / 2.0])  # [H, W, 2] px from the centre
    count = jnp.sum(hit, axis=(1, 2))  # [N]
    seen = count > 0
    weight = hit / jnp.maximum(count, 1.0)[:, None, None]  # [N, H, W], sums to 1 on a frame with hits

    def mean_std(values):  # values [N, H, W] or [H, W] -> mean [N], std [N] over the hit pixels
        mean = jnp.sum(weight * values, axis=(1, 2))
        var = jnp.sum(weight * (values - mean[:, None, None]) ** 2, axis=(1, 2))
        return mean, jnp.sqrt(var + 1e-12)

    (col, col_std), (row, row_std) = mean_std(planes[..., 0]), mean_std(planes[..., 1])
    metres = (depth - STATS_DEPTH_CENTRE) * STATS_DEPTH_GAIN
    depth_mean, depth_std = mean_std(metres)
    nearest = jnp.min(jnp.where(hit > 0, metres, jnp.inf), axis=(1, 2))
    stats = jnp.stack([jnp.sqrt(count), col, row, col_std, row_std, depth_mean, nearest, depth_std], axis=-1)
    return jnp.where(seen[:, None], stats, 0.0)


def frame_changes(obs: jax.Array, reset: jax.Array, previous: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Per-pixel change since the previous frame. obs [B, T, H, W, C], reset [B, T], previous [B, 1, H, W, C] (the
    frame before step 0). Returns the changes [B, T, H, W, C] (0 where reset: an episode's first frame has no
    predecessor) and the new previous frame [B, 1, H, W, C] (step T - 1's)."""
    obs = obs.astype(jnp.float32)  # an integer frame would wrap around below zero
    before = jnp.concatenate([previous.astype(jnp.float32), obs[:, :-1]], axis=1)
    return jnp.where(reset[..., None, None, None], 0.0, obs - before), obs[:, -1:]


def long_exposure(obs: jax.Array, reset: jax.Array, exposure: jax.Array, rate: float) -> jax.Array:
    """An exponential average over an episode of each frame with its hit mask. obs [B, T, H, W, C], reset [B, T],
    exposure [B, H, W, C + 1] (the average after the step before step 0). Returns the averages after each step
    [B, T, H, W, C + 1]: e_t = e_(t-1) + rate * (x_t - e_(t-1)), with e_t = x_t where reset (the episode's first
    frame). Over about 1 / rate steps a tumbling target sweeps a region centred nearer its centre of mass than any
    one silhouette is."""
    frames = with_hit_mask(obs.astype(jnp.float32))

    def step(e, inp):
        x, r = inp  # [B, H, W, C + 1], [B]
        e = jnp.where(r[:, None, None, None], x, e + rate * (x - e))
        return e, e

    _, seen = jax.lax.scan(step, exposure.astype(jnp.float32), (jnp.swapaxes(frames, 0, 1), reset.T))
    return jnp.swapaxes(seen, 0, 1)
