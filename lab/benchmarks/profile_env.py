"""Where a 64x64 env step's time goes: the full step beside its parts, each jitted and timed on its own.

    python lab/benchmarks/profile_env.py [--envs 64] [--res 64] [--mode depth] [--out benchmarks/results_profile.json]

Parts (all vmapped over the envs, median of timed calls after a warm-up, on the states of a warmed-up run):
  full step          scan of 10 `env.step` (same_step auto-reset, final observation in info: 2 renders per step)
  dynamics           `transition` + `score` only
  initial_state      the fresh-episode draw that every step makes for the auto-reset
  render (moved)     `render` of the stepped poses (the observation)
  render (culled)    `render` of the fresh poses with the target moved behind the camera (the second render of a
                     step whose env did not finish): the renderer's fixed cost per call
  postprocess        `to_observation`, blurs (off), noise, frame drop, history push of one frame
Everything is timed per call of 10 steps (or 10 repeats of the part) so the numbers add up against the full step.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp

from ramavt_jax import env as env_lib
from ramavt_jax import render

sys.path[:0] = [str(Path(__file__).resolve().parent), str(Path(__file__).resolve().parents[2] / "benchmarks")]
from hlo_profile import trace_breakdown  # noqa: E402

REPEATS = 10


def _timeit(fn, args, budget_s=2.0, min_reps=5, max_reps=200):
    out = fn(*args)
    jax.block_until_ready(out)
    times = []
    start = time.perf_counter()
    while len(times) < min_reps or (time.perf_counter() - start < budget_s and len(times) < max_reps):
        t = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def _repeat(fn):
    """fn(x, *rest) -> one jitted call that runs fn REPEATS times in a scan (x perturbed so nothing is hoisted)."""

    def run(*args):
        def body(c, i):
            out = fn(*args, i)
            return c + jax.tree.reduce(
                lambda a, b: a + b, jax.tree.map(lambda x: jnp.sum(x.astype(jnp.float32)), out)
            ), None

        return jax.lax.scan(body, jnp.float32(0), jnp.arange(REPEATS))[0]

    return jax.jit(run)


def profile(num_envs=64, res=64, mode="depth", budget_s=2.0, seed=0):
    """Part timings and the trace breakdown of this checkout's env step."""
    config = env_lib.EnvConfig(camera=render.CameraConfig(resolution=res), obs_mode=mode)
    tenv = env_lib.TrackingEnv(config)
    return _profile(tenv, config, num_envs, mode, budget_s, seed)


def _profile(tenv, config, num_envs, mode, budget_s, seed):
    params = tenv.default_params()
    v_step = jax.vmap(tenv.step, in_axes=(0, 0, 0, None))

    def scan_steps(state, key):
        def body(state, k):
            k_act, k_env = jax.random.split(k)
            actions = jax.random.randint(k_act, (num_envs,), 0, env_lib.NUM_ACTIONS)
            obs, state, reward, *_ = v_step(jax.random.split(k_env, num_envs), state, actions, params)
            return state, reward.mean() + obs[:, 0, 0, 0].mean()

        return jax.lax.scan(body, state, jax.random.split(key, REPEATS))

    key = jax.random.key(seed)
    _, state = jax.jit(jax.vmap(tenv.reset, in_axes=(0, None)))(jax.random.split(key, num_envs), params)
    full = jax.jit(scan_steps)
    state, _ = full(state, jax.random.key(1))  # into the tracked regime
    results = {}
    results["full step"] = _timeit(full, (state, jax.random.key(2)), budget_s)
    hlo = full.lower(state, jax.random.key(2)).compile().as_text()
    breakdown = trace_breakdown(full, (state, jax.random.key(2)), 5, _label, hlo)

    keys = jax.random.split(jax.random.key(3), num_envs)
    actions = jnp.arange(num_envs) % env_lib.NUM_ACTIONS

    def dyn(state, i):
        ks = jax.vmap(lambda k: jax.random.fold_in(k, i))(keys)
        moved = jax.vmap(tenv.transition, in_axes=(0, 0, 0, None))(ks, state, actions, params)
        return jax.vmap(tenv.score, in_axes=(0, None))(moved, params)[1:4]

    results["dynamics"] = _timeit(_repeat(dyn), (state,), budget_s)

    def init(state, i):
        ks = jax.vmap(lambda k: jax.random.fold_in(k, i))(keys)
        fresh = jax.vmap(tenv.initial_state, in_axes=(0, None))(ks, params)
        return fresh.target_pos, fresh.target.geom_size

    results["initial_state"] = _timeit(_repeat(init), (state,), budget_s)

    poses = jax.vmap(tenv.pose, in_axes=(0, None))(state, params)
    light = tenv.lighting(params)
    shade = mode != "depth"
    v_render = jax.vmap(lambda t, p, r: render.render(t, p, r, config.camera, light, shade))

    def ren(state, i):
        f = v_render(state.target, poses.position + 1e-6 * i, poses.rotation)
        return f.depth, f.rgb

    results["render (moved)"] = _timeit(_repeat(ren), (state,), budget_s)

    def ren_culled(state, i):
        far = jnp.broadcast_to(jnp.array([0.0, 0.0, -1e6]), poses.position.shape) + 1e-6 * i
        f = v_render(state.target, far, poses.rotation)
        return f.depth, f.rgb

    results["render (culled)"] = _timeit(_repeat(ren_culled), (state,), budget_s)
    frame = jax.jit(v_render)(state.target, poses.position, poses.rotation)

    def post(state, i):
        ks = jax.vmap(lambda k: jax.random.fold_in(k, i))(keys)
        f = jax.tree.map(lambda a: a + 0 * i, frame)
        return jax.vmap(tenv._postprocess, in_axes=(0, 0, 0, None))(ks, f, state, params)[0]

    results["postprocess"] = _timeit(_repeat(post), (state,), budget_s)
    hit_fraction = float(jnp.mean(frame.hit))
    return results, hit_fraction, breakdown


_SOURCE = {}


def _line(path, line):
    if path not in _SOURCE:
        try:
            _SOURCE[path] = Path(path).read_text().splitlines()
        except OSError:
            _SOURCE[path] = []
    lines = _SOURCE[path]
    return lines[line - 1].strip() if 0 < line <= len(lines) else "?"


_ENV_PARTS = {
    "TrackingEnv._postprocess": "env: post-processing (noise, frame drop, history)",
    "TrackingEnv.transition": "env: dynamics and reward",
    "TrackingEnv.score": "env: dynamics and reward",
    "TrackingEnv.initial_state": "env: fresh-episode draw (auto-reset)",
    "TrackingEnv.reset": "env: fresh-episode draw (auto-reset)",
    "_where.<locals>.<lambda>": "env: auto-reset selects",
    "TrackingEnv.step": "env: step glue (keys, selects)",
}


def _label(stack, op_name, thunk):
    """'<part> | <innermost ramavt_jax function: source line>' for one thunk's HLO call stack.

    (The renderer runs inside a custom batching rule, whose trace does not keep the env's frames, so render calls
    are split by loop / not loop rather than by the env line that called them.)"""
    own = next(((f, fn, ln) for f, fn, ln in stack if "ramavt_jax/" in f), None)
    if own is None:
        return f"other (scan, actions, jax internals) | {thunk.rsplit('.', 1)[0]}"
    short = own[0].split("ramavt_jax/")[1]
    detail = f"{short}:{own[1]}: {_line(own[0], own[2])[:60]}"
    if short.startswith("render/image"):
        return f"render: observation and blur | {detail}"
    if short.startswith("render/"):
        body = "render_batch))/while/body" in op_name or "render_batch)/while/body" in op_name
        kind = "cast loop" if body else "setup, work list, assembly"
        if "_colour_pass" in " ".join(fn for _, fn, _ in stack):
            kind = "colour loop"
        return f"render: {kind} | {short}:{own[1]}: {_line(own[0], own[2])[:60]}"
    if short == "dynamics.py":
        return f"env: dynamics and reward | {detail}"
    if short == "env.py":
        return f"{_ENV_PARTS.get(own[1], 'env: other')} | {detail}"
    return f"other | {detail}"


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--envs", type=int, default=64)
    p.add_argument("--res", type=int, default=64)
    p.add_argument("--mode", default="depth")
    p.add_argument("--budget", type=float, default=2.0)
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    load0 = os.getloadavg()[0]
    res, hit, breakdown = profile(a.envs, a.res, a.mode, a.budget)
    load1 = os.getloadavg()[0]
    full = res["full step"]
    print(
        f"{a.mode} {a.res}x{a.res}, {a.envs} envs, {REPEATS} steps per call, hit fraction {hit:.3f}, "
        f"load {load0:.2f} -> {load1:.2f}"
    )
    for k, v in res.items():
        print(
            f"  {k:<18} {1e3 * v:8.2f} ms   {100 * v / full:5.1f}% of the full step   "
            f"({a.envs * REPEATS / v:,.0f} per s)"
        )
    total = sum(breakdown.values())
    print(
        f"\nprofiler trace of the full step (exclusive thunk time, {1e3 * total:.1f} ms per call of {REPEATS} steps):"
    )
    groups = {}
    for k, v in breakdown.items():
        groups[k.split(" | ")[0]] = groups.get(k.split(" | ")[0], 0.0) + v
    for g, v in sorted(groups.items(), key=lambda kv: -kv[1]):
        print(f"  {100 * v / total:5.1f}%  {1e3 * v:8.2f} ms  {g}")
        for k, w in breakdown.items():
            if k.split(" | ")[0] == g and w > 0.005 * total:
                print(f"           {100 * w / total:5.1f}%  {k.split(' | ', 1)[1]}")
    if a.out:
        Path(a.out).write_text(
            json.dumps(
                dict(
                    envs=a.envs,
                    res=a.res,
                    mode=a.mode,
                    hit_fraction=hit,
                    load=[load0, load1],
                    seconds_per_10=res,
                    trace=breakdown,
                ),
                indent=1,
            )
        )


if __name__ == "__main__":
    main()
