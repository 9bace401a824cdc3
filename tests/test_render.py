"""Renderer tests: MuJoCo's own ray casting (mj_multiRay) is the reference for every target file."""

from __future__ import annotations

import glob
import os
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from ramavt_jax import render as R  # noqa: E402
from ramavt_jax import targets  # noqa: E402

# Own models: every geom type, rotated geoms (euler / quat / axisangle / fromto), several and nested bodies,
# a body offset from the world origin, sites and a free joint.
TEST_MJCF = {
    "all_types": """
<mujoco><compiler angle="degree"/><worldbody>
  <body name="a" pos="0.3 -0.2 0.1" euler="10 20 30"><freejoint/>
    <geom type="sphere" size="0.4" pos="0 0 0" rgba="1 0 0 1"/>
    <geom type="box" size="0.5 0.2 0.1" pos="0.8 0 0" euler="0 30 45" rgba="0 1 0 1"/>
    <geom type="capsule" size="0.15" fromto="-0.3 0.5 0 -0.9 1.0 0.4" rgba="0 0 1 1"/>
    <geom type="cylinder" size="0.2 0.3" pos="0 -0.8 0.2" quat="0.9 0.3 0.2 0.1" rgba="1 1 0 1"/>
    <geom type="ellipsoid" size="0.3 0.15 0.45" pos="0 0 -0.7" axisangle="1 1 0 40" rgba="0 1 1 1"/>
  </body></worldbody></mujoco>""",
    "multibody": """
<mujoco><worldbody>
  <body name="hub" pos="1 2 3" quat="0.7 0.1 0.7 0.1">
    <geom type="cylinder" size="0.5 1.0" density="500"/>
    <body name="wing1" pos="0 1.6 0" euler="0.3 0 0.2">
      <geom type="box" size="0.05 0.6 0.9" density="100"/>
    </body>
    <body name="wing2" pos="0 -1.6 0.1" euler="-0.3 0.1 0">
      <geom type="box" size="0.05 0.6 0.9" density="100"/>
      <body name="tip" pos="0 -0.8 0"><geom type="sphere" size="0.2"/><geom type="capsule" size="0.05 0.4" euler="0.5 0 0"/></body>
    </body>
  </body></worldbody></mujoco>""",
    "slender": """
<mujoco><worldbody>
  <body name="b"><site name="s" pos="0 0 1"/>
    <geom type="capsule" size="0.05 2.0" euler="0 1.5707963 0.3"/>
    <geom type="cylinder" size="0.6 0.02" pos="0 0 0.5"/>
    <geom type="ellipsoid" size="0.05 0.5 0.2" pos="0.5 0 -0.4" euler="0.2 0.4 0.6"/>
    <geom type="box" size="0.01 0.01 1.5" pos="-0.5 0.2 0" euler="1 0 0"/>
  </body></worldbody></mujoco>""",
}


def _model_paths():
    paths = sorted(glob.glob(str(Path(targets.MODEL_DIR) / "*.xml")))
    extra = os.environ.get("RAMAVT_EXTRA_TARGETS", "")
    paths += [p for p in extra.split(os.pathsep) if p]
    return paths


def _random_rotation(rng):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, q)
    return mat.reshape(3, 3)


def _world_from_body(path):
    """MuJoCo model/data and the world pose of the loader's body frame, fitted from the geom poses."""
    model = mujoco.MjModel.from_xml_path(str(path))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    arrays, _ = targets.load_numpy(path)
    n = model.ngeom
    xmat = data.geom_xmat.reshape(-1, 3, 3)
    rot = xmat[0] @ arrays["geom_mat"][0].astype(np.float64).T
    pos = data.geom_xpos[0] - rot @ arrays["geom_pos"][0]
    # The loader's geoms must be a rigid transform of MuJoCo's.
    np.testing.assert_allclose(data.geom_xpos, arrays["geom_pos"][:n] @ rot.T + pos, atol=2e-4 * (1 + np.abs(pos).max()))
    np.testing.assert_allclose(xmat, np.einsum("ij,gjk->gik", rot, arrays["geom_mat"][:n]), atol=1e-4)
    return model, data, rot, pos


def _mujoco_depth(model, data, rot_wb, pos_wb, position, rotation, cam):
    """Depth image from mj_multiRay for the body at (position, rotation) in the camera frame."""
    rot_wc = rot_wb @ rotation.T
    pos_wc = pos_wb - rot_wc @ position
    rays = np.asarray(R.camera_rays(cam), np.float64).reshape(-1, 3)
    vec = rays @ rot_wc.T
    nray = vec.shape[0]
    geomid = np.zeros(nray, np.int32)
    dist = np.zeros(nray, np.float64)
    mujoco.mj_multiRay(model, data, pos_wc, vec.reshape(-1), None, 1, -1, geomid, dist, None, nray, 1e9)
    hit = (dist >= cam.near) & (dist <= cam.far)
    return np.where(hit, dist, 0.0).reshape(cam.resolution, cam.resolution), hit.reshape(cam.resolution, cam.resolution)


def _poses(rng, radius, cam, n):
    """Random poses: centred, off-centre/partly out of view, near, far (some beyond `far`)."""
    tan = np.tan(np.radians(cam.fov_deg) / 2)
    out = []
    for i in range(n):
        kind = i % 4
        if kind == 0:  # in view, moderate distance
            z = rng.uniform(2.5, 4.0) * radius + 1.0
            xy = rng.uniform(-0.3, 0.3, 2) * z * tan
        elif kind == 1:  # partly out of view
            z = rng.uniform(2.0, 3.5) * radius + 1.0
            xy = rng.choice([-1, 1], 2) * rng.uniform(0.8, 1.2, 2) * z * tan
        elif kind == 2:  # near: the target fills the view
            z = radius * rng.uniform(1.2, 1.6) + 0.3
            xy = rng.uniform(-0.2, 0.2, 2) * z * tan
        else:  # far, straddling the far limit for large targets
            z = rng.uniform(0.7, 1.0) * cam.far
            xy = rng.uniform(-0.5, 0.5, 2) * z * tan
        out.append((np.array([xy[0], xy[1], z]), _random_rotation(rng)))
    return out


def _edge_pixels(mask):
    """Pixels with a differing 8-neighbour."""
    p = np.pad(mask, 1, mode="edge")
    h, w = mask.shape
    edge = np.zeros_like(mask)
    for dv in (-1, 0, 1):
        for du in (-1, 0, 1):
            edge |= p[1 + dv : 1 + dv + h, 1 + du : 1 + du + w] != mask
    return edge


def _check_against_mujoco(path, seed=0, n_poses=8, res=40):
    cam = R.CameraConfig(resolution=res, fov_deg=60.0)
    light = R.default_lighting()
    model, data, rot_wb, pos_wb = _world_from_body(path)
    target = targets.load(path)
    rng = np.random.default_rng(seed)
    radius = float(target.bound_radius)
    poses = _poses(rng, radius, cam, n_poses)
    positions = jnp.asarray(np.stack([p for p, _ in poses]), jnp.float32)
    rotations = jnp.asarray(np.stack([r for _, r in poses]), jnp.float32)
    batch = jax.tree.map(lambda a: jnp.broadcast_to(a, (n_poses,) + a.shape), target)
    frames = R.render_batch(batch, positions, rotations, cam, light, shade=False)
    total_hits = 0
    for i, (pos, rot) in enumerate(poses):
        ref_depth, ref_hit = _mujoco_depth(model, data, rot_wb, pos_wb, pos, rot, cam)
        depth = np.asarray(frames.depth[i])
        hit = np.asarray(frames.hit[i])
        both = hit & ref_hit
        err = np.abs(depth - ref_depth)[both]
        assert err.size == 0 or err.max() < 1e-4, f"{path} pose {i}: depth error {err.max():.2e} m"
        mismatch = hit != ref_hit
        near_far = np.abs(np.where(hit, depth, ref_depth) - cam.far) < 1e-3
        bad = mismatch & ~_edge_pixels(ref_hit) & ~near_far
        assert not bad.any(), f"{path} pose {i}: {bad.sum()} hit/miss mismatches away from silhouette edges"
        assert mismatch.sum() <= max(2, 0.02 * ref_hit.sum()), f"{path} pose {i}: {mismatch.sum()} mismatches"
        total_hits += ref_hit.sum()
    assert total_hits > 0, f"{path}: no pose saw the target"


@pytest.fixture(scope="module")
def own_models(tmp_path_factory):
    root = tmp_path_factory.mktemp("mjcf")
    paths = {}
    for name, xml in TEST_MJCF.items():
        p = root / f"{name}.xml"
        p.write_text(xml)
        paths[name] = p
    return paths


@pytest.mark.parametrize("name", sorted(TEST_MJCF))
def test_own_models_match_mujoco(own_models, name):
    _check_against_mujoco(own_models[name], seed=1, n_poses=12)


@pytest.mark.parametrize("path", _model_paths(), ids=lambda p: Path(p).stem)
def test_catalogue_matches_mujoco(path):
    _check_against_mujoco(path, seed=2, n_poses=8)
