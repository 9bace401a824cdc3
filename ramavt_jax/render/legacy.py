"""The previous renderer (kept as the benchmarks' baseline and a test reference): screen-space tile culling,
global tile compaction, chunked ray casting. `ramavt_jax.render.renderer` replaced it.

The image is cut into square tiles (8x8 pixels by default). A tile is only ray-cast when its pixel range overlaps
the exact image-plane bounding box of the target's bounding sphere. For a batch, the needed (env, tile) pairs of
all envs are compacted into one list (``jnp.nonzero`` with a static size) and processed ``chunk`` tiles at a time in
a ``lax.while_loop`` whose trip count is the number of needed tiles divided by ``chunk``: the work done scales with
the image area the targets cover, shapes stay static under jit, and there is no fallback path to fall into.
Results are gathered back into full images at the end (tiles that were not cast stay empty).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ramavt_jax.render import intersect
from ramavt_jax.render.camera import CameraConfig, Frame, Lighting
from ramavt_jax.targets import CAPSULE, CYLINDER, SPHERE, TargetModel

DEFAULT_TILE = 8
DEFAULT_CHUNK_RAYS = 4096  # rays per loop iteration when chunk is None (64 tiles: measured best of 64/256/1024)
DEFAULT_GEOMS_PER_TILE = 4  # geoms per work item (a tile with more geoms gives several items); 4 measured best of 2-8


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


def _half_extents(targets: TargetModel) -> jax.Array:
    """Half extents [..., G, 3] of each geom's bounding box in its own frame."""
    t = targets.geom_type[..., None]
    size = targets.geom_size
    r, h = size[..., 0:1], size[..., 1:2]
    radial = jnp.concatenate([r, r, h], axis=-1)
    ext = jnp.where(t == SPHERE, jnp.broadcast_to(r, size.shape), size)
    ext = jnp.where(t == CYLINDER, radial, ext)
    ext = jnp.where(t == CAPSULE, radial + jnp.concatenate([0 * r, 0 * r, r], axis=-1), ext)
    return ext


def _geom_screen_boxes(targets: TargetModel, positions, rotations, cam: CameraConfig):
    """Conservative pixel boxes (umin, umax, vmin, vmax) [B, G] of every geom and visibility [B, G].

    The box is the intersection of the projection of the geom's bounding sphere and, when all 8 corners of the
    geom's oriented bounding box lie in front of the camera, the projection of those corners (exact for boxes;
    thin panels have huge bounding spheres but small boxes).
    """
    pos = jnp.einsum("bij,bgj->bgi", rotations, targets.geom_pos) + positions[:, None, :]  # [B, G, 3]
    rot = jnp.einsum("bij,bgjk->bgik", rotations, targets.geom_mat)  # [B, G, 3, 3] camera_from_geom
    radius = jnp.where(targets.geom_mask, targets.geom_rbound, -1.0)
    umin, umax, vmin, vmax, visible = jax.vmap(jax.vmap(_projected_bounds, in_axes=(0, 0, None)), in_axes=(0, 0, None))(
        pos, radius, cam)
    ext = _half_extents(targets)  # [B, G, 3]
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], np.float32)  # [8, 3]
    off = ext[:, :, None, :] * signs  # [B, G, 8, 3] geom frame
    corners = [pos[:, :, None, i] + sum(rot[:, :, None, i, j] * off[..., j] for j in range(3)) for i in range(3)]
    cz = corners[2]
    front = jnp.min(cz, axis=-1) > 1e-3  # [B, G]
    inv_z = 1.0 / jnp.where(cz > 1e-3, cz, 1.0)
    f, c = cam.focal(), cam.centre()
    u = f * corners[0] * inv_z + c
    v = f * corners[1] * inv_z + c
    umin = jnp.where(front, jnp.maximum(umin, jnp.min(u, -1) - 1.0), umin)
    umax = jnp.where(front, jnp.minimum(umax, jnp.max(u, -1) + 1.0), umax)
    vmin = jnp.where(front, jnp.maximum(vmin, jnp.min(v, -1) - 1.0), vmin)
    vmax = jnp.where(front, jnp.minimum(vmax, jnp.max(v, -1) + 1.0), vmax)
    return umin, umax, vmin, vmax, visible & targets.geom_mask


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
    work items (a tile and up to ``geoms_per_tile`` of the geoms overlapping it) ray-cast per loop iteration;
    ``tile`` the tile side in pixels. None of them changes the result. ``shade=False`` leaves rgb at zero.
    """
    positions = jnp.asarray(positions, jnp.float32)
    rotations = jnp.asarray(rotations, jnp.float32)
    b = positions.shape[0]
    nt = -(-cam.resolution // tile)
    lo_px = np.arange(nt, dtype=np.float32) * tile
    u_rng = v_rng = np.stack([lo_px, lo_px + tile - 1], 1)  # [nt, 2] pixel range of each tile column / row
    n_tiles = nt * nt
    npix = tile * tile
    total = b * n_tiles
    if chunk is None:  # small batches must not pay for a mostly empty chunk
        chunk = max(1, min(DEFAULT_CHUNK_RAYS // npix, max(16, total // 8)))
    chunk = int(min(chunk, total))
    n_geoms = targets.geom_type.shape[-1]
    kg = int(min(geoms_per_tile, n_geoms))
    n_groups = -(-n_geoms // kg)

    tables = jax.vmap(intersect.geom_table)(targets, positions, rotations)  # [B, F, G]
    tables = jnp.moveaxis(tables, 1, 0).reshape(tables.shape[1], b * n_geoms)  # [F, B*G]
    if shade:
        stables = jax.vmap(intersect.shade_table)(targets, positions, rotations)
        stables = jnp.moveaxis(stables, 1, 0).reshape(stables.shape[1], b * n_geoms)  # [S, B*G]
    # Per (env, tile, geom): does the geom's screen box overlap the tile? (separable in u and v)
    umin, umax, vmin, vmax, visible = _geom_screen_boxes(targets, positions, rotations, cam)
    over_u = (u_rng[:, 1] >= umin[..., None]) & (u_rng[:, 0] <= umax[..., None])  # [B, G, nt]
    over_v = (v_rng[:, 1] >= vmin[..., None]) & (v_rng[:, 0] <= vmax[..., None])
    over_u = over_u & visible[..., None]
    overlap = jnp.transpose(over_v, (0, 2, 1))[:, :, None, :] & jnp.transpose(over_u, (0, 2, 1))[:, None, :, :]
    overlap = overlap.reshape(total, n_geoms)  # [B*T, G], tile = tv * nt + tu
    n_over = jnp.sum(overlap, axis=1, dtype=jnp.int32)
    # Work items: (tile, group j) for the j-th group of kg overlapping geoms; groups run in order (j = 0 first, its
    # results are set; later groups merge by depth), each group's list padded to whole chunks.
    counts = jnp.stack([jnp.sum(n_over > j * kg, dtype=jnp.int32) for j in range(n_groups)])
    n_chunks = -(-counts // chunk)
    chunk_end = jnp.cumsum(n_chunks)
    chunk_start = chunk_end - n_chunks
    orders = jnp.stack([jnp.nonzero(n_over > j * kg, size=total, fill_value=total)[0].astype(jnp.int32)
                        for j in range(n_groups)])
    orders = jnp.concatenate([orders, jnp.full((n_groups, chunk), total, jnp.int32)], axis=1)
    # lighting may be shared ([3], []) or per env ([B, 3], [B]), e.g. when env params are randomised
    sun_all = jnp.broadcast_to(jnp.asarray(lighting.sun_dir, jnp.float32), (b, 3))
    amb_all = jnp.broadcast_to(jnp.asarray(lighting.ambient, jnp.float32), (b,))
    tx0 = jnp.asarray(((np.arange(nt) * tile - cam.centre()) / cam.focal()), jnp.float32)
    pix = np.arange(npix)
    px = jnp.asarray((pix % tile) / cam.focal(), jnp.float32)
    py = jnp.asarray((pix // tile) / cam.focal(), jnp.float32)
    geom_iota = jnp.arange(n_geoms, dtype=jnp.int32)
    slot_iota = jnp.arange(kg, dtype=jnp.int32)

    def body(state):
        i, dbuf, cbuf = state
        j = jnp.sum(i >= chunk_end, dtype=jnp.int32)
        ids = jax.lax.dynamic_slice(orders, (j, (i - chunk_start[j]) * chunk), (1, chunk))[0]
        safe = jnp.minimum(ids, total - 1)
        env, tid = safe // n_tiles, safe % n_tiles
        ov = overlap[safe]  # [K, G]
        rank = jnp.cumsum(ov, axis=1, dtype=jnp.int32)
        want = j * kg + slot_iota + 1  # [kg] ranks of this group's slots
        sel = ov[:, None, :] & (rank[:, None, :] == want[None, :, None])  # [K, kg, G]
        gid = jnp.sum(jnp.where(sel, geom_iota, 0), axis=2)  # [K, kg]
        gvalid = jnp.any(sel, axis=2)
        col = env[:, None] * n_geoms + gid  # [K, kg]
        x = (tx0[tid % nt][:, None] + px)[:, None, :]  # [K, 1, P]
        y = (tx0[tid // nt][:, None] + py)[:, None, :]
        tab = jnp.take(tables, col, axis=1)[..., None]  # [F, K, kg, 1]
        t = intersect.cast(tab, x, y, cam.near)  # [K, kg, P]
        t = jnp.where(gvalid[:, :, None], t, jnp.inf)
        tmin = jnp.min(t, axis=1)  # [K, P]
        old = dbuf[safe]
        new = tmin < old
        dbuf = dbuf.at[ids].set(jnp.where(new, tmin, old), mode="drop")  # padding ids (== total) are dropped
        if shade:
            slot = jnp.argmin(t, axis=1)  # [K, P]
            win = slot[:, None, :] == slot_iota[None, :, None]  # [K, kg, P]
            st = jnp.take(stables, col, axis=1)[..., None]  # [S, K, kg, 1]
            st = jnp.sum(jnp.where(win, st, 0.0), axis=2)  # [S, K, P] features of the winning geom
            hitp = jnp.isfinite(tmin)
            n = intersect.surface_normal(st, x[:, 0], y[:, 0], jnp.where(hitp, tmin, 1.0))  # 3 x [K, P]
            sun = sun_all[env].T[:, :, None]  # [3, K, 1]
            amb = amb_all[env][:, None]
            lam = jnp.maximum(n[0] * sun[0] + n[1] * sun[1] + n[2] * sun[2], 0.0)
            light = amb + (1.0 - amb) * lam  # [K, P]
            rgb = jnp.stack([st[intersect.S_RGB0 + k] * light for k in range(3)])  # [3, K, P]
            oldc = cbuf[:, safe]
            cbuf = cbuf.at[:, ids].set(jnp.where(new, jnp.clip(rgb, 0.0, 1.0), oldc), mode="drop")
        return i + 1, dbuf, cbuf

    dbuf = jnp.full((total, npix), jnp.inf, jnp.float32)
    cbuf = jnp.zeros((3, total, npix) if shade else (1, 1, 1), jnp.float32)
    _, dbuf, cbuf = jax.lax.while_loop(lambda s: s[0] < chunk_end[-1], body, (jnp.int32(0), dbuf, cbuf))
    depth = _assemble(dbuf, b, nt, tile, cam.resolution)
    hit = depth <= cam.far
    depth = jnp.where(hit, depth, 0.0)
    if shade:
        rgb = _assemble(jnp.moveaxis(cbuf, 0, -1), b, nt, tile, cam.resolution)
        rgb = jnp.where(hit[..., None], rgb, 0.0)
    else:
        rgb = jnp.zeros(depth.shape + (3,), jnp.float32)
    return Frame(depth=depth, rgb=rgb, hit=hit)
