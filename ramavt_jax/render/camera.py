"""Pinhole camera, lighting and the rendered frame.

Camera frame: x right, y down, z along the boresight. Pixel (row v, column u) looks along
``((u - c) / f, (v - c) / f, 1)`` with ``c = (res - 1) / 2``; with this un-normalised direction the ray
parameter ``t`` of a hit equals its z depth.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct


@dataclasses.dataclass(frozen=True)
class CameraConfig:
    """Static (hashable) pinhole camera: square images of ``resolution`` pixels."""

    resolution: int = 64  # H = W = resolution, 8 <= resolution <= 1024
    fov_deg: float = 60.0  # full field of view, 0 < fov < 180
    far: float = 20.0  # max range and depth normalisation (m)
    near: float = 0.05  # hits closer than this are ignored (m)

    def __post_init__(self):
        if isinstance(self.resolution, bool) or not isinstance(self.resolution, (int, np.integer)):
            raise ValueError(f"CameraConfig.resolution must be an int, got {self.resolution!r}")
        if not 8 <= int(self.resolution) <= 1024:
            raise ValueError(f"CameraConfig.resolution must be in [8, 1024] pixels, got {self.resolution}")
        if not 0.0 < float(self.fov_deg) < 180.0:
            raise ValueError(f"CameraConfig.fov_deg must be in (0, 180) degrees, got {self.fov_deg}")
        if not float(self.near) > 0.0:
            raise ValueError(f"CameraConfig.near must be > 0, got {self.near}")
        if not float(self.far) > float(self.near):
            raise ValueError(f"CameraConfig.far ({self.far}) must be greater than near ({self.near})")

    def focal(self) -> float:
        """Focal length in pixels: (res / 2) / tan(fov / 2)."""
        return (self.resolution / 2.0) / math.tan(math.radians(self.fov_deg) / 2.0)

    def centre(self) -> float:
        """Principal point (same for rows and columns): (res - 1) / 2."""
        return (self.resolution - 1) / 2.0


def pixel_coords(cam: CameraConfig) -> np.ndarray:
    """Normalised image-plane coordinates (u - c) / f for u = 0 .. res-1 (float32 numpy, [res])."""
    return ((np.arange(cam.resolution, dtype=np.float64) - cam.centre()) / cam.focal()).astype(np.float32)


def camera_rays(cam: CameraConfig) -> jax.Array:
    """Un-normalised ray directions [H, W, 3]: ((u - c)/f, (v - c)/f, 1) for row v, column u."""
    s = jnp.asarray(pixel_coords(cam))
    h = w = cam.resolution
    x = jnp.broadcast_to(s[None, :], (h, w))
    y = jnp.broadcast_to(s[:, None], (h, w))
    return jnp.stack([x, y, jnp.ones((h, w), jnp.float32)], axis=-1)


@struct.dataclass
class Lighting:
    """Directional sun light plus ambient term, in the camera frame."""

    sun_dir: jax.Array  # [3] unit vector from the surface towards the sun (camera frame)
    ambient: jax.Array  # [] ambient fraction in [0, 1]


def default_lighting() -> Lighting:
    """Sun from above-left-behind the camera (so faces towards the camera are lit), 20% ambient."""
    d = np.array([-0.4, -0.6, -0.7], np.float64)
    return Lighting(sun_dir=jnp.asarray(d / np.linalg.norm(d), jnp.float32), ambient=jnp.float32(0.2))


@struct.dataclass
class Frame:
    """A rendered image (leading batch axes allowed)."""

    depth: jax.Array  # [H, W] f32 z depth (m); 0 where no hit or beyond far
    rgb: jax.Array  # [H, W, 3] f32 in [0, 1]; zeros where no hit (black sky)
    hit: jax.Array  # [H, W] bool
