"""The whole training chunk of this checkout against an earlier git revision, from a real run's state, interleaved.

    python benchmarks/ab_chunk.py runs/quick --baseline bc1a0fc [--seeds 3] [--rounds 3]
    python benchmarks/ab_chunk.py runs/quick --baseline bc1a0fc --baseline-run runs/old_quick   # other networks

Both versions' ``Trainer.chunk`` (collect + learn, as ``ramavt train`` runs it) start from the same state: the latest
checkpoint of ``RUN`` (a run of ``--preset``; for ``--seeds N`` that state is copied to N seeds, vmapped as
``--seeds N`` training does). The baseline's package comes from ``git archive BASELINE ramavt_jax`` under another
module name, so both versions live in one process and their calls alternate (same machine load). Both must hold the
same state layout, unless ``--baseline-run`` gives the baseline a run of its own (a run of the baseline's preset,
e.g. when the preset's network changed since): each version then starts from its own run's state. ``--act-only`` adds a third program: this checkout's chunk before learning starts (acting only).
Prints the chunk times per round, the medians, the load average; writes JSON to ``--out``.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_train import export_package, merge_json  # noqa: E402

from ramavt_jax import train as T  # noqa: E402
from ramavt_jax import train_config  # noqa: E402
from ramavt_jax.training.checkpoint import CheckpointStore  # noqa: E402

BASELINE_MODULE = "ramavt_baseline"


def import_baseline(rev: str, where: Path, module: str = "train"):
    """The ``ramavt_jax`` package of git revision ``rev`` imported as ``ramavt_baseline``: its ``module``."""
    package = where / BASELINE_MODULE
    export_package(rev, where).rename(package)
    for path in package.rglob("*.py"):
        path.write_text(path.read_text().replace("ramavt_jax", BASELINE_MODULE))
    sys.path.insert(0, str(where))
    return importlib.import_module(f"{BASELINE_MODULE}.{module}")


def _restore(run: Path, like):
    """The latest checkpoint of ``run`` in the layout of ``like`` (zero-size leaves are not stored: taken from like)."""
    store = CheckpointStore(run / "checkpoints", create=False)
    try:
        return store.restore(like)[0]
    except Exception:  # a --seeds run stores a leading seed axis: take seed 0
        stacked = jax.tree.map(lambda x: jnp.zeros((1, *x.shape), x.dtype), like)
        return jax.tree.map(lambda x: x[0], store.restore(stacked)[0])


def _zeros_like_init(trainer, key):
    return jax.tree.map(lambda x: jnp.zeros(x.shape, x.dtype), jax.eval_shape(trainer.init, key))


def _recast(state, template):
    return jax.tree.unflatten(jax.tree.structure(template), jax.tree.leaves(state))


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("run", type=Path, help="a run folder of --preset with checkpoints")
    p.add_argument("--baseline", required=True, help="git revision to compare with (e.g. a commit or a tag)")
    p.add_argument("--baseline-run", type=Path, default=None,
                   help="a run of the baseline's preset whose state the baseline starts from (default: RUN)")
    p.add_argument("--preset", default="quick", choices=sorted(train_config.PRESETS))
    p.add_argument("--seeds", type=int, default=1)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--act-only", action="store_true")
    p.add_argument("--out", default=str(Path(__file__).resolve().parent / "results_ab_chunk.json"))
    a = p.parse_args(argv)
    if a.seeds < 1 or a.rounds < 1:
        p.error("--seeds and --rounds must be >= 1")
    key = jax.random.PRNGKey(0)
    with tempfile.TemporaryDirectory() as tmp:
        base_train = import_baseline(a.baseline, Path(tmp))
        trainers = {a.baseline: base_train.Trainer(base_train.preset(a.preset)), "this": T.Trainer(train_config.preset(a.preset))}
        state = _restore(a.run, _zeros_like_init(trainers["this"], key))
        base_state = state
        if a.baseline_run is not None:  # restored in this checkout's layout of the baseline run's own config
            saved = json.loads((a.baseline_run / "config.json").read_text())["config"]
            base_state = _restore(a.baseline_run, _zeros_like_init(T.Trainer(train_config.TrainConfig.from_dict(saved)),
                                                                   key))
        states = {"this": state, a.baseline: _recast(base_state, jax.eval_shape(trainers[a.baseline].init, key))}
        if a.act_only:  # learning_starts above the restored step count: the chunk only collects
            trainers["this, acting only"] = T.Trainer(train_config.preset(a.preset, learning_starts=train_config.preset(
                a.preset).replay.capacity_steps))
            states["this, acting only"] = state.replace(env_steps=jnp.zeros_like(state.env_steps))
        if a.seeds > 1:
            states = {k: jax.tree.map(lambda x: jnp.stack([x] * a.seeds), s) for k, s in states.items()}
        chunk = {k: jax.jit(jax.vmap(tr.chunk) if a.seeds > 1 else tr.chunk) for k, tr in trainers.items()}
        load0, times = os.getloadavg(), {k: [] for k in trainers}
        for k in trainers:
            t = time.perf_counter()
            jax.block_until_ready(chunk[k](states[k]))
            print(f"{k}: compile + first chunk {time.perf_counter() - t:.1f} s", flush=True)
        for r in range(a.rounds):
            for k in trainers:
                t = time.perf_counter()
                jax.block_until_ready(chunk[k](states[k]))
                times[k].append(time.perf_counter() - t)
            print(f"round {r + 1}: " + ", ".join(f"{k} {v[-1]:.2f} s" for k, v in times.items()) +
                  f" (load {os.getloadavg()[0]:.2f})", flush=True)
    med = {k: statistics.median(v) for k, v in times.items()}
    for k, v in med.items():
        print(f"{k}: median chunk {v:.2f} s, {med[a.baseline] / v:.2f}x the baseline {a.baseline}")
    merge_json(a.out, f"{a.preset}_seeds{a.seeds}_vs_{a.baseline}", dict(
        run=str(a.run), baseline_run=str(a.baseline_run or a.run), env_steps=int(state.env_steps), chunk_s=times, median_s=med,
        loadavg_start=load0, loadavg_end=os.getloadavg(), jax=jax.__version__))


if __name__ == "__main__":
    main()
