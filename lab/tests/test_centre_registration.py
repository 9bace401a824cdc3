"""lab/centre_registration.py: ICP recovers a known rigid motion of a smooth body, and the online estimator finds
the centre a spinning, drifting body turns about (across the spin's axis) (seen by a moving chaser), where the visible surface's centroid
lies on its near side."""

import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from lab import centre_registration as reg
from lab.tests.test_centre_from_motion import ellipsoid_depth
from ramavt_jax.render.camera import CameraConfig, camera_rays

CAMERA = CameraConfig(resolution=64)
RAYS = np.asarray(camera_rays(CAMERA), np.float64)
AXES = np.array([1.4, 0.9, 0.6])  # m, semi-axes: a body whose turn the surface shows


def test_icp_recovers_a_rigid_motion():
    rotation, centre = Rotation.from_rotvec([0.4, 0.7, -0.2]).as_matrix(), np.array([0.3, -0.2, 5.0])
    turn, shift = Rotation.from_rotvec([0.05, -0.08, 0.04]).as_matrix(), np.array([0.04, -0.03, 0.05])
    source = reg.frame_points(ellipsoid_depth(RAYS, centre, rotation, AXES), RAYS, jump=0.6)
    moved_centre = turn @ centre + shift  # the body turned by `turn` about the camera's origin, then shifted
    dest = reg.frame_points(ellipsoid_depth(RAYS, moved_centre, turn @ rotation, AXES), RAYS, jump=0.6)
    found = reg.icp(source[0], dest[0], dest[1], cKDTree(dest[0]), np.eye(3), np.zeros(3), 0.4, 30, 20)
    assert found is not None and found[2] < 0.01
    np.testing.assert_allclose(found[0] @ centre + found[1], moved_centre, atol=0.01)  # the centre maps onto itself
    angle = np.linalg.norm(Rotation.from_matrix(found[0] @ turn.T).as_rotvec())
    assert angle < 0.01


def test_online_estimate_finds_the_centre_the_surface_turns_about():
    centre0, velocity = np.array([0.2, -0.1, 5.0]), np.array([0.03, -0.02, 0.02])  # m, m/s, camera axes
    spin = 0.15 * np.array([0.2, 1.0, 0.3]) / np.linalg.norm([0.2, 1.0, 0.3])  # rad/s, mostly across the image
    chaser_velocity = np.array([0.02, 0.0, 0.03])  # the chaser's own, known to it
    start = Rotation.from_rotvec([0.4, 0.7, -0.2])
    tracker = reg.OnlineRegistration(CAMERA, reg.Settings(baselines=(10, 30), window=100))
    for t in range(101):
        time = t * reg.DT
        centre_world, chaser = centre0 + velocity * time, chaser_velocity * time
        attitude = (Rotation.from_rotvec(spin * time) * start).as_matrix()
        depth = ellipsoid_depth(RAYS, centre_world - chaser, attitude, AXES)
        estimate, estimated_velocity = tracker.update(depth, chaser)
    visible = reg.frame_points(depth, RAYS, jump=0.6)[2] + chaser
    axis = spin / np.linalg.norm(spin)

    def across_axis(x):  # a steady spin shows where the centre is only across its axis; along it the prior holds
        return x - (x @ axis) * axis

    assert np.linalg.norm(across_axis(visible - centre_world)) > 0.3  # the near side: what a frame alone shows
    assert np.linalg.norm(across_axis(estimate - centre_world)) < 0.05
    np.testing.assert_allclose(estimated_velocity, velocity, atol=0.02)


def test_settings_are_checked():
    with pytest.raises(ValueError, match="window"):
        reg.Settings(baselines=(10, 300), window=200)
    with pytest.raises(ValueError, match="pull"):
        reg.Settings(pull=0.0)
