"""The centre of mass as the point the visible surface turns about, from long-baseline registration of depth frames:
a geometric estimator, no learning, on the episodes lab/centre_estimator.py scores its fits on (the validation
targets, the same behaviour and seed):

    python lab/centre_registration.py --resolution 32 64 --out lab/results/centre/registration.json

Each depth frame is back-projected to camera-frame points and moved by the chaser's own displacement, dead-reckoned
from its commands, into a frame that does not follow the chaser ("world": the first camera frame's axes and
origin). There the target is a rigid body: its points at step t are R p + T of its points at an earlier step s. The
motion (R, T) of each pair is found by point-to-plane ICP (nearest neighbours beyond `--trim` m ignored), started
from the chained motions of consecutive pairs, over baselines of `--baselines` steps: a pair far apart has turned
through a large angle, so its (I - R) is well conditioned where a one-step flow is not (lab/centre_from_motion.py,
range flow over ten pairs: 0.37-0.47 m).

The centre c is a body point, so it maps onto itself: c_t = R c_s + T; and it drifts at a velocity v (free drift
over a window of seconds; the Hill frame's turn and the CW terms, about 1e-3 rad/s, are left out). Over the pairs
that end in the last `--window` steps, least squares in (c_now, v):

    (I - R) c_now + ((t - s) dt I - (now - s) dt (I - R)) v = T

Along an axis the body does not turn about over the window, (I - R) sees nothing; that component is pulled toward
the newest frame's visible-surface centroid with weight `--pull` (a Tikhonov prior). The estimate at a step uses
frames up to that step only (causal). Reported as lab/centre_estimator.py's rows: mean errors in m over the live
steps after `--skip`, 3-D, across the image and along the boresight, per target.
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
from pathlib import Path

import jax
import numpy as np
from scipy.spatial import cKDTree
from tqdm import tqdm

from lab.centre_estimator import DESIRED, collect, errors_by_target, print_errors, visible_centroid, write_results
from lab.centre_from_motion import chaser_track
from ramavt_jax import env as env_lib
from ramavt_jax.evaluation import rollouts
from ramavt_jax.render.camera import camera_rays

DT = 0.1  # s per env step
# Settings.depth_offset, depth_gain as fit_depth_prior found them on 2 episodes per training target at 64x64
# (lab/results/centre/registration_val.json: depth_priors)
FITTED_DEPTH_PRIOR = (0.242, 0.249)


def frame_points(depth: np.ndarray, rays: np.ndarray, jump: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Of a z-depth frame [H, W] (m, 0 where nothing is hit): (points [N, 3] every hit pixel back-projected,
    normals [N, 3] unit surface normals from the neighbours (NaN where a neighbour is missed or jumps over ``jump``
    m), and the centroid [3])."""
    grid = depth[..., None] * rays  # [H, W, 3]
    hit = depth > 0
    padded = np.pad(grid, ((1, 1), (1, 1), (0, 0)))
    hit_p = np.pad(hit, 1)
    depth_p = np.pad(depth, 1)
    right, left = padded[1:-1, 2:], padded[1:-1, :-2]
    down, up = padded[2:, 1:-1], padded[:-2, 1:-1]
    normal = np.cross(right - left, down - up)
    normal /= np.maximum(np.linalg.norm(normal, axis=-1, keepdims=True), 1e-12)
    smooth = hit_p[1:-1, 2:] & hit_p[1:-1, :-2] & hit_p[2:, 1:-1] & hit_p[:-2, 1:-1]
    smooth &= np.abs(depth_p[1:-1, 2:] - depth_p[1:-1, :-2]) < jump
    smooth &= np.abs(depth_p[2:, 1:-1] - depth_p[:-2, 1:-1]) < jump
    normal = np.where(smooth[..., None], normal, np.nan)
    points = grid[hit]
    return points, normal[hit], points.mean(0) if len(points) else np.full(3, np.nan)


def surface_prior(points: np.ndarray, centroid: np.ndarray, settings: Settings) -> np.ndarray:
    """[3] the prior of the centre from one frame's points [N, 3] and their centroid [3] (camera frame)."""
    behind = settings.depth_offset + settings.depth_gain * (points[:, 2].max() - centroid[2])
    return centroid + np.array([0.0, 0.0, behind])


def fit_depth_prior(episodes, camera: env_lib.CameraConfig, skip: int = 100, every: int = 5) -> tuple[float, float]:
    """(depth_offset, depth_gain) of Settings by least squares on recorded episodes' frames (every ``every``-th
    live step after ``skip``, with at least 20 target pixels): the true centre's depth behind the visible centroid
    against the visible surface's depth extent behind it."""
    rays = np.asarray(camera_rays(camera), np.float64)
    extent, behind = [], []
    labels, alive = np.asarray(episodes.label), np.asarray(episodes.alive)
    for e, t in zip(*np.nonzero(alive[:, skip::every])):
        t = skip + every * t
        points, _, centroid = frame_points(np.asarray(episodes.obs[e, t, ..., -1], np.float64) * camera.far, rays, 0.6)
        if len(points) >= 20:
            extent.append(points[:, 2].max() - centroid[2])
            behind.append(labels[e, t, 2] * DESIRED[2] + DESIRED[2] - centroid[2])
    design = np.stack([np.ones(len(extent)), extent], axis=1)
    offset, gain = np.linalg.lstsq(design, np.asarray(behind), rcond=None)[0]
    return float(offset), float(gain)


def _rotvec(w: np.ndarray) -> np.ndarray:
    """The rotation matrix of rotation vector w [3] (Rodrigues)."""
    angle = np.linalg.norm(w)
    if angle < 1e-12:
        return np.eye(3)
    k = w / angle
    cross = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * cross + (1 - np.cos(angle)) * cross @ cross


def icp(src, dst, dst_normals, tree, rotation, translation, trim: float, iters: int, min_points: int):
    """Point-to-plane ICP of points src [N, 3] onto dst [M, 3] (normals [M, 3], NaN rows unused; tree: cKDTree of
    dst), from (rotation [3, 3], translation [3]). Returns (rotation, translation, rms in m) or None where fewer than
    ``min_points`` pairs match."""
    centre = dst.mean(0)  # solve about the points, not the camera: a well-conditioned small-angle step
    rms = np.inf
    for _ in range(iters):
        moved = src @ rotation.T + translation
        dist, idx = tree.query(moved, distance_upper_bound=trim)
        ok = np.isfinite(dist)
        ok[ok] &= ~np.isnan(dst_normals[idx[ok], 0])
        if ok.sum() < min_points:
            return None
        p, q, n = moved[ok] - centre, dst[idx[ok]] - centre, dst_normals[idx[ok]]
        design = np.concatenate([np.cross(p, n), n], axis=1)
        residual = np.sum((q - p) * n, axis=1)
        step = np.linalg.lstsq(design, residual, rcond=None)[0]
        turn = _rotvec(step[:3])
        rotation = turn @ rotation
        translation = turn @ (translation - centre) + centre + step[3:]
        rms = float(np.sqrt(np.mean(residual**2)))
        if np.linalg.norm(step) < 1e-6:
            break
    return rotation, translation, rms


@dataclasses.dataclass(frozen=True)
class Settings:
    """The estimator's settings (module docstring); lengths in m, steps of DT."""

    baselines: tuple[int, ...] = (10, 30)  # steps between registered frames
    window: int = 200  # steps of pairs in each centre solve
    pull: float = 0.1  # weight of the prior (the visible centroid) in the centre solve
    huber: float = 0.02  # m: pair residuals beyond it are down-weighted (a wrong registration)
    rounds: int = 3  # reweightings of the centre solve
    trim: float = 0.4  # m: nearest neighbours further are not matched
    jump: float = 0.6  # m: a depth step a normal is not taken over
    iters: int = 20  # ICP iterations
    min_points: int = 20  # matched points an ICP needs
    max_rms: float = 0.1  # m: pairs whose ICP residual is larger are dropped
    # The prior behind the visible surface: the centroid moved along the boresight by depth_offset + depth_gain *
    # (the deepest visible point's depth - the centroid's), fitted on training frames (fit_depth_prior); 0, 0: the
    # centroid itself. The surface seen is always the near side, so the centre lies behind it.
    depth_offset: float = 0.0
    depth_gain: float = 0.0

    def __post_init__(self):
        if not self.baselines or min(self.baselines) < 1 or self.window < max(self.baselines):
            raise ValueError(f"baselines must be >= 1 step and the window ({self.window}) at least the longest")
        if min(self.pull, self.huber, self.trim, self.jump, self.max_rms) <= 0 or min(self.rounds, self.iters) < 1:
            raise ValueError("pull, huber, trim, jump and max_rms must be > 0, rounds and iters >= 1")


class OnlineRegistration:
    """The estimator over one episode, a step at a time (causal): update() with each new depth frame and the
    chaser's displacement since the episode's start; it returns the centre and its velocity in the world frame."""

    def __init__(self, camera: env_lib.CameraConfig, settings: Settings = Settings()):
        self.rays = np.asarray(camera_rays(camera), np.float64)
        self.settings = settings
        keep = max(settings.baselines) + 1
        self.frames: collections.deque = collections.deque(maxlen=keep)  # (points, normals, tree | None)
        self.poses: collections.deque = collections.deque(maxlen=keep)  # chained: step-0 world points to step t
        self.times: collections.deque = collections.deque(maxlen=keep)  # s, each kept frame's time
        self.pairs: collections.deque = collections.deque()  # (end step, start time, end time, rotation, translation)
        self.last = np.eye(4)  # the previous step's motion: the next one's start
        self.step, self.time = -1, 0.0
        self.centre, self.velocity = np.full(3, np.nan), np.zeros(3)

    def _icp(self, source, dest, start: np.ndarray):
        s = self.settings
        return icp(source[0], dest[0], dest[1], dest[2], start[:3, :3], start[:3, 3], s.trim, s.iters, s.min_points)

    def update(self, depth: np.ndarray, chaser: np.ndarray, time: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """depth [H, W] (m, 0 where nothing is hit), chaser [3] (m, camera axes, from the episode's start), time (s
        since the start, the chaser's clock; None: DT per step, the env's step without a time delay). Returns
        (centre [3], velocity [3]) in the world frame (the first camera frame's origin and axes): the solve's, or,
        on a frame without enough target, the last one moved on at its velocity (NaN before any)."""
        s, self.step = self.settings, self.step + 1
        elapsed = (self.step * DT if time is None else time) - self.time
        self.time += elapsed
        points, normals, centroid = frame_points(depth, self.rays, s.jump)
        points = points + chaser
        tree = cKDTree(points) if len(points) >= s.min_points else None
        frame = (points, normals, tree)
        previous = self.frames[-1] if self.frames else None
        motion = None
        if tree is not None and previous is not None and previous[2] is not None:
            motion = self._icp(previous, frame, self.last)
        if motion is not None:
            self.last = np.eye(4)
            self.last[:3, :3], self.last[:3, 3] = motion[0], motion[1]
        pose = self.last @ self.poses[-1] if self.poses else np.eye(4)
        self.frames.append(frame)
        self.poses.append(pose)
        self.times.append(self.time)
        for k in s.baselines:
            if tree is None or len(self.frames) <= k or self.frames[-1 - k][2] is None:
                continue
            found = self._icp(self.frames[-1 - k], frame, pose @ np.linalg.inv(self.poses[-1 - k]))
            if found is not None and found[2] < s.max_rms:
                self.pairs.append((self.step, self.times[-1 - k], self.time, found[0], found[1]))
        while self.pairs and self.pairs[0][0] <= self.step - s.window:
            self.pairs.popleft()
        if np.isnan(centroid[0]) or tree is None:
            self.centre = self.centre + self.velocity * elapsed
        else:
            self.centre, self.velocity = self._solve(surface_prior(points - chaser, centroid, s) + chaser)
        return self.centre, self.velocity

    def _solve(self, prior: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(centre, velocity) now by reweighted least squares over the pairs, pulled toward ``prior`` [3]."""
        s, eye = self.settings, np.eye(3)
        prior_rows = np.concatenate([s.pull * eye, np.zeros((3, 3))], axis=1)
        if not self.pairs:
            return prior, np.zeros(3)
        start, end = (np.array([p[i] for p in self.pairs])[:, None, None] for i in (1, 2))  # s
        turn = eye - np.array([p[3] for p in self.pairs])  # [P, 3, 3]
        target = np.array([p[4] for p in self.pairs])  # [P, 3]
        design = np.concatenate([turn, (end - start) * eye - (self.time - start) * turn], axis=2)  # [P, 3, 6]
        weight = np.ones(len(design))
        for _ in range(s.rounds):
            rows = np.concatenate([(design * weight[:, None, None]).reshape(-1, 6), prior_rows])
            rhs = np.concatenate([(target * weight[:, None]).reshape(-1), s.pull * prior])
            solution = np.linalg.lstsq(rows, rhs, rcond=None)[0]
            residual = np.linalg.norm(np.einsum("pij,j->pi", design, solution) - target, axis=1)
            weight = np.sqrt(np.minimum(1.0, s.huber / np.maximum(residual, 1e-9)))
        return solution[:3], solution[3:]


def estimate(episodes, camera: env_lib.CameraConfig, settings: Settings = Settings()) -> np.ndarray:
    """[E, T, 3] the estimate over recorded episodes in the label's units (the error to the desired point over the
    stand-off), the chaser's displacement dead-reckoned from the recorded commands."""
    depth = np.asarray(episodes.obs[..., -1], np.float64) * camera.far
    _, chaser = chaser_track(np.asarray(episodes.action))
    out = np.zeros(np.asarray(episodes.label).shape)
    for e in tqdm(range(depth.shape[0]), desc=f"register {camera.resolution}x{camera.resolution}", unit="episode"):
        tracker = OnlineRegistration(camera, settings)
        for t in range(depth.shape[1]):
            centre = tracker.update(depth[e, t], chaser[e, t])[0] - chaser[e, t]  # camera frame
            out[e, t] = (centre - DESIRED) / DESIRED[2]
    return out


def prior_alone(episodes, camera: env_lib.CameraConfig, settings: Settings) -> np.ndarray:
    """[E, T, 3] the surface prior of each frame alone (no registration), in the label's units; NaN without target."""
    rays = np.asarray(camera_rays(camera), np.float64)
    depth = np.asarray(episodes.obs[..., -1], np.float64) * camera.far
    out = np.full(np.asarray(episodes.label).shape, np.nan)
    for e, t in np.ndindex(*depth.shape[:2]):
        points, _, centroid = frame_points(depth[e, t], rays, settings.jump)
        if len(points):
            out[e, t] = (surface_prior(points, centroid, settings) - DESIRED) / DESIRED[2]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--resolution", type=int, nargs="+", default=[32])
    for field in dataclasses.fields(Settings):  # every setting, its default the dataclass's
        many = isinstance(field.default, tuple)
        kind = type(field.default[0] if many else field.default)
        ap.add_argument(
            f"--{field.name.replace('_', '-')}", type=kind, nargs="+" if many else None, default=field.default
        )
    ap.add_argument(
        "--skip-centroid-prior", action="store_true", help="no row with the plain centroid as the prior (saves time)"
    )
    ap.add_argument("--val-episodes", type=int, default=4, help="per evaluated target")
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--skip", type=int, default=100)
    ap.add_argument("--episodes", type=int, help="score only the first N episodes (a quick look)")
    ap.add_argument("--eval-targets", default="val", help="a split or names, as `ramavt eval` takes")
    ap.add_argument("--train-targets", default="train", help="the targets the depth prior is fitted on")
    ap.add_argument(
        "--prior-episodes", type=int, default=2, help="per training target, to fit the depth prior; 0: the centroid"
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    names = rollouts.resolve_targets(args.eval_targets)
    train_names = rollouts.resolve_targets(args.train_targets)
    fields = {f.name for f in dataclasses.fields(Settings)}
    try:
        settings = Settings(**{k: tuple(v) if k == "baselines" else v for k, v in vars(args).items() if k in fields})
    except ValueError as e:
        ap.error(str(e))
    rows, priors = {}, {}
    for resolution in args.resolution:
        camera, res = env_lib.CameraConfig(resolution=resolution), f"{resolution}x{resolution}"
        root = jax.random.PRNGKey(args.seed)
        if args.prior_episodes:  # fitted on the training targets' episodes (fold 0), never on the scored ones
            fit_eps = collect(train_names, args.prior_episodes, args.steps, jax.random.fold_in(root, 0), camera)
            offset, gain = fit_depth_prior(fit_eps, camera, args.skip)
            priors[res] = {"depth_offset": offset, "depth_gain": gain}
            print(f"{res}: the centre lies {offset:.3f} m + {gain:.3f} x the visible depth extent behind the centroid")
        eps = collect(names, args.val_episodes, args.steps, jax.random.fold_in(root, 1), camera)
        if args.episodes:
            eps = jax.tree.map(lambda x: x[: args.episodes], eps)
        rows[f"visible centroid, {res}"] = errors_by_target(visible_centroid(eps, camera), eps, names, args.skip)
        arms = {"registration": settings}
        if res in priors:
            fitted = dataclasses.replace(settings, **priors[res])
            rows[f"visible centroid moved behind, {res}"] = errors_by_target(
                prior_alone(eps, camera, fitted), eps, names, args.skip
            )
            arms = {"registration": fitted}
            if not args.skip_centroid_prior:
                arms = {"registration, centroid prior": settings} | arms
        for name, arm in arms.items():
            rows[f"{name}, {res}"] = errors_by_target(estimate(eps, camera, arm), eps, names, args.skip)
        print_errors(rows, "3d", width=40)
    write_results(args, errors=rows, depth_priors=priors)


if __name__ == "__main__":
    main()
