"""Image augmentation for sequences (RAD-style, as the original code): crop-and-resize, cutout, flips, rot90.

One random draw is applied to EVERY frame of a sequence (a recurrent agent must see a consistent world).
Pure, jit-able, vmappable: ``augment_batch`` vmaps ``augment_sequence`` over sequences with per-sequence keys.

Caveat for the trainer: flips and rotations change the image axes but not the action semantics (actions are
velocities in the camera frame), so a flipped/rotated sequence is a *different* task unless actions are remapped.
``augment_sequence(..., return_info=True)`` returns the draw (``flip_lr``, ``flip_ud``, ``rot90_k``) so a trainer
can permute actions accordingly; the paper reports that its augmentations "work unsatisfactorily", which this
mismatch may explain. Crop and cutout are semantics-preserving.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp


@dataclasses.dataclass(frozen=True)
class AugmentConfig:
    crop: bool = True
    crop_fraction: float = 0.75  # *orig* 192/256 crop, resized back to full size
    cutout: bool = True
    cutout_min: float = 10 / 256  # side of the square hole, fraction of the image side (*orig* 10-30 px of 256)
    cutout_max: float = 30 / 256
    cutout_value: float = 0.0  # background value of depth / colour images
    flip: bool = True
    flip_prob: float = 0.2  # each of horizontal and vertical, independently
    rot90: bool = True  # rotate by k * 90 degrees, k uniform in {0, 1, 2, 3} (square images only)

    def __post_init__(self):
        if not 0.0 < self.crop_fraction <= 1.0:
            raise ValueError(f"AugmentConfig: crop_fraction must be in (0, 1], got {self.crop_fraction}")
        if not 0.0 <= self.cutout_min <= self.cutout_max < 1.0:
            raise ValueError(
                f"AugmentConfig: need 0 <= cutout_min <= cutout_max < 1 (fractions of the image side), "
                f"got cutout_min={self.cutout_min}, cutout_max={self.cutout_max}"
            )
        if not 0.0 <= self.flip_prob <= 1.0:
            raise ValueError(f"AugmentConfig: flip_prob must be in [0, 1], got {self.flip_prob}")


def _crop_resize(key, obs, fraction):
    t, h, w, c = obs.shape
    ch, cw = max(1, round(fraction * h)), max(1, round(fraction * w))
    ky, kx = jax.random.split(key)
    y0 = jax.random.randint(ky, (), 0, h - ch + 1)
    x0 = jax.random.randint(kx, (), 0, w - cw + 1)
    crop = jax.lax.dynamic_slice(obs, (0, y0, x0, 0), (t, ch, cw, c))
    # Bilinear upsampling: convex combinations, so the value range is preserved.
    return jax.image.resize(crop, (t, h, w, c), method="linear", antialias=False).astype(obs.dtype)


def _cutout(key, obs, lo, hi, value):
    t, h, w, c = obs.shape
    ks, ky, kx = jax.random.split(key, 3)
    side = jax.random.uniform(ks, (), minval=lo, maxval=hi)
    sh = jnp.round(side * h).astype(jnp.int32)
    sw = jnp.round(side * w).astype(jnp.int32)
    y0 = jax.random.randint(ky, (), 0, h - sh + 1)
    x0 = jax.random.randint(kx, (), 0, w - sw + 1)
    rows = jnp.arange(h)[:, None]
    cols = jnp.arange(w)[None, :]
    hole = (rows >= y0) & (rows < y0 + sh) & (cols >= x0) & (cols < x0 + sw)  # [H, W]
    return jnp.where(hole[None, :, :, None], jnp.asarray(value, obs.dtype), obs)


def augment_sequence(key: jax.Array, obs: jax.Array, config: AugmentConfig, return_info: bool = False):
    """Augment one sequence obs [T, H, W, C] with one random draw shared by all frames -> [T, H, W, C].

    With ``return_info`` also returns {'flip_lr', 'flip_ud' (bool), 'rot90_k' (int32)}; the order of operations
    is crop -> cutout -> flip_lr -> flip_ud -> rot90 (counter-clockwise, ``jnp.rot90`` convention).
    """
    if obs.ndim != 4:
        raise ValueError(f"augment_sequence: expected obs [T, H, W, C], got shape {obs.shape}")
    t, h, w, c = obs.shape
    if config.rot90 and h != w:
        raise ValueError(f"augment_sequence: rot90 needs square images, got {h}x{w}")
    k_crop, k_cut, k_lr, k_ud, k_rot = jax.random.split(key, 5)
    if config.crop and config.crop_fraction < 1.0:
        obs = _crop_resize(k_crop, obs, config.crop_fraction)
    if config.cutout and config.cutout_max > 0.0:
        obs = _cutout(k_cut, obs, config.cutout_min, config.cutout_max, config.cutout_value)
    flip_lr = jnp.zeros((), bool)
    flip_ud = jnp.zeros((), bool)
    rot_k = jnp.zeros((), jnp.int32)
    if config.flip:
        flip_lr = jax.random.bernoulli(k_lr, config.flip_prob)
        flip_ud = jax.random.bernoulli(k_ud, config.flip_prob)
        obs = jnp.where(flip_lr, obs[:, :, ::-1], obs)
        obs = jnp.where(flip_ud, obs[:, ::-1], obs)
    if config.rot90:
        rot_k = jax.random.randint(k_rot, (), 0, 4)
        obs = jax.lax.switch(rot_k, [lambda x, k=k: jnp.rot90(x, k, axes=(1, 2)) for k in range(4)], obs)
    if return_info:
        return obs, {"flip_lr": flip_lr, "flip_ud": flip_ud, "rot90_k": rot_k}
    return obs


def augment_batch(key: jax.Array, obs: jax.Array, config: AugmentConfig, return_info: bool = False):
    """Augment a batch of sequences obs [B, T, H, W, C], an independent draw per sequence."""
    if obs.ndim != 5:
        raise ValueError(f"augment_batch: expected obs [B, T, H, W, C], got shape {obs.shape}")
    keys = jax.random.split(key, obs.shape[0])
    return jax.vmap(lambda k, o: augment_sequence(k, o, config, return_info))(keys, obs)


__all__ = ["AugmentConfig", "augment_sequence", "augment_batch"]
