"""The target's visible surface as the newest depth frame shows it: its centroid, and the tracking state measured to
it instead of to the centre of mass. Diagnostics of where the centre is (centre_precision.py, centre_estimator.py,
centroid_offset.py); they read the simulator's state and the frame, never a policy's input."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ramavt_jax import env as env_lib
from ramavt_jax.imitation import true_tracking_state
from ramavt_jax.render import CameraConfig, camera_rays

__all__ = ["surface_centroid", "visible_tracking_state"]


def surface_centroid(depth: jax.Array, camera: CameraConfig) -> tuple[jax.Array, jax.Array]:
    """Of a z-depth image [H, W] (0 where nothing is hit): ([3] the mean camera-frame point of its hit pixels, each
    back-projected along its ray at its depth, in the depth's units; [] how many there are)."""
    hit = depth > 0
    count = jnp.sum(hit)
    points = camera_rays(camera) * depth[..., None]  # [H, W, 3]: ray (x, y, 1) times z depth
    return jnp.sum(jnp.where(hit[..., None], points, 0.0), axis=(0, 1)) / jnp.maximum(count, 1), count


def visible_tracking_state(
    env_state: env_lib.EnvState, env_params: env_lib.EnvParams, camera: CameraConfig
) -> jax.Array:
    """[6] imitation.true_tracking_state with the error measured to the centroid of the target's visible surface
    instead of its centre of mass: the mean camera-frame point of the newest frame's target pixels ('depth' or 'rgbd'
    observations: depth / far last; a target at stand-off scale k is drawn at 1 / k, so the frame is already in
    stand-off units). On a frame without a target pixel, the true state. The newest frame is read sharp: under the
    blur perturbation the observation averages it with earlier ones, and the Gaussian or motion blur of EnvParams
    would move depth into background pixels; neither is applied here."""
    if env_state.frames.shape[-1] not in (1, 4):
        raise ValueError(
            f"visible_tracking_state needs a depth channel ('depth' or 'rgbd' observations), got "
            f"{env_state.frames.shape[-1]} channels"
        )
    centroid, count = surface_centroid(env_state.frames[-1][..., -1] * camera.far, camera)  # m / k
    error = (centroid - env_params.desired_pos) / env_params.desired_pos[2]
    true = true_tracking_state(env_state, env_params)
    return jnp.where(count > 0, true.at[:3].set(error), true)
