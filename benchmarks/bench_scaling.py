"""Scaling: env steps/s vs envs per device and devices, and trained frames/s vs devices, with the envs (and, for
training, the replay rows and learner batch) split over a 1-D device mesh (``ramavt_jax.distributed``).

    python benchmarks/bench_scaling.py [--out benchmarks/results_scaling.json] [--quick]
    python benchmarks/bench_scaling.py --devices 1 2 4 8 --real-devices     # a machine with several GPUs
    ramavt bench scaling [--quick]

The device count is fixed when JAX starts, so this process starts no JAX backend itself: it launches one worker
process (this file with ``--worker``) per device count D. On a CPU-only machine the workers get D *forced* CPU
devices (``XLA_FLAGS=--xla_force_host_platform_device_count=D``, ``JAX_PLATFORMS=cpu``), which all share the
machine's cores; where an accelerator is visible (probed in a short subprocess) or with ``--real-devices`` they
use the first D real devices. Each worker measures

* env: a jitted ``lax.scan`` of 10 vmapped ``TrackingEnv.step`` calls (64x64 depth, random actions, same-step
  auto-reset) over N = E * D envs, env state split along the env axis with ``NamedSharding(mesh, P('data'))``
  (in and out shardings, so it stays split); one warm-up call, then the median of >= 3 timed calls (fewer when
  one call outlasts the time budget). With D > 1 the step is split two ways: 'gspmd' (the global vmapped step
  with sharding constraints on state, keys and actions, split by XLA's partitioner) and
  'shard_map' (each device steps its own E envs, no collectives). The placement of the state (devices holding
  shards, rows per shard) and the number of collectives in the compiled program are recorded;
* train: the 'quick' preset (32x32 depth, small RAMAVT, replay ratio 2) with 16 (--quick) or 32 envs per device,
  one chunk as the whole run, learning from the 2nd iteration on; chunks run until learning has started, then
  1-2 further chunks are timed: env steps/s of the training loop, updates/s, trained frames/s (= updates/s *
  batch_size * train_len). Envs per device are fixed, so the updates per iteration (replay ratio fixed) grow with D:
  this is weak scaling. The learner batch is split over the devices (data-parallel) when batch_size % D == 0.

Efficiency is measured against the "1 device" point of the same run at the same envs per device:
``speedup = rate(D) / rate(1)``, ``efficiency = speedup / D``. Results go to JSON (written after every worker, so an
interrupted run keeps what it measured) and a PNG (left: env steps/s vs envs per device, one line per D; right:
trained frames/s vs D).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

DEFAULT_OUT = Path(__file__).resolve().parent / "results_scaling.json"  # beside this script, from any directory

STEPS_PER_CALL = 10
TRAIN_REPLAY_STEPS_PER_ENV = 250  # replay rows hold this many steps (>= the 31-step window); speed barely depends on it
PARTITIONS = ("shard_map", "gspmd")  # how the env step is split over D > 1 devices (see env_point)
RESULT_PREFIX = "RESULT "
POINT_PREFIX = "POINT "


# ============================================================================================ worker (one per D)
def _placement(tree, n: int) -> dict:
    """Devices holding shards of the env-axis leaves of ``tree`` and the rows per shard (n / D when split)."""
    import jax

    devices, rows = set(), set()
    for leaf in jax.tree.leaves(tree):
        for shard in leaf.addressable_shards:
            devices.add(shard.device.id)
            if leaf.ndim and leaf.shape[0] == n:
                rows.add(int(shard.data.shape[0]))
    return {"state_devices": len(devices), "rows_per_shard": sorted(rows)}


def _collectives(compiled) -> dict:
    """Number of cross-device collectives in a compiled program's HLO (0 = every device works alone)."""
    try:
        text = compiled.as_text()
    except Exception:  # noqa: BLE001
        return {}
    ops = ("all-gather", "all-reduce", "all-to-all", "collective-permute", "reduce-scatter")
    return {op: len(re.findall(rf"= [^=]*? {op}(?:-start)?\(", text)) for op in ops}


def env_point(
    envs_per_device: int,
    mesh,
    num_devices: int,
    resolution: int,
    budget_s: float,
    partition: str = "gspmd",
    seed: int = 0,
) -> dict:
    """Env steps/s of N = envs_per_device * D envs, state split over ``mesh`` along the env axis.

    partition: 'gspmd' jits the vmapped step over the global batch with sharding constraints and lets XLA's
    partitioner split it (how the trainer split it before it moved the env step under shard_map); 'shard_map' runs the same vmapped step on
    each device's own N / D envs (``jax.shard_map``, per-device keys from ``fold_in(key, device index)``), no
    collectives but one scalar mean. With one device (mesh None) both are the plain jitted program ('none').
    """
    import jax
    from jax.sharding import NamedSharding
    from jax.sharding import PartitionSpec as P

    from ramavt_jax import distributed
    from ramavt_jax import env as env_lib
    from ramavt_jax.render import CameraConfig

    n = envs_per_device * num_devices
    tracking_env = env_lib.TrackingEnv(env_lib.EnvConfig(camera=CameraConfig(resolution=resolution), obs_mode="depth"))
    params = tracking_env.default_params()
    v_reset = jax.vmap(tracking_env.reset, in_axes=(0, None))
    v_step = jax.vmap(tracking_env.step, in_axes=(0, 0, 0, None))
    if mesh is None:
        env_sh = rep = None
        partition = "none"
    else:
        env_sh, rep = NamedSharding(mesh, P(distributed.DATA_AXIS)), distributed.replicated(mesh)

    def steps(state, key, num, split, mean):
        def body(state, k):
            k_act, k_env = jax.random.split(k)
            actions = split(jax.random.randint(k_act, (num,), 0, env_lib.NUM_ACTIONS))
            keys = split(jax.random.split(k_env, num))
            obs, state, reward, *_ = v_step(keys, state, actions, params)
            return split(state), mean(reward.mean() + obs[:, 0, 0, 0].mean())

        return jax.lax.scan(body, state, jax.random.split(key, STEPS_PER_CALL))

    if partition == "shard_map":

        def local(state, key):
            key = jax.random.fold_in(key, jax.lax.axis_index(distributed.DATA_AXIS))
            return steps(state, key, envs_per_device, lambda x: x, lambda x: jax.lax.pmean(x, distributed.DATA_AXIS))

        # check_vma=False: the renderer's while_loop carries unsharded-typed buffers
        run = jax.shard_map(
            local,
            mesh=mesh,
            in_specs=(P(distributed.DATA_AXIS), P()),
            out_specs=(P(distributed.DATA_AXIS), P()),
            check_vma=False,
        )
    elif partition in ("gspmd", "none"):

        def run(state, key):  # per-env leaves kept split along the env axis inside the scan
            return steps(state, key, n, lambda t: distributed.constrain_envs(t, mesh), lambda x: x)
    else:
        raise ValueError(f"partition must be 'gspmd' or 'shard_map', got {partition!r}")

    key = jax.random.key(seed)
    reset_keys = jax.random.split(key, n)
    if mesh is not None:
        reset_keys = jax.device_put(reset_keys, env_sh)
    reset = jax.jit(lambda k: v_reset(k, params)[1], in_shardings=env_sh, out_shardings=env_sh)
    state = reset(reset_keys)
    step_fn = jax.jit(run, in_shardings=(env_sh, rep), out_shardings=(env_sh, rep))
    t0 = time.perf_counter()
    compiled = step_fn.lower(state, key).compile()
    compile_s = time.perf_counter() - t0
    state, out = compiled(state, jax.random.key(1))  # warm-up: envs move into the tracked regime
    jax.block_until_ready((state, out))
    times, i, start = [], 0, time.perf_counter()
    # >= 3 timed calls, then more until budget_s; a slow point (>= 3 * budget_s spent) stops earlier
    while (len(times) < 3 and time.perf_counter() - start < 3 * budget_s) or (
        time.perf_counter() - start < budget_s and len(times) < 20
    ):
        t = time.perf_counter()
        state, out = compiled(state, jax.random.key(2 + i))
        jax.block_until_ready((state, out))
        times.append(time.perf_counter() - t)
        i += 1
    dt = statistics.median(times)
    rate = n * STEPS_PER_CALL / dt
    place = _placement(state, n)
    return {
        "kind": "env",
        "partition": partition,
        "devices": num_devices,
        "envs_per_device": envs_per_device,
        "num_envs": n,
        "resolution": resolution,
        "obs_mode": "depth",
        "env_steps_per_s": rate,
        "frames_per_s": rate,
        "call_s": dt,
        "repeats": len(times),
        "compile_s": compile_s,
        **place,
        "placement_ok": place["state_devices"] == num_devices and place["rows_per_shard"] == [envs_per_device],
        "collectives": _collectives(compiled),
    }


def train_config(num_envs: int, iterations_per_chunk: int):
    """The 'quick' preset with ``num_envs`` envs, one chunk as the whole run, learning from the 2nd iteration."""
    from ramavt_jax import presets

    base = presets.preset("quick")
    per_iter = num_envs * base.acting.rollout_steps
    frames_per_update = base.replay.batch_size * base.replay.train_len
    updates = max(
        1, round(base.learner.replay_ratio * per_iter / frames_per_update)
    )  # keep the preset's ratio (2) if whole
    return presets.preset(
        "quick",
        num_envs=num_envs,
        iterations_per_chunk=iterations_per_chunk,
        total_env_steps=per_iter * iterations_per_chunk,
        capacity_steps=num_envs * TRAIN_REPLAY_STEPS_PER_ENV,
        # rows hold 2 * rollout_steps = 40 >= burn_in + train_len + 1 = 31 steps after 2 iterations: can_sample
        learning_starts=2 * per_iter,
        replay_ratio=updates * frames_per_update / per_iter,
        eval_episodes=0,
        checkpoint_every_chunks=0,
    )


def train_point(
    envs_per_device: int,
    mesh,
    num_devices: int,
    iterations_per_chunk: int,
    timed_chunks: int,
    max_warmup_chunks: int = 4,
) -> dict:
    import jax
    import numpy as np

    from ramavt_jax.training import program as train_log

    n = envs_per_device * num_devices
    cfg = train_config(n, iterations_per_chunk)
    prog = train_log._compiled(cfg, None, 1, mesh)
    state = prog.init(jax.random.PRNGKey(0))
    warm, learning = 0, False
    t_warm = time.perf_counter()
    while not learning:  # chunks until every iteration of a chunk learns (the first one compiles nothing: AOT)
        if warm >= max_warmup_chunks:
            raise RuntimeError(f"no learning after {warm} chunks (learning_starts={cfg.learner.learning_starts})")
        state, m = prog.chunk(state)
        m = jax.device_get(m)
        warm += 1
        learning = bool(np.asarray(m.updates)[-1] > 0)
    warm_s = time.perf_counter() - t_warm
    can_sample = bool(np.asarray(jax.device_get(prog.trainer.replay.can_sample(state.replay))))
    walls, updates = [], []
    for _ in range(timed_chunks):
        t = time.perf_counter()
        state, m = prog.chunk(state)
        m = jax.device_get(m)
        jax.block_until_ready(state)
        walls.append(time.perf_counter() - t)
        updates.append(int(np.asarray(m.updates).sum()))
    expected = cfg.updates_per_iteration * cfg.run.iterations_per_chunk
    wall = statistics.median(walls)
    ups = statistics.median(u / w for u, w in zip(updates, walls))
    frames_per_update = cfg.replay.batch_size * cfg.replay.train_len
    return dict(
        kind="train",
        partition="none" if mesh is None else "trainer",
        devices=num_devices,
        envs_per_device=envs_per_device,
        num_envs=n,
        preset="quick",
        resolution=cfg.env.camera.resolution,
        batch_size=cfg.replay.batch_size,
        train_len=cfg.replay.train_len,
        rollout_steps=cfg.acting.rollout_steps,
        iterations_per_chunk=cfg.run.iterations_per_chunk,
        updates_per_iteration=cfg.updates_per_iteration,
        replay_ratio=cfg.learner.replay_ratio,
        learning_starts=cfg.learner.learning_starts,
        replay_capacity=cfg.replay.capacity_steps,
        data_parallel_batch=mesh is not None and cfg.replay.batch_size % num_devices == 0,
        warmup_chunks=warm,
        warmup_s=warm_s,
        replay_can_sample=can_sample,
        timed_chunks=len(walls),
        chunk_s=wall,
        chunk_wall_s=walls,
        updates_per_chunk=updates,
        all_iterations_learned=all(u == expected for u in updates),
        env_steps_per_s=statistics.median(cfg.env_steps_per_chunk / w for w in walls),
        updates_per_s=ups,
        trained_frames_per_s=ups * frames_per_update,
        compile_s=prog.compile_s,
        memory=prog.memory,
        collectives=_collectives(prog.chunk),
        **_placement(state.actor.env_state, n),
    )


def worker(args) -> None:
    """Runs inside the D-device process: measure, print POINT lines as it goes and one RESULT line at the end."""
    import jax

    from ramavt_jax import distributed

    devices = jax.devices()
    d = args.devices
    if len(devices) < d:
        raise SystemExit(f"worker: {d} devices requested but {len(devices)} visible ({devices[0].platform})")
    mesh = distributed.make_mesh(d)
    info = {
        "devices": d,
        "platform": devices[0].platform,
        "device_kind": devices[0].device_kind,
        "visible_devices": len(devices),
        "jax": jax.__version__,
        "forced_cpu_devices": not args.real_devices,
    }
    print(
        f"worker D={d}: {d} x {info['device_kind']} ({info['platform']}), mesh "
        f"{None if mesh is None else dict(mesh.shape)}",
        flush=True,
    )
    points = []
    for e in args.envs_per_device:
        for partition in args.env_partitions if mesh is not None else ["none"]:
            p = env_point(e, mesh, d, args.resolution, args.budget, partition)
            points.append(p)
            print(POINT_PREFIX + json.dumps(p), flush=True)
    if args.train_envs_per_device > 0:
        p = train_point(args.train_envs_per_device, mesh, d, args.iterations_per_chunk, args.timed_chunks)
        points.append(p)
        print(POINT_PREFIX + json.dumps(p), flush=True)
    print(RESULT_PREFIX + json.dumps({"info": info, "points": points}), flush=True)


# ============================================================================================ parent
def _probe_backend(timeout_s: float = 120) -> dict:
    """Backend and device count as a fresh process sees them (this process starts no JAX backend)."""
    code = "import json, jax; d = jax.devices(); print(json.dumps([d[0].platform, len(d), d[0].device_kind]))"
    try:
        r = subprocess.run([sys.executable, "-c", code], check=False, capture_output=True, text=True, timeout=timeout_s)
        platform_, count, kind = json.loads(r.stdout.strip().splitlines()[-1])
        return {"platform": platform_, "count": count, "device_kind": kind}
    except Exception as e:  # noqa: BLE001
        return {"platform": "cpu", "count": 1, "device_kind": "unknown", "probe_error": repr(e)}


def _worker_env(d: int, real_devices: bool) -> dict:
    env = dict(os.environ)
    if not real_devices:
        flags = re.sub(r"--xla_force_host_platform_device_count=\S+", "", env.get("XLA_FLAGS", "")).strip()
        env["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count={d}".strip()
        env["JAX_PLATFORMS"] = "cpu"
    return env


def _run_worker(d: int, worker_args: list[str], real_devices: bool, timeout_s: float) -> dict:
    """One worker process; streams its output; returns its RESULT (or the POINTs it printed before failing)."""
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", "--devices", str(d), *worker_args]
    if real_devices:
        cmd.append("--real-devices")
    t0 = time.time()
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=_worker_env(d, real_devices)
    )
    lines: list[str] = []

    def pump():
        for line in proc.stdout:
            lines.append(line.rstrip("\n"))
            if line.startswith(POINT_PREFIX):
                print(f"  [D={d}] {_row(json.loads(line[len(POINT_PREFIX) :]))}", flush=True)
            elif not line.startswith(RESULT_PREFIX) and line.strip():
                print(f"  [D={d}] {line.rstrip()}", flush=True)

    reader = threading.Thread(target=pump, daemon=True)
    reader.start()
    status = "ok"
    try:
        proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        status = f"timeout after {timeout_s:.0f} s"
    reader.join(timeout=10)
    if status == "ok" and proc.returncode != 0:
        status = f"exit code {proc.returncode}"
    result = None
    for line in lines:
        if line.startswith(RESULT_PREFIX):
            result = json.loads(line[len(RESULT_PREFIX) :])
    if result is None:  # keep the points measured before the failure
        measured = [json.loads(x[len(POINT_PREFIX) :]) for x in lines if x.startswith(POINT_PREFIX)]
        result = {"info": {"devices": d}, "points": measured}
        if status == "ok":
            status = "no RESULT line"
    result["status"], result["wall_s"] = status, time.time() - t0
    if status != "ok":
        result["output_tail"] = lines[-30:]
        print(f"  [D={d}] worker failed ({status}); keeping its {len(result['points'])} point(s)", flush=True)
    return result


def add_efficiency(points: list[dict]) -> None:
    """speedup and efficiency of every point against the "1 device" point at the same envs per device."""
    base = {(p["kind"], p["envs_per_device"]): p for p in points if p["devices"] == 1}
    for p in points:
        key = "env_steps_per_s" if p["kind"] == "env" else "trained_frames_per_s"
        b = base.get((p["kind"], p["envs_per_device"]))
        if b is None:
            p["speedup_vs_1_device"] = p["efficiency"] = None
            continue
        p["speedup_vs_1_device"] = p[key] / b[key]
        p["efficiency"] = p["speedup_vs_1_device"] / p["devices"]


def _row(p: dict) -> str:
    coll = sum((p.get("collectives") or {}).values())
    if p["kind"] == "env":
        return (
            f"env {p['partition']:>9} D={p['devices']} envs/dev {p['envs_per_device']:>4} (N={p['num_envs']:>4}): "
            f"{p['env_steps_per_s']:>6.0f} env steps/s, compile {p['compile_s']:.1f} s, state on "
            f"{p['state_devices']} device(s), rows/shard {p['rows_per_shard']}, {coll} collectives"
        )
    return (
        f"train D={p['devices']} envs/dev {p['envs_per_device']:>4} (N={p['num_envs']:>4}): "
        f"{p['env_steps_per_s']:>7.0f} env steps/s, {p['updates_per_s']:.2f} updates/s, "
        f"{p['trained_frames_per_s']:.0f} trained frames/s, chunk {p['chunk_s']:.1f} s, compile "
        f"{p['compile_s']:.1f} s, data-parallel batch: {p['data_parallel_batch']}, {coll} collectives"
    )


def table(points: list[dict]) -> str:
    def f(v, fmt, suffix=""):
        return "-" if v is None else format(v, fmt) + suffix

    cols = [
        ("kind", 5, "<"),
        ("split by", 9, "<"),
        ("D", 2, ">"),
        ("envs/dev", 8, ">"),
        ("envs", 5, ">"),
        ("env steps/s", 11, ">"),
        ("updates/s", 9, ">"),
        ("trained fr/s", 12, ">"),
        ("vs 1 device", 11, ">"),
        ("efficiency", 10, ">"),
        ("compile s", 9, ">"),
        ("on devs", 7, ">"),
        ("collectives", 11, ">"),
    ]
    lines = [
        "| " + " | ".join(f"{name:{a}{w}}" for name, w, a in cols) + " |",
        "|" + "|".join("-" * (w + 2) for _, w, _ in cols) + "|",
    ]
    order = {"none": 0, "shard_map": 1, "gspmd": 2, "trainer": 3}
    for p in sorted(
        points, key=lambda p: (p["kind"], p["envs_per_device"], p["devices"], order.get(p.get("partition"), 3))
    ):
        train = p["kind"] == "train"
        coll = p.get("collectives")
        values = [
            p["kind"],
            p.get("partition", "-"),
            p["devices"],
            p["envs_per_device"],
            p["num_envs"],
            f(p["env_steps_per_s"], ",.0f"),
            f(p.get("updates_per_s") if train else None, ".2f"),
            f(p.get("trained_frames_per_s") if train else None, ",.0f"),
            f(p.get("speedup_vs_1_device"), ".2f", "x"),
            f(p.get("efficiency"), ".0%"),
            f(p["compile_s"], ".1f"),
            p["state_devices"],
            "-" if coll is None else sum(coll.values()),
        ]
        lines.append("| " + " | ".join(f"{v!s:{a}{w}}" for v, (_, w, a) in zip(values, cols)) + " |")
    return "\n".join(lines)


def plot(points: list[dict], path, title: str = "") -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_env, ax_train) = plt.subplots(1, 2, figsize=(11, 4))
    env = [p for p in points if p["kind"] == "env"]
    lines = sorted({(p["devices"], p.get("partition", "none")) for p in env})
    palette = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    colors = {d: palette[i % len(palette)] for i, d in enumerate(sorted({d for d, _ in lines}))}
    for d, part in lines:
        ps = sorted(
            (p for p in env if p["devices"] == d and p.get("partition", "none") == part),
            key=lambda p: p["envs_per_device"],
        )
        label = f"{d} device{'s' if d > 1 else ''}" + ("" if part == "none" else f" ({part})")
        ax_env.plot(
            [p["envs_per_device"] for p in ps],
            [p["env_steps_per_s"] for p in ps],
            marker="o",
            ls="--" if part == "gspmd" else "-",
            color=colors[d],
            label=label,
        )
    ax_env.set_xscale("log", base=2)
    ax_env.set_yscale("log")
    sizes = sorted({p["envs_per_device"] for p in env})
    ax_env.set_xticks(sizes, [str(e) for e in sizes])
    ax_env.set_xlabel("envs per device")
    ax_env.set_ylabel("env steps/s (64x64 depth)")
    ax_env.set_title("env throughput")
    ax_env.grid(alpha=0.3)
    ax_env.legend(fontsize=8)
    train = sorted((p for p in points if p["kind"] == "train"), key=lambda p: p["devices"])
    if train:
        ds = [p["devices"] for p in train]
        ax_train.plot(ds, [p["trained_frames_per_s"] for p in train], marker="o", label="trainer chunk")
        one = next((p for p in train if p["devices"] == 1), None)
        if one is not None:
            ax_train.plot(
                ds, [one["trained_frames_per_s"] * d for d in ds], ls="--", color="gray", label="linear from 1 device"
            )
        ax_train.set_xticks(ds)
        ax_train.legend(fontsize=8, loc="upper left")
    ax_train.set_xlabel("devices")
    ax_train.set_ylabel("trained frames/s")
    ax_train.set_title(f"training ('quick' preset, {train[0]['envs_per_device'] if train else '?'} envs/device)")
    ax_train.grid(alpha=0.3)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _write(out: Path, result: dict) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))


def run(
    out: str | Path = str(DEFAULT_OUT),
    quick: bool = False,
    devices=None,
    envs_per_device=None,
    train_envs_per_device: int | None = None,
    real_devices: bool | None = None,
    iterations_per_chunk: int | None = None,
    timed_chunks: int | None = None,
    budget_s: float | None = None,
    resolution: int = 64,
    timeout_s: float | None = None,
    png: str | Path | None = None,
    env_partitions=PARTITIONS,
) -> dict:
    """Launch one worker per device count, print the table, write JSON to ``out`` and the plot to ``png`` (default
    ``scaling.png`` beside ``out``). ``real_devices`` None: real devices when a probe process sees an accelerator,
    else forced CPU devices. ``train_envs_per_device`` 0 skips the training measurement."""
    import jax  # importing starts no backend

    t_start = time.time()
    out = Path(out)
    png = Path(png) if png is not None else out.with_name("scaling.png")
    probe = None
    if real_devices is None:
        probe = _probe_backend()
        real_devices = probe["platform"] != "cpu"
    if devices is None:
        devices = (1, 2) if quick else (1, 2, 4)
        if real_devices and probe is not None:
            devices = tuple(d for d in (1, 2, 4, 8, 16) if d <= probe["count"]) or (1,)
    envs_per_device = tuple(envs_per_device or ((16, 64) if quick else (16, 64, 256)))
    if train_envs_per_device is None:
        train_envs_per_device = 16 if quick else 32
    iterations_per_chunk = iterations_per_chunk or (3 if quick else 5)
    timed_chunks = timed_chunks or (1 if quick else 2)
    budget_s = budget_s if budget_s is not None else 1.0
    timeout_s = timeout_s or (300 if quick else 480)
    worker_args = [
        "--envs-per-device",
        *map(str, envs_per_device),
        "--train-envs-per-device",
        str(train_envs_per_device),
        "--iterations-per-chunk",
        str(iterations_per_chunk),
        "--timed-chunks",
        str(timed_chunks),
        "--budget",
        str(budget_s),
        "--resolution",
        str(resolution),
        "--env-partitions",
        *env_partitions,
    ]
    machine = {
        "platform": platform.platform(),
        "processor": platform.processor(),
        "cpu_count": os.cpu_count(),
        "jax": jax.__version__,
        "loadavg_start": os.getloadavg(),
        "python": platform.python_version(),
        "forced_cpu_devices": not real_devices,
        "probe": probe,
    }
    settings = {
        "devices": list(devices),
        "envs_per_device": list(envs_per_device),
        "train_envs_per_device": train_envs_per_device,
        "iterations_per_chunk": iterations_per_chunk,
        "timed_chunks": timed_chunks,
        "budget_s": budget_s,
        "resolution": resolution,
        "quick": quick,
        "steps_per_call": STEPS_PER_CALL,
        "timeout_s": timeout_s,
        "baseline": "1 device",
        "env_partitions": list(env_partitions),
    }
    where = "real devices" if real_devices else "forced CPU devices (all share this machine's cores)"
    print(
        f"scaling over D in {list(devices)} ({where}); envs/device {list(envs_per_device)}; training 'quick' "
        f"preset with {train_envs_per_device} envs/device",
        flush=True,
    )
    workers, points = [], []
    result = {"partial": True, "machine": machine, "settings": settings, "workers": workers, "points": points}
    for d in devices:
        w = _run_worker(d, worker_args, real_devices, timeout_s)
        workers.append({k: v for k, v in w.items() if k != "points"})
        if w.get("info", {}).get("device_kind") and "device_kind" not in machine:
            machine["device_kind"] = w["info"]["device_kind"]
            machine["device_platform"] = w["info"]["platform"]
        points.extend(w["points"])
        add_efficiency(points)
        _write(out, result)
    machine["loadavg_end"] = os.getloadavg()
    result["partial"] = any(w["status"] != "ok" for w in workers)
    result["wall_s"] = time.time() - t_start
    print()
    print(table(points))
    print(
        "vs 1 device = rate(D) / rate(1 device) at the same envs per device; efficiency = that / D. "
        f"Load average {machine['loadavg_start'][0]:.1f} -> {machine['loadavg_end'][0]:.1f} on "
        f"{os.cpu_count()} cores."
    )
    _write(out, result)
    if points:
        plot(
            points,
            png,
            title=f"{machine.get('device_kind', '?')} x D, {where}; load average {machine['loadavg_start'][0]:.1f}",
        )
        result["png"] = str(png)
        print(f"wrote {out} and {png} ({result['wall_s']:.0f} s)")
    else:
        print(f"wrote {out} (no points measured)")
    return result


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default=str(DEFAULT_OUT))
    p.add_argument("--png", default=None, help="plot path (default: scaling.png beside --out)")
    p.add_argument("--quick", action="store_true", help="D in 1 2; 16 and 64 envs/device; shorter timing")
    p.add_argument("--devices", type=int, nargs="+", default=None, help="device counts D (one worker each)")
    p.add_argument("--envs-per-device", type=int, nargs="+", default=None)
    p.add_argument("--train-envs-per-device", type=int, default=None, help="0 = skip the training measurement")
    p.add_argument("--iterations-per-chunk", type=int, default=None)
    p.add_argument("--timed-chunks", type=int, default=None)
    p.add_argument("--budget", type=float, default=None, help="seconds of timed calls per env point (>= 3 calls)")
    p.add_argument("--resolution", type=int, default=64)
    p.add_argument(
        "--env-partitions",
        nargs="+",
        default=None,
        choices=PARTITIONS,
        help="how the env step is split over D > 1 devices (default: both)",
    )
    p.add_argument("--timeout", type=float, default=None, help="seconds per worker before it is killed")
    group = p.add_mutually_exclusive_group()
    group.add_argument(
        "--real-devices",
        dest="real_devices",
        action="store_true",
        default=None,
        help="use the first D real devices (GPUs) instead of forced CPU devices",
    )
    group.add_argument(
        "--forced-cpu",
        dest="real_devices",
        action="store_false",
        help="forced CPU devices even where an accelerator is visible",
    )
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.worker:
        a.devices = a.devices[0] if a.devices else 1
        a.real_devices = bool(a.real_devices)
        a.envs_per_device = a.envs_per_device or [16, 64, 256]
        a.train_envs_per_device = 32 if a.train_envs_per_device is None else a.train_envs_per_device
        a.iterations_per_chunk = a.iterations_per_chunk or 5
        a.timed_chunks = a.timed_chunks or 2
        a.budget = 2.0 if a.budget is None else a.budget
        a.env_partitions = a.env_partitions or list(PARTITIONS)
        worker(a)
        return
    run(
        a.out,
        a.quick,
        a.devices,
        a.envs_per_device,
        a.train_envs_per_device,
        a.real_devices,
        a.iterations_per_chunk,
        a.timed_chunks,
        a.budget,
        a.resolution,
        a.timeout,
        a.png,
        a.env_partitions or PARTITIONS,
    )


if __name__ == "__main__":
    main()
