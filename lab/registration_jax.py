"""lab/centre_registration.py's estimator as pure JAX functions, so that it runs inside a compiled flight (vmapped
over episodes, scanned over steps) and can be flown on every ground with the package's evaluation:

    python -m lab.registration_jax --targets val --episodes 20 --out lab/results/centre/jax_val.json

Status: it follows the numpy estimator (lab/tests/test_registration_jax.py: within 2 cm on a synthetic tumble), and
on the first 300 steps of one episode per validation target at 64x64 it missed by 0.20 m where the numpy one missed
by 0.19 (0.46 against 0.09 on Capsule-val0, 0.18 against 0.48 on Satellite-val0). Its brute-force matching costs
about 0.2 s per episode step on the 2-core CPU (377 s for those 1,800 steps): a flight of the 120 validation
episodes would take hours there, so none was flown with it; it is meant for a GPU.

Changes from the numpy estimator, all for the compiler: each frame's target pixels are compacted into MAX_POINTS
slots, and ICP finds each point's nearest neighbour by brute force over them instead of a k-d tree, for a fixed
number of iterations; the centre's reweighted least squares solves 6x6 normal equations. (Projective association,
each point matched to the pixel it projects onto, was tried first: on the first 300 steps of one episode per
validation target it missed by 0.25-0.45 m where the k-d tree's estimate missed by 0.19, its matches sliding along
the capsule's and the satellite's surfaces.)
State (RegState) holds the last frames, their chained poses and the registered pairs of the last `window` steps.

`registration_policy` is the `mpc` planner told the estimate (lab/registration_flight.py's `registration` arm):
it reads the newest depth frame and the chaser's own displacement since the episode's start (odometry; exact
without actuator noise), and, like the ceiling, the env's noise-free model for everything else.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import jax
import jax.numpy as jnp
from flax import struct

from lab.centre_registration import DT, FITTED_DEPTH_PRIOR, Settings
from ramavt_jax import baselines
from ramavt_jax import env as env_lib
from ramavt_jax.baselines import Policy
from ramavt_jax.evaluation import rollouts, tables
from ramavt_jax.render.camera import camera_rays

HILL_FROM_CAM = jnp.asarray(env_lib.HILL_FROM_CAM)
MAX_POINTS = 1024  # target pixels kept per frame (the validation targets show at most about 720 at 64x64)  # the last half of the ICP iterations match within a quarter of Settings.trim


@struct.dataclass
class RegState:
    """One episode's estimator state. K = the longest baseline + 1 frames kept, W = the window's steps, B baselines."""

    points: jax.Array  # [K, M, 3] world points of the kept frames' target pixels, compacted (ring: step % K)
    hit: jax.Array  # [K, M] bool: which of the M slots hold a point
    enough: jax.Array  # [K] bool: the frame had enough target pixels to register
    poses: jax.Array  # [K, 4, 4] chained: world points of step 0 to that step
    last: jax.Array  # [4, 4] the latest consecutive motion (the next one's start)
    pair_rot: jax.Array  # [B, W, 3, 3] registered pairs ending in the last W steps (ring: step % W)
    pair_trans: jax.Array  # [B, W, 3]
    pair_end: jax.Array  # [B, W] int32: the step each pair ends at
    pair_ok: jax.Array  # [B, W] bool
    step: jax.Array  # [] int32: the step of the newest frame (-1 before any)
    centre: jax.Array  # [3] world frame
    velocity: jax.Array  # [3]


def initial_state(settings: Settings, resolution: int) -> RegState:
    keep, window, count = max(settings.baselines) + 1, settings.window, len(settings.baselines)
    eye = jnp.eye(4)
    return RegState(
        points=jnp.zeros((keep, MAX_POINTS, 3)),
        hit=jnp.zeros((keep, MAX_POINTS), bool),
        enough=jnp.zeros(keep, bool),
        poses=jnp.broadcast_to(eye, (keep, 4, 4)),
        last=eye,
        pair_rot=jnp.broadcast_to(jnp.eye(3), (count, window, 3, 3)),
        pair_trans=jnp.zeros((count, window, 3)),
        pair_end=jnp.zeros((count, window), jnp.int32),
        pair_ok=jnp.zeros((count, window), bool),
        step=jnp.asarray(-1, jnp.int32),
        centre=jnp.full(3, jnp.nan),
        velocity=jnp.zeros(3),
    )


def surface(depth: jax.Array, rays: jax.Array, jump: float):
    """Of a z-depth frame [H, W] (0 where nothing is hit): (points [H, W, 3] camera frame, hit [H, W], normals
    [H, W, 3], smooth [H, W]: the normal is taken from four hit neighbours without a jump over ``jump``)."""
    grid = depth[..., None] * rays
    hit = depth > 0
    pad_grid = jnp.pad(grid, ((1, 1), (1, 1), (0, 0)))
    pad_hit, pad_depth = jnp.pad(hit, 1), jnp.pad(depth, 1)
    normal = jnp.cross(pad_grid[1:-1, 2:] - pad_grid[1:-1, :-2], pad_grid[2:, 1:-1] - pad_grid[:-2, 1:-1])
    normal = normal / jnp.maximum(jnp.linalg.norm(normal, axis=-1, keepdims=True), 1e-12)
    smooth = hit & pad_hit[1:-1, 2:] & pad_hit[1:-1, :-2] & pad_hit[2:, 1:-1] & pad_hit[:-2, 1:-1]
    smooth &= jnp.abs(pad_depth[1:-1, 2:] - pad_depth[1:-1, :-2]) < jump
    smooth &= jnp.abs(pad_depth[2:, 1:-1] - pad_depth[:-2, 1:-1]) < jump
    return grid, hit, normal, smooth


def compact(grid, hit, normal, smooth):
    """The target pixels of a frame as MAX_POINTS slots: (points [M, 3], used [M], normals [M, 3], smooth [M])."""
    (idx,) = jnp.nonzero(hit.reshape(-1), size=MAX_POINTS, fill_value=0)
    used = jnp.arange(MAX_POINTS) < hit.sum()
    take = lambda x: x.reshape(-1, x.shape[-1])[idx] if x.ndim == 3 else x.reshape(-1)[idx]  # noqa: E731
    return take(grid), used, take(normal), take(smooth) & used


def _rotvec(w: jax.Array) -> jax.Array:
    angle = jnp.linalg.norm(w)
    k = w / jnp.maximum(angle, 1e-12)
    cross = jnp.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return jnp.eye(3) + jnp.sin(angle) * cross + (1 - jnp.cos(angle)) * cross @ cross


def icp(source, source_used, dest, dest_used, dest_normal, dest_smooth, start, settings: Settings):
    """Point-to-plane ICP of world points source [M, 3] (where source_used) onto world points dest [M, 3] (normals,
    smooth: the numpy estimator's NaN normals), each matched to its nearest destination point (brute force over
    the M slots), from ``start`` [4, 4]. Returns (motion [4, 4], rms [] m, matched [] count)."""
    pivot = jnp.sum(jnp.where(dest_used[:, None], dest, 0.0), 0) / jnp.maximum(dest_used.sum(), 1)
    p, dest = source - pivot, dest - pivot  # about the points: a well-conditioned small-angle step
    start = start.at[:3, 3].set(start[:3, :3] @ pivot + start[:3, 3] - pivot)
    dest_sq = jnp.where(dest_used, jnp.sum(dest * dest, -1), jnp.inf)

    def match(motion):
        q = p @ motion[:3, :3].T + motion[:3, 3]
        gap = jnp.sum(q * q, -1)[:, None] + dest_sq[None, :] - 2.0 * q @ dest.T  # [M, M] squared distances
        idx = jnp.argmin(gap, axis=1)
        dist = jnp.sqrt(jnp.maximum(jnp.take_along_axis(gap, idx[:, None], 1)[:, 0], 0.0))
        ok = source_used & (dist < settings.trim) & dest_smooth[idx]
        return q, dest[idx], dest_normal[idx], ok

    def body(_, motion):
        q, d, n, ok = match(motion)
        design = jnp.concatenate([jnp.cross(q, n), n], axis=1) * ok[:, None]
        residual = jnp.sum((d - q) * n, axis=1) * ok
        step = jnp.linalg.lstsq(design, residual)[0]  # minimum norm, as the numpy estimator's
        turn = _rotvec(step[:3])
        return jnp.eye(4).at[:3, :3].set(turn @ motion[:3, :3]).at[:3, 3].set(turn @ motion[:3, 3] + step[3:])

    motion = jax.lax.fori_loop(0, settings.iters, body, start)
    q, d, n, ok = match(motion)
    count = ok.sum()
    rms = jnp.sqrt(jnp.sum(jnp.where(ok, jnp.sum((d - q) * n, axis=1) ** 2, 0.0)) / jnp.maximum(count, 1))
    world = motion.at[:3, 3].set(motion[:3, 3] + pivot - motion[:3, :3] @ pivot)  # back from about the pivot
    return world, rms, count


def solve_centre(state: RegState, prior: jax.Array, settings: Settings):
    """(centre, velocity) now by reweighted least squares over the kept pairs (centre_registration's _solve)."""
    eye = jnp.eye(3)
    rot, trans = state.pair_rot.reshape(-1, 3, 3), state.pair_trans.reshape(-1, 3)
    ok = state.pair_ok.reshape(-1)
    baseline = jnp.repeat(jnp.asarray(settings.baselines), settings.window)
    turn = eye - rot
    start_age = ((state.step - (state.pair_end.reshape(-1) - baseline)) * DT)[:, None, None]
    design = jnp.concatenate([turn, baseline[:, None, None] * DT * eye - start_age * turn], axis=2)  # [P, 3, 6]
    prior_rows = jnp.concatenate([settings.pull * eye, jnp.zeros((3, 3))], axis=1)

    def weighted_solve(weight):  # [P] squared row weights -> [6] (centre, velocity)
        normal = jnp.einsum("p,pki,pkj->ij", weight, design, design) + prior_rows.T @ prior_rows
        right = jnp.einsum("p,pki,pk->i", weight, design, trans) + prior_rows.T @ (settings.pull * prior)
        return jnp.linalg.solve(normal, right)

    def reweighted(_, solution):
        residual = jnp.linalg.norm(jnp.einsum("pij,j->pi", design, solution) - trans, axis=1)
        return weighted_solve(jnp.where(ok, jnp.minimum(1.0, settings.huber / jnp.maximum(residual, 1e-9)), 0.0))

    # the first round weighs every pair 1 (as the numpy solve's), then rounds reweight from the last solution
    solution = jax.lax.fori_loop(0, settings.rounds - 1, reweighted, weighted_solve(ok.astype(design.dtype)))
    solution = jnp.where(ok.any(), solution, jnp.concatenate([prior, jnp.zeros(3)]))
    return solution[:3], solution[3:]


def update(state: RegState, depth: jax.Array, chaser: jax.Array, camera, settings: Settings) -> RegState:
    """One step of the estimator: depth [H, W] (m / k), chaser [3] (the chaser's displacement since the start,
    camera axes, m / k). The estimate is state.centre, state.velocity (world frame)."""
    rays = camera_rays(camera)
    keep = max(settings.baselines) + 1
    step = state.step + 1
    grid, hit, normal, smooth = surface(depth, rays, settings.jump)
    enough = hit.sum() >= settings.min_points
    points, used, normals, smooth_c = compact(grid, hit, normal, smooth)
    world = points + chaser
    prev = (step - 1) % keep

    def register(src, start):
        return icp(state.points[src], state.hit[src], world, used, normals, smooth_c, start, settings)

    consecutive, rms, matched = register(prev, state.last)
    good = enough & state.enough[prev] & (step > 0) & (matched >= settings.min_points)
    last = jnp.where(good, consecutive, state.last)
    pose = jnp.where(step > 0, last @ state.poses[prev], jnp.eye(4))
    slot = step % keep
    state = state.replace(
        points=state.points.at[slot].set(world),
        hit=state.hit.at[slot].set(used),
        enough=state.enough.at[slot].set(enough),
        poses=state.poses.at[slot].set(pose),
        last=last,
        step=step,
    )
    ring = step % settings.window
    for b, k in enumerate(settings.baselines):
        src = (step - k) % keep
        motion, rms, matched = register(src, pose @ jnp.linalg.inv(state.poses[src]))
        ok = enough & state.enough[src] & (step >= k) & (matched >= settings.min_points) & (rms < settings.max_rms)
        state = state.replace(
            pair_rot=state.pair_rot.at[b, ring].set(motion[:3, :3]),
            pair_trans=state.pair_trans.at[b, ring].set(motion[:3, 3]),
            pair_end=state.pair_end.at[b, ring].set(step),
            pair_ok=state.pair_ok.at[b, ring].set(ok),
        )
    count = jnp.maximum(hit.sum(), 1)
    centroid = jnp.sum(jnp.where(hit[..., None], grid, 0.0), axis=(0, 1)) / count
    deepest = jnp.max(jnp.where(hit, grid[..., 2], -jnp.inf))
    prior = centroid.at[2].add(settings.depth_offset + settings.depth_gain * (deepest - centroid[2])) + chaser
    centre, velocity = solve_centre(state, prior, settings)
    moved_on = state.centre + state.velocity * DT  # a frame without enough target: the last estimate, moved on
    return state.replace(
        centre=jnp.where(enough, centre, moved_on), velocity=jnp.where(enough, velocity, state.velocity)
    )


@struct.dataclass
class PolicyState:
    estimator: RegState
    start: jax.Array  # [3] the chaser's Hill position at the episode's start


def registration_policy(camera, settings: Settings = Settings()) -> Policy:
    """The `mpc` planner told the registration's centre and velocity (module docstring)."""
    planner = baselines.make_policy("mpc", camera)

    def init(key):
        return PolicyState(estimator=initial_state(settings, camera.resolution), start=jnp.full(3, jnp.nan))

    def act(key, pstate, obs, env_state, params):
        start = jnp.where(jnp.isnan(pstate.start), env_state.chaser_pos, pstate.start)
        scale = env_state.scale  # frames show the target at 1 / k: the estimator works in m / k
        moved = HILL_FROM_CAM.T @ (env_state.chaser_pos - start) / scale
        estimator = update(pstate.estimator, obs[..., -1] * camera.far, moved, camera, settings)
        centre_cam = jnp.where(jnp.isnan(estimator.centre), params.desired_pos, estimator.centre - moved) * scale
        told = env_state.replace(
            target_pos=env_state.chaser_pos + HILL_FROM_CAM @ centre_cam,
            target_vel=HILL_FROM_CAM @ (estimator.velocity * scale),
        )
        action, _ = planner.act(key, planner.init(key), obs, told, params)
        return action, PolicyState(estimator=estimator, start=start)

    return Policy("registration", init, act)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--targets", default="val")
    ap.add_argument("--episodes", type=int, default=20, help="per target")
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--resolution", type=int, default=64)
    ap.add_argument("--setting", default="none", help="a Table II setting: " + ", ".join(rollouts.PERTURBATIONS))
    ap.add_argument("--depth-prior", type=float, nargs=2, default=FITTED_DEPTH_PRIOR, metavar=("OFFSET", "GAIN"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    names = rollouts.resolve_targets(args.targets)
    camera = env_lib.CameraConfig(resolution=args.resolution)
    settings = Settings(depth_offset=args.depth_prior[0], depth_gain=args.depth_prior[1])
    tracking_env = tables.suite_env(env_lib.EnvConfig(camera=camera), names, rollouts.PERTURBATION_VALUES)
    result = tables.evaluate_setting(
        tracking_env,
        registration_policy(camera, settings),
        {},
        args.episodes,
        args.steps,
        jax.random.PRNGKey(args.seed),
        args.setting,
        rollouts.PERTURBATION_VALUES,
    )
    overall = result["overall"]
    print(
        f"registration: AER {overall['return_mean']:+.1f}, AEL {overall['length_mean']:.1f}, lost {overall['lost_fraction']:.1%}"
    )
    for target, summary in result["per_target"].items():
        print(f"  {target}: {summary['return_mean']:+.1f}")
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        settings_dict = dataclasses.asdict(settings)
        args.out.write_text(
            json.dumps({"command": vars(args) | {"out": str(args.out)}, "settings": settings_dict, **result}, indent=1)
        )


if __name__ == "__main__":
    main()
