"""Env throughput: full env steps/s (dynamics + render + auto-reset) vs number of envs and resolution, for depth
and RGBD, beside MuJoCo's C ray caster `mj_multiRay` (one thread) rendering the same kind of scenes.

    python benchmarks/bench_env.py [--out benchmarks/results_env.json] [--quick]
    ramavt bench env [--quick]

Each point jit-compiles a `lax.scan` of 10 vmapped `env.step` calls with random actions over the training
targets (initial-state distribution of DESIGN.md, targets tumbling), then reports the median of timed calls.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import jax

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_render import bench_mujoco  # noqa: E402

from ramavt_jax import env as env_lib  # noqa: E402
from ramavt_jax import render  # noqa: E402

STEPS_PER_CALL = 10


def bench_env_point(num_envs: int, res: int, mode: str, budget_s: float, seed: int = 0) -> dict:
    config = env_lib.EnvConfig(camera=render.CameraConfig(resolution=res), obs_mode=mode)
    tracking_env = env_lib.TrackingEnv(config)
    params = tracking_env.default_params()
    v_reset = jax.vmap(tracking_env.reset, in_axes=(0, None))
    v_step = jax.vmap(tracking_env.step, in_axes=(0, 0, 0, None))

    def run(state, key):
        def body(state, k):
            k_act, k_env = jax.random.split(k)
            actions = jax.random.randint(k_act, (num_envs,), 0, env_lib.NUM_ACTIONS)
            obs, state, reward, *_ = v_step(jax.random.split(k_env, num_envs), state, actions, params)
            return state, reward.mean() + obs[:, 0, 0, 0].mean()
        return jax.lax.scan(body, state, jax.random.split(key, STEPS_PER_CALL))

    key = jax.random.key(seed)
    _, state = jax.jit(v_reset)(jax.random.split(key, num_envs), params)
    t0 = time.perf_counter()
    compiled = jax.jit(run).lower(state, key).compile()
    compile_s = time.perf_counter() - t0
    state, _ = compiled(state, jax.random.key(1))  # warm-up moves envs into the tracked regime
    jax.block_until_ready(state)
    times = []
    start = time.perf_counter()
    i = 0
    while len(times) < 3 or (time.perf_counter() - start < budget_s and len(times) < 30):
        t = time.perf_counter()
        state, out = compiled(state, jax.random.key(2 + i))
        jax.block_until_ready(out)
        times.append(time.perf_counter() - t)
        i += 1
    dt = statistics.median(times)
    return dict(num_envs=num_envs, resolution=res, mode=mode, env_steps_per_s=num_envs * STEPS_PER_CALL / dt,
                compile_s=compile_s, repeats=len(times))


def run(out: str | Path = "benchmarks/results_env.json", quick: bool = False, budget_s: float = 3.0) -> dict:
    env_sweep = (1, 64, 1024) if quick else (1, 16, 64, 256, 1024, 4096)
    res_sweep = (64, 128) if quick else (64, 84, 128, 256)
    res_envs = 64 if quick else 256
    points = []
    for mode in ("depth", "rgbd"):
        for n in env_sweep:
            points.append(bench_env_point(n, 64, mode, budget_s))
            print(_row(points[-1]), flush=True)
            _write_partial(out, points)
        for res in res_sweep:
            if res == 64 and res_envs in env_sweep:
                continue
            points.append(bench_env_point(res_envs, res, mode, budget_s))
            print(_row(points[-1]), flush=True)
    mujoco = []
    for res in res_sweep:
        m = bench_mujoco(64, res, budget_s)
        mujoco.append(dict(resolution=res, num_envs=64, **m))
        print(f"mj_multiRay 1 thread  res {res:>3}: {m['fps']:>9.0f} frames/s", flush=True)
    result = dict(
        machine=dict(platform=platform.platform(), processor=platform.processor(), cpu_count=os.cpu_count(),
                     jax=jax.__version__, devices=[str(d) for d in jax.devices()],
                     glibc_tunables=os.environ.get("GLIBC_TUNABLES", "")),
        steps_per_call=STEPS_PER_CALL,
        env=points,
        mujoco_mj_multiRay=mujoco,
    )
    _summary(points, mujoco)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2))
    print(f"wrote {out}")
    return result


def _write_partial(out, points):
    """Keep what was measured if a long sweep is stopped."""
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    Path(out).write_text(json.dumps(dict(partial=True, env=points), indent=2))


def _row(p: dict) -> str:
    return (f"env {p['mode']:<5} res {p['resolution']:>3} envs {p['num_envs']:>5}: {p['env_steps_per_s']:>10.0f} "
            f"env steps/s (compile {p['compile_s']:.1f} s)")


def _summary(points, mujoco):
    print("\nratio to mj_multiRay (1 thread, same resolution); env steps include dynamics and auto-reset")
    mj = {m["resolution"]: m["fps"] for m in mujoco}
    for p in points:
        if p["resolution"] in mj:
            print(f"  {p['mode']:<5} res {p['resolution']:>3} envs {p['num_envs']:>5}: "
                  f"{p['env_steps_per_s'] / mj[p['resolution']]:.2f}x (both processes use this machine's cores: "
                  f"{os.cpu_count()})")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default="benchmarks/results_env.json")
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--budget", type=float, default=3.0, help="seconds of timed calls per point")
    args = parser.parse_args()
    run(args.out, args.quick, args.budget)
