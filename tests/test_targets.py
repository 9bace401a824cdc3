"""Target catalogue and MJCF loader: catalogue contents, padding, principal-frame transform, error messages."""

from __future__ import annotations

import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import jax
import mujoco
import numpy as np
import pytest

from ramavt_jax import render, targets
from ramavt_jax.cli.commands import catalogue_table
from ramavt_jax.rotations import quat_to_mat, random_quaternion
from ramavt_jax.targets import specs

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))  # the generator is a build-time script
import catalogue_gen  # noqa: E402

# bound_radius (m) and mass (kg) ranges per class. The size rule (catalogue_gen) caps every bounding radius at
# 2.4 m so that the target fits the 60-degree view at the 5 m stand-off; spacecraft classes are scaled down to it
# with their densities kept (hence the small masses of the scaled rockets, satellites and stations).
RADIUS_RANGE = {
    "asteroid": (0.4, 2.401),
    "capsule": (1.5, 2.401),
    "rocket": (1.5, 2.401),
    "satellite": (1.5, 2.401),
    "station": (1.5, 2.401),
}
MASS_RANGE = {
    "asteroid": (100.0, 1e5),
    "capsule": (1e3, 1.5e4),
    "rocket": (50.0, 1e3),
    "satellite": (50.0, 1e3),
    "station": (50.0, 1e3),
}


@pytest.fixture(scope="module")
def catalogue():
    return targets.load_many(targets.ALL_TARGETS)


# ------------------------------------------------------------------------------------- analytic mass properties
def _primitive_mass_inertia(kind: str, size: np.ndarray, density: float) -> tuple[float, np.ndarray]:
    """Mass and principal inertia (about the geom centre, in geom axes) of a solid MuJoCo primitive."""
    if kind == "box":
        a, b, c = size
        m = density * 8 * a * b * c
        return m, m / 3 * np.array([b * b + c * c, a * a + c * c, a * a + b * b])
    if kind in ("sphere", "ellipsoid"):
        a, b, c = (size[0],) * 3 if kind == "sphere" else size
        m = density * 4 / 3 * np.pi * a * b * c
        return m, m / 5 * np.array([b * b + c * c, a * a + c * c, a * a + b * b])
    if kind == "cylinder":
        r, h = size[:2]
        m = density * np.pi * r * r * 2 * h
        ixx = m * (3 * r * r + 4 * h * h) / 12
        return m, np.array([ixx, ixx, m * r * r / 2])
    if kind == "capsule":
        r, h = size[:2]
        mc = density * np.pi * r * r * 2 * h
        ms = density * 4 / 3 * np.pi * r**3
        ixx = mc * (r * r / 4 + h * h / 3) + ms * (2 * r * r / 5 + h * h + 3 * h * r / 4)
        return mc + ms, np.array([ixx, ixx, mc * r * r / 2 + ms * 2 * r * r / 5])
    raise AssertionError(kind)


def _composite(masses, inertias, positions, rotations) -> tuple[float, np.ndarray, np.ndarray]:
    """Total mass, centre of mass and inertia tensor about it of rigidly joined primitives (one frame)."""
    masses = np.asarray(masses, float)
    positions = np.asarray(positions, float)
    total = masses.sum()
    com = (masses[:, None] * positions).sum(0) / total
    tensor = np.zeros((3, 3))
    for m, inertia, p, rot in zip(masses, inertias, positions, rotations):
        d = p - com
        tensor += rot @ np.diag(inertia) @ rot.T + m * (d @ d * np.eye(3) - np.outer(d, d))
    return total, com, tensor


def _geom_densities(path: Path, model) -> np.ndarray:
    """Density of every geom of `model` (by name, from the XML; MuJoCo's default is 1000)."""
    by_name = {g.get("name"): float(g.get("density", 1000.0)) for g in ET.parse(path).iter("geom")}
    names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) for g in range(model.ngeom)]
    assert all(n in by_name for n in names), "every geom needs a unique name for this check"
    return np.array([by_name[n] for n in names])


def _check_body_frame(arrays: dict, densities: np.ndarray, rtol: float = 2e-3) -> None:
    """Recompute the inertia tensor from the loader's body-frame geoms: it must be diag(inertia) about the origin."""
    n = int(arrays["geom_mask"].sum())
    masses, inertias = [], []
    for g in range(n):
        kind = targets.SUPPORTED_GEOM_TYPES[int(arrays["geom_type"][g])]
        m, inertia = _primitive_mass_inertia(kind, arrays["geom_size"][g].astype(float), densities[g])
        masses.append(m)
        inertias.append(inertia)
    mats = arrays["geom_mat"][:n].astype(float)
    total, com, tensor = _composite(masses, inertias, arrays["geom_pos"][:n], mats)
    scale = float(np.max(arrays["inertia"]))
    np.testing.assert_allclose(total, arrays["mass"], rtol=rtol)
    np.testing.assert_allclose(com, 0.0, atol=1e-4 * max(1.0, float(arrays["bound_radius"])))
    np.testing.assert_allclose(tensor, np.diag(arrays["inertia"]), atol=rtol * scale)
    # geom rotations are proper rotations
    np.testing.assert_allclose(np.einsum("gji,gjk->gik", mats, mats), np.broadcast_to(np.eye(3), mats.shape), atol=1e-5)
    np.testing.assert_allclose(np.linalg.det(mats), 1.0, atol=1e-5)


# ------------------------------------------------------------------------------------------------- catalogue
def test_catalogue_names_classes_and_split():
    assert len(targets.CATALOGUE) == 24
    counts = {}
    for name, cls in targets.CATALOGUE.items():
        assert name.lower().startswith(cls)
        counts[cls] = counts.get(cls, 0) + 1
    assert counts == {"asteroid": 8, "capsule": 4, "rocket": 4, "satellite": 4, "station": 4}
    train, val, test = set(targets.TRAIN_TARGETS), set(targets.VAL_TARGETS), set(targets.TEST_TARGETS)
    assert len(targets.TRAIN_TARGETS) == 12 and len(targets.VAL_TARGETS) == 6 and len(targets.TEST_TARGETS) == 6
    assert not train & test and not train & val and not val & test
    assert train | val | test == set(targets.ALL_TARGETS) == set(targets.CATALOGUE)
    assert test == {"Asteroid-v4", "Asteroid-v5", "Capsule-v2", "Rocket-v2", "Satellite-v2", "Station-v2"}
    # the split shows in the name; the 18 original models keep their catalogue indices
    assert all("-val" in n for n in val) and not any("-val" in n for n in train | test)
    counts = (("Asteroid", 6), ("Capsule", 3), ("Rocket", 3), ("Satellite", 3), ("Station", 3))
    assert targets.ALL_TARGETS[:18] == tuple(f"{c}-v{i}" for c, k in counts for i in range(k))
    assert sorted(targets.CATALOGUE[n] for n in val) == sorted(targets.CATALOGUE[n] for n in test)  # same class mix
    assert targets.split("train") == targets.TRAIN_TARGETS and targets.split("test") == targets.TEST_TARGETS
    assert targets.split("val") == targets.VAL_TARGETS and targets.split("all") == targets.ALL_TARGETS
    with pytest.raises(targets.TargetError, match="unknown split"):
        targets.split("validation")


def test_validation_models_follow_their_class_size_rule():
    """Each validation model is drawn at its class's factor and is not the largest of its class, so adding it left
    the training and test models' scale (and files) as they were."""
    models = {t.name: t for t in catalogue_gen.all_targets()}
    radii = {r["name"]: r["bound_radius"] for r in catalogue_table()}
    for name in targets.VAL_TARGETS:
        cls = targets.CATALOGUE[name]
        originals = [n for n in targets.TRAIN_TARGETS + targets.TEST_TARGETS if targets.CATALOGUE[n] == cls]
        assert {models[n].scale for n in originals} == {models[name].scale}, name
        assert radii[name] <= max(radii[n] for n in originals) <= catalogue_gen.MAX_BOUND_RADIUS + 1e-3, name
        assert radii[name] >= min(radii[n] for n in originals) / 1.5, name


def test_validation_models_are_seen_whole_at_the_stand_off():
    """A depth frame of each validation model at the 5 m stand-off, in a few attitudes: the target covers pixels,
    at depths within its bounding sphere, and never reaches the image border."""
    cam = render.CameraConfig(resolution=32)
    batch, infos = targets.load_many(targets.VAL_TARGETS)
    n, poses = len(infos), 3
    rotations = jax.vmap(lambda k: quat_to_mat(random_quaternion(k)))(
        jax.random.split(jax.random.PRNGKey(0), n * poses)
    )
    tiled = jax.tree.map(lambda a: np.repeat(np.asarray(a), poses, axis=0), batch)
    positions = np.tile([0.0, 0.0, 5.0], (n * poses, 1)).astype(np.float32)
    frames = render.render_batch(tiled, positions, rotations, cam, render.default_lighting(), shade=False)
    hit, depth = np.asarray(frames.hit), np.asarray(frames.depth)
    for i in range(n * poses):
        info, r = infos[i // poses], infos[i // poses].bound_radius
        assert hit[i].sum() >= 10, (info.name, hit[i].sum())
        assert np.all((depth[i][hit[i]] >= 5.0 - r - 1e-3) & (depth[i][hit[i]] <= 5.0 + r + 1e-3)), info.name
        border = np.concatenate([hit[i][0], hit[i][-1], hit[i][:, 0], hit[i][:, -1]])
        assert not border.any(), info.name


def test_val_is_a_target_spec_like_test():
    from ramavt_jax.evaluation import rollouts

    assert rollouts.resolve_targets("val") == targets.VAL_TARGETS
    assert rollouts.resolve_targets("val,Capsule-v0,Capsule-val0") == targets.VAL_TARGETS + ("Capsule-v0",)
    assert not set(rollouts.resolve_targets("val")) & set(rollouts.resolve_targets("test"))


def test_package_does_not_ship_the_generator():
    package = Path(targets.__file__).parent
    assert not (package / "catalogue_gen.py").exists() and not (package / "mjcf_builder.py").exists()
    with pytest.raises(ModuleNotFoundError):
        __import__("ramavt_jax.targets.catalogue_gen")
    assert Path(catalogue_gen.__file__).parent.name == "scripts"
    assert catalogue_gen.MODEL_DIR.resolve() == targets.MODEL_DIR.resolve()


def test_catalogue_loads_with_plausible_sizes_and_masses(catalogue):
    batch, infos = catalogue
    assert [i.name for i in infos] == list(targets.ALL_TARGETS)
    for k, info in enumerate(infos):
        cls = targets.CATALOGUE[info.name]
        lo, hi = RADIUS_RANGE[cls]
        assert lo <= info.bound_radius <= hi, (info.name, info.bound_radius)
        lo, hi = MASS_RANGE[cls]
        assert lo <= info.mass <= hi, (info.name, info.mass)
        assert 1 <= info.num_geoms <= 24
        inertia = np.asarray(batch.inertia[k], float)
        assert np.all(inertia > 0) and np.all(np.diff(inertia) >= 0), (info.name, inertia)
        a, b, c = inertia
        assert a + b >= c * (1 - 1e-5), (info.name, inertia)  # triangle inequality
        np.testing.assert_allclose(inertia, info.inertia, rtol=1e-5)
        assert float(batch.mass[k]) == pytest.approx(info.mass, rel=1e-6)
        assert float(batch.bound_radius[k]) == pytest.approx(info.bound_radius, rel=1e-6)


def test_every_catalogue_target_fits_the_view_at_the_stand_off(catalogue):
    """Size rule: bounding radius <= 2.4 m, below the 2.89 m half-width of the 60-degree view at 5 m; the
    largest model of each scaled class sits at the cap."""
    _, infos = catalogue
    half_width = 5.0 * np.tan(np.deg2rad(30.0))
    radii = {i.name: i.bound_radius for i in infos}
    assert max(radii.values()) <= catalogue_gen.MAX_BOUND_RADIUS + 1e-3 < half_width
    for cls in ("capsule", "rocket", "satellite", "station"):
        assert max(r for n, r in radii.items() if targets.CATALOGUE[n] == cls) == pytest.approx(
            catalogue_gen.MAX_BOUND_RADIUS, abs=1e-3
        ), cls


def test_generator_reproduces_the_committed_files():
    for t in catalogue_gen.all_targets():
        assert (targets.MODEL_DIR / f"{t.name}.xml").read_text() == t.xml(), t.name


def test_held_out_variants_are_similar_in_scale():
    rows = {r["name"]: r for r in catalogue_table()}
    for cls in ("capsule", "rocket", "satellite", "station"):
        radii = [rows[f"{cls.capitalize()}-v{i}"]["bound_radius"] for i in range(3)]
        assert radii[2] <= 1.5 * max(radii[:2]) and radii[2] >= min(radii[:2]) / 1.5, (cls, radii)


@pytest.mark.parametrize("name", targets.ALL_TARGETS)
def test_catalogue_file_conventions(name):
    path = targets.resolve(name)
    root = ET.parse(path).getroot()
    bodies = root.find("worldbody").findall("body")
    assert len(bodies) == 1 and bodies[0].get("name") == "target"
    assert bodies[0].find("freejoint") is not None
    assert root.find("worldbody").find("geom") is None
    assert root.find("asset") is None  # no meshes, materials or textures
    geoms = list(root.iter("geom"))
    assert all(g.get("rgba") and (g.get("density") or g.get("mass")) for g in geoms)
    model = mujoco.MjModel.from_xml_path(str(path))
    np.testing.assert_array_equal(model.opt.gravity, 0.0)
    # spacecraft are hollow (effective densities well below solid metal); asteroids are rock
    densities = _geom_densities(path, model)
    if targets.CATALOGUE[name] == "asteroid":
        assert np.all((densities >= 1000) & (densities <= 3500))
    else:
        assert np.all((densities > 10) & (densities <= 1000))


def test_variants_differ():
    batch, infos = targets.load_many(targets.ALL_TARGETS)
    signatures = set()
    for k, info in enumerate(infos):
        ratios = np.asarray(batch.inertia[k]) / float(batch.inertia[k].max())
        signatures.add((info.num_geoms, info.geom_types, tuple(np.round(ratios, 2))))
    assert len(signatures) == len(infos)


@pytest.mark.parametrize("name", targets.ALL_TARGETS)
def test_catalogue_principal_frame_matches_analytic_inertia(name):
    """The loader's body-frame geoms, with the file's densities, reproduce diag(inertia) about the origin."""
    path = targets.resolve(name)
    model = mujoco.MjModel.from_xml_path(str(path))
    arrays, info = targets.load_numpy(name)
    _check_body_frame(arrays, _geom_densities(path, model))
    # single rigid body: MuJoCo's own principal inertia agrees
    np.testing.assert_allclose(np.sort(model.body_inertia[1]), arrays["inertia"], rtol=1e-4)


# --------------------------------------------------------------------------------------------------- padding
def test_padding_and_select(catalogue):
    batch, infos = catalogue
    n, width = len(infos), max(i.num_geoms for i in infos)
    assert batch.geom_type.shape == (n, width) and batch.num_geoms == width
    assert batch.geom_size.shape == (n, width, 3) and batch.geom_mat.shape == (n, width, 3, 3)
    assert batch.geom_rgb.shape == (n, width, 3) and batch.geom_rbound.shape == (n, width)
    assert batch.bound_radius.shape == (n,) and batch.inertia.shape == (n, 3) and batch.mass.shape == (n,)
    mask = np.asarray(batch.geom_mask)
    np.testing.assert_array_equal(mask.sum(1), [i.num_geoms for i in infos])
    for k, info in enumerate(infos):
        assert mask[k, : info.num_geoms].all() and not mask[k, info.num_geoms :].any()
        pad = slice(info.num_geoms, None)
        assert np.all(np.asarray(batch.geom_size[k, pad]) == 0) and np.all(np.asarray(batch.geom_rbound[k, pad]) == 0)
        np.testing.assert_array_equal(
            np.asarray(batch.geom_mat[k, pad]), np.broadcast_to(np.eye(3), (width - info.num_geoms, 3, 3))
        )
        rgb = np.asarray(batch.geom_rgb[k, : info.num_geoms])
        assert np.all((rgb >= 0) & (rgb <= 1))
    # select (jitted, traced index) equals loading the target on its own with the same padding
    k = targets.ALL_TARGETS.index("Satellite-v1")
    picked = jax.jit(targets.select)(batch, k)
    single = targets.load("Satellite-v1", pad_to=width)
    for a, b in zip(jax.tree.leaves(picked), jax.tree.leaves(single)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    wide, _ = targets.load_many(["Asteroid-v2", "Station-v0"], pad_to=32)
    assert wide.geom_type.shape == (2, 32)
    with pytest.raises(targets.TargetError, match="pad_to"):
        targets.load_many(targets.ALL_TARGETS, pad_to=3)
    with pytest.raises(targets.TargetError, match="padding size"):
        targets.load("Station-v0", pad_to=3)
    with pytest.raises(targets.TargetError, match="no targets"):
        targets.load_many([])


def test_catalogue_table():
    rows = catalogue_table()
    assert [r["name"] for r in rows] == list(targets.ALL_TARGETS)
    for r in rows:
        assert set(r) == {"name", "class", "split", "num_geoms", "bound_radius", "mass"}
        assert r["class"] == targets.CATALOGUE[r["name"]]
        assert r["split"] == (
            "test" if r["name"] in targets.TEST_TARGETS else "val" if r["name"] in targets.VAL_TARGETS else "train"
        )
        assert r["num_geoms"] >= 1 and r["bound_radius"] > 0 and r["mass"] > 0


# -------------------------------------------------------------------------------------- principal frame
def _write(tmp_path: Path, text: str, name: str = "model.xml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _rot_z(deg: float) -> np.ndarray:
    c, s = np.cos(np.deg2rad(deg)), np.sin(np.deg2rad(deg))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def test_single_offset_rotated_box_is_centred_and_diagonal(tmp_path):
    half, mass = np.array([0.5, 0.2, 1.5]), 120.0
    path = _write(
        tmp_path,
        f"""
<mujoco><worldbody>
  <body pos="3 -2 1" euler="0 0 30"><freejoint/>
    <geom type="box" size="{half[0]} {half[1]} {half[2]}" mass="{mass}" pos="0.7 0.4 -0.2" euler="20 0 45"
          rgba="0.9 0.1 0.2 1"/>
  </body>
</worldbody></mujoco>""",
    )
    arrays, info = targets.load_numpy(path)
    a, b, c = half
    expected = mass / 3 * np.array([b * b + c * c, a * a + c * c, a * a + b * b])
    np.testing.assert_allclose(arrays["inertia"], np.sort(expected), rtol=1e-5)
    assert info.mass == pytest.approx(mass)
    np.testing.assert_allclose(arrays["geom_pos"][0], 0.0, atol=1e-5)
    # the box axes are the principal axes: geom_mat is a signed permutation taking sizes to sorted moments
    mat = arrays["geom_mat"][0]
    np.testing.assert_allclose(np.abs(mat), np.round(np.abs(mat)), atol=1e-5)
    body_half = np.abs(mat) @ half
    np.testing.assert_allclose(mass / 3 * (body_half @ body_half - body_half**2), arrays["inertia"], rtol=1e-5)
    assert info.bound_radius == pytest.approx(np.linalg.norm(half), rel=1e-5)
    np.testing.assert_allclose(arrays["geom_rgb"][0], [0.9, 0.1, 0.2], atol=1e-6)
    assert info.name == "model" and info.geom_types == ("box",)


def test_two_box_composite_matches_parallel_axis_theorem(tmp_path):
    # two uniform-density boxes on a line rotated 40 deg about z; analytic COM and tensor in the file's frame
    density = 200.0
    h1, p1 = np.array([1.0, 0.5, 0.5]), np.array([-1.0, 0.0, 0.0])
    h2, p2 = np.array([0.5, 0.5, 0.25]), np.array([1.5, 0.3, 0.0])
    rot = _rot_z(40.0)
    path = _write(
        tmp_path,
        f"""
<mujoco><worldbody>
  <body name="t" euler="0 0 40"><freejoint/>
    <geom name="a" type="box" size="{h1[0]} {h1[1]} {h1[2]}" pos="{p1[0]} {p1[1]} {p1[2]}" density="{density}"/>
    <geom name="b" type="box" size="{h2[0]} {h2[1]} {h2[2]}" pos="{p2[0]} {p2[1]} {p2[2]}" density="{density}"/>
  </body>
</worldbody></mujoco>""",
    )
    arrays, info = targets.load_numpy(path)
    parts = [_primitive_mass_inertia("box", h, density) for h in (h1, h2)]
    total, com, tensor = _composite([m for m, _ in parts], [i for _, i in parts], [rot @ p1, rot @ p2], [rot, rot])
    assert info.mass == pytest.approx(total, rel=1e-6)
    np.testing.assert_allclose(arrays["inertia"], np.linalg.eigvalsh(tensor), rtol=1e-5)
    # uniform density: the mass-weighted mean of the geom centres is the origin of the body frame
    masses = np.array([m for m, _ in parts])
    np.testing.assert_allclose((masses[:, None] * arrays["geom_pos"][:2]).sum(0) / total, 0.0, atol=1e-5)
    # the transform is rigid: distances between geoms are kept
    assert np.linalg.norm(arrays["geom_pos"][0] - arrays["geom_pos"][1]) == pytest.approx(np.linalg.norm(p1 - p2))
    _check_body_frame(arrays, np.array([density, density]))


def test_user_model_with_nested_bodies_and_rotated_geoms(tmp_path):
    """A user's own MJCF: nested welded bodies, all primitive types, euler/axisangle/quat/fromto orientations."""
    path = _write(
        tmp_path,
        """
<mujoco model="my_probe">
  <compiler angle="degree"/>
  <worldbody>
    <body name="root" pos="10 0 -4" quat="0.9 0.1 0.3 -0.2"><freejoint/>
      <geom name="bus" type="box" size="0.6 0.5 0.4" density="250" rgba="0.8 0.6 0.2 1"/>
      <geom name="tank" type="sphere" size="0.3" pos="0 0 0.6" density="400"/>
      <body name="arm" pos="0.6 0 0" euler="0 30 0">
        <geom name="boom" type="capsule" fromto="0 0 0 1.5 0.2 0" size="0.05" density="800"/>
        <body name="tip" pos="1.5 0.2 0" axisangle="1 1 0 60">
          <geom name="dish" type="ellipsoid" size="0.5 0.4 0.08" density="150" euler="10 20 30"/>
          <geom name="feed" type="cylinder" size="0.04 0.3" pos="0 0 0.3" density="500"/>
        </body>
      </body>
      <body name="panel" pos="0 -0.5 0" zaxis="0 1 1">
        <geom name="wing" type="box" size="1.2 0.5 0.01" pos="0 0 -1.3" density="100" rgba="0.1 0.1 0.4 1"/>
      </body>
    </body>
  </worldbody>
</mujoco>""",
        "my_probe.xml",
    )
    model = mujoco.MjModel.from_xml_path(str(path))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    densities = _geom_densities(path, model)
    arrays, info = targets.load_numpy(path)
    assert info.name == "my_probe" and info.num_geoms == 6
    assert info.geom_types == ("box", "sphere", "capsule", "ellipsoid", "cylinder", "box")
    _check_body_frame(arrays, densities)
    # independent composite from MuJoCo's world poses of the geoms: same mass and principal moments
    parts = [
        _primitive_mass_inertia(targets.SUPPORTED_GEOM_TYPES[int(t)], s, d)
        for t, s, d in zip(model.geom_type, model.geom_size, densities)
    ]
    total, com, tensor = _composite(
        [m for m, _ in parts], [i for _, i in parts], data.geom_xpos, data.geom_xmat.reshape(-1, 3, 3)
    )
    assert info.mass == pytest.approx(total, rel=1e-4)
    np.testing.assert_allclose(arrays["inertia"], np.linalg.eigvalsh(tensor), rtol=1e-4)
    # rigid transform: pairwise geom distances and the distance of each geom to the COM are kept
    world = data.geom_xpos
    dist = lambda p: np.linalg.norm(p[:, None] - p[None], axis=-1)  # noqa: E731
    np.testing.assert_allclose(dist(arrays["geom_pos"]), dist(world), atol=1e-5)
    np.testing.assert_allclose(
        np.linalg.norm(arrays["geom_pos"], axis=1), np.linalg.norm(world - com, axis=1), atol=1e-5
    )
    # and it loads as a TargetModel / batches with catalogue targets
    model_j = targets.load(path)
    assert model_j.geom_type.shape == (6,)
    batch, infos = targets.load_many([path, "Capsule-v1"])
    assert batch.geom_type.shape[0] == 2 and infos[0].name == "my_probe"


# ------------------------------------------------------------------------------------------------ bad input
def test_unknown_name_suggests_catalogue_names():
    with pytest.raises(targets.TargetError, match=r"unknown target 'Satellite-v7'.*Did you mean.*Satellite-v0"):
        targets.load("Satellite-v7")
    with pytest.raises(targets.TargetError, match="not in the catalogue"):
        targets.load("Blimp")


def test_nonexistent_file(tmp_path):
    with pytest.raises(targets.TargetError, match="does not exist"):
        targets.load(tmp_path / "missing.xml")
    with pytest.raises(targets.TargetError, match="does not exist"):
        targets.load_many(["Capsule-v0", str(tmp_path / "nope" / "x.xml")])


BAD_MODELS = {
    # not well-formed XML
    "unclosed_tag": (
        '<mujoco><worldbody><body><geom type="box" size="1 1 1"></body></worldbody></mujoco>',
        "cannot parse MJCF",
    ),
    "not_xml": ("this is not xml at all", "cannot parse MJCF"),
    # well-formed, but not valid MJCF
    "unknown_element": ("<mujoco><worldbody><body><banana/></body></worldbody></mujoco>", "unrecognized element"),
    "bad_geom_type": (
        '<mujoco><worldbody><body><freejoint/><geom type="dodecahedron" size="1"/></body></worldbody></mujoco>',
        "invalid keyword",
    ),
    "not_mujoco": ("<spaceship><part/></spaceship>", "Unrecognized XML model type"),
    "massless_body": ("<mujoco><worldbody><body><freejoint/></body></worldbody></mujoco>", "cannot parse MJCF"),
    # unsupported geom types
    "inline_mesh": (
        '<mujoco><asset><mesh name="m" vertex="0 0 0 1 0 0 0 1 0 0 0 1"/></asset><worldbody>'
        '<body><freejoint/><geom type="mesh" mesh="m"/></body></worldbody></mujoco>',
        r"unsupported geom type\(s\) \['mesh'\]",
    ),
    "hfield": (
        '<mujoco><asset><hfield name="h" nrow="3" ncol="3" size="1 1 0.1 0.1"/></asset><worldbody>'
        '<body><freejoint/><geom type="box" size="0.1 0.1 0.1"/><geom type="hfield" hfield="h"/></body>'
        "</worldbody></mujoco>",
        r"unsupported geom type\(s\) \['hfield'\]",
    ),
    "plane_in_world": (
        '<mujoco><worldbody><geom type="plane" size="5 5 0.1"/><body><freejoint/>'
        '<geom type="box" size="0.1 0.1 0.1"/></body></worldbody></mujoco>',
        r"unsupported geom type\(s\) \['plane'\]",
    ),
    "plane_in_body": (
        '<mujoco><worldbody><body><freejoint/><geom type="box" size="0.1 0.1 0.1"/>'
        '<geom type="plane" size="1 1 0.1"/></body></worldbody></mujoco>',
        "plane",
    ),
    # mass problems
    "geoms_in_worldbody": (
        '<mujoco><worldbody><geom type="box" size="1 1 1"/><geom type="sphere" size="1" '
        'pos="2 0 0"/></worldbody></mujoco>',
        "zero mass.*<body>",
    ),
    "mixed_world_geom": (
        '<mujoco><worldbody><geom name="rock" type="sphere" size="1" pos="5 0 0"/><body><freejoint/>'
        '<geom type="box" size="1 1 1"/></body></worldbody></mujoco>',
        "rock.*worldbody",
    ),
    "no_geoms": ("<mujoco><worldbody/></mujoco>", "no geoms"),
}


@pytest.mark.parametrize("case", sorted(BAD_MODELS))
def test_bad_models_raise_target_error(tmp_path, case):
    text, pattern = BAD_MODELS[case]
    path = _write(tmp_path, text, f"{case}.xml")
    with pytest.raises(targets.TargetError, match=pattern) as err:
        targets.load(path)
    assert str(path) in str(err.value)  # the message names the offending file


def test_catalogue_table_with_user_file(tmp_path):
    path = _write(
        tmp_path,
        '<mujoco><worldbody><body><freejoint/><geom type="sphere" size="0.5"/></body></worldbody></mujoco>',
        "ball.xml",
    )
    rows = catalogue_table(["Rocket-v2", path])
    assert rows[0]["split"] == "test" and rows[0]["class"] == "rocket"
    assert rows[1]["name"] == "ball" and rows[1]["class"] == "custom" and rows[1]["split"] == "custom"
    assert rows[1]["mass"] == pytest.approx(1000 * 4 / 3 * np.pi * 0.125, rel=1e-5)
    assert rows[1]["bound_radius"] == pytest.approx(0.5)


# ------------------------------------------------------------------------------------------------ NAME@Rm
def _reach(arrays) -> float:
    """How far the real geoms reach from the centre of mass (m), from the geometry, not the stored radius."""
    reach = np.linalg.norm(arrays["geom_pos"], axis=1) + arrays["geom_rbound"]
    return float(reach[arrays["geom_mask"]].max())


def test_sized_spec_scales_every_length_and_nothing_else():
    base, _ = targets.load_numpy("Satellite-v2")
    for radius in (0.3, 12.0):
        sized, info = targets.load_numpy(f"Satellite-v2@{radius:g}m")
        factor = radius / float(base["bound_radius"])
        assert info.name == f"Satellite-v2@{radius:g}m"
        for key in ("geom_size", "geom_pos", "geom_rbound"):
            np.testing.assert_allclose(sized[key], base[key] * factor, rtol=1e-6, atol=1e-7)
        for key in ("geom_type", "geom_mat", "geom_rgb", "geom_mask", "inertia", "mass"):
            np.testing.assert_array_equal(sized[key], base[key])
        assert _reach(sized) == pytest.approx(radius, rel=1e-5)  # the geoms themselves reach that far


def test_sized_spec_works_on_files_and_in_target_lists(tmp_path):
    path = tmp_path / "ball.xml"
    path.write_text(
        '<mujoco><worldbody><body><freejoint/><geom type="sphere" size="0.7" density="100"/></body>'
        "</worldbody></mujoco>"
    )
    arrays, info = targets.load_numpy(f"{path}@2m")
    assert info.name == "ball@2m" and float(arrays["geom_size"][0, 0]) == pytest.approx(2.0)
    from ramavt_jax.evaluation import rollouts

    assert rollouts.resolve_targets(f"Capsule-v0@0.4m,{path}@3m") == ("Capsule-v0@0.4m", f"{path}@3m")
    rows = catalogue_table(["Capsule-v0@0.4m"])
    assert rows[0]["class"] == "capsule" and rows[0]["split"] == "custom" and rows[0]["name"] == "Capsule-v0@0.4m"
    # one size, one spelling (and so one set of episodes); a file whose own name looks like a suffix is a file
    assert rollouts.resolve_targets("Capsule-v0@.40m,Capsule-v0@0.4m") == ("Capsule-v0@0.4m",)
    odd = tmp_path / "probe@2m"
    odd.write_text(path.read_text())
    assert targets.load_numpy(str(odd))[1].bound_radius == pytest.approx(0.7)


def test_a_resized_target_gets_its_size_stand_off_in_the_env():
    from ramavt_jax import env

    tracking_env = env.TrackingEnv(env.EnvConfig(targets=("Satellite-v2@0.3m", "Satellite-v2@12m", "Satellite-v2")))
    params = tracking_env.default_params()
    k = [float(env.standoff_scale(targets.select(params.catalogue, i), params)) for i in range(3)]
    assert k == pytest.approx([0.6, 4.8, 1.0])


@pytest.mark.parametrize(
    "spec",
    [
        "Satellite-v2@0m",
        "Satellite-v2@-1m",
        "Satellite-v2@bigm",
        "Satellite-v2@nanm",
        "Satellite-v2@1e-9m",
        "Satellite-v2@1m@2m",
        "Satellite-v9@1m",
    ],
)
def test_bad_sized_specs_raise_one_line_target_errors(spec):
    with pytest.raises(targets.TargetError) as err:
        targets.load_numpy(spec)
    assert "\n" not in str(err.value) and spec.split("@")[0] in str(err.value)


def test_val_sizes_split_resizes_validation_shapes_outside_the_catalogue_sizes():
    resized = targets.split("val-sizes")
    assert resized == targets.VAL_SIZE_TARGETS and len(resized) == 6
    bases = [specs.sized_spec(s)[0] for s in resized]
    assert set(bases) <= set(targets.VAL_TARGETS)  # shapes of the validation split only: never trained, never test
    radii = [_reach(targets.load_numpy(s)[0]) for s in resized]
    catalogue = [targets.load_numpy(n)[1].bound_radius for n in targets.ALL_TARGETS]
    assert all(r < min(catalogue) or r > max(catalogue) for r in radii)
    assert sum(r < 0.5 for r in radii) == 3 and max(radii) == pytest.approx(12.0)
