"""The training chunk compiled at XLA's default LLVM optimisation level against a lower one, in one process.

    python lab/benchmarks/bench_compile_level.py [--level 1] [--chunks 8] [--preset quick]

Compiles the preset's chunk twice (the persistent cache off, so both compile from cold): at the backend's default
and with ``xla_backend_optimization_level=LEVEL``. Each program then runs its own chain of states from the same
initial state, the two alternating chunk by chunk (A B, B A, ...), so that both see the same machine load and the
same stage of training. Prints and writes (``--out``, JSON) the compile times, every chunk's time, the medians and
the load average. A lower level that compiles faster and runs as fast would shorten every run's start-up.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import jax

sys.path[:0] = [str(Path(__file__).resolve().parent), str(Path(__file__).resolve().parents[2] / "benchmarks")]
from bench_train import code_version, merge_json  # noqa: E402

from ramavt_jax import presets  # noqa: E402
from ramavt_jax.train import Trainer  # noqa: E402

DEFAULT_OUT = Path(__file__).resolve().parent / "results_compile_level.json"


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--level", type=int, default=1, help="the lower xla_backend_optimization_level to compare")
    p.add_argument("--chunks", type=int, default=8, help="chunks per program")
    p.add_argument("--preset", default="quick")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT)
    a = p.parse_args(argv)
    jax.config.update("jax_enable_compilation_cache", False)
    load = [os.getloadavg()[0]]
    trainer = Trainer(presets.preset(a.preset))
    init = jax.jit(trainer.init)
    lowered = jax.jit(trainer.chunk, donate_argnums=0).lower(jax.eval_shape(trainer.init, jax.random.PRNGKey(0)))
    names = {"default": None, f"level{a.level}": {"xla_backend_optimization_level": a.level}}
    programs, compile_s = {}, {}
    for name, options in names.items():
        t = time.perf_counter()
        programs[name] = lowered.compile(options)
        compile_s[name] = time.perf_counter() - t
        print(f"{name}: compiled in {compile_s[name]:.1f} s", flush=True)
    states = {name: init(jax.random.PRNGKey(0)) for name in names}
    chunk_s: dict[str, list[float]] = {name: [] for name in names}
    order = list(names)
    for k in range(a.chunks):
        for name in order if k % 2 == 0 else order[::-1]:
            t = time.perf_counter()
            states[name], metrics = programs[name](states[name])
            jax.block_until_ready(metrics)
            chunk_s[name].append(time.perf_counter() - t)
        print(f"chunk {k + 1}: " + ", ".join(f"{n} {chunk_s[n][-1]:.2f} s" for n in order), flush=True)
    load.append(os.getloadavg()[0])
    medians = {n: statistics.median(v) for n, v in chunk_s.items()}
    low = f"level{a.level}"
    print(
        f"median chunk: default {medians['default']:.2f} s, {low} {medians[low]:.2f} s "
        f"({medians[low] / medians['default']:.3f}x); compile {compile_s['default']:.1f} s against "
        f"{compile_s[low]:.1f} s; load {load[0]:.1f} -> {load[1]:.1f}"
    )
    merge_json(
        a.out,
        f"{a.preset}_level{a.level}",
        dict(
            compile_s=compile_s,
            chunk_s=chunk_s,
            median_chunk_s=medians,
            load=load,
            date=time.strftime("%Y-%m-%d"),
            commit=code_version(),
        ),
    )


if __name__ == "__main__":
    main()
