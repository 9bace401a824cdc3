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

PAD = 32  # one geom count for every model: one compilation

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
    np.testing.assert_allclose(
        data.geom_xpos, arrays["geom_pos"][:n] @ rot.T + pos, atol=2e-4 * (1 + np.abs(pos).max())
    )
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
    normal = np.zeros(3 * nray, np.float64)
    mujoco.mj_multiRay(model, data, pos_wc, vec.reshape(-1), None, 1, -1, geomid, dist, normal, nray, 1e9)
    hit = (dist >= cam.near) & (dist <= cam.far)
    shape = (cam.resolution, cam.resolution)
    normal_cam = (normal.reshape(-1, 3) @ rot_wc).reshape(shape + (3,))
    return np.where(hit, dist, 0.0).reshape(shape), hit.reshape(shape), normal_cam, geomid.reshape(shape)


def _albedo(model):
    rgba = np.array(model.geom_rgba, np.float64)
    has = model.geom_matid >= 0
    rgba[has] = model.mat_rgba[model.geom_matid[has]]
    return rgba[:, :3]


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
    edge = np.zeros(mask.shape, bool)
    for dv in (-1, 0, 1):
        for du in (-1, 0, 1):
            edge |= p[1 + dv : 1 + dv + h, 1 + du : 1 + du + w] != mask
    return edge


def _check_against_mujoco(path, seed=0, n_poses=8, res=40):
    cam = R.CameraConfig(resolution=res, fov_deg=60.0)
    light = R.default_lighting()
    model, data, rot_wb, pos_wb = _world_from_body(path)
    target = targets.load(path, pad_to=max(PAD, model.ngeom))
    rng = np.random.default_rng(seed)
    radius = float(target.bound_radius)
    poses = _poses(rng, radius, cam, n_poses)
    positions = jnp.asarray(np.stack([p for p, _ in poses]), jnp.float32)
    rotations = jnp.asarray(np.stack([r for _, r in poses]), jnp.float32)
    batch = jax.tree.map(lambda a: jnp.broadcast_to(a, (n_poses,) + a.shape), target)
    frames = R.render_batch(batch, positions, rotations, cam, light, shade=True)
    albedo = _albedo(model)
    sun, amb = np.asarray(light.sun_dir, np.float64), float(light.ambient)
    total_hits = 0
    for i, (pos, rot) in enumerate(poses):
        ref_depth, ref_hit, ref_normal, ref_geom = _mujoco_depth(model, data, rot_wb, pos_wb, pos, rot, cam)
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
        # Lambertian colour from MuJoCo's normals (away from silhouette and geom edges, where normals jump).
        ref_rgb = albedo[ref_geom] * (amb + (1 - amb) * np.maximum(ref_normal @ sun, 0.0))[..., None]
        interior = both & ~_edge_pixels(np.where(ref_hit, ref_geom, -1))
        cerr = np.abs(np.asarray(frames.rgb[i]) - ref_rgb)[interior]
        assert cerr.size == 0 or np.quantile(cerr.max(-1), 0.99) < 2e-3, (
            f"{path} pose {i}: colour error {cerr.max():.2e}"
        )
        assert not np.asarray(frames.rgb[i])[~hit].any(), "sky must be black"
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
    _check_against_mujoco(path, seed=2, n_poses=12)


# ----------------------------------------------------------------------------------------------- API behaviour


@pytest.fixture(scope="module")
def scene(own_models):
    """A batch of 5 poses of the all-types model at 32x32."""
    cam = R.CameraConfig(resolution=32)
    target = targets.load(own_models["all_types"], pad_to=PAD)
    rng = np.random.default_rng(5)
    poses = _poses(rng, float(target.bound_radius), cam, 5)
    pos = jnp.asarray(np.stack([p for p, _ in poses]), jnp.float32)
    rot = jnp.asarray(np.stack([r for _, r in poses]), jnp.float32)
    batch = jax.tree.map(lambda a: jnp.broadcast_to(a, (5,) + a.shape), target)
    return cam, target, batch, pos, rot


def _frames_equal(a, b, atol=1e-5):
    np.testing.assert_allclose(np.asarray(a.depth), np.asarray(b.depth), atol=atol)
    np.testing.assert_allclose(np.asarray(a.rgb), np.asarray(b.rgb), atol=atol)
    np.testing.assert_array_equal(np.asarray(a.hit), np.asarray(b.hit))


def test_camera_config_validation():
    cam = R.CameraConfig()
    assert cam.resolution == 64 and np.isclose(cam.focal(), 32 / np.tan(np.radians(30)))
    hash(cam)
    for kwargs in [
        dict(resolution=4),
        dict(resolution=2048),
        dict(resolution=64.0),
        dict(fov_deg=0.0),
        dict(fov_deg=180.0),
        dict(near=0.0),
        dict(far=0.01),
    ]:
        with pytest.raises(ValueError):
            R.CameraConfig(**kwargs)


def test_camera_rays():
    cam = R.CameraConfig(resolution=9, fov_deg=90.0)
    rays = np.asarray(R.camera_rays(cam))
    assert rays.shape == (9, 9, 3) and rays.dtype == np.float32
    np.testing.assert_allclose(rays[4, 4], [0, 0, 1])
    np.testing.assert_allclose(rays[0, 8], [4 / 4.5, -4 / 4.5, 1], rtol=1e-6)  # top-right: x right, y down


@pytest.mark.slow
def test_jit_matches_no_jit(scene):
    _, target, _, pos, rot = scene
    cam = R.CameraConfig(resolution=16)
    light = R.default_lighting()
    jitted = jax.jit(R.render, static_argnames=("cam", "shade"))(target, pos[0], rot[0], cam, light)
    with jax.disable_jit():
        eager = R.render(target, pos[0], rot[0], cam, light)
    _frames_equal(jitted, eager)
    assert np.asarray(jitted.hit).any()


@pytest.mark.slow
def test_vmap_matches_loop_and_batch(scene):
    cam, _, batch, pos, rot = scene
    light = R.default_lighting()
    vm = jax.jit(jax.vmap(R.render, in_axes=(0, 0, 0, None, None)), static_argnums=3)(batch, pos, rot, cam, light)
    for i in range(pos.shape[0]):
        one = R.render(jax.tree.map(lambda a: a[i], batch), pos[i], rot[i], cam, light)
        _frames_equal(jax.tree.map(lambda a: a[i], vm), one)
    for chunk in (None, 7):
        _frames_equal(R.render_batch(batch, pos, rot, cam, light, chunk=chunk), vm)
    depth_only = R.render_batch(batch, pos, rot, cam, light, shade=False)
    np.testing.assert_array_equal(np.asarray(depth_only.depth), np.asarray(vm.depth))
    assert not np.asarray(depth_only.rgb).any()


@pytest.mark.slow
def test_tiling_is_exact(scene):
    """The tile culling must never drop a hit: compare with tiles covering everything (tile = resolution)."""
    cam, _, batch, pos, rot = scene
    light = R.default_lighting()
    a = R.render_batch(batch, pos, rot, cam, light, tile=8)
    b = R.render_batch(batch, pos, rot, cam, light, tile=32)
    c = R.render_batch(batch, pos, rot, R.CameraConfig(resolution=32), light, tile=5)  # non-dividing tile
    _frames_equal(a, b)
    _frames_equal(a, c)


def test_observation_modes(scene):
    cam, _, batch, pos, rot = scene
    frames = R.render_batch(batch, pos, rot, cam, R.default_lighting())
    for mode, ch in [("depth", 1), ("color", 3), ("rgbd", 4)]:
        obs = np.asarray(R.to_observation(frames, mode, cam.far))
        assert obs.shape == (5, 32, 32, ch) and obs.dtype == np.float32
        assert obs.min() >= 0.0 and obs.max() <= 1.0
    depth = np.asarray(R.to_observation(frames, "depth", cam.far))[..., 0]
    np.testing.assert_allclose(depth, np.asarray(frames.depth) / cam.far, rtol=1e-6)
    assert (depth[~np.asarray(frames.hit)] == 0).all()
    rgbd = np.asarray(R.to_observation(frames, "rgbd", cam.far))
    np.testing.assert_array_equal(rgbd[..., 3], depth)
    with pytest.raises(ValueError, match="unknown observation mode"):
        R.to_observation(frames, "infrared", cam.far)


def test_gaussian_blur():
    img = jax.random.uniform(jax.random.PRNGKey(0), (24, 20, 3))
    np.testing.assert_array_equal(np.asarray(R.gaussian_blur(img, 0.0)), np.asarray(img))
    out = jax.jit(R.gaussian_blur)(img, jnp.float32(1.5))
    assert out.shape == img.shape
    assert abs(float(out.mean()) - float(img.mean())) < 0.01
    assert float(out.std()) < float(img.std())
    const = jnp.full((16, 16, 1), 0.7)
    np.testing.assert_allclose(np.asarray(R.gaussian_blur(const, 2.0)), 0.7, atol=1e-5)  # borders do not darken
    batched = jax.vmap(R.gaussian_blur, in_axes=(0, 0))(jnp.stack([img, img]), jnp.array([0.0, 1.5]))
    np.testing.assert_allclose(np.asarray(batched[1]), np.asarray(out), atol=1e-6)


def test_motion_blur():
    img = jnp.zeros((21, 21, 1)).at[10, 10, 0].set(1.0)
    np.testing.assert_array_equal(np.asarray(R.motion_blur(img, 0.0, 0.3)), np.asarray(img))
    out = np.asarray(jax.jit(R.motion_blur)(img, 8.0, 0.0))
    assert out.shape == img.shape
    np.testing.assert_allclose(out.sum(), 1.0, atol=1e-5)
    assert out[10].sum() > 0.99  # a horizontal streak stays in its row
    vert = np.asarray(R.motion_blur(img, 8.0, np.pi / 2))
    assert vert[:, 10].sum() > 0.99


@pytest.mark.slow
def test_vmapped_render_uses_batch_rule_with_per_env_lighting():
    """vmap(render) goes through render_batch's custom rule; per-env lighting and nested vmap still match a loop."""
    tg = targets.load_many(["Satellite-v0", "Capsule-v0"])[0]
    cam = R.CameraConfig(resolution=24)
    pos = jnp.array([[0.0, 0.0, 5.0], [0.3, 0.2, 6.0]])
    rot = jnp.broadcast_to(jnp.eye(3), (2, 3, 3))
    light = R.default_lighting()
    flipped = jax.vmap(lambda s: R.Lighting(sun_dir=s, ambient=jnp.float32(0.2)))(
        jnp.stack([light.sun_dir, -light.sun_dir])
    )
    out = jax.jit(jax.vmap(lambda t, p, r, l: R.render(t, p, r, cam, l, True)))(tg, pos, rot, flipped)
    for i, lit in enumerate([light, R.Lighting(sun_dir=-light.sun_dir, ambient=jnp.float32(0.2))]):
        one = R.render(jax.tree.map(lambda x: x[i], tg), pos[i], rot[i], cam, lit, True)
        np.testing.assert_allclose(out.depth[i], one.depth, atol=1e-6)
        np.testing.assert_allclose(out.rgb[i], one.rgb, atol=1e-6)
    nested = jax.vmap(
        jax.vmap(lambda p, r: R.render(jax.tree.map(lambda x: x[0], tg), p, r, cam, light, False), in_axes=(0, None)),
        in_axes=(None, 0),
    )(pos, rot)
    assert nested.depth.shape == (2, 2, 24, 24)
    single = R.render(jax.tree.map(lambda x: x[0], tg), pos[1], rot[0], cam, light, False)
    np.testing.assert_allclose(nested.depth[0, 1], single.depth, atol=1e-6)


# ----------------------------------------------------------------------------------------------- fast paths


def test_specialised_kernels_match_general_cast():
    """The per-type kernels (ellipsoid, box, cylinder) give the general kernel's depths on random rays and poses."""
    from ramavt_jax.render import geometry, intersect

    rng = np.random.default_rng(7)
    cam = R.CameraConfig(resolution=32)
    jitted = {}  # kernel -> its jitted cast (every type has the same shapes: the general one compiles once)
    cast = lambda kernel: jitted.setdefault(kernel, jax.jit(lambda cols, x, y: kernel(cols, x, y, cam.near)))
    for gtype, kernel in [
        (targets.SPHERE, intersect.cast_ellipsoid),
        (targets.ELLIPSOID, intersect.cast_ellipsoid),
        (targets.BOX, intersect.cast_box),
        (targets.CYLINDER, intersect.cast_cylinder),
    ]:
        g = 16
        model = targets.TargetModel(
            geom_type=jnp.full((1, g), gtype, jnp.int32),
            geom_size=jnp.asarray(rng.uniform(0.1, 1.0, (1, g, 3)), jnp.float32),
            geom_pos=jnp.asarray(rng.normal(0, 0.5, (1, g, 3)), jnp.float32),
            geom_mat=jnp.asarray(np.stack([_random_rotation(rng) for _ in range(g)])[None], jnp.float32),
            geom_rgb=jnp.ones((1, g, 3)),
            geom_rbound=jnp.ones((1, g)),
            geom_mask=jnp.ones((1, g), bool),
            bound_radius=jnp.ones((1,)),
            inertia=jnp.ones((1, 3)),
            mass=jnp.ones((1,)),
        )
        pos = jnp.array([[0.2, -0.1, 3.0]])
        p, r = geometry.geom_frames(model, pos, jnp.asarray(_random_rotation(rng), jnp.float32)[None])
        table = geometry.cast_table(model, *geometry.unit_frames(model, p, r))  # [G, F]
        s = np.asarray(R.camera_rays(cam))
        x, y = jnp.asarray(s[..., 0])[None], jnp.asarray(s[..., 1])[None]  # [1, H, W]
        cols = [table[:, i, None, None] for i in range(table.shape[1])]
        ref = np.asarray(cast(intersect.cast)(cols, x, y))
        out = np.asarray(cast(kernel)(cols, x, y))
        assert np.isfinite(ref).sum() > 50, gtype
        np.testing.assert_array_equal(np.isfinite(out), np.isfinite(ref))
        fin = np.isfinite(ref)
        np.testing.assert_allclose(out[fin], ref[fin], rtol=2e-5, atol=2e-5)


@pytest.mark.slow
def test_render_options_do_not_change_the_image(scene):
    """Chunk size and the specialised kernels change nothing (beyond float rounding)."""
    cam, _, batch, pos, rot = scene
    light = R.default_lighting()
    ref = R.render_batch(batch, pos, rot, cam, light, specialise=False)
    for kwargs in [dict(), dict(chunk=1), dict(chunk=3), dict(chunk=1000)]:
        _frames_equal(R.render_batch(batch, pos, rot, cam, light, **kwargs), ref, atol=2e-5)


def test_hidden_targets_cost_no_work_and_render_empty(scene):
    cam, _, batch, pos, rot = scene
    behind = pos.at[:, 2].set(-1e6)
    frame = R.render_batch(batch, behind, rot, cam, R.default_lighting())
    assert not np.asarray(frame.hit).any() and not np.asarray(frame.depth).any() and not np.asarray(frame.rgb).any()


@pytest.mark.parametrize("com_z, offset_z", [(-1.0, 5.0), (21.0, -4.0)])
@pytest.mark.slow
def test_no_work_shortcut_keeps_geoms_far_from_the_centre_of_mass(com_z, offset_z):
    """The empty-batch shortcut looks at the centres of mass: a sphere (radius 2 m) 4-5 m from its target's centre of
    mass reaches into view from behind the camera and from beyond the far plane (20 m), and is rendered as without
    the shortcut."""
    from ramavt_jax.render import renderer

    cam = R.CameraConfig(resolution=16)
    sphere = targets.TargetModel(
        geom_type=jnp.full((1, 1), targets.SPHERE, jnp.int32),
        geom_size=jnp.full((1, 1, 3), 2.0),
        geom_pos=jnp.array([[[0.0, 0.0, offset_z]]]),
        geom_mat=jnp.eye(3)[None, None],
        geom_rgb=jnp.ones((1, 1, 3)),
        geom_rbound=jnp.full((1, 1), 2.0),
        geom_mask=jnp.ones((1, 1), bool),
        bound_radius=jnp.full((1,), 7.0),
        inertia=jnp.ones((1, 3)),
        mass=jnp.ones((1,)),
    )
    pos, rot, light = jnp.array([[0.0, 0.0, com_z]]), jnp.eye(3)[None], R.default_lighting()
    frame = R.render_batch(sphere, pos, rot, cam, light)
    assert np.asarray(frame.hit).any()
    _frames_equal(frame, renderer._render_seen(sphere, pos, rot, light, cam, True, None, renderer.DEFAULT_TILE, True))


@pytest.mark.parametrize("n", [1, 5, 64, 65, 1000, 2049, 70000])
def test_prefix_sum(n):
    from ramavt_jax.render.renderer import _prefix_sum

    x = np.random.default_rng(n).integers(0, 70, (3, n)).astype(np.int32)
    np.testing.assert_array_equal(np.asarray(_prefix_sum(jnp.asarray(x))), np.cumsum(x, axis=-1))


def test_observation_with_traced_per_env_far(scene):
    cam, _, batch, pos, rot = scene
    frames = R.render_batch(batch, pos, rot, cam, R.default_lighting())
    far = jnp.linspace(10.0, 30.0, pos.shape[0])
    for mode in ("depth", "rgbd"):
        obs = jax.jit(jax.vmap(lambda f, d: R.to_observation(f, mode, d)))(frames, far)
        for i in range(pos.shape[0]):
            one = R.to_observation(jax.tree.map(lambda a: a[i], frames), mode, float(far[i]))
            np.testing.assert_allclose(np.asarray(obs[i]), np.asarray(one), rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("e", [1, 7, 64, 1344, 5000])
def test_find_pair_is_searchsorted(e):
    from ramavt_jax.render.renderer import _find_pair, _search_levels

    rng = np.random.default_rng(e)
    counts = rng.integers(0, 5, (2, e)) * (rng.random((2, e)) < 0.6)
    ends = np.cumsum(counts, axis=-1).astype(np.int32)
    # every item of both rows (and, for the shorter row, items past its end) in one jitted call: one compilation
    # per e instead of dozens of eager op compilations
    k = np.arange(max(int(ends.max()), 1), dtype=np.int32)
    cls, kk = np.repeat(np.arange(2, dtype=np.int32), k.size), np.tile(k, 2)
    got = np.asarray(jax.jit(lambda e_, c, q: _find_pair(_search_levels(e_), c, q))(ends, cls, kk))
    for c in (0, 1):
        np.testing.assert_array_equal(got[cls == c], np.searchsorted(ends[c], k, side="right"))


def test_add_noise_matches_the_plain_formula_and_skips_when_off():
    keys = jax.random.split(jax.random.key(3), 4)
    img = jax.random.uniform(jax.random.key(4), (4, 12, 10, 1))
    mask = img > 0.3

    def plain(k, i, s, m):
        return jnp.clip(jnp.where(m, i + s * jax.random.normal(k, i.shape), i), 0.0, 1.0)

    for std in (jnp.zeros(4), jnp.array([0.0, 0.1, 0.0, 0.3])):
        got = jax.jit(jax.vmap(R.add_noise))(keys, img, std, mask)
        np.testing.assert_array_equal(np.asarray(got), np.asarray(jax.jit(jax.vmap(plain))(keys, img, std, mask)))
    one = jax.jit(R.add_noise)(keys[1], img[1], 0.1, mask[1])
    np.testing.assert_array_equal(np.asarray(one), np.asarray(jax.jit(plain)(keys[1], img[1], 0.1, mask[1])))
    shared = jax.vmap(R.add_noise, in_axes=(0, 0, None, 0))(keys, img, 0.0, mask)
    np.testing.assert_array_equal(np.asarray(shared), np.asarray(img))
