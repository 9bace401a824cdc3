"""Rendering a batch of targets: per-geom screen boxes, a flat list of (env, geom, tile) work items, and one
fixed-size, branch-free ray-casting kernel per chunk of items.

0. A batch in which no target reaches between the near and far planes returns an empty frame at once.
1. Setup (`geometry`: all envs and geoms at once, explicit multiply-adds on [B, G] arrays, no tiny matmuls): each geom's
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
   where it is the nearest geom, computes the normal and Lambertian light there only (others are masked) and merges
   the light and its (env, geom) pair's index by ``scatter-max``; the albedo is looked up once per pixel after the
   loop (a geom within float rounding of another's depth may tie: the larger index wins). Pixels nobody hits stay
   black.

On a GPU, ``chunk`` can be the whole item capacity of the batch (one iteration); on CPU, chunks of about 16k-64k
rays keep the kernel's operands in cache. Neither ``chunk`` nor ``tile`` changes the result.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from ramavt_jax.render import geometry, intersect
from ramavt_jax.render.camera import CameraConfig, Frame, Lighting
from ramavt_jax.targets import BOX, CAPSULE, CYLINDER, ELLIPSOID, SPHERE, TargetModel

DEFAULT_TILE = 8
DEFAULT_CHUNK_RAYS = 16384  # rays per loop iteration when chunk is None (measured best of 4k-64k on 2 cores)
_WIN_RTOL = 1e-6  # second (colour) pass: a geom wins a pixel when its depth is within this of the pixel's depth


def _columns(rows: jax.Array) -> list[jax.Array]:
    """[C, F] gathered feature rows -> F arrays [C, 1, 1] (broadcast against a [C, tile, tile] item)."""
    return [rows[:, i, None, None] for i in range(rows.shape[1])]


def _search_levels(ends: jax.Array):
    """Loop-invariant tables for `_find_pair` on the non-decreasing ``ends`` [K, E]: a B-ary search tree of L levels
    (B^L >= E, B about E^(1/L) with L = ceil(log_64 E)); level l is [K, B^l, B], padded with int32 max."""
    e = ends.shape[-1]
    levels = max(1, int(np.ceil(np.log(max(e, 2)) / np.log(64))))
    block = int(np.ceil(e ** (1.0 / levels)))
    while block**levels < e:
        block += 1
    pad = jnp.pad(ends, ((0, 0), (0, block**levels - e)), constant_values=np.iinfo(np.int32).max)
    out = []
    for lv in range(levels):
        idx = (np.arange(block ** (lv + 1)) + 1) * block ** (levels - 1 - lv) - 1
        out.append(pad[:, idx].reshape(ends.shape[0], block**lv, block))
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

    A batch in which no target can be seen costs one bounds check (an empty 64-env render cost 0.84 ms here without
    it, against 2.6 ms for a full one: the work list's setup and the buffers), and the env's second render of a step
    is such a batch whenever no episode ended.
    """
    positions = jnp.asarray(positions, jnp.float32)
    rotations = jnp.asarray(rotations, jnp.float32)
    b, res = positions.shape[0], cam.resolution
    # Only the images that carry information pass through the cond (its outputs are always written in full): rgb stays
    # a zero constant outside it when not shaded (64 envs at 128x128: 12 MB of zeros per render otherwise), and hit is
    # depth > 0 (every hit lies at or beyond the near plane, > 0).
    images = (lambda frame: (frame.depth, frame.rgb)) if shade else (lambda frame: (frame.depth,))
    no_depth, no_rgb = jnp.zeros((b, res, res), jnp.float32), jnp.zeros((b, res, res, 3), jnp.float32)
    empty = (no_depth, no_rgb) if shade else (no_depth,)
    cast = functools.partial(_render_seen, cam=cam, shade=shade, chunk=chunk, tile=tile, specialise=specialise)
    out = jax.lax.cond(
        geometry.may_be_seen(targets, positions, cam),
        lambda *a: images(cast(*a)),
        lambda *_: empty,
        targets,
        positions,
        rotations,
        lighting,
    )
    return Frame(depth=out[0], rgb=out[1] if shade else no_rgb, hit=out[0] > 0)


@dataclasses.dataclass(frozen=True)
class _WorkList:
    """The batch's work items (step 2 of the module doc), laid out for the casting loops: one list per geom class,
    each padded to whole chunks and laid end to end, so that chunk j belongs to one class and runs its kernel."""

    table: jax.Array  # [B*G, F] cast features per (env, geom) pair: an item gathers one contiguous row
    counts: jax.Array  # [B*G] items per pair (the area of its tile rectangle; 0 if it cannot be seen)
    tu0: jax.Array  # [B*G] first tile column of the pair's rectangle
    tv0: jax.Array  # [B*G] first tile row
    nu: jax.Array  # [B*G] tile columns of the rectangle (>= 1)
    ends: jax.Array  # [K, B*G] inclusive prefix sums of each class's item counts over the pairs
    n_items: jax.Array  # [K] items per class
    chunk_end: jax.Array  # [K] chunks up to and including each class's
    levels: tuple  # `_search_levels` of ends
    kernels: tuple  # K intersection kernels, one per class
    batch: int  # B
    n_geoms: int  # G
    tiles: int  # tiles per image side
    chunk: int  # items per chunk

    @property
    def n_chunks(self) -> jax.Array:
        return self.chunk_end[-1]


@dataclasses.dataclass(frozen=True)
class _Chunk:
    """The items of one chunk, each [C] (C = chunk), and their rays."""

    cls: jax.Array  # [] the chunk's geom class
    pair: jax.Array  # (env, geom) pair index
    env: jax.Array  # env index; B for padding (scatters drop it)
    tv: jax.Array  # tile row
    tu: jax.Array  # tile column
    x: jax.Array  # [C, 1, tile] ray slope of each pixel column
    y: jax.Array  # [C, tile, 1] ray slope of each pixel row


def _chunk_size(b: int, nt: int, tile: int, chunk: int | None) -> int:
    """Items per loop iteration when ``chunk`` is None: cache-sized on CPU, where small batches must not pay for a
    mostly empty chunk; a few large fixed-size iterations for the whole batch on accelerators."""
    if chunk is not None:
        return int(chunk)
    if jax.default_backend() == "cpu":
        return int(max(8, min(DEFAULT_CHUNK_RAYS // (tile * tile), (b * nt * nt * 2) // 8)))
    return int(max(1024, b * nt * nt // 2))


def _work_list(
    targets: TargetModel,
    p: jax.Array,
    r: jax.Array,
    unit: tuple,
    cam: CameraConfig,
    tile: int,
    chunk: int | None,
    specialise: bool,
) -> _WorkList:
    """The work items of B targets (leading [B]): their geoms' frames p, r (geometry.geom_frames) and unit frames
    ``unit`` (geometry.unit_frames)."""
    b, n_geoms = targets.geom_type.shape  # [B, G]
    nt = -(-cam.resolution // tile)
    chunk = _chunk_size(b, nt, tile, chunk)
    umin, umax, vmin, vmax, visible = geometry.screen_boxes(targets, p, r, cam)
    tu0, nu = geometry.tile_range(umin, umax, tile, nt)
    tv0, nv = geometry.tile_range(vmin, vmax, tile, nt)
    counts = jnp.where(visible, nu * nv, 0).reshape(-1)
    gtype = targets.geom_type.reshape(-1)
    classes = _CLASSES if specialise else (("all", (SPHERE, CAPSULE, ELLIPSOID, CYLINDER, BOX), intersect.cast),)
    member = jnp.stack([functools.reduce(jnp.logical_or, [gtype == t for t in types]) for _, types, _ in classes])
    ends = _prefix_sum(jnp.where(member, counts, 0))
    n_items = ends[:, -1]
    return _WorkList(
        table=geometry.cast_table(targets, *unit),
        counts=counts,
        tu0=tu0.reshape(-1),
        tv0=tv0.reshape(-1),
        nu=jnp.maximum(nu.reshape(-1), 1),
        ends=ends,
        n_items=n_items,
        chunk_end=jnp.cumsum((n_items + chunk - 1) // chunk),
        levels=tuple(_search_levels(ends)),
        kernels=tuple(k for _, _, k in classes),
        batch=b,
        n_geoms=n_geoms,
        tiles=nt,
        chunk=chunk,
    )


def _chunk_items(work: _WorkList, j: jax.Array, cam: CameraConfig, tile: int) -> _Chunk:
    """Chunk j's items: their class, pair, env, tile and ray coordinates."""
    cls = jnp.sum(j >= work.chunk_end, dtype=jnp.int32)
    first = jnp.where(cls > 0, work.chunk_end[jnp.maximum(cls - 1, 0)], 0)
    k = (j - first) * work.chunk + jnp.arange(work.chunk, dtype=jnp.int32)
    pair = jnp.minimum(_find_pair(work.levels, cls, k), work.batch * work.n_geoms - 1)
    local = k - (work.ends[cls, pair] - work.counts[pair])
    nu_k = work.nu[pair]
    dv = local // nu_k
    tv = jnp.clip(work.tv0[pair] + dv, 0, work.tiles - 1)
    tu = jnp.clip(work.tu0[pair] + (local - dv * nu_k), 0, work.tiles - 1)
    env = jnp.where(k < work.n_items[cls], pair // work.n_geoms, work.batch)
    tx0 = jnp.asarray((np.arange(work.tiles) * tile - cam.centre()) / cam.focal(), jnp.float32)
    px = jnp.asarray(np.arange(tile) / cam.focal(), jnp.float32)
    return _Chunk(
        cls=cls,
        pair=pair,
        env=env,
        tv=tv,
        tu=tu,
        x=(tx0[tu][:, None] + px)[:, None, :],
        y=(tx0[tv][:, None] + px)[:, :, None],
    )


def _cast(work: _WorkList, items: _Chunk, near: float) -> jax.Array:
    """[C, tile, tile] each item's ray depths through its geom (inf where missed), by its class's kernel."""
    rows = work.table[items.pair]  # [C, F], one operand (the switch materialises its operands)

    def branch(kernel):
        return lambda rows, x, y: kernel(_columns(rows), x, y, near)

    if len(work.kernels) == 1:
        return branch(work.kernels[0])(rows, items.x, items.y)
    return jax.lax.switch(items.cls, [branch(k) for k in work.kernels], rows, items.x, items.y)


def _depth_pass(work: _WorkList, cam: CameraConfig, tile: int) -> jax.Array:
    """The nearest depth per pixel, in image layout [B, tile rows, pixel row in tile, tile columns, pixel column in
    tile]: an item's pixels are one [tile, tile] window, and the final image is a reshape (no transpose pass)."""

    def body(state):
        j, dbuf = state
        items = _chunk_items(work, j, cam, tile)
        t = _cast(work, items, cam.near)
        return j + 1, dbuf.at[items.env, items.tv, :, items.tu, :].min(t, mode="drop")

    nt = work.tiles
    dbuf = jnp.full((work.batch, nt, tile, nt, tile), jnp.inf, jnp.float32)
    n_chunks = work.n_chunks
    return jax.lax.while_loop(lambda s: s[0] < n_chunks, body, (jnp.int32(0), dbuf))[1]


def _colour_pass(
    work: _WorkList, stable: jax.Array, lighting: Lighting, dbuf: jax.Array, cam: CameraConfig, tile: int
) -> tuple[jax.Array, jax.Array]:
    """The Lambertian light [B, ...] and the winning pair's index [B, ...] (-1: no hit) per pixel, in dbuf's layout;
    ``stable`` [B*G, S] is geometry.shade_table's."""
    b = work.batch
    # lighting may be shared ([3], []) or per env ([B, 3], [B]), e.g. when env params are randomised
    sun_all = jnp.broadcast_to(jnp.asarray(lighting.sun_dir, jnp.float32), (b, 3))
    amb_all = jnp.broadcast_to(jnp.asarray(lighting.ambient, jnp.float32), (b,))

    def body(state):
        j, (lbuf, wbuf) = state
        items = _chunk_items(work, j, cam, tile)
        t = _cast(work, items, cam.near)
        safe_env = jnp.minimum(items.env, b - 1)
        best = dbuf[safe_env, items.tv, :, items.tu, :]  # [C, tile, tile]
        win = (t <= best * (1.0 + _WIN_RTOL)) & (t <= cam.far)
        st = _columns(stable[items.pair])  # S x [C, 1, 1]
        n = intersect.surface_normal(st, items.x, items.y, jnp.where(win, t, 1.0))
        sun = sun_all[safe_env].T[:, :, None, None]  # [3, C, 1, 1]
        amb = amb_all[safe_env][:, None, None]
        light = amb + (1.0 - amb) * jnp.maximum(n[0] * sun[0] + n[1] * sun[1] + n[2] * sun[2], 0.0)
        # Two scatters: the light and which (env, geom) pair won each pixel; the colour is looked up once after the
        # loop. With one scatter per colour channel XLA recomputed the normal and the light for each channel.
        where = (items.env, items.tv, slice(None), items.tu, slice(None))
        lbuf = lbuf.at[where].max(jnp.where(win, light, 0.0), mode="drop")
        wbuf = wbuf.at[where].max(jnp.where(win, items.pair[:, None, None], -1), mode="drop")
        return j + 1, (lbuf, wbuf)

    bufs = (jnp.zeros(dbuf.shape, jnp.float32), jnp.full(dbuf.shape, -1, jnp.int32))
    n_chunks = work.n_chunks
    return jax.lax.while_loop(lambda s: s[0] < n_chunks, body, (jnp.int32(0), bufs))[1]


def _render_seen(
    targets: TargetModel,
    positions: jax.Array,
    rotations: jax.Array,
    lighting: Lighting,
    cam: CameraConfig,
    shade: bool,
    chunk: int | None,
    tile: int,
    specialise: bool,
) -> Frame:
    """`render_batch` without the visibility shortcut: the work list and the casting loops."""
    p, r = geometry.geom_frames(targets, positions, rotations)
    unit = geometry.unit_frames(targets, p, r)  # m, o, q, e, hl
    work = _work_list(targets, p, r, unit, cam, tile, chunk, specialise)
    dbuf = _depth_pass(work, cam, tile)
    b, res, side = work.batch, cam.resolution, work.tiles * tile
    depth = dbuf.reshape(b, side, side)[:, :res, :res]
    hit = depth <= cam.far
    depth = jnp.where(hit, depth, 0.0)
    if not shade:
        return Frame(depth=depth, rgb=jnp.zeros(depth.shape + (3,), jnp.float32), hit=hit)
    stable = geometry.shade_table(targets, *unit)  # [B*G, S]
    lbuf, wbuf = _colour_pass(work, stable, lighting, dbuf, cam, tile)
    winner = wbuf.reshape(b, side, side)[:, :res, :res]  # [B, H, W] pair index, -1: no hit
    light = lbuf.reshape(b, side, side)[:, :res, :res, None]
    albedo = stable[jnp.maximum(winner, 0), intersect.S_RGB0 : intersect.S_RGB0 + 3]  # [B, H, W, 3]
    rgb = jnp.where(winner[..., None] >= 0, jnp.clip(albedo * light, 0.0, 1.0), 0.0)
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


@functools.cache
def vmappable_render(cam: CameraConfig, shade: bool, batch_fn=None):
    """render(target, position, rotation, lighting) for one target whose ``jax.vmap`` is one ``batch_fn`` call
    (default `render_batch`)."""
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
        return (frame := batch_fn(target, position, rotation, cam, lighting, shade)), jax.tree.map(
            lambda _: True, frame
        )

    return render_one
