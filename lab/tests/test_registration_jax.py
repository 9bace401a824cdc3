"""lab/registration_jax.py: the compiled estimator follows the numpy one (lab/centre_registration.py) on a spinning,
drifting ellipsoid seen by a moving chaser."""

import jax
import jax.numpy as jnp
import numpy as np
from scipy.spatial.transform import Rotation

from lab import centre_registration as reg
from lab import registration_jax as rj
from lab.tests.test_centre_from_motion import ellipsoid_depth
from ramavt_jax.render.camera import CameraConfig, camera_rays

CAMERA = CameraConfig(resolution=48)
RAYS = np.asarray(camera_rays(CAMERA), np.float64)


def test_compiled_estimator_follows_the_numpy_one():
    settings = reg.Settings(baselines=(5, 15), window=40, depth_offset=0.2, depth_gain=0.25)
    centre0, velocity = np.array([0.2, -0.1, 5.0]), np.array([0.03, -0.02, 0.02])
    spin = 0.3 * np.array([0.2, 1.0, 0.3]) / np.linalg.norm([0.2, 1.0, 0.3])
    start, chaser_velocity = Rotation.from_rotvec([0.4, 0.7, -0.2]), np.array([0.02, 0.0, 0.03])
    steps = np.arange(41) * reg.DT
    chaser = chaser_velocity * steps[:, None]
    depth = np.stack(
        [
            ellipsoid_depth(
                RAYS, centre0 + velocity * t - c, (Rotation.from_rotvec(spin * t) * start).as_matrix(), [1.4, 0.9, 0.6]
            )
            for t, c in zip(steps, chaser)
        ]
    )
    tracker = reg.OnlineRegistration(CAMERA, settings)
    expected = np.array([tracker.update(d, c)[0] for d, c in zip(depth, chaser)])

    def body(state, frame):
        state = rj.update(state, frame[0], frame[1], CAMERA, settings)
        return state, state.centre

    _, found = jax.lax.scan(
        body, rj.initial_state(settings, CAMERA.resolution), (jnp.asarray(depth, jnp.float32), jnp.asarray(chaser))
    )
    found = np.asarray(found)
    axis, centre = spin / np.linalg.norm(spin), centre0 + velocity * steps[-1]

    def across_axis(x):
        return np.linalg.norm(x - (x @ axis) * axis)

    visible = reg.frame_points(depth[-1], RAYS, jump=0.6)[2] + chaser[-1]
    # what both follow is the centre (across the spin's axis), far nearer than the surface a frame shows
    assert across_axis(expected[-1] - centre) < 0.1 < across_axis(visible - centre)
    np.testing.assert_allclose(found[-10:], expected[-10:], atol=0.02)
