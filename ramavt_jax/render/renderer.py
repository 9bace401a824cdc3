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
DEFAULT_CHUNK_RAYS = 16384  # rays per loop iteration when chunk is None


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


@functools.partial(jax.jit, static_argnames=("cam", "shade", "chunk", "tile"))
def render_batch(
    targets: TargetModel,
    positions: jax.Array,
    rotations: jax.Array,
    cam: CameraConfig,
    lighting: Lighting,
    shade: bool = True,
    chunk: int | None = None,
    tile: int = DEFAULT_TILE,
) -> Frame:
    """Render B targets at once: targets with leading [B], positions [B, 3], rotations [B, 3, 3] -> Frame [B, ...].

    position = target centre of mass in the camera frame; rotation = camera_from_body. ``chunk`` is the number of
    tiles ray-cast per loop iteration (default: about 16k rays); ``tile`` the tile side in pixels. Neither changes
    the result. ``shade=False`` leaves rgb at zero.
    """
    positions = jnp.asarray(positions, jnp.float32)
    rotations = jnp.asarray(rotations, jnp.float32)
    b = positions.shape[0]
    nt, xs, ys, u_rng, v_rng = _tile_layout(cam, tile)
    n_tiles = nt * nt
    npix = tile * tile
    total = b * n_tiles
    if chunk is None:
        chunk = max(1, DEFAULT_CHUNK_RAYS // npix)
    chunk = int(min(chunk, total))
    n_chunks = -(-total // chunk)
    cap = n_chunks * chunk

    tables = jax.vmap(intersect.geom_table)(targets, positions, rotations)  # [B, F, G]
    if shade:
        stables = jax.vmap(intersect.shade_table)(targets, positions, rotations)  # [B, S, G]
    radius = jnp.broadcast_to(targets.bound_radius, (b,))
    need = jax.vmap(_tile_mask, in_axes=(0, 0, None, None, None))(positions, radius, cam, u_rng, v_rng)
    flat = need.reshape(-1)
    count = jnp.sum(flat, dtype=jnp.int32)
    order = jnp.nonzero(flat, size=cap, fill_value=0)[0].astype(jnp.int32)
    xs_t, ys_t = jnp.asarray(xs), jnp.asarray(ys)
    sun = jnp.asarray(lighting.sun_dir, jnp.float32)
    amb = jnp.asarray(lighting.ambient, jnp.float32)

    def body(state):
        i, dbuf, cbuf = state
        start = i * chunk
        ids = jax.lax.dynamic_slice(order, (start,), (chunk,))
        env, tid = ids // n_tiles, ids % n_tiles
        x, y = xs_t[tid], ys_t[tid]  # [K, P]
        tab = jnp.transpose(tables[env], (1, 2, 0))[..., None]  # [F, G, K, 1]
        t = intersect.cast(tab, x, y, cam.near)  # [G, K, P]
        tmin = jnp.min(t, axis=0)
        hit = tmin <= cam.far
        depth = jnp.where(hit, tmin, 0.0)
        dbuf = jax.lax.dynamic_update_slice(dbuf, depth, (start, 0))
        if shade:
            g = jnp.argmin(t, axis=0)  # [K, P]
            st = jnp.take_along_axis(stables[env], g[:, None, :], axis=2)  # [K, S, P]
            st = jnp.moveaxis(st, 1, 0)  # [S, K, P]
            n = intersect.surface_normal(st, x, y, jnp.where(hit, tmin, 1.0))
            lam = jnp.maximum(n[0] * sun[0] + n[1] * sun[1] + n[2] * sun[2], 0.0)
            light = jnp.where(hit, amb + (1.0 - amb) * lam, 0.0)
            rgb = jnp.stack([st[intersect.S_RGB0 + k] * light for k in range(3)], axis=-1)  # [K, P, 3]
            cbuf = jax.lax.dynamic_update_slice(cbuf, jnp.clip(rgb, 0.0, 1.0), (start, 0, 0))
        return i + 1, dbuf, cbuf

    dbuf = jnp.zeros((cap + 1, npix), jnp.float32)
    cbuf = jnp.zeros((cap + 1, npix, 3) if shade else (1, 1, 3), jnp.float32)
    _, dbuf, cbuf = jax.lax.while_loop(lambda s: s[0] * chunk < count, body, (jnp.int32(0), dbuf, cbuf))

    slot = jnp.where(flat, jnp.cumsum(flat, dtype=jnp.int32) - 1, cap)  # compacted position, or the empty row
    depth = _assemble(dbuf[slot], b, nt, tile, cam.resolution)
    hit = depth > 0.0
    if shade:
        rgb = _assemble(cbuf[slot], b, nt, tile, cam.resolution)
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

    Jit- and vmap-able; for many envs call `render_batch`, which shares one compacted tile list over the batch.
    """
    batch = jax.tree.map(lambda a: jnp.asarray(a)[None], target)
    frame = render_batch(batch, jnp.asarray(position)[None], jnp.asarray(rotation)[None], cam, lighting, shade)
    return jax.tree.map(lambda a: a[0], frame)
