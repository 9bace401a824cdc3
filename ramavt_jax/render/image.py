"""Frames to network observations, and image blur (Gaussian, motion).

Both blurs are skipped at run time when they are off (sigma / length 0, the default): a single image uses a
``lax.cond``, and under ``jax.vmap`` a custom batching rule runs the batched blur only when any image of the batch
needs it (a plain vmapped cond would turn into a select that always pays for the blur).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from ramavt_jax.render.camera import Frame

OBSERVATION_MODES = {"depth": 1, "color": 3, "rgbd": 4}


def observation_channels(mode: str) -> int:
    if mode not in OBSERVATION_MODES:
        raise ValueError(f"unknown observation mode {mode!r}; choose one of {sorted(OBSERVATION_MODES)}")
    return OBSERVATION_MODES[mode]


def to_observation(frame: Frame, mode: str, far: float) -> jax.Array:
    """Frame -> [H, W, C] float32 in [0, 1] (leading batch axes kept).

    'depth' (C=1): depth / far clipped to [0, 1], 0 for background; 'color' (C=3): rgb; 'rgbd' (C=4): rgb then depth.
    """
    observation_channels(mode)
    depth = jnp.clip(frame.depth / far, 0.0, 1.0)[..., None].astype(jnp.float32)
    if mode == "depth":
        return depth
    rgb = jnp.clip(frame.rgb, 0.0, 1.0).astype(jnp.float32)
    if mode == "color":
        return rgb
    return jnp.concatenate([rgb, depth], axis=-1)


def _filter_rows_cols(image: jax.Array, k: jax.Array) -> jax.Array:
    """Separable 'same' filtering of [H, W, C] with the 1-D kernel k [2R+1] along rows and columns (zero padded)."""
    r = (k.shape[0] - 1) // 2
    h, w, _ = image.shape
    pad = jnp.pad(image, ((r, r), (r, r), (0, 0)))
    out = sum(k[i] * pad[i : i + h, :, :] for i in range(2 * r + 1))
    out = sum(k[i] * out[:, i : i + w, :] for i in range(2 * r + 1))
    return out


def _skip_when_off(impl):
    """f(image, amount, *rest) -> impl(...) where amount > 0 else image; evaluated only when needed (see above)."""

    @jax.custom_batching.custom_vmap
    def f(image, amount, *rest):
        return jax.lax.cond(amount > 0, impl, lambda i, *_: i, image, amount, *rest)

    @f.def_vmap
    def f_batched(axis_size, in_batched, image, amount, *rest):
        def full(x, b):
            return x if b else jnp.broadcast_to(x, (axis_size,) + x.shape)

        image = full(image, in_batched[0])
        axes = tuple(0 if b else None for b in in_batched[1:])
        out = jax.lax.cond(
            jnp.any(amount > 0),
            lambda: jax.vmap(impl, in_axes=(0,) + axes)(image, amount, *rest),
            lambda: image,
        )
        return out, True

    return f


def gaussian_blur(image: jax.Array, sigma, max_radius: int = 8) -> jax.Array:
    """Separable Gaussian blur of [H, W, C]; sigma (pixels) may be traced; sigma == 0 returns the image unchanged.

    The kernel has a static support of 2 * max_radius + 1 taps (ample for sigma <= max_radius / 3) and is
    normalised over the taps that fall inside the image, so borders do not darken and the mean is kept.
    """
    image = jnp.asarray(image)
    return _gaussian_fn(int(max_radius))(image, jnp.asarray(sigma, jnp.float32))


@functools.cache
def _gaussian_fn(max_radius: int):
    return _skip_when_off(functools.partial(_gaussian_blur, max_radius=max_radius))


def _gaussian_blur(image, sigma, max_radius):
    taps = jnp.arange(-max_radius, max_radius + 1, dtype=jnp.float32)
    safe = jnp.maximum(sigma, 1e-6)
    k = jnp.exp(-0.5 * (taps / safe) ** 2)
    k = k / jnp.sum(k)
    blurred = _filter_rows_cols(image, k)
    weight = _filter_rows_cols(jnp.ones(image.shape[:2] + (1,), image.dtype), k)
    return jnp.where(sigma > 0, blurred / weight, image).astype(image.dtype)


def add_noise(key: jax.Array, image: jax.Array, std, mask: jax.Array) -> jax.Array:
    """clip(where(mask, image + std * N(0, 1), image), 0, 1) with the normal draw of ``jax.random.normal(key,
    image.shape)``; when std == 0 (the default of every env) no random numbers are drawn at run time, which on CPU
    is most of an env step's post-processing (threefry for every pixel). std may be traced; mask broadcasts."""
    image = jnp.asarray(image)
    return _noise_fn()(image, jnp.asarray(std, image.dtype), key, jnp.asarray(mask))


@functools.cache
def _noise_fn():
    def noisy(image, std, key, mask):
        return jnp.clip(
            jnp.where(mask, image + std * jax.random.normal(key, image.shape, image.dtype), image), 0.0, 1.0
        )

    skip = _skip_when_off(noisy)
    return lambda image, std, key, mask: jnp.clip(skip(image, std, key, mask), 0.0, 1.0)


def motion_blur(image: jax.Array, length_px, angle_rad, samples: int = 9) -> jax.Array:
    """Linear motion blur of [H, W, C]: average of `samples` copies shifted along a line of length_px pixels at
    angle_rad (0 = along +u, columns) centred on each pixel, bilinear sampling, edges clamped. Both may be traced;
    length 0 returns the image unchanged.
    """
    image = jnp.asarray(image)
    return _motion_fn(int(samples))(image, jnp.asarray(length_px, jnp.float32), jnp.asarray(angle_rad, jnp.float32))


@functools.cache
def _motion_fn(samples: int):
    return _skip_when_off(functools.partial(_motion_blur, samples=samples))


def _motion_blur(image, length, angle_rad, samples):
    h, w, _ = image.shape
    s = (jnp.arange(samples, dtype=jnp.float32) / max(samples - 1, 1) - 0.5) * length  # [S]
    du, dv = s * jnp.cos(angle_rad), s * jnp.sin(angle_rad)
    vv, uu = jnp.meshgrid(jnp.arange(h, dtype=jnp.float32), jnp.arange(w, dtype=jnp.float32), indexing="ij")

    def sample(du_i, dv_i):
        coords = [jnp.clip(vv + dv_i, 0, h - 1), jnp.clip(uu + du_i, 0, w - 1)]
        return jnp.stack(
            [
                jax.scipy.ndimage.map_coordinates(image[..., c], coords, order=1, mode="nearest")
                for c in range(image.shape[-1])
            ],
            axis=-1,
        )

    out = jnp.mean(jax.vmap(sample)(du, dv), axis=0)
    return jnp.where(length > 0, out, image).astype(image.dtype)
