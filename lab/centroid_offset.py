"""How far what the camera sees of a target is centred from the centre it spins about (the tracked point): for each
target, over random attitudes at its stand-off (5 m times its stand-off scale k, env.standoff_scale), the centroid of
the visible surface points (depth image back-projected), as a sideways offset of its direction at the stand-off and
as a 3-D distance, both in stand-off units (metres / k: metres for every catalogue target, k = 1). A policy that
holds the visible centroid instead of the centre misses by about the sideways figure.

    python lab/centroid_offset.py --targets train,val,test --attitudes 48

Targets: splits and/or catalogue names or MJCF files, as `ramavt eval --targets` takes them.
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np

from lab.surface import surface_centroid
from ramavt_jax import env as env_lib
from ramavt_jax import render, rotations
from ramavt_jax import targets as targets_lib
from ramavt_jax.evaluation import rollouts

STANDOFF = 5.0  # m, the nominal desired distance


def centroid_offsets(target: targets_lib.TargetModel, rotations_b: jax.Array, cam: render.CameraConfig) -> dict:
    """Visible-surface centroid of ``target`` at (0, 0, 5 m) in each attitude of ``rotations_b`` [B, 3, 3]:
    {'sideways': [B'] m, 'distance': [B'] m} over the B' <= B attitudes in which the target is seen."""
    frames = jax.jit(
        jax.vmap(
            lambda r: render.render(target, jnp.array([0.0, 0.0, STANDOFF]), r, cam, render.default_lighting(), False)
        )
    )(rotations_b)
    depth = jnp.where(frames.hit, frames.depth, 0.0)  # [B, H, W] m, 0 where the target is not hit
    centres, counts = jax.vmap(lambda d: surface_centroid(d, cam))(depth)
    centres = np.asarray(centres)[np.asarray(counts) > 0]  # camera frame, the attitudes in which it is seen
    return {
        "sideways": np.linalg.norm(centres[:, :2] / centres[:, 2:] * STANDOFF, axis=1),
        "distance": np.linalg.norm(centres - np.array([0.0, 0.0, STANDOFF]), axis=1),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--targets", default="train,val,test")
    ap.add_argument("--attitudes", type=int, default=48, help="random attitudes per target")
    ap.add_argument("--resolution", type=int, default=64)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    if args.attitudes < 1 or args.resolution < 8:
        ap.error("--attitudes must be >= 1 and --resolution >= 8")
    items = [t for part in args.targets.split(",") for t in rollouts.resolve_targets(part)]
    cam = render.CameraConfig(resolution=args.resolution)
    keys = jax.random.split(jax.random.PRNGKey(args.seed), args.attitudes)
    rotations_b = jax.vmap(lambda k: rotations.quat_to_mat(rotations.random_quaternion(k)))(keys)
    params = env_lib.TrackingEnv(env_lib.EnvConfig(camera=cam, targets=("Asteroid-v0",))).default_params()
    print(f"{'target':36s} {'k':>5s} {'sideways mean':>13s} {'max':>6s} {'3-D mean':>9s}   (stand-off units)")
    for name in dict.fromkeys(items):
        target = targets_lib.load(name)
        k = float(env_lib.standoff_scale(target, params))
        got = centroid_offsets(targets_lib.scaled(target, 1.0 / k), rotations_b, cam)  # seen as the env renders it
        if not got["sideways"].size:
            print(f"{name:36s} {k:5.2f} not seen in any attitude")
            continue
        print(
            f"{name:36s} {k:5.2f} {got['sideways'].mean():13.2f} {got['sideways'].max():6.2f} "
            f"{got['distance'].mean():9.2f}"
        )


if __name__ == "__main__":
    main()
