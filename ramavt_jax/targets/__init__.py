"""Target catalogue: MJCF models of space objects loaded into fixed-size JAX arrays.

A target is a rigid body made of MuJoCo primitives (sphere, capsule, ellipsoid, cylinder, box). MuJoCo parses the
file and computes masses, inertias and geom frames; we express every geom in the target's *principal inertia frame*
(origin at the centre of mass, axes along the principal axes), so the attitude dynamics can use a diagonal inertia
and the renderer only needs the pose of that frame.

Targets of different sizes batch together because every array is padded to the same number of geoms
(`geom_mask` marks the real ones).
"""

from __future__ import annotations

import dataclasses
import difflib
import os
from collections.abc import Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from ramavt_jax.targets.specs import TargetError, sized_spec

# MuJoCo's own geom type codes (mujoco.mjtGeom); kept as plain ints so this module imports without mujoco.
SPHERE, CAPSULE, ELLIPSOID, CYLINDER, BOX = 2, 3, 4, 5, 6
SUPPORTED_GEOM_TYPES = {SPHERE: "sphere", CAPSULE: "capsule", ELLIPSOID: "ellipsoid", CYLINDER: "cylinder", BOX: "box"}

MODEL_DIR = Path(__file__).parent / "models"

# name -> class; the order defines the catalogue index.
CATALOGUE: dict[str, str] = {
    **{f"Asteroid-v{i}": "asteroid" for i in range(6)},
    **{f"Capsule-v{i}": "capsule" for i in range(3)},
    **{f"Rocket-v{i}": "rocket" for i in range(3)},
    **{f"Satellite-v{i}": "satellite" for i in range(3)},
    **{f"Station-v{i}": "station" for i in range(3)},
    # validation models, appended so that the 18 original models keep their catalogue indices
    **{f"Asteroid-val{i}": "asteroid" for i in range(2)},
    **{f"{cls.capitalize()}-val0": cls for cls in ("capsule", "rocket", "satellite", "station")},
}
# Held-out split as in the original benchmark: asteroids v4, v5 and the v2 of every other class.
TEST_TARGETS: tuple[str, ...] = ("Asteroid-v4", "Asteroid-v5", "Capsule-v2", "Rocket-v2", "Satellite-v2", "Station-v2")
# Validation split (models named *-val*, in neither of the others): for choosing among runs and settings, so that the
# test split is only looked at for the final numbers.
VAL_TARGETS: tuple[str, ...] = tuple(n for n in CATALOGUE if "-val" in n)
TRAIN_TARGETS: tuple[str, ...] = tuple(n for n in CATALOGUE if n not in TEST_TARGETS and n not in VAL_TARGETS)
ALL_TARGETS: tuple[str, ...] = tuple(CATALOGUE)
# Size-validation split: the validation models resized (``NAME@Rm``, see `sized_spec`) to bounding radii outside
# the catalogue's 0.56-2.4 m, three small and three large, so that choices about other sizes (stand-off rule, size
# randomisation) can be made without looking at the user models of examples/targets/.
VAL_SIZE_TARGETS: tuple[str, ...] = (
    "Satellite-val0@0.3m",
    "Capsule-val0@0.35m",
    "Asteroid-val0@0.45m",
    "Rocket-val0@4m",
    "Asteroid-val1@6m",
    "Station-val0@12m",
)

# Shape grounds: procedurally generated models for evaluation only (scripts/procedural_targets.py --ground), six of
# each kind (satellite, stack, module chain, rock), bounding radii log-uniform in 0.3-12 m, each geom's density spread
# 3x either way. 'val-shapes' is for choosing; 'test-shapes' (another seed) is held out like the test split. No
# training split draws from their seeds.
SHAPES_DIR = MODEL_DIR / "shapes"


def _generated(prefix: str) -> tuple[str, ...]:
    """Names of the generated models ``<prefix>-<kind><index>`` in SHAPES_DIR, in index order."""
    return tuple(sorted((p.stem for p in SHAPES_DIR.glob(f"{prefix}-*.xml")), key=lambda stem: int(stem[-3:])))


VAL_SHAPE_TARGETS: tuple[str, ...] = _generated("Gen1001")
TEST_SHAPE_TARGETS: tuple[str, ...] = _generated("Gen2002")


@struct.dataclass
class TargetModel:
    """One target (or a batch, with leading axes) as padded primitive arrays, in its principal inertia frame.

    Shapes for a single target with G padded geoms:
      geom_type   [G] int32     MuJoCo geom type code (2 sphere, 3 capsule, 4 ellipsoid, 5 cylinder, 6 box)
      geom_size   [G, 3] f32    MuJoCo size convention (radius / half-lengths / half-extents)
      geom_pos    [G, 3] f32    geom centre in the body frame
      geom_mat    [G, 3, 3] f32 body_from_geom rotation (columns are the geom axes in the body frame)
      geom_rgb    [G, 3] f32    albedo in [0, 1]
      geom_rbound [G] f32       radius of a sphere about geom_pos that encloses the geom
      geom_mask   [G] bool      True for real geoms, False for padding
      bound_radius [] f32       radius of a sphere about the centre of mass that encloses the whole target
      inertia     [3] f32       principal moments of inertia (kg m^2), matching the body axes
      mass        [] f32        total mass (kg)
    """

    geom_type: jax.Array
    geom_size: jax.Array
    geom_pos: jax.Array
    geom_mat: jax.Array
    geom_rgb: jax.Array
    geom_rbound: jax.Array
    geom_mask: jax.Array
    bound_radius: jax.Array
    inertia: jax.Array
    mass: jax.Array

    @property
    def num_geoms(self) -> int:
        return self.geom_type.shape[-1]


@dataclasses.dataclass(frozen=True)
class TargetInfo:
    """Host-side description of a loaded target (for listings and reports)."""

    name: str
    path: str
    num_geoms: int
    bound_radius: float
    mass: float
    inertia: tuple[float, float, float]
    geom_types: tuple[str, ...]


_LENGTH_FIELDS = ("geom_size", "geom_pos", "geom_rbound", "bound_radius")  # what a uniform resize multiplies


def resolve(name_or_path: str | os.PathLike) -> Path:
    """Catalogue name (e.g. ``"Satellite-v1"``) or a path to an MJCF file, either with an optional ``@<radius>m``
    size suffix (`sized_spec`) -> path of the file (at its own size: `load_numpy` applies the suffix)."""
    text, _ = sized_spec(name_or_path)
    if text in CATALOGUE:
        path = MODEL_DIR / f"{text}.xml"
        if not path.is_file():
            raise TargetError(f"catalogue file {path} for target {text!r} is missing from the installation")
        return path
    if text in VAL_SHAPE_TARGETS or text in TEST_SHAPE_TARGETS:
        return SHAPES_DIR / f"{text}.xml"
    path = Path(text).expanduser()
    if path.is_dir():
        raise TargetError(f"target {text!r} is a folder; give an MJCF file (.xml) or a catalogue name")
    if text.lower().endswith(".xml") or os.sep in text:
        if not path.is_file():
            raise TargetError(f"target file {path} does not exist")
        return path
    close = difflib.get_close_matches(text, list(CATALOGUE), n=3, cutoff=0.6)
    hint = f" Did you mean {' or '.join(close)}?" if close else ""
    raise TargetError(
        f"unknown target {text!r}: not in the catalogue ({', '.join(CATALOGUE)}) and not an .xml file.{hint}"
    )


def _load_mj_model(path: Path):
    import mujoco

    try:
        return mujoco.MjModel.from_xml_path(str(path))
    except Exception as exc:  # mujoco raises ValueError with the parser message
        raise TargetError(f"cannot parse MJCF file {path}: {exc}") from exc


def load_numpy(name_or_path: str | os.PathLike, pad_to: int | None = None) -> tuple[dict[str, np.ndarray], TargetInfo]:
    """Parse one target with MuJoCo; return padded numpy arrays (TargetModel fields) and a TargetInfo.

    A ``@<radius>m`` suffix (``"Satellite-v2@0.3m"``) resizes the model so that its bounding radius is that many
    metres: every length is multiplied by one factor; mass and inertia are kept, as in `scaled` (torque-free rotation
    does not change under a uniform scale of the inertia). All geoms of the model belong to the target (bodies
    without joints are welded together; a free joint is fine).
    Raises TargetError for unknown names, malformed files, unsupported geom types or a massless model.
    """
    import mujoco

    base, radius = sized_spec(name_or_path)
    path = resolve(base)
    model = _load_mj_model(path)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)  # world poses at qpos0

    if model.ngeom == 0:
        raise TargetError(f"{path}: the model has no geoms")
    bad = sorted({int(t) for t in model.geom_type if int(t) not in SUPPORTED_GEOM_TYPES})
    if bad:
        names = [mujoco.mjtGeom(t).name.replace("mjGEOM_", "").lower() for t in bad]
        raise TargetError(
            f"{path}: unsupported geom type(s) {names}; supported are {sorted(SUPPORTED_GEOM_TYPES.values())}"
        )

    # Composite mass properties of all bodies, about the common centre of mass.
    in_world = [
        mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or f"#{g}"
        for g in range(model.ngeom)
        if model.geom_bodyid[g] == 0
    ]
    masses = np.asarray(model.body_mass, dtype=np.float64)
    total_mass = float(masses.sum())
    if not total_mass > 0.0 and in_world:
        raise TargetError(f"{path}: the model has zero mass; put the geoms in a <body> (not <worldbody> directly)")
    if not total_mass > 0.0:  # every geom in a body, and all weightless
        raise TargetError(
            f'{path}: the model has zero mass (its geoms in <body> elements weigh nothing: density="0" or '
            f'mass="0"); give the geoms a density or a mass'
        )
    if in_world:
        raise TargetError(
            f"{path}: geom(s) {in_world} are placed directly in <worldbody>; put every geom of the target in a <body>"
        )
    com = (masses[:, None] * data.xipos).sum(0) / total_mass
    inertia_world = np.zeros((3, 3))
    for b in range(model.nbody):
        if masses[b] <= 0:
            continue
        rot = data.ximat[b].reshape(3, 3)
        inertia_world += rot @ np.diag(model.body_inertia[b]) @ rot.T
        d = data.xipos[b] - com
        inertia_world += masses[b] * (d @ d * np.eye(3) - np.outer(d, d))
    moments, axes = np.linalg.eigh(inertia_world)
    if np.linalg.det(axes) < 0:  # keep a right-handed body frame
        axes[:, 2] *= -1.0
    world_from_body = axes  # columns are the principal axes in world coordinates

    geom_pos = (data.geom_xpos - com) @ world_from_body  # [G, 3] body coordinates
    geom_mat = np.einsum("ji,gjk->gik", world_from_body, data.geom_xmat.reshape(-1, 3, 3))  # body_from_geom
    rgba = np.array(model.geom_rgba, dtype=np.float64)
    has_mat = model.geom_matid >= 0
    if has_mat.any():
        rgba[has_mat] = model.mat_rgba[model.geom_matid[has_mat]]
    rbound = np.array(model.geom_rbound, dtype=np.float64)
    bound_radius = float(np.max(np.linalg.norm(geom_pos, axis=1) + rbound))

    n = model.ngeom
    if pad_to is not None and pad_to < n:
        raise TargetError(f"{path}: has {n} geoms, more than the padding size {pad_to}")
    arrays = dict(
        geom_type=np.asarray(model.geom_type, np.int32),
        geom_size=np.asarray(model.geom_size, np.float32),
        geom_pos=geom_pos.astype(np.float32),
        geom_mat=geom_mat.astype(np.float32),
        geom_rgb=rgba[:, :3].astype(np.float32),
        geom_rbound=rbound.astype(np.float32),
        geom_mask=np.ones(n, bool),
        bound_radius=np.float32(bound_radius),
        inertia=moments.astype(np.float32),
        mass=np.float32(total_mass),
    )
    if radius is not None:
        factor = radius / bound_radius
        arrays.update({k: (arrays[k] * factor).astype(np.float32) for k in _LENGTH_FIELDS})
        arrays["bound_radius"], bound_radius = np.float32(radius), radius  # exact, not the float32 product
    arrays = _pad_geoms(arrays, n if pad_to is None else pad_to)
    type_names = tuple(SUPPORTED_GEOM_TYPES[int(t)] for t in model.geom_type)
    name = base if base in CATALOGUE else path.stem
    name = name if radius is None else f"{name}@{radius:g}m"
    info = TargetInfo(name, str(path), n, bound_radius, total_mass, tuple(float(m) for m in moments), type_names)
    return arrays, info


_GEOM_FIELDS = ("geom_type", "geom_size", "geom_pos", "geom_mat", "geom_rgb", "geom_rbound", "geom_mask")


def _pad_geoms(arrays: dict[str, np.ndarray], pad: int) -> dict[str, np.ndarray]:
    """Per-geom arrays [G, ...] padded to [pad, ...]: padding geoms are masked off, with zero size and an
    identity rotation."""
    out = dict(arrays)
    for k in _GEOM_FIELDS:
        a = arrays[k]
        if k == "geom_mat":
            padded = np.broadcast_to(np.eye(3, dtype=a.dtype), (pad, 3, 3)).copy()
        else:
            padded = np.zeros((pad,) + a.shape[1:], a.dtype)
        padded[: a.shape[0]] = a
        out[k] = padded
    return out


def load(name_or_path: str | os.PathLike, pad_to: int | None = None) -> TargetModel:
    """Load one target (catalogue name or MJCF path) as a TargetModel with arrays of shape [G, ...]."""
    arrays, _ = load_numpy(name_or_path, pad_to)
    return TargetModel(**{k: jnp.asarray(v) for k, v in arrays.items()})


def load_many(
    names_or_paths: Sequence[str | os.PathLike], pad_to: int | None = None
) -> tuple[TargetModel, list[TargetInfo]]:
    """Load several targets padded to a common geom count; arrays get a leading axis [N, G, ...]."""
    if len(names_or_paths) == 0:
        raise TargetError("no targets given")
    loaded = [load_numpy(t) for t in names_or_paths]
    width = max(info.num_geoms for _, info in loaded)
    if pad_to is not None:
        if pad_to < width:
            raise TargetError(f"pad_to={pad_to} is smaller than the largest target ({width} geoms)")
        width = pad_to
    stacked = [_pad_geoms(arrays, width) for arrays, _ in loaded]  # each MJCF is parsed once
    batch = {k: jnp.asarray(np.stack([s[k] for s in stacked])) for k in stacked[0]}
    return TargetModel(**batch), [info for _, info in loaded]


def select(catalogue: TargetModel, index: jax.Array) -> TargetModel:
    """Pick target `index` from a stacked [N, ...] TargetModel (jit-able; index may be traced)."""
    return jax.tree.map(lambda a: a[index], catalogue)


def scaled(target: TargetModel, factor: jax.Array) -> TargetModel:
    """The same target with every length multiplied by `factor` (a scalar, may be traced); inertia and mass are
    left as they are (used for rendering at a scaled stand-off and for size randomisation, where the torque-free
    rotation does not depend on a uniform scale of the inertia)."""
    return target.replace(**{k: getattr(target, k) * factor for k in _LENGTH_FIELDS})


def geom_bound_radius(geom_type: jax.Array, geom_size: jax.Array) -> jax.Array:
    """[..., G] Radius of the smallest sphere about each geom's centre that encloses it, as MuJoCo's geom_rbound:
    sphere r, capsule r + h, ellipsoid max(a, b, c), cylinder sqrt(r^2 + h^2), box |half-extents|."""
    r, h = geom_size[..., 0], geom_size[..., 1]
    return jnp.select(
        [geom_type == SPHERE, geom_type == CAPSULE, geom_type == ELLIPSOID, geom_type == CYLINDER],
        [r, r + h, jnp.max(geom_size, axis=-1), jnp.hypot(r, h)],
        jnp.linalg.norm(geom_size, axis=-1),
    )


def stretched(target: TargetModel, factors: jax.Array) -> TargetModel:
    """The same target stretched along its principal axes by `factors` [3] (one target; vmap for a batch; may be
    traced): a point p of the body becomes diag(factors) p. Mass is kept, and the inertia is the stretched body's
    (its principal axes stay the body axes): with the second moments M_i = (I_j + I_k - I_i) / 2, each M_i is
    multiplied by factors_i^2.

    Geoms stay MuJoCo primitives. A sphere becomes an ellipsoid along the body axes, exact at any angle. Boxes and
    ellipsoids are stretched along their own axes by the length of diag(factors) applied to each axis: exact when
    their axes are body axes (in any order). A cylinder's radius takes the geometric mean of its two radial factors
    (exact when they are equal); a capsule's too, with its half-length set so that its tips land where the stretch
    puts them (its caps stay hemispheres, so it is exact only for a uniform stretch). A geom at another angle keeps
    its kind and orientation: an approximation (a stretched box at an angle would be a parallelepiped).
    geom_rbound and bound_radius are recomputed from the stretched geoms, so they bound what is rendered."""
    factors = jnp.asarray(factors, jnp.float32)
    along_axes = jnp.linalg.norm(factors[:, None] * target.geom_mat, axis=-2)  # [G, 3] per geom axis
    radial = jnp.sqrt(along_axes[:, 0] * along_axes[:, 1])
    is_sphere, is_capsule = target.geom_type == SPHERE, target.geom_type == CAPSULE
    round_ = (target.geom_type == CYLINDER) | is_capsule
    size_factors = jnp.where(round_[:, None], jnp.stack([radial, along_axes[:, 2], radial], -1), along_axes)
    size_factors = jnp.where(is_sphere[:, None], factors, size_factors)
    geom_size = jnp.where(is_sphere[:, None], target.geom_size[:, :1], target.geom_size) * size_factors
    radius, half_length = target.geom_size[:, 0], target.geom_size[:, 1]
    tip = jnp.maximum((half_length + radius) * along_axes[:, 2] - radius * radial, 0.0)  # a capsule's new half-length
    geom_size = geom_size.at[:, 1].set(jnp.where(is_capsule, tip, geom_size[:, 1]))
    geom_mat = jnp.where(is_sphere[:, None, None], jnp.eye(3, dtype=target.geom_mat.dtype), target.geom_mat)
    geom_type = jnp.where(is_sphere, ELLIPSOID, target.geom_type)
    geom_pos = target.geom_pos * factors
    geom_rbound = jnp.where(target.geom_mask, geom_bound_radius(geom_type, geom_size), target.geom_rbound)
    reach = jnp.where(target.geom_mask, jnp.linalg.norm(geom_pos, axis=-1) + geom_rbound, 0.0)
    second_moments = (jnp.sum(target.inertia) / 2 - target.inertia) * factors**2
    inertia = jnp.sum(second_moments) - second_moments
    return target.replace(
        geom_type=geom_type,
        geom_size=geom_size,
        geom_pos=geom_pos,
        geom_mat=geom_mat,
        geom_rbound=geom_rbound,
        bound_radius=jnp.max(reach),
        inertia=inertia,
    )


def shifted(target: TargetModel, offset: jax.Array) -> TargetModel:
    """The same target with its geometry moved by ``offset`` [3] (body frame, m; one target; may be traced) while its
    centre of mass, the origin it spins about, stays put: every geom_pos + offset. Mass and inertia are kept (a
    modelling shortcut: moved mass would change the inertia); bound_radius is recomputed about the origin, so it
    still encloses the geoms."""
    geom_pos = target.geom_pos + jnp.asarray(offset, target.geom_pos.dtype)
    reach = jnp.where(target.geom_mask, jnp.linalg.norm(geom_pos, axis=-1) + target.geom_rbound, 0.0)
    return target.replace(geom_pos=geom_pos, bound_radius=jnp.max(reach))


SPLITS: tuple[str, ...] = ("train", "val", "test", "all", "val-sizes", "val-shapes", "test-shapes")


def split(name: str) -> tuple[str, ...]:
    """'train', 'val', 'test', 'all' -> catalogue names; 'val-sizes' -> the resized validation models; 'val-shapes',
    'test-shapes' -> the shape grounds' generated models."""
    table = {
        "train": TRAIN_TARGETS,
        "val": VAL_TARGETS,
        "test": TEST_TARGETS,
        "all": ALL_TARGETS,
        "val-sizes": VAL_SIZE_TARGETS,
        "val-shapes": VAL_SHAPE_TARGETS,
        "test-shapes": TEST_SHAPE_TARGETS,
    }
    if name not in table:
        raise TargetError(f"unknown split {name!r}; choose one of {sorted(table)}")
    return table[name]
