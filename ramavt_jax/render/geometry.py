"""Per-geom setup of a batch render, on [B, G] arrays with explicit multiply-adds (no tiny matmuls): each geom's
frame in the camera, its unit frame and the ray-casting features (`intersect`'s order), its shading features, and a
conservative pixel box from its bounding sphere and oriented bounding box."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ramavt_jax.render import intersect
from ramavt_jax.render.camera import CameraConfig
from ramavt_jax.targets import BOX, CAPSULE, CYLINDER, SPHERE, TargetModel

BIG = 1e30  # a capsule feature of non-capsules: no half-length limit


def mat3(a):
    """[..., 3, 3] array -> nested lists a[i][j] of [...] arrays."""
    return [[a[..., i, j] for j in range(3)] for i in range(3)]


def geom_frames(targets: TargetModel, positions, rotations):
    """Camera-frame geom centres p[i] and camera_from_geom rotations r[i][j], each [B, G] (explicit FMAs)."""
    rb = mat3(rotations[:, None])  # [B, 1] each
    gm = mat3(targets.geom_mat)  # [B, G]
    gp = [targets.geom_pos[..., i] for i in range(3)]
    r = [[rb[i][0] * gm[0][k] + rb[i][1] * gm[1][k] + rb[i][2] * gm[2][k] for k in range(3)] for i in range(3)]
    p = [rb[i][0] * gp[0] + rb[i][1] * gp[1] + rb[i][2] * gp[2] + positions[:, None, i] for i in range(3)]
    return p, r


def shape(geom_type, size):
    """Per geom: inverse unit-frame scale, quadric q, slab half-extents e (3 lists of [B, G]) and capsule half-length."""
    r, h = size[..., 0], size[..., 1]
    sph = (geom_type == SPHERE) | (geom_type == CAPSULE)
    cyl = geom_type == CYLINDER
    box = geom_type == BOX
    scale = [
        jnp.where(sph, r, size[..., 0]),
        jnp.where(sph | cyl, r, size[..., 1]),
        jnp.where(sph, r, jnp.where(cyl, h, size[..., 2])),
    ]
    inv_s = [1.0 / jnp.where(s > 0, s, 1.0) for s in scale]  # padding geoms have zero size
    round_ = (geom_type == CYLINDER) | (geom_type == CAPSULE)
    one = jnp.ones_like(r)
    q = [jnp.where(box, 0.25, one), jnp.where(box, 0.25, one), jnp.where(box, 0.25, jnp.where(round_, 0.0, one))]
    hl = jnp.where(geom_type == CAPSULE, h / jnp.maximum(r, 1e-30), 0.0)
    e = [jnp.where(box, 1.0, 2.0 * one), jnp.where(box, 1.0, 2.0 * one), jnp.where(box | cyl, 1.0, 2.0 * one) + hl]
    return inv_s, q, e, hl


def unit_frames(targets: TargetModel, p, r):
    """unit_from_camera m[i][j] and the camera origin in the unit frame o[i] ([B, G] each), plus shape data."""
    inv_s, q, e, hl = shape(targets.geom_type, targets.geom_size)
    m = [[inv_s[i] * r[j][i] for j in range(3)] for i in range(3)]
    o = [-(m[i][0] * p[0] + m[i][1] * p[1] + m[i][2] * p[2]) for i in range(3)]
    return m, o, q, e, hl


def cast_table(targets: TargetModel, m, o, q, e, hl) -> jax.Array:
    """Features of `intersect.cast` (rows in its order) as [B*G, NUM_FEATURES]."""
    mask = targets.geom_mask
    c = jnp.where(mask, q[0] * o[0] * o[0] + q[1] * o[1] * o[1] + q[2] * o[2] * o[2] - 1.0, jnp.inf)
    cap_hl = jnp.where(targets.geom_type == CAPSULE, hl, BIG)
    lo = [jnp.where(mask, -e[i] - o[i], jnp.inf) for i in range(3)]
    hi = [jnp.where(mask, e[i] - o[i], jnp.inf) for i in range(3)]
    rows = (
        [m[i][j] for i in range(3) for j in range(3)]
        + [q[i] * o[i] for i in range(3)]
        + [c]
        + q
        + lo
        + hi
        + o
        + [cap_hl, q[1] * q[2], q[0] * q[2], q[0] * q[1]]
    )
    assert len(rows) == intersect.NUM_FEATURES
    return jnp.stack(rows, axis=-1).reshape(-1, intersect.NUM_FEATURES).astype(jnp.float32)


def shade_table(targets: TargetModel, m, o, q, e, hl) -> jax.Array:
    """Features of `intersect.surface_normal` plus the albedo as [B*G, NUM_SHADE_FEATURES]."""
    cap = targets.geom_type == CAPSULE
    qn = [jnp.where(cap, 1.0, q[i]) for i in range(3)]
    rgb = [targets.geom_rgb[..., i] for i in range(3)]
    rows = [m[i][j] for i in range(3) for j in range(3)] + o + qn + e + [hl] + rgb
    assert len(rows) == intersect.NUM_SHADE_FEATURES
    return jnp.stack(rows, axis=-1).reshape(-1, intersect.NUM_SHADE_FEATURES).astype(jnp.float32)


def half_extents(targets: TargetModel):
    """Half extents (3 lists of [B, G]) of each geom's bounding box in its own frame."""
    t = targets.geom_type
    s = [targets.geom_size[..., i] for i in range(3)]
    r, h = s[0], s[1]
    radial = (t == SPHERE) | (t == CYLINDER) | (t == CAPSULE)
    ex = jnp.where(radial, r, s[0])
    ey = jnp.where(radial, r, s[1])
    ez = jnp.where(t == SPHERE, r, jnp.where(t == CYLINDER, h, jnp.where(t == CAPSULE, h + r, s[2])))
    return [ex, ey, ez]


def screen_boxes(targets: TargetModel, p, r, cam: CameraConfig):
    """Conservative pixel boxes (umin, umax, vmin, vmax) [B, G] of every geom and whether it can be seen [B, G].

    The projection of the geom's bounding sphere, intersected, when all 8 corners of the geom's oriented bounding box
    lie in front of the camera, with the projection of those corners (exact for boxes; thin panels have huge
    bounding spheres but small boxes). One pixel of margin on each side.
    """
    f, c = cam.focal(), cam.centre()
    radius = targets.geom_rbound
    cx, cy, cz = p
    den = cz * cz - radius * radius
    in_front = cz > radius * 1.001 + 1e-6
    inv_den = 1.0 / jnp.where(in_front, den, 1.0)

    def extent(a):
        root = jnp.sqrt(jnp.maximum(a * a + den, 0.0)) * radius
        lo = (a * cz - root) * inv_den
        hi = (a * cz + root) * inv_den
        return jnp.where(in_front, f * lo + c - 1.0, -jnp.inf), jnp.where(in_front, f * hi + c + 1.0, jnp.inf)

    umin, umax = extent(cx)
    vmin, vmax = extent(cy)
    visible = targets.geom_mask & (cz + radius > cam.near) & (cz - radius < cam.far)
    # The 8 corners as one [8, B, G] array per coordinate, reduced over the corner axis. Not chains of minimum over 8
    # arrays: XLA fuses such an elementwise chain into each of its consumers (the tile ranges, the item counts of every
    # geom class), recomputing all corners in each; a reduction is computed once.
    ext = half_extents(targets)
    signs = np.array([(sx, sy, sz) for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], np.float32)
    off = [signs[:, k, None, None] * ext[k][None] for k in range(3)]  # [8, B, G]
    corner = [p[i][None] + r[i][0][None] * off[0] + r[i][1][None] * off[1] + r[i][2][None] * off[2] for i in range(3)]
    inv_z = 1.0 / jnp.where(corner[2] > 1e-3, corner[2], 1.0)
    us, vs = f * corner[0] * inv_z + c, f * corner[1] * inv_z + c
    front = jnp.min(corner[2], axis=0) > 1e-3
    umin = jnp.where(front, jnp.maximum(umin, jnp.min(us, axis=0) - 1.0), umin)
    umax = jnp.where(front, jnp.minimum(umax, jnp.max(us, axis=0) + 1.0), umax)
    vmin = jnp.where(front, jnp.maximum(vmin, jnp.min(vs, axis=0) - 1.0), vmin)
    vmax = jnp.where(front, jnp.minimum(vmax, jnp.max(vs, axis=0) + 1.0), vmax)
    return umin, umax, vmin, vmax, visible


def tile_range(lo, hi, tile: int, nt: int):
    """First tile index and tile count [B, G] int32 of the tiles whose pixels [k*tile, k*tile+tile-1] meet [lo, hi]."""
    lo = jnp.clip(lo, -2.0 * tile, (nt + 2.0) * tile)
    hi = jnp.clip(hi, -2.0 * tile, (nt + 2.0) * tile)
    first = jnp.maximum(jnp.ceil((lo - (tile - 1)) / tile), 0.0)
    last = jnp.minimum(jnp.floor(hi / tile), nt - 1.0)
    return first.astype(jnp.int32), jnp.maximum(last - first + 1.0, 0.0).astype(jnp.int32)


def may_be_seen(targets: TargetModel, positions: jax.Array, cam: CameraConfig) -> jax.Array:
    """[] bool: some env's target reaches between the near and the far plane (conservative: the sphere about the
    centre of mass that holds every geom's bounding sphere). False, e.g., for a batch whose targets were all moved
    behind the camera (the env's culled second render)."""
    reach = jnp.max(
        jnp.where(targets.geom_mask, jnp.linalg.norm(targets.geom_pos, axis=-1) + targets.geom_rbound, 0.0), axis=-1
    )  # [B]
    z = positions[:, 2]
    return jnp.any((z + reach > cam.near) & (z - reach < cam.far))
