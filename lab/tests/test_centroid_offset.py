"""lab/centroid_offset.py: a sphere about its centre is seen centred; moved off it, it is seen off centre."""

import jax.numpy as jnp
import numpy as np

from lab import centroid_offset  # noqa: E402
from ramavt_jax import render, targets

SPHERE = (
    '<mujoco><worldbody><body name="target"><freejoint/><geom type="sphere" size="0.6"/></body></worldbody></mujoco>'
)


def test_a_sphere_is_seen_centred_and_a_moved_one_to_the_side(tmp_path):
    (tmp_path / "ball.xml").write_text(SPHERE)
    ball = targets.load(tmp_path / "ball.xml")
    cam = render.CameraConfig(resolution=32)
    attitudes = jnp.stack([jnp.eye(3), jnp.diag(jnp.array([-1.0, -1.0, 1.0]))])  # the second turns x to -x
    centred = centroid_offset.centroid_offsets(ball, attitudes, cam)
    assert np.all(centred["sideways"] < 0.03)
    # pixels sample the disc evenly: the seen points lie about 2/3 r in front of the centre (0.4 m; coarser at 32 px)
    assert np.all((centred["distance"] > 0.35) & (centred["distance"] < 0.5)), centred["distance"]
    moved = centroid_offset.centroid_offsets(targets.shifted(ball, jnp.array([0.5, 0.0, 0.0])), attitudes, cam)
    assert np.all((moved["sideways"] > 0.45) & (moved["sideways"] < 0.7)), moved["sideways"]
