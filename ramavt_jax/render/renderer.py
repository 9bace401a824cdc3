"""Rendering a batch of targets: per-geom screen boxes, a flat list of (env, geom, tile) work items, and one
fixed-size, branch-free ray-casting kernel per chunk of items.

1. Setup (all envs and geoms at once, explicit multiply-adds on [B, G] arrays, no tiny matmuls): each geom's
   transform into its unit frame (``intersect`` features) and a conservative pixel box: the projection of its bounding
   sphere, tightened by the projection of its oriented bounding box's corners when they are all in front of the
   camera. The box becomes a rectangle of tiles (``tile`` x ``tile`` pixels) per (env, geom).
2. Work items: every tile of every (env, geom) rectangle. Their count per (env, geom) is the rectangle's area, an
   exclusive prefix sum over the B*G pairs numbers them, and item k finds its pair by a branch-free binary search
   (``log2(B*G)`` gathers). No list of the size of the whole image batch is ever built, and envs or geoms that cannot
   be seen (behind the camera, beyond ``far``, padding) own no items.
3. Casting: a ``lax.while_loop`` takes ``chunk`` items per iteration (the trip count is the batch's total item count
   over ``chunk``: one loop for the whole batch, not one per env), gathers each item's geom features, intersects all
   ``tile*tile`` rays of the item with the geom (``intersect.cast``: dense SIMD over pixels) and merges by
   ``scatter-min`` into a depth buffer of tiles. Items of one tile never need to be processed together, so the
   per-pixel work is exactly one ray-geom test per overlapping geom.
4. Colour (``shade=True``) is a second pass over the same items: each item recomputes its depths, keeps the pixels
   where it is the nearest geom, computes the normal and Lambertian colour there only (others are masked to 0) and
   merges by ``scatter-max``; pixels nobody hits stay black.

On a GPU, ``chunk`` can be the whole item capacity of the batch (one iteration); on CPU, chunks of about 16k-64k
rays keep the kernel's operands in cache. Neither ``chunk`` nor ``tile`` changes the result.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ramavt_jax.render import intersect
from ramavt_jax.render.camera import CameraConfig, Frame, Lighting
from ramavt_jax.targets import BOX, CAPSULE, CYLINDER, ELLIPSOID, SPHERE, TargetModel

DEFAULT_TILE = 8
DEFAULT_CHUNK_RAYS = 16384  # rays per loop iteration when chunk is None (measured best of 4k-64k on 2 cores)
_BIG = 1e30
_WIN_RTOL = 1e-6  # second (colour) pass: a geom wins a pixel when its depth is within this of the pixel's depth


def _mat3(a):
    """[..., 3, 3] array -> nested lists a[i][j] of [...] arrays."""
    return [[a[..., i, j] for j in range(3)] for i in range(3)]


def _geom_frames(targets: TargetModel, positions, rotations):
    """Camera-frame geom centres p[i] and camera_from_geom rotations r[i][j], each [B, G] (explicit FMAs)."""
    rb = _mat3(rotations[:, None])  # [B, 1] each
    gm = _mat3(targets.geom_mat)  # [B, G]
    gp = [targets.geom_pos[..., i] for i in range(3)]
    r = [[rb[i][0] * gm[0][k] + rb[i][1] * gm[1][k] + rb[i][2] * gm[2][k] for k in range(3)] for i in range(3)]
    p = [rb[i][0] * gp[0] + rb[i][1] * gp[1] + rb[i][2] * gp[2] + positions[:, None, i] for i in range(3)]
    return p, r


def _shape(geom_type, size):
    """Per geom: inverse unit-frame scale, quadric q, slab half-extents e (3 lists of [B, G]) and capsule half-length."""
    r, h = size[..., 0], size[..., 1]
    sph = (geom_type == SPHERE) | (geom_type == CAPSULE)
    cyl = geom_type == CYLINDER
    box = geom_type == BOX
    scale = [jnp.where(sph, r, size[..., 0]), jnp.where(sph | cyl, r, size[..., 1]), jnp.where(sph, r, jnp.where(cyl, h, size[..., 2]))]
    inv_s = [1.0 / jnp.where(s > 0, s, 1.0) for s in scale]  # padding geoms have zero size
    round_ = (geom_type == CYLINDER) | (geom_type == CAPSULE)
    one = jnp.ones_like(r)
    q = [jnp.where(box, 0.25, one), jnp.where(box, 0.25, one), jnp.where(box, 0.25, jnp.where(round_, 0.0, one))]
    hl = jnp.where(geom_type == CAPSULE, h / jnp.maximum(r, 1e-30), 0.0)
    e = [jnp.where(box, 1.0, 2.0 * one), jnp.where(box, 1.0, 2.0 * one), jnp.where(box | cyl, 1.0, 2.0 * one) + hl]
    return inv_s, q, e, hl


def _unit_frames(targets: TargetModel, p, r):
    """unit_from_camera m[i][j] and the camera origin in the unit frame o[i] ([B, G] each), plus shape data."""
    inv_s, q, e, hl = _shape(targets.geom_type, targets.geom_size)
    m = [[inv_s[i] * r[j][i] for j in range(3)] for i in range(3)]
    o = [-(m[i][0] * p[0] + m[i][1] * p[1] + m[i][2] * p[2]) for i in range(3)]
    return m, o, q, e, hl


def _cast_table(targets: TargetModel, m, o, q, e, hl) -> jax.Array:
    """Features of `intersect.cast` (rows in its order) as [B*G, NUM_FEATURES]."""
    mask = targets.geom_mask
    c = jnp.where(mask, q[0] * o[0] * o[0] + q[1] * o[1] * o[1] + q[2] * o[2] * o[2] - 1.0, jnp.inf)
    cap_hl = jnp.where(targets.geom_type == CAPSULE, hl, _BIG)
    lo = [jnp.where(mask, -e[i] - o[i], jnp.inf) for i in range(3)]
    hi = [jnp.where(mask, e[i] - o[i], jnp.inf) for i in range(3)]
    rows = ([m[i][j] for i in range(3) for j in range(3)] + [q[i] * o[i] for i in range(3)] + [c] + q + lo + hi + o
            + [cap_hl, q[1] * q[2], q[0] * q[2], q[0] * q[1]])
    assert len(rows) == intersect.NUM_FEATURES
    return jnp.stack(rows, axis=-1).reshape(-1, intersect.NUM_FEATURES).astype(jnp.float32)


def _shade_table(targets: TargetModel, m, o, q, e, hl) -> jax.Array:
    """Features of `intersect.surface_normal` plus the albedo as [B*G, NUM_SHADE_FEATURES]."""
    cap = targets.geom_type == CAPSULE
    qn = [jnp.where(cap, 1.0, q[i]) for i in range(3)]
    rgb = [targets.geom_rgb[..., i] for i in range(3)]
    rows = [m[i][j] for i in range(3) for j in range(3)] + o + qn + e + [hl] + rgb
    assert len(rows) == intersect.NUM_SHADE_FEATURES
    return jnp.stack(rows, axis=-1).reshape(-1, intersect.NUM_SHADE_FEATURES).astype(jnp.float32)


def _half_extents(targets: TargetModel):
    """Half extents (3 lists of [B, G]) of each geom's bounding box in its own frame."""
    t = targets.geom_type
    s = [targets.geom_size[..., i] for i in range(3)]
    r, h = s[0], s[1]
    radial = (t == SPHERE) | (t == CYLINDER) | (t == CAPSULE)
    ex = jnp.where(radial, r, s[0])
    ey = jnp.where(radial, r, s[1])
    ez = jnp.where(t == SPHERE, r, jnp.where(t == CYLINDER, h, jnp.where(t == CAPSULE, h + r, s[2])))
    return [ex, ey, ez]


def _screen_boxes(targets: TargetModel, p, r, cam: CameraConfig):
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
    ext = _half_extents(targets)
    us, vs, zs = [], [], []
    for sx in (-1.0, 1.0):
        for sy in (-1.0, 1.0):
            for sz in (-1.0, 1.0):
                off = (sx * ext[0], sy * ext[1], sz * ext[2])
                corner = [p[i] + r[i][0] * off[0] + r[i][1] * off[1] + r[i][2] * off[2] for i in range(3)]
                inv_z = 1.0 / jnp.where(corner[2] > 1e-3, corner[2], 1.0)
                us.append(f * corner[0] * inv_z + c)
                vs.append(f * corner[1] * inv_z + c)
                zs.append(corner[2])
    front = functools.reduce(jnp.minimum, zs) > 1e-3
    umin = jnp.where(front, jnp.maximum(umin, functools.reduce(jnp.minimum, us) - 1.0), umin)
    umax = jnp.where(front, jnp.minimum(umax, functools.reduce(jnp.maximum, us) + 1.0), umax)
    vmin = jnp.where(front, jnp.maximum(vmin, functools.reduce(jnp.minimum, vs) - 1.0), vmin)
    vmax = jnp.where(front, jnp.minimum(vmax, functools.reduce(jnp.maximum, vs) + 1.0), vmax)
    return umin, umax, vmin, vmax, visible


def _tile_range(lo, hi, tile: int, nt: int):
    """First tile index and tile count [B, G] int32 of the tiles whose pixels [k*tile, k*tile+tile-1] meet [lo, hi]."""
    lo = jnp.clip(lo, -2.0 * tile, (nt + 2.0) * tile)
    hi = jnp.clip(hi, -2.0 * tile, (nt + 2.0) * tile)
    first = jnp.maximum(jnp.ceil((lo - (tile - 1)) / tile), 0.0)
    last = jnp.minimum(jnp.floor(hi / tile), nt - 1.0)
    return first.astype(jnp.int32), jnp.maximum(last - first + 1.0, 0.0).astype(jnp.int32)


def _columns(rows: jax.Array) -> list[jax.Array]:
    """[C, F] gathered feature rows -> F arrays [C, 1, 1] (broadcast against a [C, tile, tile] item)."""
    return [rows[:, i, None, None] for i in range(rows.shape[1])]


def _search_levels(ends: jax.Array):
    """Loop-invariant tables for `_find_pair` on the non-decreasing ``ends`` [K, E]: a B-ary search tree of L levels
    (B^L >= E, B about E^(1/L) with L = ceil(log_64 E)); level l is [K, B^l, B], padded with int32 max."""
    e = ends.shape[-1]
    levels = max(1, int(np.ceil(np.log(max(e, 2)) / np.log(64))))
    block = int(np.ceil(e ** (1.0 / levels)))
    while block ** levels < e:
        block += 1
    pad = jnp.pad(ends, ((0, 0), (0, block ** levels - e)), constant_values=np.iinfo(np.int32).max)
    out = []
    for lv in range(levels):
        idx = (np.arange(block ** (lv + 1)) + 1) * block ** (levels - 1 - lv) - 1
        out.append(pad[:, idx].reshape(ends.shape[0], block ** lv, block))
    return out


def _find_pair(levels, cls: jax.Array, k: jax.Array) -> jax.Array:
    """Number of entries of row ``cls`` of the non-decreasing ends that are <= k, for every k [C]: the index of the
    (env, geom) pair that owns item k. One gather of [C, B] entries and one compare-count per level (`_search_levels`)."""
    node = jnp.zeros(k.shape, jnp.int32)
    for table in levels:
        block = table.shape[-1]
        below = jnp.sum(table[cls, node] <= k[:, None], axis=1, dtype=jnp.int32)
        node = node * block + below
    return node


# Geom classes with their own specialised kernel; each class's work items form their own list and loop.
_CLASSES = (
    ("ellipsoid", (SPHERE, ELLIPSOID), intersect.cast_ellipsoid),
    ("box", (BOX,), intersect.cast_box),
    ("cylinder", (CYLINDER,), intersect.cast_cylinder),
    ("capsule", (CAPSULE,), intersect.cast),
)


def _prefix_sum(x: jax.Array, block: int = 32) -> jax.Array:
    """Inclusive prefix sum of int32 counts along the last axis: blocks of ``block`` summed by one integer matmul
    with a triangular matrix per level, log_block(N) levels (XLA:CPU lowers a long jnp.cumsum to a quadratic
    reduce-window, and an associative scan to dozens of tiny ops)."""
    n = x.shape[-1]
    tri = jnp.asarray(np.triu(np.ones((block, block), np.int32)))

    def blocksum(v, k):
        return jax.lax.dot_general(v, tri[:k, :k], (((v.ndim - 1,), (0,)), ((), ())), preferred_element_type=jnp.int32)

    if n <= block:
        return blocksum(x, n)
    m = -(-n // block)
    lead = x.shape[:-1]
    inner = blocksum(jnp.pad(x, [(0, 0)] * len(lead) + [(0, m * block - n)]).reshape(lead + (m, block)), block)
    totals = inner[..., -1]
    offsets = _prefix_sum(totals, block) - totals
    return (inner + offsets[..., None]).reshape(lead + (m * block,))[..., :n]


@functools.partial(jax.jit, static_argnames=("cam", "shade", "chunk", "tile", "specialise"))
def render_batch(
    targets: TargetModel,
    positions: jax.Array,
    rotations: jax.Array,
    cam: CameraConfig,
    lighting: Lighting,
    shade: bool = True,
    chunk: int | None = None,
    tile: int = DEFAULT_TILE,
    specialise: bool = True,
) -> Frame:
    """Render B targets at once: targets with leading [B], positions [B, 3], rotations [B, 3, 3] -> Frame [B, ...].

    position = target centre of mass in the camera frame; rotation = camera_from_body. ``chunk`` is the number of
    work items (one geom over one tile of ``tile`` x ``tile`` pixels) cast per loop iteration; ``specialise=False``
    runs every geom through the general kernel `intersect.cast` (a test reference). None of them changes the
    result beyond float rounding. ``shade=False`` leaves rgb at zero (and skips the colour pass).
    """
    positions = jnp.asarray(positions, jnp.float32)
    rotations = jnp.asarray(rotations, jnp.float32)
    b = positions.shape[0]
    n_geoms = targets.geom_type.shape[-1]
    nt = -(-cam.resolution // tile)
    n_pairs = b * n_geoms
    if chunk is None:
        if jax.default_backend() == "cpu":  # cache-sized chunks; small batches must not pay for a mostly empty one
            chunk = max(8, min(DEFAULT_CHUNK_RAYS // (tile * tile), (b * nt * nt * 2) // 8))
        else:  # accelerators: a few large fixed-size iterations for the whole batch
            chunk = max(1024, b * nt * nt // 2)
    chunk = int(chunk)

    p, r = _geom_frames(targets, positions, rotations)
    m, o, q, e, hl = _unit_frames(targets, p, r)
    table = _cast_table(targets, m, o, q, e, hl)  # [B*G, F]: an item gathers one contiguous row
    umin, umax, vmin, vmax, visible = _screen_boxes(targets, p, r, cam)
    tu0, nu = _tile_range(umin, umax, tile, nt)
    tv0, nv = _tile_range(vmin, vmax, tile, nt)
    counts = jnp.where(visible, nu * nv, 0).reshape(-1)  # items per (env, geom)
    tu0, tv0, nu = tu0.reshape(-1), tv0.reshape(-1), jnp.maximum(nu.reshape(-1), 1)
    gtype = targets.geom_type.reshape(-1)
    classes = _CLASSES if specialise else (("all", (SPHERE, CAPSULE, ELLIPSOID, CYLINDER, BOX), intersect.cast),)
    kernels = [k for _, _, k in classes]
    n_cls = len(classes)

    # One list per geom class (ends [K, B*G]: inclusive prefix sums of the class's item counts over the pairs), each
    # padded to whole chunks and laid end to end: chunk j belongs to class cls(j) and runs that class's kernel.
    member = jnp.stack([functools.reduce(jnp.logical_or, [gtype == t for t in types]) for _, types, _ in classes])
    ends = _prefix_sum(jnp.where(member, counts, 0))  # [K, B*G]
    n_items = ends[:, -1]  # [K]
    chunk_end = jnp.cumsum((n_items + chunk - 1) // chunk)  # [K]
    levels = _search_levels(ends)
    n_chunks = chunk_end[-1]

    tx0 = jnp.asarray((np.arange(nt) * tile - cam.centre()) / cam.focal(), jnp.float32)
    px = jnp.asarray(np.arange(tile) / cam.focal(), jnp.float32)
    item_iota = jnp.arange(chunk, dtype=jnp.int32)

    def items(j):
        """Chunk j: class, pair index, env (b for padding: dropped), tile row/column, ray coordinates."""
        cls = jnp.sum(j >= chunk_end, dtype=jnp.int32)
        first = jnp.where(cls > 0, chunk_end[jnp.maximum(cls - 1, 0)], 0)
        k = (j - first) * chunk + item_iota
        pair = jnp.minimum(_find_pair(levels, cls, k), n_pairs - 1)
        local = k - (ends[cls, pair] - counts[pair])
        nu_k = nu[pair]
        dv = local // nu_k
        tv = jnp.clip(tv0[pair] + dv, 0, nt - 1)
        tu = jnp.clip(tu0[pair] + (local - dv * nu_k), 0, nt - 1)
        env = jnp.where(k < n_items[cls], pair // n_geoms, b)
        x = (tx0[tu][:, None] + px)[:, None, :]  # [C, 1, tile] (pixel column)
        y = (tx0[tv][:, None] + px)[:, :, None]  # [C, tile, 1] (pixel row)
        return cls, pair, env, tv, tu, x, y

    def cast(cls, pair, x, y):
        rows = table[pair]  # [C, F], one operand (the switch materialises its operands)

        def branch(kernel):
            return lambda rows, x, y: kernel(_columns(rows), x, y, cam.near)

        if n_cls == 1:
            return branch(kernels[0])(rows, x, y)
        return jax.lax.switch(cls, [branch(k) for k in kernels], rows, x, y)

    # Buffers in image layout [B, tile rows, pixel row in tile, tile columns, pixel column in tile]: an item's
    # pixels are one [tile, tile] window, and the final image is a reshape (no transpose pass).
    def depth_body(state):
        j, dbuf = state
        cls, pair, env, tv, tu, x, y = items(j)
        t = cast(cls, pair, x, y)  # [C, tile, tile]
        return j + 1, dbuf.at[env, tv, :, tu, :].min(t, mode="drop")

    dbuf = jnp.full((b, nt, tile, nt, tile), jnp.inf, jnp.float32)
    _, dbuf = jax.lax.while_loop(lambda s: s[0] < n_chunks, depth_body, (jnp.int32(0), dbuf))

    if shade:
        stable = _shade_table(targets, m, o, q, e, hl)  # [B*G, S]
        # lighting may be shared ([3], []) or per env ([B, 3], [B]), e.g. when env params are randomised
        sun_all = jnp.broadcast_to(jnp.asarray(lighting.sun_dir, jnp.float32), (b, 3))
        amb_all = jnp.broadcast_to(jnp.asarray(lighting.ambient, jnp.float32), (b,))

        def colour_body(state):
            j, cbuf = state
            cls, pair, env, tv, tu, x, y = items(j)
            t = cast(cls, pair, x, y)
            safe_env = jnp.minimum(env, b - 1)
            best = dbuf[safe_env, tv, :, tu, :]  # [C, tile, tile]
            win = (t <= best * (1.0 + _WIN_RTOL)) & (t <= cam.far)
            st = _columns(stable[pair])  # S x [C, 1, 1]
            n = intersect.surface_normal(st, x, y, jnp.where(win, t, 1.0))
            sun = sun_all[safe_env].T[:, :, None, None]  # [3, C, 1, 1]
            amb = amb_all[safe_env][:, None, None]
            lam = jnp.maximum(n[0] * sun[0] + n[1] * sun[1] + n[2] * sun[2], 0.0)
            light = amb + (1.0 - amb) * lam
            # One plane per channel (a [tile, tile] window each, like the depth buffer).
            cbuf = tuple(cbuf[k].at[env, tv, :, tu, :].max(
                jnp.where(win, jnp.clip(st[intersect.S_RGB0 + k] * light, 0.0, 1.0), 0.0), mode="drop") for k in range(3))
            return j + 1, cbuf

        cbuf = tuple(jnp.zeros((b, nt, tile, nt, tile), jnp.float32) for _ in range(3))
        _, cbuf = jax.lax.while_loop(lambda s: s[0] < n_chunks, colour_body, (jnp.int32(0), cbuf))

    res = cam.resolution
    depth = dbuf.reshape(b, nt * tile, nt * tile)[:, :res, :res]
    hit = depth <= cam.far
    depth = jnp.where(hit, depth, 0.0)
    if shade:
        rgb = jnp.stack([c.reshape(b, nt * tile, nt * tile)[:, :res, :res] for c in cbuf], axis=-1)
    else:
        rgb = jnp.zeros(depth.shape + (3,), jnp.float32)
    return Frame(depth=depth, rgb=rgb, hit=hit)


def render(
    target: TargetModel,
    position: jax.Array,
    rotation: jax.Array,
    cam: CameraConfig,
    lighting: Lighting,
    shade: bool = True,
) -> Frame:
    """Render one target: position [3] (centre of mass, camera frame), rotation [3, 3] camera_from_body -> Frame.

    Jit- and vmap-able. Under ``jax.vmap`` it becomes one `render_batch` call (a custom batching rule), so a
    vmapped env step shares one work list over all its envs instead of running a batched loop per env.
    """
    return vmappable_render(cam, bool(shade))(target, jnp.asarray(position), jnp.asarray(rotation), lighting)


@functools.lru_cache(maxsize=None)
def vmappable_render(cam: CameraConfig, shade: bool, batch_fn=None):
    """render(target, position, rotation, lighting) for one target whose ``jax.vmap`` is one ``batch_fn`` call
    (default `render_batch`; the benchmarks pass the old renderer's to compare inside the same env step)."""
    batch_fn = render_batch if batch_fn is None else batch_fn

    @jax.custom_batching.custom_vmap
    def render_one(target, position, rotation, lighting):
        batch = jax.tree.map(lambda a: jnp.asarray(a)[None], (target, position, rotation))
        frame = batch_fn(*batch, cam, lighting, shade)
        return jax.tree.map(lambda a: a[0], frame)

    @render_one.def_vmap
    def render_many(axis_size, in_batched, target, position, rotation, lighting):
        def batched(x, is_batched):
            x = jnp.asarray(x)
            return x if is_batched else jnp.broadcast_to(x, (axis_size,) + x.shape)

        target, position, rotation = jax.tree.map(batched, (target, position, rotation), tuple(in_batched[:3]))
        lighting = jax.tree.map(batched, lighting, in_batched[3])
        return (frame := batch_fn(target, position, rotation, cam, lighting, shade)), jax.tree.map(lambda _: True, frame)

    return render_one
