"""Ray casting against MuJoCo primitives with one branch-free kernel for every geom type.

Every geom is handled in its *unit frame* (geom frame scaled per axis by 1 / size) as the intersection of one
quadric ``sum_k q_k x_k^2 <= 1`` with three slabs ``|x_k| <= e_k``:

  type        unit-frame scale      quadric q             slabs e
  sphere      1/r                   (1, 1, 1)             (2, 2, 2)  (inactive)
  ellipsoid   1/(a, b, c)           (1, 1, 1)             (2, 2, 2)  (inactive)
  cylinder    (1/r, 1/r, 1/h)       (1, 1, 0)             (2, 2, 1)  (caps)
  box         1/(a, b, c)           (1/4, 1/4, 1/4)       (1, 1, 1)  (quadric inactive: radius 2 > sqrt 3)
  capsule     1/r                   (1, 1, 0)             (2, 2, h/r + 2) + an end-cap sphere at z = +-h/r

A capsule is the infinite unit cylinder until the entry point lies beyond an end of the segment; then the ray must
enter through that end's hemisphere (the disc at z = +-h/r lies inside the end sphere), so one more sphere test
gives the hit. The camera sits at the origin of the camera frame, so every ray origin in a geom's unit frame is a
per-geom constant and a ray direction is ``M @ (x, y, 1)`` with a per-geom 3x3 ``M``: all per-geom transforms are
computed once per frame (``geom_table``), and the per pixel-geom work is a handful of multiply-adds, two square
roots and a few divisions. Quadratics use the numerically stable form ``q = -(b + sign(b) sqrt(b^2 - a c))``,
roots ``q / a`` and ``c / q`` (the textbook form loses metres in float32 on grazing rays).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ramavt_jax.targets import BOX, CAPSULE, CYLINDER, SPHERE, TargetModel

# Rows of the per-geom feature table.
M0, BQ0, C, Q0, LO0, HI0, O0, CAPHL, W0 = 0, 9, 12, 13, 16, 19, 22, 25, 26
NUM_FEATURES = 29
# Rows of the per-geom shading table (gathered per pixel for the winning geom).
S_M0, S_O0, S_QN0, S_E0, S_HL, S_RGB0 = 0, 9, 12, 15, 18, 19
NUM_SHADE_FEATURES = 22

_BIG = 1e30


def _unit_scale_and_shape(geom_type: jax.Array, size: jax.Array):
    """Per geom: inverse unit-frame scale [G,3], quadric q [G,3], slab half-extents e [G,3], capsule half-length."""
    t = geom_type[:, None]
    r = size[:, 0:1]
    h = size[:, 1:2]
    radial = jnp.broadcast_to(r, size.shape)
    scale = jnp.where((t == SPHERE) | (t == CAPSULE), radial, size)
    scale = jnp.where(t == CYLINDER, jnp.concatenate([r, r, h], axis=1), scale)
    scale = jnp.where(scale > 0, scale, 1.0)  # padding geoms have zero size
    inv_s = 1.0 / scale
    ones = jnp.ones_like(size)
    q = jnp.where(t == BOX, 0.25, ones)
    q = jnp.where((t == CYLINDER) | (t == CAPSULE), jnp.array([1.0, 1.0, 0.0], size.dtype), q)
    hl = jnp.where(geom_type == CAPSULE, h[:, 0] / r[:, 0].clip(1e-30), 0.0)
    e = jnp.where(t == BOX, ones, 2.0 * ones)
    e = jnp.where(t == CYLINDER, jnp.array([2.0, 2.0, 1.0], size.dtype), e)
    e = e.at[:, 2].add(hl)
    return inv_s, q, e, hl


def geom_transforms(target: TargetModel, position: jax.Array, rotation: jax.Array):
    """unit_from_camera matrix M [G,3,3] and the camera origin in each unit frame o [G,3], plus shape data."""
    rot_cg = jnp.einsum("ij,gjk->gik", rotation, target.geom_mat)  # camera_from_geom
    pos_cg = jnp.einsum("ij,gj->gi", rotation, target.geom_pos) + position
    inv_s, q, e, hl = _unit_scale_and_shape(target.geom_type, target.geom_size)
    m = inv_s[:, :, None] * jnp.swapaxes(rot_cg, 1, 2)  # M[g, i, j] = inv_s[g, i] * R_cg[g, j, i]
    o = -jnp.einsum("gij,gj->gi", m, pos_cg)
    return m, o, q, e, hl, inv_s


def geom_table(target: TargetModel, position: jax.Array, rotation: jax.Array) -> jax.Array:
    """Per-geom features for `cast`, structure-of-arrays: [NUM_FEATURES, G] float32 (single target)."""
    m, o, q, e, hl, _ = geom_transforms(target, position, rotation)
    c = jnp.sum(q * o * o, axis=1) - 1.0
    c = jnp.where(target.geom_mask, c, jnp.inf)  # padding: no real root, never hit
    cap_hl = jnp.where(target.geom_type == CAPSULE, hl, _BIG)
    # Padding geoms: both slab planes at +inf -> the slab interval is empty for every ray.
    lo = jnp.where(target.geom_mask[:, None], -e - o, jnp.inf)
    hi = jnp.where(target.geom_mask[:, None], e - o, jnp.inf)
    rows = [
        m.reshape(-1, 9).T,  # 9
        (q * o).T,  # 3
        c[None],  # 1
        q.T,  # 3
        lo.T,  # 3
        hi.T,  # 3
        o.T,  # 3
        cap_hl[None],  # 1
        jnp.stack([q[:, 1] * q[:, 2], q[:, 0] * q[:, 2], q[:, 0] * q[:, 1]]),  # 3 pair weights (x, y, z cross terms)
    ]
    return jnp.concatenate(rows, axis=0).astype(jnp.float32)


def shade_table(target: TargetModel, position: jax.Array, rotation: jax.Array) -> jax.Array:
    """Per-geom features for `surface_normal`: [NUM_SHADE_FEATURES, G] float32 (single target)."""
    m, o, q, e, hl, _ = geom_transforms(target, position, rotation)
    qn = jnp.where((target.geom_type == CAPSULE)[:, None], 1.0, q)
    rows = [m.reshape(-1, 9).T, o.T, qn.T, e.T, hl[None], target.geom_rgb.T]
    return jnp.concatenate(rows, axis=0).astype(jnp.float32)


def _stable_roots(a, b, c, disc):
    """Roots of a t^2 + 2 b t + c = 0 as (valid, near, far) given disc = b^2 - a c; stable in float32."""
    sq = jnp.sqrt(jnp.maximum(disc, 0.0))
    qq = jnp.where(b < 0, sq - b, -b - sq)
    r1 = qq / a
    r2 = c / qq
    return disc >= 0, jnp.minimum(r1, r2), jnp.maximum(r1, r2)


def cast(table, x, y, near: float):
    """Ray parameter (== z depth) of the entry point for every geom: [G, *pix]; +inf where missed.

    table: [NUM_FEATURES, G, *lead] features broadcastable against x/y of shape [*pix] (e.g. table
    [F, G, K, 1] with x, y [K, P]). Only entries at t >= near count.
    """
    f = [table[i] for i in range(NUM_FEATURES)]
    dx = f[M0 + 0] * x + f[M0 + 1] * y + f[M0 + 2]
    dy = f[M0 + 3] * x + f[M0 + 4] * y + f[M0 + 5]
    dz = f[M0 + 6] * x + f[M0 + 7] * y + f[M0 + 8]
    dx2, dy2, dz2 = dx * dx, dy * dy, dz * dz
    a = f[Q0] * dx2 + f[Q0 + 1] * dy2 + f[Q0 + 2] * dz2
    b = f[BQ0] * dx + f[BQ0 + 1] * dy + f[BQ0 + 2] * dz
    c = f[C]
    # b^2 - a c = a - sum_{i<j} q_i q_j (o_i d_j - o_j d_i)^2 (Lagrange identity): no cancellation of |o|^2-sized
    # terms when the camera is far from the geom (b^2 and a c are both ~|o|^2 a there).
    ox, oy, oz = f[O0], f[O0 + 1], f[O0 + 2]
    wx = oy * dz - oz * dy
    wy = oz * dx - ox * dz
    wz = ox * dy - oy * dx
    wz2 = wz * wz
    disc = a - (f[W0] * wx * wx + f[W0 + 1] * wy * wy + f[W0 + 2] * wz2)
    ok, t_in, t_out = _stable_roots(a, b, c, disc)
    for k, d in enumerate((dx, dy, dz)):
        inv = 1.0 / d
        s1 = f[LO0 + k] * inv
        s2 = f[HI0 + k] * inv
        t_in = jnp.maximum(t_in, jnp.minimum(s1, s2))
        t_out = jnp.minimum(t_out, jnp.maximum(s1, s2))
    ok = ok & (t_in <= t_out)
    # Capsules: entry beyond an end of the segment -> the ray must come in through that end's sphere.
    z_in = oz + t_in * dz
    cap_hl = f[CAPHL]
    beyond = jnp.abs(z_in) > cap_hl
    ozs = oz - jnp.where(z_in > 0, cap_hl, -cap_hl)
    a_s = a + dz2
    wxs = oy * dz - ozs * dy
    wys = ozs * dx - ox * dz
    disc_s = a_s - (wxs * wxs + wys * wys + wz2)
    ok_s, ts_in, _ = _stable_roots(a_s, b + ozs * dz, c + ozs * ozs, disc_s)
    t_in = jnp.where(beyond, ts_in, t_in)
    ok = jnp.where(beyond, ok_s, ok)
    return jnp.where(ok & (t_in >= near), t_in, jnp.inf)


def _directions(f, x, y):
    dx = f[M0 + 0] * x + f[M0 + 1] * y + f[M0 + 2]
    dy = f[M0 + 3] * x + f[M0 + 4] * y + f[M0 + 5]
    dz = f[M0 + 6] * x + f[M0 + 7] * y + f[M0 + 8]
    return dx, dy, dz


def cast_ellipsoid(table, x, y, near: float):
    """`cast` for spheres and ellipsoids (unit-sphere quadric, no active slab, no caps): one square root, one division.

    The entry root is c / (sqrt(disc) - b); it is the entry in front of the camera only when the camera is outside
    (c > 0) and the ray approaches (b < 0). Otherwise both roots are behind the camera or it is inside the geom,
    which `cast` also reports as a miss (the entry lies behind the near plane).
    """
    f = [table[i] for i in range(NUM_FEATURES)]
    dx, dy, dz = _directions(f, x, y)
    ox, oy, oz = f[O0], f[O0 + 1], f[O0 + 2]
    a = dx * dx + dy * dy + dz * dz
    b = ox * dx + oy * dy + oz * dz
    c = f[C]
    wx = oy * dz - oz * dy
    wy = oz * dx - ox * dz
    wz = ox * dy - oy * dx
    disc = a - (wx * wx + wy * wy + wz * wz)
    t = c / (jnp.sqrt(jnp.maximum(disc, 0.0)) - b)
    return jnp.where((disc >= 0) & (b < 0) & (c > 0) & (t >= near), t, jnp.inf)


def cast_box(table, x, y, near: float):
    """`cast` for boxes: the three slabs only (the box's quadric is an inactive sphere of radius 2 around it)."""
    f = [table[i] for i in range(NUM_FEATURES)]
    t_in, t_out = None, None
    for k, d in enumerate(_directions(f, x, y)):
        inv = 1.0 / d
        s1 = f[LO0 + k] * inv
        s2 = f[HI0 + k] * inv
        lo, hi = jnp.minimum(s1, s2), jnp.maximum(s1, s2)
        t_in = lo if t_in is None else jnp.maximum(t_in, lo)
        t_out = hi if t_out is None else jnp.minimum(t_out, hi)
    return jnp.where((t_in <= t_out) & (t_in >= near), t_in, jnp.inf)


def cast_cylinder(table, x, y, near: float):
    """`cast` for cylinders: the infinite unit cylinder x^2 + y^2 <= 1 and the cap slab |z| <= 1."""
    f = [table[i] for i in range(NUM_FEATURES)]
    dx, dy, dz = _directions(f, x, y)
    ox, oy = f[O0], f[O0 + 1]
    a = dx * dx + dy * dy
    b = ox * dx + oy * dy
    wz = ox * dy - oy * dx
    disc = a - wz * wz
    ok, t_in, t_out = _stable_roots(a, b, f[C], disc)
    inv = 1.0 / dz
    s1 = f[LO0 + 2] * inv
    s2 = f[HI0 + 2] * inv
    t_in = jnp.maximum(t_in, jnp.minimum(s1, s2))
    t_out = jnp.minimum(t_out, jnp.maximum(s1, s2))
    return jnp.where(ok & (t_in <= t_out) & (t_in >= near), t_in, jnp.inf)


def surface_normal(st, x, y, t):
    """Unit outward normal (camera frame) at the hit ``t`` of the ray (x, y, 1) on the geom described by ``st``.

    st: [NUM_SHADE_FEATURES, *pix] per-pixel features of the hit geom; x, y, t: [*pix]. Returns 3 arrays [*pix].
    """
    m = [st[S_M0 + i] for i in range(9)]
    d = [m[3 * i] * x + m[3 * i + 1] * y + m[3 * i + 2] for i in range(3)]
    p = [st[S_O0 + i] + t * d[i] for i in range(3)]
    hl = st[S_HL]
    w = [p[0], p[1], p[2] - jnp.clip(p[2], -hl, hl)]
    nq = [st[S_QN0 + i] * w[i] for i in range(3)]
    close_q = jnp.sqrt(nq[0] * w[0] + nq[1] * w[1] + nq[2] * w[2])
    close = [jnp.abs(p[i]) / st[S_E0 + i] for i in range(3)]
    best = close_q
    n = nq
    for k in range(3):
        take = close[k] > best
        best = jnp.where(take, close[k], best)
        axis = [jnp.sign(p[k]) if i == k else jnp.zeros_like(p[k]) for i in range(3)]
        n = [jnp.where(take, axis[i], n[i]) for i in range(3)]
    # Gradient in the unit frame -> camera frame: n_cam = M^T n_unit.
    nc = [m[i] * n[0] + m[3 + i] * n[1] + m[6 + i] * n[2] for i in range(3)]
    norm = jnp.sqrt(nc[0] * nc[0] + nc[1] * nc[1] + nc[2] * nc[2])
    inv = 1.0 / jnp.maximum(norm, 1e-30)
    return [v * inv for v in nc]
