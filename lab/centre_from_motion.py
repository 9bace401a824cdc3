"""Can the centre of mass be found from the frames' motion, without learning? Geometric estimates, no network,
on the episodes lab/centre_estimator.py scores its fits on (the validation targets, 4 episodes each, the same
behaviour and seed):

    python lab/centre_from_motion.py --out results/val/centre_from_motion.json

1. The rigid motion between two depth frames (range flow). A surface point X of a rigid body moves at
   V(X) = a + w x X (camera frame, w the spin, a the velocity of the body point at the camera's origin). Where the
   surface is smooth, the z depth d of a fixed pixel with ray r (z component 1) and unit surface normal n changes
   at d' (n . r) = n . V(X) = n . a + (X x n) . w: one linear equation per pixel in the six unknowns (a, w),
   solved by least squares over the target's pixels (those whose four neighbours are hit too, with no depth jump
   over `--jump` m), in one frame pair or summed over `--spin-windows` pairs (the chaser's own velocity, known from
   its commands, taken out of a, which is then held fixed over the window). The spin is what tells where the centre
   is (a = v - w x c, v the centre's velocity): an estimate of the centre from the frames' motion can be no better
   than the spin it is built on. Reported: the spin's error relative to its size, against the true spin.
2. The visible surface's centroid averaged over time (a polynomial of `--degree` fitted to the last `--windows`
   steps, evaluated at the newest). The chaser's own displacement, dead-reckoned from its commands (exact here: no
   actuator noise, no lag), is added before the fit and taken out after, so that what is averaged moves like the
   target alone. If the target turned through a large angle within the window, the centroid's offset from the
   centre, fixed in the body, would turn with it and average out; reported as errors in m / k as the fits'.
   `reference: episode mean` is what an even average over a whole episode would leave: each episode's offset
   averaged over all its steps (after `--skip`), with the true track (non-causal; a fit that weights steps
   unequally may fall below it).
3. The centre from the flow's motions (`centre from flow`): with a + v_chaser = v - w x c at each of the last
   `--centre-window` pairs (each motion from `--centre-pairs` pairs), least squares in the centre and the target's
   velocity, the centre moving at that velocity less the chaser's dead-reckoned displacement, and pulled toward the
   visible centroid with weight `--pull` (the centre's component along an unchanging spin is not seen otherwise).
   The estimate at a step uses the frames up to it only.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import numpy as np

from lab.centre_estimator import (
    DESIRED,
    collect,
    errors_by_target,
    print_errors,
    visible_centroid,
    write_results,
)
from ramavt_jax import env as env_lib
from ramavt_jax.evaluation import rollouts
from ramavt_jax.render.camera import camera_rays


def flow_rows(depth0: np.ndarray, depth1: np.ndarray, rays: np.ndarray, dt: float, jump: float):
    """The rigid-motion equation of each inner pixel between z-depth frames depth0, depth1 [N, H, W] (m, 0 where
    nothing is hit), rays [H, W, 3] (camera_rays). Returns rows [N, H-2, W-2, 6] (n, X x n), rhs [N, H-2, W-2]
    (d' (n . r)) and valid [N, H-2, W-2] bool (hit in both frames with its four neighbours, no jump over ``jump``)."""
    hit = (depth0 > 0) & (depth1 > 0)
    mid = 0.5 * (depth0 + depth1)
    points = mid[..., None] * rays  # [N, H, W, 3]: the surface between the two frames
    inner = (slice(None), slice(1, -1), slice(1, -1))
    right, left, down, up = (
        (slice(None), slice(1, -1), slice(2, None)),
        (slice(None), slice(1, -1), slice(None, -2)),
        (slice(None), slice(2, None), slice(1, -1)),
        (slice(None), slice(None, -2), slice(1, -1)),
    )
    normal = np.cross(points[right] - points[left], points[down] - points[up])
    normal /= np.maximum(np.linalg.norm(normal, axis=-1, keepdims=True), 1e-12)
    valid = hit[inner] & hit[right] & hit[left] & hit[down] & hit[up]
    valid &= (np.abs(mid[right] - mid[left]) < jump) & (np.abs(mid[down] - mid[up]) < jump)
    valid &= np.abs(depth1 - depth0)[inner] < jump  # a silhouette edge passing the pixel is not a smooth motion
    rows = np.concatenate([normal, np.cross(points[inner], normal)], axis=-1)
    rhs = (depth1 - depth0)[inner] / dt * np.sum(normal * rays[1:-1, 1:-1], axis=-1)
    return rows, rhs, valid


def rigid_motion(rows, rhs, valid, chaser_velocity: np.ndarray, window: int = 1, min_pixels: int = 30) -> np.ndarray:
    """[N, 6] (a + chaser velocity, w) of each frame pair by least squares over its last ``window`` pairs (the
    target's own motion, held fixed over them), from flow_rows' [N, ...] of consecutive pairs; chaser_velocity
    [N, 3] the chaser's mean velocity over each pair (camera frame; the body's points seen to move against it).
    NaN where fewer than ``min_pixels`` valid rows (summed over the window) or a singular system."""
    weight = valid[..., None].astype(np.float64)
    rhs = rhs + np.einsum("nhwi,ni->nhw", rows[..., :3], chaser_velocity)  # n . (a + v_chaser): the target's part
    normal = np.einsum("nhwi,nhwj->nij", rows * weight, rows)
    right = np.einsum("nhwi,nhw->ni", rows * weight, rhs)
    normal, right, count = (_trailing_sum(x, window) for x in (normal, right, valid.sum(axis=(1, 2))))
    solvable = (count >= min_pixels) & (np.linalg.cond(normal) < 1e8)
    out = np.full(right.shape, np.nan)
    out[solvable] = np.linalg.solve(normal[solvable], right[solvable][..., None])[..., 0]
    return out


def _trailing_sum(x: np.ndarray, window: int) -> np.ndarray:
    """Sums over the last ``window`` entries along axis 0 (fewer at the start): causal."""
    total = np.cumsum(x, axis=0)
    total[window:] = total[window:] - total[:-window]
    return total


def chaser_track(action: np.ndarray, speed: float = 1.0, dt: float = 0.1):
    """Dead reckoning from the commands (no lag, no actuator noise), action [E, T] taken after each obs. Returns
    (velocity [E, T, 3] the chaser's mean over the step after each obs, position [E, T, 3] at each obs relative to
    the first), camera frame, m/s and m: the env's trapezoidal update of a velocity that jumps to each command."""
    command = env_lib.ACTIONS[action] * speed
    before = np.concatenate([np.zeros_like(command[:, :1]), command[:, :-1]], axis=1)
    velocity = 0.5 * (before + command)
    position = np.concatenate([np.zeros_like(velocity[:, :1]), np.cumsum(velocity * dt, axis=1)[:, :-1]], axis=1)
    return velocity, position


def fitted_track(points: np.ndarray, window: int, degree: int, dt: float = 0.1) -> np.ndarray:
    """[T, 3] at each step the value at that step of a polynomial of ``degree`` fitted by least squares to the last
    ``window`` points [T, 3] (NaN rows skipped); NaN where fewer than degree + 2 points."""
    out = np.full(points.shape, np.nan)
    for t in range(len(points)):
        span = np.arange(max(0, t - window + 1), t + 1)
        ok = ~np.isnan(points[span, 0])
        if ok.sum() >= degree + 2:
            design = np.vander((span[ok] - t) * dt, degree + 1)
            out[t] = np.linalg.lstsq(design, points[span[ok]], rcond=None)[0][-1]
    return out


def _cross_matrix(w: np.ndarray) -> np.ndarray:
    """[3, 3] the matrix of w x (.)."""
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def centre_from_flow(
    motion: np.ndarray,
    chaser_position: np.ndarray,
    centroid: np.ndarray,
    window: int,
    pull: float,
    dt: float = 0.1,
    skip: int = 0,
) -> np.ndarray:
    """[T, 3] the centre (camera frame, m) at each step t >= ``skip`` from rigid_motion's [T-1, 6] (a + chaser
    velocity, w) of the ``window`` pairs that end by obs t (pairs t - window .. t - 1; a motion summed over several
    pairs is placed at its last pair, a lag of a few steps that the slowly turning spin hardly notices): least
    squares in the centre c_t and the target's velocity v, with the centre at pair s at c_t + v (s - t) dt minus the
    chaser's displacement since (chaser_position [T, 3]), and a + v_chaser = v - w x c there. The component of c
    along an unchanging spin is not observable this way, so each estimate is also pulled toward that step's visible
    centroid [T, 3] (NaN: none) with weight ``pull``."""
    out = np.full(centroid.shape, np.nan)
    for t in range(skip, len(centroid)):
        pairs = [s for s in range(max(0, t - window), t) if not np.isnan(motion[s, 0])]  # seen by obs t
        if len(pairs) < 5:
            continue
        design, target = [], []
        for s in pairs:
            spin = _cross_matrix(motion[s, 3:])
            design.append(np.hstack([-spin, np.eye(3) - (s - t) * dt * spin]))
            target.append(motion[s, :3] - np.cross(motion[s, 3:], chaser_position[s] - chaser_position[t]))
        if pull > 0 and not np.isnan(centroid[t, 0]):
            design.append(np.hstack([pull * np.eye(3), np.zeros((3, 3))]))
            target.append(pull * centroid[t])
        out[t] = np.linalg.lstsq(np.vstack(design), np.concatenate(target), rcond=None)[0][:3]
    return out


def spin_errors(episodes, names, camera, windows, skip: int, jump: float, dt: float = 0.1) -> dict:
    """{'pairs W': {target: {'spin', 'error', 'relative', 'solved', 'pixels'}}}: medians over the live pairs after
    ``skip`` of the true spin (rad/s; at the pair, while a motion summed over W pairs is of the W pairs up to it),
    the estimate's error (rad/s) and that error over the spin, the share of pairs with an estimate, and the median
    number of the target's pixels in a frame, for each window of ``windows``."""
    rays = np.asarray(camera_rays(camera), np.float64)
    velocity, _ = chaser_track(np.asarray(episodes.action), dt=dt)
    motion, alive = np.asarray(episodes.motion, np.float64), np.asarray(episodes.alive)
    target = np.asarray(episodes.target)
    errors, spins, pixels = {window: [] for window in windows}, [], []
    for e in range(len(target)):
        depth = np.asarray(episodes.obs[e, ..., -1], np.float64) * camera.far
        flow = flow_rows(depth[:-1], depth[1:], rays, dt, jump)  # once per episode, for every window
        true = 0.5 * (motion[e, :-1, :3] + motion[e, 1:, :3])  # the spin midway through each pair
        live = alive[e, 1:].copy()
        live[:skip] = False
        for window in windows:
            estimate = rigid_motion(*flow, velocity[e, :-1], window)[:, 3:]
            errors[window].append(np.linalg.norm(estimate - true, axis=-1)[live])
        spins.append(np.linalg.norm(true, axis=-1)[live])
        pixels.append((depth[1:] > 0).sum(axis=(1, 2))[live])
    table = {}
    for window in windows:
        for i, name in enumerate(names):
            pick = np.nonzero(target == i)[0]
            error = np.concatenate([errors[window][e] for e in pick])
            spin = np.concatenate([spins[e] for e in pick])
            ok = ~np.isnan(error)
            table.setdefault(f"pairs {window}", {})[name] = {
                "spin": float(np.median(spin)),
                "error": float(np.median(error[ok])) if ok.any() else None,
                "relative": float(np.median(error[ok] / spin[ok])) if ok.any() else None,
                "solved": float(ok.mean()),
                "pixels": float(np.median(np.concatenate([pixels[e] for e in pick]))),
            }
    return table


def flow_centre(
    episodes, camera, pairs: int, window: int, pull: float, skip: int, jump: float, dt: float = 0.1
) -> np.ndarray:
    """[E, T, 3] centre_from_flow's error estimate (stand-off distances, as Episodes.label), on rigid_motion over
    ``pairs`` frame pairs."""
    rays = np.asarray(camera_rays(camera), np.float64)
    velocity, position = chaser_track(np.asarray(episodes.action), dt=dt)
    centroid = visible_centroid(episodes, camera) * DESIRED[2] + DESIRED
    out = np.full(centroid.shape, np.nan)
    for e in range(centroid.shape[0]):
        depth = np.asarray(episodes.obs[e, ..., -1], np.float64) * camera.far
        motion = rigid_motion(*flow_rows(depth[:-1], depth[1:], rays, dt, jump), velocity[e, :-1], pairs)
        out[e] = centre_from_flow(motion, position[e], centroid[e], window, pull, dt, skip)
    return (out - DESIRED) / DESIRED[2]


def averaged_centroid(episodes, camera, window: int, degree: int, dt: float = 0.1) -> np.ndarray:
    """[E, T, 3] the time-averaged visible centroid's error estimate (stand-off distances, as Episodes.label):
    the chaser's dead-reckoned position added to each frame's centroid, fitted_track, the position taken out."""
    centroid = visible_centroid(episodes, camera) * DESIRED[2] + DESIRED  # m, NaN on blank frames
    _, position = chaser_track(np.asarray(episodes.action), dt=dt)
    track = np.stack([fitted_track(c, window, degree, dt) for c in centroid + position])
    return (track - position - DESIRED) / DESIRED[2]


def episode_mean_offset(episodes, camera, skip: int) -> np.ndarray:
    """[E, T, 3] a reference for averages of the centroid, not an estimate: the true error plus the centroid's offset
    from the centre averaged over the whole episode after ``skip`` (non-causal, and with the true track)."""
    offset = visible_centroid(episodes, camera) - np.asarray(episodes.label)
    live = np.asarray(episodes.alive).copy()
    live[:, :skip] = False
    offset = np.where(live[..., None], offset, np.nan)
    return np.asarray(episodes.label) + np.nanmean(offset, axis=1, keepdims=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--spin-windows", type=int, nargs="*", default=[1, 10], help="frame pairs per spin estimate")
    ap.add_argument("--windows", type=int, nargs="*", default=[50, 200], help="steps of each centroid average")
    ap.add_argument("--degree", type=int, default=2, help="of the polynomial fitted to the centroid's track")
    ap.add_argument("--centre-pairs", type=int, default=10, help="frame pairs per motion of the centre from flow")
    ap.add_argument("--centre-window", type=int, default=50, help="steps of motions per centre from flow; 0: none")
    ap.add_argument("--pull", type=float, default=0.1, help="weight of the visible centroid in the centre from flow")
    ap.add_argument("--jump", type=float, default=0.6, help="m: a larger depth step is an edge, not a surface")
    ap.add_argument("--val-episodes", type=int, default=4, help="per evaluated target")
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--skip", type=int, default=100, help="steps left out (the approach)")
    ap.add_argument(
        "--eval-targets",
        default="val",
        help="a split or names, as `ramavt eval` takes; targets at stand-off scale k = 1 (the catalogue's:"
        " the desired point 5 m ahead and 1 m/s commands are assumed)",
    )
    ap.add_argument("--resolution", type=int, default=32)
    ap.add_argument("--seed", type=int, default=0, help="the recorded episodes' draw (centre_estimator's)")
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    if (
        min(args.spin_windows + args.windows + [args.centre_pairs], default=1) < 1
        or args.centre_window < 0
        or args.degree < 0
        or args.pull < 0
        or args.skip >= args.steps
    ):
        ap.error("windows and --centre-pairs must be >= 1, --centre-window, --degree and --pull >= 0, --skip < --steps")
    try:
        names = rollouts.resolve_targets(args.eval_targets)
    except ValueError as e:
        ap.error(f"--eval-targets: {e}")
    camera = env_lib.CameraConfig(resolution=args.resolution)
    # the key centre_estimator records its validation episodes with: the same episodes as its fits
    episodes = collect(
        names, args.val_episodes, args.steps, jax.random.fold_in(jax.random.PRNGKey(args.seed), 1), camera
    )
    spin = spin_errors(episodes, names, camera, args.spin_windows, args.skip, args.jump)
    print(f"{'spin from range flow':24s} {'error / spin':>12s} {'solved':>7s}   per target: error / spin (spin rad/s)")
    for name, table in spin.items():
        rel = [t["relative"] for t in table.values() if t["relative"] is not None]
        print(
            f"{name:24s} {np.mean(rel):12.2f} {np.mean([t['solved'] for t in table.values()]):7.2f}   "
            + " ".join(
                f"{k}:{v['relative'] if v['relative'] is None else round(v['relative'], 2)}({v['spin']:.3f})"
                for k, v in table.items()
            )
        )
    zero = np.zeros(episodes.label.shape)
    rows = {
        "desired point": errors_by_target(zero, episodes, names, args.skip),
        "visible centroid": errors_by_target(visible_centroid(episodes, camera), episodes, names, args.skip),
    }
    for window in args.windows:
        guess = averaged_centroid(episodes, camera, window, args.degree)
        rows[f"centroid averaged {window}"] = errors_by_target(guess, episodes, names, args.skip)
    if args.centre_window:
        guess = flow_centre(episodes, camera, args.centre_pairs, args.centre_window, args.pull, args.skip, args.jump)
        rows[f"centre from flow {args.centre_window}"] = errors_by_target(guess, episodes, names, args.skip)
    reference = episode_mean_offset(episodes, camera, args.skip)
    rows["reference: episode mean"] = errors_by_target(reference, episodes, names, args.skip)
    print_errors(rows, "lateral", width=24)
    write_results(args, spin=spin, errors=rows)


if __name__ == "__main__":
    main()
