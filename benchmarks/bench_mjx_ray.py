"""`mujoco.mjx.ray` vs our renderer on the same scene: depth frames/s at 64x64.

    python benchmarks/bench_mjx_ray.py [--out benchmarks/results_mjx_ray.json] [--envs 16]

mjx.ray casts one ray against every geom of an MJX model; we vmap it over the pixels of a frame and over envs
(each env = the same catalogue target at its own pose, set through qpos of the free joint). A `<material>` is
added because mjx.ray fails on models without one. Known gap measured here too: mjx.ray does not
intersect cylinders, so targets with cylinders render with holes; we report the fraction of pixels that disagree.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from ramavt_jax import render, targets

DEFAULT_OUT = Path(__file__).resolve().parent / "results_mjx_ray.json"  # beside this script, from any directory


def _time(fn, reps=5):
    times = []
    for _ in range(reps):
        t = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def run(
    out=str(DEFAULT_OUT), quick: bool = False, num_envs: int = 16, res: int = 64, target: str = "Satellite-v0"
) -> dict:
    xml = Path(targets.resolve(target)).read_text()
    xml = xml.replace("<worldbody>", '<asset><material name="m"/></asset><worldbody>', 1)
    model = mujoco.MjModel.from_xml_string(xml)
    mx = mjx.put_model(model)
    cam = render.CameraConfig(resolution=res)
    rays = render.camera_rays(cam).reshape(-1, 3)
    unit = rays / jnp.linalg.norm(rays, axis=-1, keepdims=True)
    rng = np.random.default_rng(0)
    qpos = np.zeros((num_envs, model.nq))
    qpos[:, 0:3] = np.stack([rng.normal(size=num_envs), rng.uniform(4, 8, num_envs), rng.normal(size=num_envs)], 1)
    quat = rng.normal(size=(num_envs, 4))
    qpos[:, 3:7] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    # camera at the world origin looking along world +y: map our camera rays (x right, y down, z forward)
    cam_to_world = jnp.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
    vecs = unit @ cam_to_world.T

    def frame(q):
        d = mjx.kinematics(mx, mjx.make_data(mx).replace(qpos=q))
        dist, _ = jax.vmap(lambda v: mjx.ray(mx, d, jnp.zeros(3), v))(vecs)
        return jnp.where(dist >= 0, dist * unit[:, 2], 0.0).reshape(res, res)

    mjx_fn = jax.jit(jax.vmap(frame))
    q = jnp.asarray(qpos)
    t0 = time.perf_counter()
    mjx_depth = jax.block_until_ready(mjx_fn(q))
    mjx_compile = time.perf_counter() - t0
    mjx_fps = num_envs / _time(lambda: mjx_fn(q))

    # our renderer on the same poses: MuJoCo world pose of the body -> camera frame of the principal frame
    tm, _ = targets.load_numpy(target)
    data = mujoco.MjData(model)
    poses_p, poses_r = [], []
    world_to_cam = np.asarray(cam_to_world).T
    for i in range(num_envs):
        data.qpos[:] = qpos[i]
        mujoco.mj_forward(model, data)
        # composite principal frame (single body here): centre of mass and principal axes from MuJoCo's inertia
        b = 1
        com = data.xipos[b]
        rot = data.ximat[b].reshape(3, 3)
        poses_p.append(world_to_cam @ com)
        poses_r.append(world_to_cam @ rot)
    # the loader's principal axes may differ from MuJoCo's body inertia frame by axis order/sign: use geom 0
    # poses to recover the exact body_from_loader rotation once
    loader = targets.load(target)
    data.qpos[:] = 0
    data.qpos[3] = 1.0
    mujoco.mj_forward(model, data)
    world_geom = data.geom_xpos - data.xipos[1]
    fit, *_ = np.linalg.lstsq(np.asarray(loader.geom_pos)[: model.ngeom], world_geom, rcond=None)
    world_from_loader0 = fit.T  # at identity pose
    inertial0 = data.ximat[1].reshape(3, 3)
    ours_r = jnp.asarray(np.stack([r @ inertial0.T @ world_from_loader0 for r in poses_r]), jnp.float32)
    ours_p = jnp.asarray(np.stack(poses_p), jnp.float32)
    batch = jax.tree.map(lambda a: jnp.broadcast_to(a, (num_envs,) + a.shape), loader)
    ours_fn = jax.jit(lambda p, r: render.render_batch(batch, p, r, cam, render.default_lighting(), False).depth)
    t0 = time.perf_counter()
    ours_depth = jax.block_until_ready(ours_fn(ours_p, ours_r))
    ours_compile = time.perf_counter() - t0
    ours_fps = num_envs / _time(lambda: ours_fn(ours_p, ours_r))
    disagree = float(jnp.mean((mjx_depth > 0) != (ours_depth > 0)))
    result = dict(
        target=target,
        resolution=res,
        num_envs=num_envs,
        mjx_ray_fps=mjx_fps,
        ours_fps=ours_fps,
        speedup=ours_fps / mjx_fps,
        mjx_compile_s=mjx_compile,
        ours_compile_s=ours_compile,
        hit_mask_disagreement=disagree,
        geom_types=sorted(set(int(t) for t in model.geom_type)),
    )
    print(json.dumps(result, indent=1))
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    Path(out).write_text(json.dumps(result, indent=2))
    return result


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default=str(DEFAULT_OUT))
    parser.add_argument("--envs", type=int, default=16)
    parser.add_argument("--target", default="Satellite-v0")
    args = parser.parse_args()
    run(args.out, num_envs=args.envs, target=args.target)
