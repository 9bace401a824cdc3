"""The network's inputs besides the raw frame, in one place: the hit mask and CoordConv planes the encoder's first
layer sees, the previous action one-hot at the LSTM's input, and DRLAVT's frame stack. Pure array functions without
parameters; network.Encoder and QNetwork apply them as NetworkConfig asks (a network factory may apply others, see
docs/extending.md)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = [
    "hit_mask",
    "with_hit_mask",
    "coordinate_planes",
    "with_coordinates",
    "previous_actions",
    "stack_frames",
]


def hit_mask(x: jax.Array) -> jax.Array:
    """[N, H, W, C] -> [N, H, W, 1]: 1 where any channel > 0 (the background is 0 in every observation mode)."""
    return (jnp.max(x, axis=-1, keepdims=True) > 0).astype(x.dtype)


def with_hit_mask(x: jax.Array) -> jax.Array:
    """[N, H, W, C] -> [N, H, W, C + 1]: the frame and its hit mask."""
    return jnp.concatenate([x, hit_mask(x)], axis=-1)


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


def previous_actions(
    prev_action: jax.Array, reset: jax.Array, actions: jax.Array | None, num_actions: int, dtype=jnp.float32
) -> jax.Array:
    """One-hot previous action per step [B, T, A + 1] (NetworkConfig.prev_action): ``prev_action`` [1, B] (the
    carried state's) before step 0, ``actions[:, t - 1]`` (``actions`` [B, T] or [B, T - 1], needed when T > 1)
    before step t > 0, and the extra 'none' entry A where ``reset`` [B, T]."""
    b, t = reset.shape
    prev = prev_action[0][:, None]  # [B, 1]
    if t > 1:
        if actions is None or actions.shape[1] not in (t - 1, t):
            raise ValueError(
                f"QNetwork: a prev_action network needs the window's actions [B, T] or [B, T - 1] "
                f"when T > 1, got {None if actions is None else actions.shape} for T = {t}"
            )
        prev = jnp.concatenate([prev, actions[:, : t - 1].astype(prev.dtype)], axis=1)
    prev = jnp.where(reset, num_actions, prev)
    return jax.nn.one_hot(prev, num_actions + 1, dtype=dtype)


def stack_frames(obs: jax.Array, reset: jax.Array, frames: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Frame stacking along T ('drlavt'). obs [B, T, H, W, C], reset [B, T], frames [B, K-1, H, W, C] (oldest first).

    Returns stacked [B, T, H, W, K*C] (channels oldest..newest) and the new buffer. Where reset[b, t] the
    history is replaced by copies of frame t. Only moves memory: cheap to scan.
    """
    k1 = frames.shape[1]

    def step(hist, inp):
        x, r = inp  # [B, H, W, C], [B]
        hist = jnp.where(r[:, None, None, None, None], x[:, None], hist)
        full = jnp.concatenate([hist, x[:, None]], axis=1)  # [B, K, H, W, C]
        b, k, h, w, c = full.shape
        stacked = jnp.moveaxis(full, 1, 3).reshape(b, h, w, k * c)
        return full[:, 1:] if k1 else hist, stacked

    hist, stacked = jax.lax.scan(step, frames.astype(obs.dtype), (jnp.swapaxes(obs, 0, 1), reset.T))
    return jnp.swapaxes(stacked, 0, 1), hist
