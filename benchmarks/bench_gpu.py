"""The accelerator check as one command: env steps/s from 1k to 64k envs, and the training chunk of the `quick` and
`paper` presets (env steps/s, updates/s, trained frames/s, the projected wall time of a whole run), within a deadline.

    python benchmarks/bench_gpu.py --out results_gpu        # = `ramavt bench gpu`; about 5-8 min on one H100/H200
    python benchmarks/bench_gpu.py --report results_gpu/results_gpu.json   # Markdown tables for RESULTS.md

On the lent machine (its image has jax with CUDA but not MuJoCo or flashbax): first, here, ``bash
benchmarks/gpu_wheels.sh`` (the missing packages as wheels in the ignored folder .whl/, 29 MB), then one device run
with ``carry=[".whl"]`` and ``timeout_s=570``::

    python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl &&
    export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1 && python3 benchmarks/bench_gpu.py --out $OUT --deadline-s 420

Made for a lent machine whose time is short and counted: the most wanted figures come first (64x64 depth env steps
from 1k to 64k envs, then the quick preset's chunk, then the paper preset's, then RGBD and 128x128); an item that
would start with less than ``--min-left-s`` before ``--deadline-s`` is skipped and marked so; an item that fails
(out of memory, say) is recorded with its one-line error and the next one runs; the JSON is rewritten after every
item, so a run cut short keeps what it measured. ``--smoke`` runs the same code at toy sizes (tests, CPU).

Chunk figures: the preset's compiled program as ``ramavt train`` runs it, from a fresh state with ``learning_starts``
cut to one iteration's env steps (so the timed chunks learn), ``--chunks`` chunks timed after a first one. The
projected wall time is the program's compile time plus ``total_env_steps`` at the timed rate; a real run learns only
after its own ``learning_starts``, so the projection is an upper bound on training (evaluation not included).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import jax
from bench_env import bench_point, machine  # noqa: E402 (the script's directory)

from ramavt_jax import presets
from ramavt_jax.training import program

ENV_FIRST = [("depth", 64, n) for n in (1024, 4096, 16384, 65536)]
ENV_LATER = [("rgbd", 64, 16384), ("depth", 128, 16384)]
PRESETS = ("quick", "paper")
SMOKE_ENV, SMOKE_PRESETS = [("depth", 16, 8)], ("smoke",)


def plan(smoke: bool = False) -> list[tuple]:
    """The items in the order they run: ("env", mode, resolution, envs) and ("chunk", preset)."""
    if smoke:
        return [("env", *p) for p in SMOKE_ENV] + [("chunk", p) for p in SMOKE_PRESETS]
    return [("env", *p) for p in ENV_FIRST] + [("chunk", p) for p in PRESETS] + [("env", *p) for p in ENV_LATER]


def device_info() -> dict:
    dev = jax.devices()[0]
    stats = dev.memory_stats() if hasattr(dev, "memory_stats") else None
    return {**machine(), "memory_limit_bytes": (stats or {}).get("bytes_limit")}


def chunk_throughput(preset: str, chunks: int) -> dict:
    """Time ``chunks`` training chunks of ``preset`` after a first one; see the module docstring. The program is the
    one ``ramavt train`` runs (``training.program``: the chunk compiled ahead of time, its state donated)."""
    base = presets.preset(preset)
    cfg = presets.preset(preset, eval_episodes=0, learning_starts=base.env_steps_per_iteration)
    prog = program.compiled_program(cfg, None)
    state = prog.init(jax.random.PRNGKey(0))
    t0 = time.perf_counter()
    state, _ = jax.block_until_ready(prog.chunk(state))  # its first iteration does not learn yet
    first_s = time.perf_counter() - t0
    times, updates = [], 0
    for _ in range(chunks):
        t = time.perf_counter()
        state, metrics = jax.block_until_ready(prog.chunk(state))
        times.append(time.perf_counter() - t)
        updates += int(metrics.updates.sum())
    seconds = sum(times)
    rate = chunks * cfg.env_steps_per_chunk / seconds
    return {
        "preset": preset,
        "num_envs": cfg.acting.num_envs,
        "resolution": cfg.env.camera.resolution,
        "batch_size": cfg.replay.batch_size,
        "compile_s": prog.compile_s,
        "chunk_s": times,
        "first_chunk_s": first_s,
        "env_steps_per_chunk": cfg.env_steps_per_chunk,
        "env_steps_per_s": rate,
        "updates_per_s": updates / seconds,
        "trained_frames_per_s": updates * cfg.replay.batch_size * cfg.replay.train_len / seconds,
        "memory_bytes": prog.memory,
        "total_env_steps": base.run.total_env_steps,
        "projected_train_wall_s": prog.compile_s + base.run.total_env_steps / rate,
    }


def _measure(item: tuple, budget_s: float, chunks: int) -> dict:
    if item[0] == "env":
        _, mode, res, n = item
        rows, _ = bench_point(n, res, mode, budget_s, ("new",))
        return rows[0]
    return chunk_throughput(item[1], chunks)


def run(
    out_dir: str,
    deadline_s: float = 480.0,
    min_left_s: float = 45.0,
    budget_s: float = 2.0,
    chunks: int = 2,
    smoke: bool = False,
    clock=time.monotonic,
) -> dict:
    """Run the plan, writing ``out_dir``/results_gpu.json after every item. Returns the results."""
    start = clock()
    path = Path(out_dir) / "results_gpu.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    result = {"device": device_info(), "deadline_s": deadline_s, "items": []}
    print(f"{result['device']['backend']} ({result['device']['device_kind']}), deadline {deadline_s:.0f} s", flush=True)
    for item in plan(smoke):
        left = deadline_s - (clock() - start)
        row = {"item": list(item)}
        if left < min_left_s:
            row["skipped"] = f"{left:.0f} s left before the deadline"
        else:
            try:
                row.update(_measure(item, budget_s, chunks))
            except Exception as e:  # recorded, and the next item runs (e.g. out of memory at 64k envs)
                row["error"] = f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"[:300]
        row["elapsed_s"] = clock() - start
        result["items"].append(row)
        path.write_text(json.dumps(result, indent=1))
        print(_line(row), flush=True)
    print(f"wrote {path}")
    return result


def _line(row: dict) -> str:
    what = " ".join(map(str, row["item"]))
    if "skipped" in row or "error" in row:
        return f"{what}: {row.get('skipped') or row['error']}"
    if row["item"][0] == "env":
        return f"{what}: {row['env_steps_per_s']:,.0f} env steps/s (compile {row['compile_s']:.1f} s)"
    return (
        f"{what}: {row['env_steps_per_s']:,.0f} env steps/s, {row['updates_per_s']:.1f} updates/s, "
        f"{row['trained_frames_per_s']:,.0f} trained frames/s; "
        f"whole run ~{row['projected_train_wall_s'] / 60:.1f} min"
    )


def report(result: dict) -> str:
    """Markdown tables of a results_gpu.json (written from the figures, for RESULTS.md)."""
    dev = result["device"]
    lines = [
        f"Device: {dev['device_kind']} ({dev['backend']}, jax {dev['jax']}, {dev['cpu_count']} host CPUs)",
        "",
        "| env: mode | resolution | envs | env steps/s | compile s |",
        "|---|---|---|---|---|",
    ]
    chunks = [
        "",
        "| preset | envs | resolution | batch | env steps/s | updates/s | trained frames/s | chunk s | "
        "compile s | projected training wall |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in result["items"]:
        item, note = row["item"], row.get("skipped") or row.get("error")
        if item[0] == "env":
            figures = f"{row['env_steps_per_s']:,.0f} | {row['compile_s']:.1f}" if not note else f"{note} | -"
            lines.append(f"| {item[1]} | {item[2]} | {item[3]} | {figures} |")
        elif note:
            chunks.append(f"| {item[1]} | - | - | - | {note} | - | - | - | - | - |")
        else:
            chunks.append(
                f"| {item[1]} | {row['num_envs']} | {row['resolution']} | {row['batch_size']} | "
                f"{row['env_steps_per_s']:,.0f} | {row['updates_per_s']:.2f} | "
                f"{row['trained_frames_per_s']:,.0f} | {', '.join(f'{s:.3g}' for s in row['chunk_s'])} | "
                f"{row['compile_s']:.0f} | {row['projected_train_wall_s'] / 60:.1f} min |"
            )
    return "\n".join(lines + chunks)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default=os.environ.get("OUT", "benchmarks"), help="folder for results_gpu.json")
    p.add_argument("--deadline-s", type=float, default=480.0, help="no item starts after this (default 8 min)")
    p.add_argument("--min-left-s", type=float, default=45.0, help="skip an item with less time than this left")
    p.add_argument("--budget", type=float, default=2.0, help="timing budget per env point, s")
    p.add_argument("--chunks", type=int, default=2, help="timed chunks per preset, after the compiling one")
    p.add_argument("--smoke", action="store_true", help="toy sizes (tests, CPU)")
    p.add_argument("--report", default=None, help="print Markdown tables of this results_gpu.json and exit")
    a = p.parse_args(argv)
    if a.report:
        print(report(json.loads(Path(a.report).read_text())))
        return
    result = run(a.out, a.deadline_s, a.min_left_s, a.budget, a.chunks, a.smoke)
    print("\n" + report(result))


if __name__ == "__main__":
    main()
