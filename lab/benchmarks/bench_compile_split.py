"""The training chunk compiled as one program against its acting and learning halves compiled as two, in parallel.

    python lab/benchmarks/bench_compile_split.py [--rounds 2] [--chunks 4] [--preset quick]

Baseline: the chunk as ``ramavt train`` compiles it (one program: ``iterations_per_chunk`` iterations of acting
then learning in one ``lax.scan``). The split: one program for an iteration's acting (the rollout and the replay's
add) and one for its learning (the iteration's updates), which a host loop would call in turn. XLA:CPU compiles
each program on both cores already, so whether two smaller programs compiled side by side finish sooner than one
large one is measured, not assumed. Each compile runs in a fresh process with the persistent cache off (a cold
compile, as on a fresh machine); the variants alternate over ``--rounds``. A last process compiles both and runs
``--chunks`` chunks of each from the same initial state, alternated, for the price of the split in running time
(its host loop dispatches two programs per iteration and XLA no longer fuses across them). Prints and writes
(``--out``, JSON) every figure with the load average.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import jax

sys.path[:0] = [str(Path(__file__).resolve().parent), str(Path(__file__).resolve().parents[2] / "benchmarks")]
from bench_train import code_version, merge_json  # noqa: E402

from ramavt_jax import presets  # noqa: E402
from ramavt_jax.train import Trainer  # noqa: E402

DEFAULT_OUT = Path(__file__).resolve().parent / "results_compile_split.json"
VARIANTS = ("one program", "two in turn", "two in parallel")


def _split_programs(trainer: Trainer):
    """(acting, learning) jitted: acting(params, actor, replay, env_steps, key) -> (actor, replay, stats,
    env_steps after the rollout, the next iteration's key, the learning key) and learning(learner, replay, env_steps,
    key) -> (learner, replay, learned): Trainer.iteration in two programs, the key split and step count inside."""

    def acting(params, actor, replay, env_steps, key):
        key, k_act, k_learn = jax.random.split(key, 3)
        actor, chunk, stats, _ = trainer.rollout(params, actor, env_steps, k_act)
        env_steps = env_steps + trainer.config.env_steps_per_iteration
        return actor, trainer.replay.add(replay, chunk), stats, env_steps, key, k_learn

    return jax.jit(acting, donate_argnums=(1, 2)), jax.jit(trainer.learn, donate_argnums=(0, 1))


def _lowered(trainer: Trainer):
    """The lowered fused chunk, acting and learning programs for the preset's state shapes."""
    runner = jax.eval_shape(trainer.init, jax.random.PRNGKey(0))
    key = runner.key  # the programs take the runner's key and keys split from it
    acting, learning = _split_programs(trainer)
    return (
        jax.jit(trainer.chunk, donate_argnums=0).lower(runner),
        acting.lower(runner.learner.params, runner.actor, runner.replay, runner.env_steps, key),
        learning.lower(runner.learner, runner.replay, runner.env_steps, key),
    )


def compile_once(preset: str, variant: str) -> float:
    """Seconds to compile ``variant``'s program(s) (lowering excluded: it is the same work for both)."""
    jax.config.update("jax_enable_compilation_cache", False)
    chunk, acting, learning = _lowered(Trainer(presets.preset(preset)))
    t = time.perf_counter()
    if variant == "one program":
        chunk.compile()
    elif variant == "two in turn":
        acting.compile()
        learning.compile()
    else:
        with ThreadPoolExecutor(1) as pool:  # XLA releases the GIL while it compiles
            pending = pool.submit(acting.compile)
            learning.compile()
            pending.result()
    return time.perf_counter() - t


def run_both(preset: str, chunks: int) -> dict:
    """Chunk seconds of the fused program and of the split one (a host loop over the iterations), alternated."""
    jax.config.update("jax_enable_compilation_cache", False)
    trainer = Trainer(presets.preset(preset))
    fused = jax.jit(trainer.chunk, donate_argnums=0)
    acting, learning = _split_programs(trainer)

    def split_chunk(runner):  # two dispatches an iteration (the chunk's policy average, once a chunk, left out)
        for _ in range(trainer.config.run.iterations_per_chunk):
            actor, replay, _, env_steps, key, k_learn = acting(
                runner.learner.params, runner.actor, runner.replay, runner.env_steps, runner.key
            )
            learner, replay, learned = learning(runner.learner, replay, env_steps, k_learn)
            runner = runner.replace(actor=actor, replay=replay, learner=learner, key=key, env_steps=env_steps)
        return runner, learned

    init = jax.jit(trainer.init)
    states = {"one program": init(jax.random.PRNGKey(0)), "two programs": init(jax.random.PRNGKey(0))}
    run = {"one program": fused, "two programs": split_chunk}
    times: dict[str, list[float]] = {name: [] for name in run}
    for k in range(chunks + 1):  # the first round compiles both; it is dropped
        for name in list(run) if k % 2 == 0 else list(run)[::-1]:
            t = time.perf_counter()
            states[name], out = run[name](states[name])
            jax.block_until_ready(out)
            if k:
                times[name].append(time.perf_counter() - t)
    return times


def _child(args: list[str]) -> dict:
    out = subprocess.run([sys.executable, __file__, *args], check=True, capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--rounds", type=int, default=2, help="fresh processes per variant, alternated")
    p.add_argument("--chunks", type=int, default=4, help="chunks of each program in the running-time comparison")
    p.add_argument("--preset", default="quick")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT)
    p.add_argument("--child", choices=[*VARIANTS, "run"], help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.rounds < 1 or a.chunks < 1:
        p.error(f"--rounds and --chunks must be >= 1, got {a.rounds} and {a.chunks}")
    if a.child == "run":
        print(json.dumps(run_both(a.preset, a.chunks)))
        return
    if a.child:
        print(json.dumps({"compile_s": compile_once(a.preset, a.child)}))
        return
    load = [os.getloadavg()[0]]
    compile_s: dict[str, list[float]] = {v: [] for v in VARIANTS}
    for r in range(a.rounds):
        for v in VARIANTS if r % 2 == 0 else VARIANTS[::-1]:
            compile_s[v].append(_child(["--preset", a.preset, "--child", v])["compile_s"])
            print(f"round {r + 1}: {v} compiled in {compile_s[v][-1]:.1f} s", flush=True)
    chunk_s = _child(["--preset", a.preset, "--chunks", str(a.chunks), "--child", "run"])
    load.append(os.getloadavg()[0])
    medians = {name: statistics.median(v) for name, v in chunk_s.items()}
    print("compile s: " + ", ".join(f"{v} {statistics.median(s):.1f} (median of {s})" for v, s in compile_s.items()))
    print(
        "median chunk s: " + ", ".join(f"{n} {m:.2f}" for n, m in medians.items()) + f"; load {load[0]:.2f} -> "
        f"{load[1]:.2f}"
    )
    merge_json(
        a.out,
        f"{a.preset}_compile_split",
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
