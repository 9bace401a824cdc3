"""Rendering one target or a batch: screen-space tile culling, global tile compaction, chunked ray casting.

The image is cut into square tiles (8x8 pixels by default). A tile is only ray-cast when its pixel range overlaps
the exact image-plane bounding box of the target's bounding sphere. For a batch, the needed (env, tile) pairs of
all envs are compacted into one list (``jnp.nonzero`` with a static size) and processed ``chunk`` tiles at a time in
a ``lax.while_loop`` whose trip count is the number of needed tiles divided by ``chunk``: the work done scales with
the image area the targets cover, shapes stay static under jit, and there is no fallback path to fall into.
Results are gathered back into full images at the end (tiles that were not cast stay empty).
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from ramavt_jax.render import intersect
from ramavt_jax.render.camera import CameraConfig, Frame, Lighting
from ramavt_jax.targets import TargetModel

DEFAULT_TILE = 8
DEFAULT_CHUNK_RAYS = 4096  # rays per loop iteration when chunk is None (64 tiles: measured best of 64/256/1024)
DEFAULT_GEOMS_PER_TILE = 8  # tiles overlapped by at most this many geoms take the short geom list


def _tile_layout(cam: CameraConfig, tile: int):
    """Static per-tile pixel coordinates: x, y [T, P] (normalised image plane) and pixel ranges [T, 2] each."""
    nt = -(-cam.resolution // tile)
    p = np.arange(tile * tile)
    t = np.arange(nt * nt)
    u = (t % nt)[:, None] * tile + (p % tile)[None, :]
    v = (t // nt)[:, None] * tile + (p // tile)[None, :]
    f, c = cam.focal(), cam.centre()
    x = ((u - c) / f).astype(np.float32)
    y = ((v - c) / f).astype(np.float32)
    u0 = (t % nt) * tile
    v0 = (t // nt) * tile
    return nt, x, y, np.stack([u0, u0 + tile - 1], 1).astype(np.float32), np.stack([v0, v0 + tile - 1], 1).astype(np.float32)


def _projected_bounds(centre: jax.Array, radius: jax.Array, cam: CameraConfig):
    """Pixel-coordinate box (umin, umax, vmin, vmax) containing the image of a sphere; empty when out of range."""
    cx, cy, cz = centre[0], centre[1], centre[2]
    r2 = radius * radius
    den = cz * cz - r2
    in_front = cz > radius * 1.001 + 1e-6
    safe_den = jnp.where(in_front, den, 1.0)
    f, c = cam.focal(), cam.centre()

    def extent(a):
        root = jnp.sqrt(jnp.maximum(a * a + den, 0.0)) * radius
        lo = (a * cz - root) / safe_den
        hi = (a * cz + root) / safe_den
        return jnp.where(in_front, f * lo + c - 1.0, -jnp.inf), jnp.where(in_front, f * hi + c + 1.0, jnp.inf)

    umin, umax = extent(cx)
    vmin, vmax = extent(cy)
    visible = (cz + radius > cam.near) & (cz - radius < cam.far)
    return umin, umax, vmin, vmax, visible


def _tile_mask(position, radius, cam, u_rng, v_rng):
    umin, umax, vmin, vmax, visible = _projected_bounds(position, radius, cam)
    return (
        visible
        & (u_rng[:, 1] >= umin)
        & (u_rng[:, 0] <= umax)
        & (v_rng[:, 1] >= vmin)
        & (v_rng[:, 0] <= vmax)
    )


def _assemble(tiles: jax.Array, b: int, nt: int, tile: int, res: int) -> jax.Array:
    """[B*T, tile*tile, *rest] -> [B, res, res, *rest]."""
    rest = tiles.shape[2:]
    img = tiles.reshape((b, nt, nt, tile, tile) + rest)
    img = jnp.moveaxis(img, 3, 2).reshape((b, nt * tile, nt * tile) + rest)
    return img[:, :res, :res]


@functools.partial(jax.jit, static_argnames=("cam", "shade", "chunk", "tile", "geoms_per_tile"))
def render_batch(
    targets: TargetModel,
    positions: jax.Array,
    rotations: jax.Array,
    cam: CameraConfig,
    lighting: Lighting,
    shade: bool = True,
    chunk: int | None = None,
    tile: int = DEFAULT_TILE,
    geoms_per_tile: int = DEFAULT_GEOMS_PER_TILE,
) -> Frame:
    """Render B targets at once: targets with leading [B], positions [B, 3], rotations [B, 3, 3] -> Frame [B, ...].

    position = target centre of mass in the camera frame; rotation = camera_from_body. ``chunk`` is the number of
    tiles ray-cast per loop iteration (default: about 4k rays); ``tile`` the tile side in pixels. Neither changes
    the result. ``shade=False`` leaves rgb at zero.
    """
    positions = jnp.asarray(positions, jnp.float32)
    rotations = jnp.asarray(rotations, jnp.float32)
    b = positions.shape[0]
    nt, xs, ys, u_rng, v_rng = _tile_layout(cam, tile)
    n_tiles = nt * nt
    npix = tile * tile
    total = b * n_tiles
    if chunk is None:  # ~16k rays, but small batches must not pay for a mostly empty chunk
        chunk = max(1, min(DEFAULT_CHUNK_RAYS // npix, max(16, total // 8)))
    chunk = int(min(chunk, total))
    n_chunks = -(-total // chunk)
    cap = n_chunks * chunk

    tables = jnp.swapaxes(jax.vmap(intersect.geom_table)(targets, positions, rotations), 1, 2)  # [B, G, F]
    n_geoms = tables.shape[1]
    kg = int(min(geoms_per_tile, n_geoms))
    if shade:
        stables = jnp.swapaxes(jax.vmap(intersect.shade_table)(targets, positions, rotations), 1, 2)
        stables = stables.reshape(b * n_geoms, -1)  # [B*G, S]
    # Per (env, tile, geom): does the geom's bounding sphere project onto the tile?
    geom_centre = jnp.einsum("bij,bgj->bgi", rotations, targets.geom_pos) + positions[:, None, :]
    geom_r = jnp.where(targets.geom_mask, targets.geom_rbound, -1.0)
    mask_fn = jax.vmap(jax.vmap(_tile_mask, in_axes=(0, 0, None, None, None)), in_axes=(0, 0, None, None, None))
    overlap = mask_fn(geom_centre, geom_r, cam, u_rng, v_rng)  # [B, G, T]
    overlap = jnp.swapaxes(overlap & targets.geom_mask[..., None], 1, 2).reshape(total, n_geoms)  # [B*T, G]
    n_over = jnp.sum(overlap, axis=1, dtype=jnp.int32)
    flat = n_over > 0
    small = flat & (n_over <= kg)
    big = n_over > kg
    xs_t, ys_t = jnp.asarray(xs), jnp.asarray(ys)
    # lighting may be shared ([3], []) or per env ([B, 3], [B]), e.g. when env params are randomised
    sun_all = jnp.broadcast_to(jnp.asarray(lighting.sun_dir, jnp.float32), (b, 3))
    amb_all = jnp.broadcast_to(jnp.asarray(lighting.ambient, jnp.float32), (b,))

    def cast_tiles(ids, gid, gvalid):
        """ids [K] (env*T + tile); gid [K, g] geom indices; gvalid [K, g] or None -> depth [K,P], rgb [K,P,3]."""
        env, tid = ids // n_tiles, ids % n_tiles
        x, y = xs_t[tid], ys_t[tid]  # [K, P]
        tab = jnp.transpose(tables[env[:, None], gid], (2, 1, 0))[..., None]  # [F, g, K, 1]
        t = intersect.cast(tab, x, y, cam.near)  # [g, K, P]
        if gvalid is not None:
            t = jnp.where(gvalid.T[:, :, None], t, jnp.inf)
        tmin = jnp.min(t, axis=0)
        hit = tmin <= cam.far
        depth = jnp.where(hit, tmin, 0.0)
        if not shade:
            return depth, None
        slot = jnp.argmin(t, axis=0)  # [K, P]
        g = jnp.take_along_axis(gid, slot, axis=1)  # [K, P]
        st = jnp.take(stables, (env[:, None] * n_geoms + g).reshape(-1), axis=0)  # [K*P, S] row gather
        st = st.T.reshape(st.shape[1], *depth.shape)  # [S, K, P]
        n = intersect.surface_normal(st, x, y, jnp.where(hit, tmin, 1.0))
        sun = sun_all[env].T[:, :, None]  # [3, K, 1]
        amb = amb_all[env][:, None]  # [K, 1]
        lam = jnp.maximum(n[0] * sun[0] + n[1] * sun[1] + n[2] * sun[2], 0.0)
        light = jnp.where(hit, amb + (1.0 - amb) * lam, 0.0)
        rgb = jnp.stack([st[intersect.S_RGB0 + k] * light for k in range(3)])  # [3, K, P]
        return depth, jnp.clip(rgb, 0.0, 1.0)

    def run_list(select, few: bool, bufs):
        """Cast the tiles in `select` (compacted, `chunk` per iteration) and scatter them into the image buffers."""
        count = jnp.sum(select, dtype=jnp.int32)
        order = jnp.nonzero(select, size=cap, fill_value=total)[0].astype(jnp.int32)

        def body(state):
            i, dbuf, cbuf = state
            ids = jax.lax.dynamic_slice(order, (i * chunk,), (chunk,))
            safe = jnp.minimum(ids, total - 1)
            if few:  # the (at most kg) overlapping geoms of each tile first
                ov = overlap[safe]
                gid = jnp.argsort(~ov, axis=1, stable=True)[:, :kg].astype(jnp.int32)
                gvalid = jnp.take_along_axis(ov, gid, axis=1)
            else:
                gid = jnp.broadcast_to(jnp.arange(n_geoms, dtype=jnp.int32), (chunk, n_geoms))
                gvalid = None
            depth, rgb = cast_tiles(safe, gid, gvalid)
            dbuf = dbuf.at[ids].set(depth, mode="drop")  # padding ids (== total) are dropped
            if shade:
                cbuf = cbuf.at[:, ids].set(rgb, mode="drop")
            return i + 1, dbuf, cbuf

        _, dbuf, cbuf = jax.lax.while_loop(lambda s: s[0] * chunk < count, body, (jnp.int32(0),) + bufs)
        return dbuf, cbuf

    bufs = (jnp.zeros((total, npix), jnp.float32), jnp.zeros((3, total, npix) if shade else (1, 1, 1), jnp.float32))
    bufs = run_list(small, True, bufs)
    dbuf, cbuf = run_list(big, False, bufs)
    depth = _assemble(dbuf, b, nt, tile, cam.resolution)
    hit = depth > 0.0
    if shade:
        rgb = _assemble(jnp.moveaxis(cbuf, 0, -1), b, nt, tile, cam.resolution)
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
    vmapped env step shares one compacted tile list over all its envs instead of running a batched loop per env.
    """
    return _vmappable_render(cam, bool(shade))(target, jnp.asarray(position), jnp.asarray(rotation), lighting)


@functools.lru_cache(maxsize=None)
def _vmappable_render(cam: CameraConfig, shade: bool):
    @jax.custom_batching.custom_vmap
    def render_one(target, position, rotation, lighting):
        batch = jax.tree.map(lambda a: jnp.asarray(a)[None], (target, position, rotation))
        frame = render_batch(*batch, cam, lighting, shade)
        return jax.tree.map(lambda a: a[0], frame)

    @render_one.def_vmap
    def render_many(axis_size, in_batched, target, position, rotation, lighting):
        def batched(x, is_batched):
            x = jnp.asarray(x)
            return x if is_batched else jnp.broadcast_to(x, (axis_size,) + x.shape)

        target, position, rotation = jax.tree.map(batched, (target, position, rotation), tuple(in_batched[:3]))
        lighting = jax.tree.map(batched, lighting, in_batched[3])
        frame = render_batch(target, position, rotation, cam, lighting, shade)
        return frame, jax.tree.map(lambda _: True, frame)

    return render_one
