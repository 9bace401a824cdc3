"""How close a learner update runs to this machine's limits: XLA's own count of the update's floating-point work and
memory traffic, its measured time, and the machine's measured matmul rate and memory bandwidth, in one run.

    python lab/benchmarks/roofline_learner.py                   # quick preset -> benchmarks/results_roofline.json
    python lab/benchmarks/roofline_learner.py --preset paper --batch-size 8

Figures:
  flops, bytes        ``compiled.cost_analysis()`` of ``Trainer.update`` (XLA:CPU's count after fusion)
  update_ms           median of ``--repeats`` timed updates after a warm-up
  gemm_gflops         a large square f32 matmul (2048^3), jitted: the best rate XLA reaches on this machine
  small_gemm_gflops   the update's largest matmul shape (the second conv's im2col product), jitted alone
  copy_gbs            a jitted ``x + 1`` over 256 MiB (read + write counted)
  bound_ms            the update's time if it ran at ``gemm_gflops`` and ``copy_gbs`` at once (max of the two)
  used_bytes          the same traffic counted by hlo_profile.traffic_breakdown with slices and gathers at what they
                      read (XLA counts their whole operand), and ``used_bound_ms`` from it
  traffic_by_line     those bytes by the ramavt_jax source line that made each instruction (top 20)

The bounds assume every byte comes from memory at the copy rate; data still in cache moves faster, so they say how far
the current program is from this machine's limits, not how fast any program could be.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import jax
import jax.numpy as jnp
from bench_train import _filled_replay, _median_time, machine_info, merge_json  # noqa: E402 (the script's directory)
from hlo_profile import traffic_breakdown  # noqa: E402
from profile_learner import _label  # noqa: E402

from ramavt_jax import presets
from ramavt_jax import train as T


def _cost(compiled) -> tuple[float, float]:
    """(flops, bytes accessed) of a compiled program, by XLA's cost analysis."""
    cost = compiled.cost_analysis()
    cost = cost[0] if isinstance(cost, (list, tuple)) else cost
    return float(cost.get("flops", 0.0)), float(cost.get("bytes accessed", 0.0))


def machine_limits(repeats: int) -> dict:
    """Measured matmul rates (GFLOP/s) and copy bandwidth (GB/s) of this machine under XLA."""
    key = jax.random.PRNGKey(0)
    big = jax.random.normal(key, (2048, 2048))
    matmul = jax.jit(jnp.matmul)
    gemm = 2 * 2048**3 / _median_time(lambda: matmul(big, big), repeats) / 1e9
    # the second conv under the gradient: 672 frames x 8 x 8 positions, 3 x 3 x 16 patch -> 32 channels
    patches, kernel = jax.random.normal(key, (672 * 64, 144)), jax.random.normal(key, (144, 32))
    small = 2 * patches.shape[0] * 144 * 32 / _median_time(lambda: matmul(patches, kernel), repeats) / 1e9
    x = jnp.zeros((64 * 2**20,), jnp.float32)  # 256 MiB
    add_one = jax.jit(lambda a: a + 1.0)
    copy = 2 * x.nbytes / _median_time(lambda: add_one(x), repeats) / 1e9
    return {"gemm_gflops": gemm, "small_gemm_gflops": small, "copy_gbs": copy}


def roofline(preset: str, repeats: int, batch_size: int | None = None) -> dict:
    cfg = presets.preset(preset, eval_episodes=0, learning_starts=0)
    if batch_size:
        cfg = cfg.override(batch_size=batch_size)
    tr = T.Trainer(cfg)
    key = jax.random.PRNGKey(0)
    learner, replay_state = jax.jit(tr.init)(key).learner, _filled_replay(tr, key)
    update = jax.jit(tr.update).lower(learner, replay_state, key).compile()
    flops, traffic = _cost(update)
    by_line, totals = traffic_breakdown(update.as_text(), _label)
    seconds = _median_time(lambda: update(learner, replay_state, key), repeats)
    limits = machine_limits(repeats)
    trained = cfg.replay.batch_size * cfg.replay.train_len
    bound = max(flops / (limits["gemm_gflops"] * 1e9), traffic / (limits["copy_gbs"] * 1e9))
    used_bound = max(flops / (limits["gemm_gflops"] * 1e9), totals["used"] / (limits["copy_gbs"] * 1e9))
    return {
        "preset": preset,
        "batch_size": cfg.replay.batch_size,
        "trained_frames_per_update": trained,
        "flops": flops,
        "bytes": traffic,
        "update_ms": 1e3 * seconds,
        "achieved_gflops": flops / seconds / 1e9,
        "achieved_gbs": traffic / seconds / 1e9,
        **limits,
        "bound_ms": 1e3 * bound,
        "trained_frames_per_s": trained / seconds,
        "bound_trained_frames_per_s": trained / bound,
        "used_bytes": totals["used"],
        "whole_operand_bytes": totals["whole_operands"],
        "used_bound_ms": 1e3 * used_bound,
        "traffic_by_line": dict(list(by_line.items())[:20]),
    }


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--preset", default="quick", choices=sorted(presets.PRESETS))
    p.add_argument("--batch-size", type=int, default=None)
    p.add_argument("--repeats", type=int, default=15)
    p.add_argument("--out", default=str(Path(__file__).resolve().parent / "results_roofline.json"))
    a = p.parse_args(argv)
    t0, load0 = time.time(), os.getloadavg()
    r = roofline(a.preset, a.repeats, a.batch_size)
    r["machine"] = machine_info(load0, t0)
    print(
        f"update ({a.preset}, batch {r['batch_size']}): {r['flops'] / 1e9:.2f} GFLOP, {r['bytes'] / 1e9:.2f} GB "
        f"accessed (XLA's count), {r['update_ms']:.1f} ms -> {r['achieved_gflops']:.1f} GFLOP/s, "
        f"{r['achieved_gbs']:.1f} GB/s, {r['trained_frames_per_s']:.0f} trained frames/s"
    )
    print(
        f"machine: {r['gemm_gflops']:.1f} GFLOP/s (2048^3 matmul), {r['small_gemm_gflops']:.1f} GFLOP/s "
        f"(43008x144x32 matmul), {r['copy_gbs']:.1f} GB/s (x + 1 over 256 MiB)"
    )
    print(
        f"bound: {r['bound_ms']:.1f} ms per update at both limits at once "
        f"({r['bound_trained_frames_per_s']:.0f} trained frames/s); load {load0[0]:.1f} -> {os.getloadavg()[0]:.1f}"
    )
    print(
        f"traffic counting slices and gathers at what they read: {r['used_bytes'] / 1e9:.2f} GB "
        f"(every operand whole: {r['whole_operand_bytes'] / 1e9:.2f} GB) -> bound {r['used_bound_ms']:.1f} ms"
    )
    for line, b in list(r["traffic_by_line"].items())[:12]:
        print(f"  {b / 1e6:7.1f} MB {100 * b / r['used_bytes']:5.1f} %  {line}")
    merge_json(a.out, f"{a.preset}_b{r['batch_size']}", r)


if __name__ == "__main__":
    main()
