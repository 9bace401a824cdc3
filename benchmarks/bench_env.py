"""Env throughput: full env steps/s (dynamics + render + auto-reset) vs number of envs, resolution and observation
mode, beside the baselines measured in the same run: MuJoCo's C ray caster `mj_multiRay` (one thread) on the same
targets and poses as the env's envs (at 64 envs or more, up to 128x128), timed interleaved with each point, and with
``--baseline REV`` the whole env (env.py and its renderer) of an earlier git revision, imported beside this one, its
calls interleaved too (so both see the same machine load).

    python benchmarks/bench_env.py --mj-check --baseline 1baefdc      # 3 points; + that revision's env step
    python benchmarks/bench_env.py --pixel-check --baseline 1baefdc   # cost per pixel: 64x64 and 128x128 depth
    python benchmarks/bench_env.py [--quick] [--baseline REV]          # the sweep (--quick: 6 points)
    python benchmarks/bench_env.py --gpu          # accelerator sweep: 1k .. 64k envs, one command
    ramavt bench env [--quick | --gpu | --mj-check | --pixel-check] [--baseline REV]

Results go into one JSON file (default benchmarks/results_env.json), under a key per plan and baseline (e.g.
``mj_check_vs_1baefdc``); a run replaces its own key and keeps the others.

Each point jit-compiles a `lax.scan` of 10 vmapped `env.step` calls with random actions over the training targets
(same_step auto-reset with the final observation in info: two renders per step, the second culled for envs that
did not finish), warms it up (the envs reach the tracked regime of the env's initial distribution), then reports
the median of timed calls. The 1-minute load average is printed beside every figure: other jobs on the machine
lower the absolute numbers; the ratios to the interleaved baseline are the robust figures.
"""

from __future__ import annotations

import argparse
import importlib
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_render import mujoco_caster, mujoco_on_poses  # noqa: E402

from ramavt_jax import env as env_lib  # noqa: E402
from ramavt_jax import render  # noqa: E402

DEFAULT_OUT = Path(__file__).resolve().parent / "results_env.json"  # beside this script, from any directory

STEPS_PER_CALL = 10
RENDERERS = ("new",)  # this checkout's env step; the row label of its arm
BASELINE = "baseline"  # the env of an earlier git revision (--baseline REV), in the same process
_BASELINE_MODULES = {}  # filled by run(baseline=REV): the baseline package's env and render modules


def _env_modules(which: str):
    """(env module, render module) of an arm: this checkout's, or the baseline revision's for 'baseline'."""
    if which == BASELINE:
        return _BASELINE_MODULES["env"], _BASELINE_MODULES["render"]
    return env_lib, render


def build(num_envs: int, res: int, mode: str, which: str = "new", seed: int = 0):
    """(compiled scan of STEPS_PER_CALL vmapped steps, warmed-up env state, env, params, compile seconds)."""
    env_mod, render_mod = _env_modules(which)
    config = env_mod.EnvConfig(camera=render_mod.CameraConfig(resolution=res), obs_mode=mode)
    tenv = env_mod.TrackingEnv(config)
    params = tenv.default_params()
    v_step = jax.vmap(tenv.step, in_axes=(0, 0, 0, None))

    def run(state, key):
        def body(state, k):
            k_act, k_env = jax.random.split(k)
            actions = jax.random.randint(k_act, (num_envs,), 0, env_lib.NUM_ACTIONS)
            obs, state, reward, *_ = v_step(jax.random.split(k_env, num_envs), state, actions, params)
            return state, reward.mean() + obs[:, 0, 0, 0].mean()

        return jax.lax.scan(body, state, jax.random.split(key, STEPS_PER_CALL))

    key = jax.random.key(seed)
    _, state = jax.jit(jax.vmap(tenv.reset, in_axes=(0, None)))(jax.random.split(key, num_envs), params)
    t0 = time.perf_counter()
    compiled = jax.jit(run).lower(state, key).compile()
    compile_s = time.perf_counter() - t0
    for i in range(3):  # warm-up moves envs into the tracked regime
        state, out = compiled(state, jax.random.key(100 + i))
    jax.block_until_ready(out)
    return compiled, state, tenv, params, compile_s


def time_interleaved(runners: dict, budget_s: float, min_reps: int = 3, max_reps: int = 30) -> dict:
    """Median seconds per call of each runner (callables taking the repetition index), calls alternated."""
    times = {k: [] for k in runners}
    start = time.perf_counter()
    i = 0
    while i < min_reps or (time.perf_counter() - start < budget_s * len(runners) and i < max_reps):
        for k, fn in runners.items():
            t = time.perf_counter()
            fn(i)
            times[k].append(time.perf_counter() - t)
        i += 1
    return {k: statistics.median(v) for k, v in times.items()}


def _runner(compiled, state):
    box = [state]

    def call(i):
        box[0], out = compiled(box[0], jax.random.key(1000 + i))
        jax.block_until_ready(out)

    return call


def bench_point(num_envs: int, res: int, mode: str, budget_s: float, baselines=RENDERERS):
    """Rows for this checkout's env step ('new') and each baseline arm at one (envs, res, mode), timed interleaved."""
    built = {w: build(num_envs, res, mode, w) for w in baselines}
    runners = {w: _runner(b[0], b[1]) for w, b in built.items()}
    mj_frames = 0
    if num_envs >= 64 and res <= 128:  # MuJoCo on the env's own poses, its calls interleaved with ours
        _, state, tenv, params, _ = built["new"]
        mj_frames = min(num_envs, 64)
        runners["mj_multiRay"] = mujoco_runner(*env_poses(tenv, params, state), res, mj_frames)
    load0 = os.getloadavg()[0]
    med = time_interleaved(runners, budget_s)
    load1 = os.getloadavg()[0]
    rows = [
        dict(
            renderer=w,
            num_envs=num_envs,
            resolution=res,
            mode=mode,
            env_steps_per_s=num_envs * STEPS_PER_CALL / med[w],
            compile_s=built[w][4],
            load_avg_1min=[load0, load1],
        )
        for w in baselines
    ]
    if mj_frames:
        for r in rows:
            r["mj_multiRay_fps_interleaved"] = mj_frames / med["mj_multiRay"]
            r["per_core_vs_mj_multiRay"] = r["env_steps_per_s"] / _cores() / r["mj_multiRay_fps_interleaved"]
    return rows, built["new"]


def _cores() -> int:
    return 1 if jax.default_backend() != "cpu" else os.cpu_count()


def mujoco_runner(names, pos, rot, res, frames):
    """A runner (see time_interleaved) that ray-casts ``frames`` env poses with mj_multiRay on one thread."""
    run_all, _ = mujoco_caster(names, pos, rot, res, frames)
    return lambda i: run_all()


def env_poses(tenv, params, state):
    """Catalogue names and true camera-frame poses of the envs of a state (the scenes MuJoCo ray-casts)."""
    pos = np.asarray(jax.vmap(env_lib.relative_position)(state))
    rot = np.asarray(jax.vmap(env_lib.state_rotation, in_axes=(0, None))(state, params.mean_motion))
    names = [tenv.config.targets[i] for i in np.asarray(state.target_index)]
    return names, pos, rot


def machine() -> dict:
    return dict(
        platform=platform.platform(),
        processor=platform.processor(),
        cpu_count=os.cpu_count(),
        jax=jax.__version__,
        backend=jax.default_backend(),
        devices=[str(d) for d in jax.devices()],
        device_kind=jax.devices()[0].device_kind,
        glibc_tunables=os.environ.get("GLIBC_TUNABLES", ""),
    )


def run(
    out=str(DEFAULT_OUT),
    quick=False,
    gpu=False,
    budget_s=3.0,
    mj_check=False,
    baseline: str | None = None,
    pixel_check: bool = False,
) -> dict:
    """Every plan's points; ``baseline`` (a git revision) adds that revision's env step to every point's arms."""
    extra = (BASELINE,) if baseline else ()
    if baseline:
        import tempfile

        from ab_chunk import BASELINE_MODULE, import_baseline

        base_env = import_baseline(baseline, Path(tempfile.mkdtemp()), "env")
        _BASELINE_MODULES.update(env=base_env, render=importlib.import_module(f"{BASELINE_MODULE}.render"))
    name = "gpu" if gpu else "mj_check" if mj_check else "pixel_check" if pixel_check else "quick" if quick else "sweep"
    key = f"{name}_vs_{baseline}" if baseline else name
    if gpu:  # (mode, res, envs, arms); the baseline revision only where it still fits a short run
        plan = (
            [("depth", 64, n, ("new",) + (extra if n <= 4096 else ())) for n in (1024, 4096, 16384, 65536)]
            + [("rgbd", 64, n, ("new",)) for n in (4096, 16384)]
            + [("depth", 128, 16384, ("new",))]
        )
    elif mj_check:  # the per-core comparison with MuJoCo at the three points
        plan = [
            ("depth", 64, 64, ("new",) + extra),
            ("depth", 64, 256, ("new",) + extra),
            ("rgbd", 64, 64, ("new",) + extra),
        ]
    elif pixel_check:  # the cost per pixel: 64x64 against 128x128 depth at the same envs
        plan = [("depth", res, n, ("new",) + extra) for n in (64, 256) for res in (64, 128)]
    elif quick:
        arms = RENDERERS + extra
        plan = (
            [("depth", 64, n, arms) for n in (64, 256, 1024)]
            + [("depth", 128, 256, arms)]
            + [("rgbd", 64, n, arms) for n in (64, 256)]
        )
    else:
        arms = RENDERERS + extra
        plan = (
            [("depth", 64, n, arms) for n in (1, 16, 64, 256, 1024, 4096)]
            + [("depth", r, 256, arms) for r in (84, 128, 256)]
            + [("rgbd", 64, n, arms) for n in (1, 64, 256, 1024)]
            + [("rgbd", 128, 256, arms)]
        )
    print(
        f"backend {jax.default_backend()} ({jax.devices()[0].device_kind}), {os.cpu_count()} CPUs, "
        f"GLIBC_TUNABLES={os.environ.get('GLIBC_TUNABLES', '')!r}",
        flush=True,
    )
    points, poses = [], {}
    for mode, res, n, baselines in plan:
        rows, (_, state, tenv, params, _) = bench_point(n, res, mode, budget_s, baselines)
        points += rows
        if n >= 64 and res not in poses:
            poses[res] = env_poses(tenv, params, state)
        new = rows[0]
        for r in rows:
            vs = f"  new is {new['env_steps_per_s'] / r['env_steps_per_s']:5.2f}x this" if r is not new else ""
            if "per_core_vs_mj_multiRay" in r:
                vs += (
                    f"  | per core {r['per_core_vs_mj_multiRay']:.2f}x mj_multiRay "
                    f"({r['mj_multiRay_fps_interleaved']:,.0f} frames/s interleaved)"
                )
            print(_row(r) + vs, flush=True)
        _write(out, key, dict(partial=True, env=points))
    mujoco = []
    for res, (names, pos, rot) in sorted(poses.items()):
        load0 = os.getloadavg()[0]
        m = mujoco_on_poses(names, pos, rot, res, budget_s)
        mujoco.append(
            dict(resolution=res, frames=min(len(names), 64), fps=m["fps"], load_avg_1min=[load0, os.getloadavg()[0]])
        )
        print(
            f"mj_multiRay, 1 thread, env poses, res {res:>3}: {m['fps']:>9.0f} frames/s   (load {load0:.2f})",
            flush=True,
        )
    result = dict(
        machine=machine(),
        steps_per_call=STEPS_PER_CALL,
        baseline_revision=baseline,
        env=points,
        mujoco_mj_multiRay=mujoco,
        summary=_summary(points, mujoco),
    )
    _write(out, key, result)
    print(f"wrote {out} [{key}]")
    return result


def _write(out, key, obj):
    from bench_train import merge_json  # (the script's directory; imported here: it loads the trainer)

    merge_json(out, key, obj)


def _row(p: dict) -> str:
    return (
        f"{p['renderer']:<11} {p['mode']:<5} res {p['resolution']:>3} envs {p['num_envs']:>6}: "
        f"{p['env_steps_per_s']:>10,.0f} env steps/s  compile {p['compile_s']:5.1f} s  "
        f"load {p['load_avg_1min'][0]:.2f}-{p['load_avg_1min'][1]:.2f}"
    )


def _summary(points, mujoco) -> list:
    """Ratios to mj_multiRay per core and the cost per pixel between resolutions, printed and returned."""
    cores = 1 if jax.default_backend() != "cpu" else os.cpu_count()
    mj = {m["resolution"]: m["fps"] for m in mujoco}
    lines = []
    for p in points:
        if p["resolution"] in mj or "per_core_vs_mj_multiRay" in p:
            # prefer the MuJoCo figure timed interleaved with this point (same load) over the separate one
            ratio = p.get("per_core_vs_mj_multiRay") or p["env_steps_per_s"] / cores / mj[p["resolution"]]
            lines.append(
                dict(
                    mode=p["mode"],
                    resolution=p["resolution"],
                    num_envs=p["num_envs"],
                    renderer=p["renderer"],
                    per_core_vs_mj_multiRay=ratio,
                )
            )
    new = {(p["mode"], p["resolution"], p["num_envs"]): p["env_steps_per_s"] for p in points if p["renderer"] == "new"}
    for (mode, res, n), v in new.items():
        if res != 64 and (mode, 64, n) in new:
            lines.append(
                dict(
                    mode=mode,
                    num_envs=n,
                    resolution=res,
                    pixel_rate_vs_64=v * res * res / (new[(mode, 64, n)] * 64 * 64),
                )
            )
    print(
        f"\nper core (env steps/s / {cores} cores) over one mj_multiRay thread on the same poses (timed interleaved "
        f"with the point where it was); pixel rate "
        f"(env steps/s x pixels) relative to 64x64 at the same envs (1.0 = cost per pixel flat)"
    )
    for line in lines:
        key = "per_core_vs_mj_multiRay" if "per_core_vs_mj_multiRay" in line else "pixel_rate_vs_64"
        print(
            f"  {line.get('renderer', 'new'):<11} {line['mode']:<5} res {line['resolution']:>3} "
            f"envs {line['num_envs']:>6}: {key} {line[key]:.2f}"
        )
    return lines


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default=str(DEFAULT_OUT), help="JSON file (a key per plan and baseline)")
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--gpu", action="store_true", help="accelerator sweep, 1k..64k envs (about 5-8 min)")
    parser.add_argument("--mj-check", action="store_true", help="only the step vs mj_multiRay (interleaved), 3 points")
    parser.add_argument("--budget", type=float, default=3.0, help="seconds of timed calls per point and arm")
    parser.add_argument("--pixel-check", action="store_true", help="only 64x64 against 128x128 depth, 64 and 256 envs")
    parser.add_argument("--baseline", default=None, help="a git revision whose env step joins every point, interleaved")
    args = parser.parse_args()
    run(args.out, args.quick, args.gpu, args.budget, args.mj_check, args.baseline, args.pixel_check)
