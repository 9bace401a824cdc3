"""lab/centre_precision.py: the centre told moves where the planner thinks the target is, by the offset asked
for and in the camera frame; the ceiling told its own centre flies as the ceiling; told a wrong one, it scores less
by about the error per step once it holds station."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from lab import centre_precision  # noqa: E402
from lab.surface import visible_tracking_state
from ramavt_jax import env as env_lib

CAMERA = env_lib.CameraConfig(resolution=16)


@pytest.fixture(scope="module")
def capsule():
    """(env state, params) of one Capsule-v0 episode's start."""
    tracking_env = env_lib.TrackingEnv(env_lib.EnvConfig(camera=CAMERA, targets=("Capsule-v0",)))
    params = tracking_env.eval_params()
    _, state = jax.jit(tracking_env.reset)(jax.random.PRNGKey(4), params)
    return state, params


def test_the_told_centre_moves_by_the_offset_in_the_camera_frame(capsule):
    state, _ = capsule
    offset = jnp.array([0.3, -0.2, 0.5])
    moved = env_lib.relative_position(centre_precision.told_centre(state, offset)) - env_lib.relative_position(state)
    np.testing.assert_allclose(moved, offset, atol=1e-5)


def test_the_visible_arms_tell_the_surface_centroid_on_their_axes_only(capsule):
    state, params = capsule
    desired, true = np.asarray(params.desired_pos), np.asarray(env_lib.relative_position(state))
    seen = np.asarray(visible_tracking_state(state, params, CAMERA)[:3]) * desired[2] + desired  # m, k = 1
    assert np.linalg.norm(seen - true) > 0.1  # the capsule's seen surface lies in front of its centre
    for axes in centre_precision.VISIBLE_AXES.values():
        told = env_lib.relative_position(
            centre_precision.told_centre(state, centre_precision.visible_offset(state, params, CAMERA, axes))
        )
        np.testing.assert_allclose(told, np.where(np.asarray(axes) > 0, seen, true), atol=1e-4)


def test_a_wrong_centre_costs_the_ceiling_about_its_size_per_step():
    table = centre_precision.precision_table(
        ("Asteroid-v0",), episodes=2, offsets=[0.0, 0.5], visible=False, overrides={"max_steps": 200}
    )
    exact, none, half = (table[name]["aer"] for name in ("exact", "offset 0", "offset 0.5"))
    assert none == exact  # the same episodes, the same plans
    # the reward's distance term is 1 per metre: held 0.5 m off for most of 200 steps costs on the order of 50
    assert 30.0 < exact - half < 100.0, (exact, half)


def test_the_precision_plot_is_written_and_bad_marks_are_refused(tmp_path):
    table = {"exact": {"aer": 800.0}, "offset 0.1": {"aer": 720.0}, "offset 0.3": {"aer": 560.0}}
    marks = centre_precision._marks(["agent=0.3", "a=b=0.5"])
    assert marks == {"agent": 0.3, "a=b": 0.5}
    centre_precision.plot_precision(table, marks, tmp_path / "precision.png")
    assert (tmp_path / "precision.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    for bad in ("0.3", "agent=far"):
        with pytest.raises(ValueError, match="LABEL=METRES"):
            centre_precision._marks([bad])
