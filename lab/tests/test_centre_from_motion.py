"""lab/centre_from_motion.py: the range-flow equation recovers a smooth body's rigid motion, the dead reckoning
is the env's chaser, the centre from the flow's motions solves exact motions from the past alone, and the
time-averaged centroid follows a drifting track, with the chaser's own motion taken out."""

from types import SimpleNamespace

import jax
import numpy as np
from scipy.spatial.transform import Rotation

from lab import centre_from_motion as cfm  # noqa: E402
from ramavt_jax import env as env_lib  # noqa: E402
from ramavt_jax.render.camera import CameraConfig, camera_rays  # noqa: E402


def ellipsoid_depth(rays, centre, rotation, axes):
    """[H, W] z depth of the near surface of an ellipsoid (semi-axes ``axes``, body axes ``rotation`` [3, 3]
    camera_from_body, centre [3]) along rays [H, W, 3] (z component 1); 0 where missed."""
    ray_b = rays @ rotation / axes  # the ray and the centre in the frame where the ellipsoid is a unit sphere
    centre_b = rotation.T @ centre / axes
    a = np.sum(ray_b * ray_b, -1)
    b = -2.0 * ray_b @ centre_b
    c = centre_b @ centre_b - 1.0
    disc = b * b - 4 * a * c
    return np.where(disc > 0, (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a), 0.0)


def test_range_flow_recovers_a_smooth_bodys_spin_and_velocity():
    rays = np.asarray(camera_rays(CameraConfig(resolution=96)), np.float64)
    centre, velocity, spin = np.array([0.3, -0.2, 5.0]), np.array([0.05, -0.1, 0.08]), np.array([0.1, -0.15, 0.12])
    axes, rotation, dt = np.array([1.4, 0.9, 0.6]), Rotation.from_rotvec([0.4, 0.7, -0.2]).as_matrix(), 0.1
    step = Rotation.from_rotvec(spin * dt).as_matrix()  # spin in camera axes: turns the body about its centre
    depth0 = ellipsoid_depth(rays, centre, rotation, axes)[None]
    depth1 = ellipsoid_depth(rays, centre + velocity * dt, step @ rotation, axes)[None]
    rows, rhs, valid = cfm.flow_rows(depth0, depth1, rays, dt, jump=0.3)
    still = np.zeros((1, 3))  # the chaser at rest: a is the target's own
    estimate = cfm.rigid_motion(rows, rhs, valid, still)[0]
    assert valid.sum() > 500
    np.testing.assert_allclose(estimate[3:], spin, atol=0.1 * np.linalg.norm(spin))
    point_velocity = velocity - np.cross(spin, centre)  # a: the velocity of the body point at the camera
    np.testing.assert_allclose(estimate[:3], point_velocity, atol=0.05 * np.linalg.norm(point_velocity))
    moving = cfm.rigid_motion(rows, rhs, valid, np.array([[0.2, 0.0, -0.1]]))[0]  # a chaser moving at this
    np.testing.assert_allclose(moving[:3] - estimate[:3], [0.2, 0.0, -0.1], atol=1e-9)  # velocity: the same flow


def test_dead_reckoning_is_the_envs_chaser():
    env = env_lib.TrackingEnv(env_lib.EnvConfig(camera=CameraConfig(resolution=8)))
    params = env.eval_params()
    actions = np.array([1, 1, 5, 0, 8, 8, 3, 6, 2, 10])

    @jax.jit
    def chaser_positions(state):  # the env's physics alone, no frames: [T, 3] camera frame, at each obs
        def body(state, action):
            return env.transition(jax.random.PRNGKey(1), state, action, params), state.chaser_pos

        return jax.lax.scan(body, state, actions)[1] @ env_lib.HILL_FROM_CAM

    positions = chaser_positions(env.initial_state(jax.random.PRNGKey(0), params))
    _, reckoned = cfm.chaser_track(actions[None])
    np.testing.assert_allclose(reckoned[0], positions, atol=1e-5)


def test_centre_from_flow_solves_exact_motions():
    steps, dt = 60, 0.1
    rng = np.random.default_rng(0)
    centre0, velocity = np.array([0.4, -0.3, 5.2]), np.array([0.05, 0.02, -0.03])
    chaser = np.cumsum(rng.normal(0.0, 0.02, (steps, 3)), axis=0)  # a dead-reckoned track [T, 3]
    turn = np.arange(steps - 1) * dt
    spin = 0.15 * np.stack([np.cos(0.3 * turn), np.sin(0.3 * turn), 0.5 + 0 * turn], -1)  # its axis wanders
    centre = centre0 + velocity * np.arange(steps)[:, None] * dt - chaser  # [T, 3] in the camera frame
    motion = np.concatenate([velocity - np.cross(spin, centre[:-1]), spin], -1)  # [T-1, 6] as rigid_motion's
    blank = np.full((steps, 3), np.nan)  # no centroid: no pull
    estimate = cfm.centre_from_flow(motion, chaser, blank, window=50, pull=0.0, dt=dt, skip=20)
    np.testing.assert_allclose(estimate[20:-1], centre[20:-1], atol=1e-6)
    changed = motion.copy()
    changed[40] += 1.0  # the pair of obs 40 and 41: not yet seen at obs 40
    causal = cfm.centre_from_flow(changed, chaser, blank, window=50, pull=0.0, dt=dt, skip=20)
    np.testing.assert_array_equal(causal[:41], estimate[:41])
    assert np.abs(causal[41] - estimate[41]).max() > 1e-3
    pulled = cfm.centre_from_flow(motion, chaser, centre + 1.0, window=50, pull=10.0, dt=dt, skip=20)
    assert np.all(np.abs(pulled[20:-1] - centre[20:-1]).max(-1) > 0.01)  # the centroid moves it when weighted


def test_fitted_track_follows_a_drift_and_averages_a_turning_offset():
    t = np.arange(400) * 0.1
    drift = np.stack([0.2 * t, -0.1 * t + 0.002 * t**2, 5.0 + 0 * t], -1)
    np.testing.assert_allclose(cfm.fitted_track(drift, window=50, degree=2)[3:], drift[3:], atol=1e-9)
    line = drift.copy()
    line[:, 1] = -0.1 * t
    offset = 0.4 * np.stack([np.cos(0.5 * t), np.sin(0.5 * t), 0 * t], -1)  # body-fixed, two turns per 252 steps
    seen = line + offset
    seen[::7] = np.nan  # blank frames are skipped
    fitted = cfm.fitted_track(seen, window=252, degree=1)
    # the newest end of a fit leaks part of the turn: about half of the offset is averaged away, not all of it
    assert np.nanmean(np.linalg.norm(fitted - line, axis=-1)[260:]) < 0.6 * 0.4


def test_averaged_centroid_takes_the_chasers_own_motion_out(monkeypatch):
    steps, dt = 300, 0.1
    action = np.random.default_rng(1).integers(0, len(env_lib.ACTIONS), (1, steps))
    _, chaser = cfm.chaser_track(action, dt=dt)
    drift = np.array([0.3, -0.2, 5.5]) + np.array([0.02, 0.01, -0.03]) * np.arange(steps)[:, None] * dt
    centre = (drift - chaser[0])[None]  # [1, T, 3] camera frame: the target drifts, the chaser flies its commands
    label = (centre - cfm.DESIRED) / cfm.DESIRED[2]
    monkeypatch.setattr(cfm, "visible_centroid", lambda episodes, camera: label)  # a centroid on the centre
    episodes = SimpleNamespace(action=action)
    guess = cfm.averaged_centroid(episodes, CameraConfig(resolution=8), window=50, degree=1, dt=dt)
    np.testing.assert_allclose(guess[0, 2:], label[0, 2:], atol=1e-6)  # exact once a line can be fitted
