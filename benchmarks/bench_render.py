"""Renderer throughput: frames/s vs number of envs and resolution (depth and RGBD), beside MuJoCo's C ray caster.

    python -m benchmarks.bench_render [--out benchmarks/results_render.json] [--quick]

Scenes: catalogue targets (cycled over the training split) at the environment's initial-state distribution
(x, y ~ N(0, 1) m, z ~ U[2, 12) m, uniform random attitude). MuJoCo's ``mj_multiRay`` (one thread) casts the
same rays at the same targets and poses. Each point reports the median of repeated timed calls (time-capped).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from ramavt_jax import render as R
from ramavt_jax import targets

DEFAULT_OUT = Path(__file__).resolve().parent / "results_render.json"  # beside this script, from any directory

DEFAULT_ENVS = (1, 16, 64, 256, 1024, 4096)
DEFAULT_RES = (64, 84, 128, 256)


def make_scene(num_envs: int, seed: int = 0, names=None):
    names = list(names or targets.split("train"))
    idx = np.arange(num_envs) % len(names)
    cat, _ = targets.load_many(names)
    batch = jax.tree.map(lambda a: a[jnp.asarray(idx)], cat)
    rng = np.random.default_rng(seed)
    pos = np.stack([rng.normal(size=num_envs), rng.normal(size=num_envs), rng.uniform(2, 12, num_envs)], 1)
    q = rng.normal(size=(num_envs, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    rot = np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        1,
    )
    return batch, jnp.asarray(pos, jnp.float32), jnp.asarray(rot, jnp.float32), [names[i] for i in idx], pos, rot


def _time(fn, budget_s: float, min_reps: int = 3, max_reps: int = 50) -> float:
    times = []
    start = time.perf_counter()
    while len(times) < min_reps or (time.perf_counter() - start < budget_s and len(times) < max_reps):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def bench_jax(num_envs, res, shade, budget_s, chunk=None, seed=0):
    batch, pos, rot, *_ = make_scene(num_envs, seed)
    cam = R.CameraConfig(resolution=res)
    light = R.default_lighting()
    t0 = time.perf_counter()
    compiled = R.render_batch.lower(batch, pos, rot, cam, light, shade=shade, chunk=chunk).compile()
    compile_s = time.perf_counter() - t0
    out = compiled(batch, pos, rot, light)
    jax.block_until_ready(out)
    hit_frac = float(jnp.mean(out.hit))
    dt = _time(lambda: jax.block_until_ready(compiled(batch, pos, rot, light)), budget_s)
    return dict(fps=num_envs / dt, compile_s=compile_s, hit_fraction=hit_frac)


def bench_mujoco(num_envs, res, budget_s, seed=0):
    _, _, _, names, pos, rot = make_scene(num_envs, seed)
    return mujoco_on_poses(names, pos, rot, res, budget_s)


def mujoco_on_poses(names, pos, rot, res, budget_s, max_frames=64):
    """mj_multiRay (one thread) frames/s on the given targets (names or MJCF paths) and camera-frame poses
    (pos [N, 3] target centre of mass, rot [N, 3, 3] camera_from_body), the first ``max_frames`` of them."""
    run_all, n_frames = mujoco_caster(names, pos, rot, res, max_frames)
    return dict(fps=n_frames / _time(run_all, budget_s))


def mujoco_caster(names, pos, rot, res, max_frames=64):
    """(run_all, n_frames): run_all() casts every pixel ray of the first n_frames scenes with mj_multiRay."""
    import mujoco

    pos, rot = np.asarray(pos, np.float64), np.asarray(rot, np.float64)
    cam = R.CameraConfig(resolution=res)
    rays = np.asarray(R.camera_rays(cam), np.float64).reshape(-1, 3)
    nray = rays.shape[0]
    models = {}
    for n in set(names):
        m = mujoco.MjModel.from_xml_path(str(targets.resolve(n)))
        d = mujoco.MjData(m)
        mujoco.mj_forward(m, d)
        arrays, _ = targets.load_numpy(n)
        xmat = d.geom_xmat.reshape(-1, 3, 3)
        r_wb = xmat[0] @ arrays["geom_mat"][0].astype(np.float64).T
        p_wb = d.geom_xpos[0] - r_wb @ arrays["geom_pos"][0]
        models[n] = (m, d, r_wb, p_wb)
    jobs = []
    for i, n in enumerate(names):
        m, d, r_wb, p_wb = models[n]
        r_wc = r_wb @ rot[i].T
        jobs.append((m, d, p_wb - r_wc @ pos[i], np.ascontiguousarray((rays @ r_wc.T).reshape(-1))))
    geomid = np.zeros(nray, np.int32)
    dist = np.zeros(nray, np.float64)
    n_frames = max(1, min(len(names), max_frames))

    def run_all():
        for m, d, p, v in jobs[:n_frames]:
            mujoco.mj_multiRay(m, d, p, v, None, 1, -1, geomid, dist, None, nray, cam.far)

    return run_all, n_frames


def run(envs=DEFAULT_ENVS, resolutions=DEFAULT_RES, budget_s: float = 2.0, out: str | None = None, chunk=None):
    """Run the sweep, print a table, optionally write JSON; returns the list of result rows."""
    rows = []
    print(f"jax {jax.__version__}, devices {jax.devices()}, GLIBC_TUNABLES={os.environ.get('GLIBC_TUNABLES', '')}")
    print(
        f"{'envs':>6} {'res':>5} {'mode':>6} {'frames/s':>11} {'mj_multiRay fps':>16} {'ratio':>7} {'hit%':>6} {'compile s':>10}"
    )
    points = [(n, 64) for n in envs] + [(64, r) for r in resolutions if r != 64]
    mj_cache = {}
    for n, res in points:
        key = (min(n, 64), res)
        if key not in mj_cache:
            mj_cache[key] = bench_mujoco(n, res, budget_s)["fps"]
        for mode, shade in (("depth", False), ("rgbd", True)):
            r = bench_jax(n, res, shade, budget_s, chunk=chunk)
            row = dict(
                envs=n,
                resolution=res,
                mode=mode,
                fps=r["fps"],
                mujoco_fps=mj_cache[key],
                ratio=r["fps"] / mj_cache[key],
                hit_fraction=r["hit_fraction"],
                compile_s=r["compile_s"],
            )
            rows.append(row)
            print(
                f"{n:>6} {res:>5} {mode:>6} {r['fps']:>11.0f} {mj_cache[key]:>16.0f} {row['ratio']:>7.2f} "
                f"{100 * r['hit_fraction']:>6.1f} {r['compile_s']:>10.2f}",
                flush=True,
            )
    if out:
        os.makedirs(os.path.dirname(out) or ".", exist_ok=True)
        with open(out, "w") as f:
            json.dump(
                dict(jax=jax.__version__, glibc_tunables=os.environ.get("GLIBC_TUNABLES", ""), rows=rows), f, indent=1
            )
        print(f"wrote {out}")
    return rows


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default=str(DEFAULT_OUT))
    p.add_argument("--envs", type=int, nargs="*", default=list(DEFAULT_ENVS))
    p.add_argument("--res", type=int, nargs="*", default=list(DEFAULT_RES))
    p.add_argument("--budget", type=float, default=2.0, help="seconds of timing per point")
    p.add_argument("--chunk", type=int, default=None)
    p.add_argument("--quick", action="store_true", help="envs 1 64 256, resolution 64 only")
    a = p.parse_args(argv)
    if a.quick:
        a.envs, a.res = [1, 64, 256], [64]
    run(a.envs, a.res, a.budget, a.out, a.chunk)


if __name__ == "__main__":
    main()
