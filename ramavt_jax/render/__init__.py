"""Ray-cast renderer: depth / colour / RGBD images of a target made of MuJoCo primitives.

Public API::

    CameraConfig, camera_rays, Lighting, default_lighting, Frame
    render(target, position, rotation, cam, lighting, shade=True) -> Frame
    render_batch(targets, positions, rotations, cam, lighting, shade=True, chunk=None) -> Frame [B, ...]
    to_observation(frame, mode, far) -> [H, W, C] in [0, 1]
    gaussian_blur(image, sigma), motion_blur(image, length_px, angle_rad), add_noise(key, image, std, mask)
"""

from ramavt_jax.render.camera import CameraConfig, Frame, Lighting, camera_rays, default_lighting
from ramavt_jax.render.image import (
    OBSERVATION_MODES,
    add_noise,
    gaussian_blur,
    motion_blur,
    observation_channels,
    to_observation,
)
from ramavt_jax.render.renderer import render, render_batch

__all__ = [
    "CameraConfig",
    "Frame",
    "Lighting",
    "OBSERVATION_MODES",
    "add_noise",
    "camera_rays",
    "default_lighting",
    "gaussian_blur",
    "motion_blur",
    "observation_channels",
    "render",
    "render_batch",
    "to_observation",
]
