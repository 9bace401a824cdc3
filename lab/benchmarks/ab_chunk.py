"""The whole training chunk of this checkout against an earlier git revision, from a real run's state, interleaved.

    python lab/benchmarks/ab_chunk.py runs/quick --baseline bc1a0fc [--seeds 3] [--rounds 3]
    python lab/benchmarks/ab_chunk.py runs/quick --baseline bc1a0fc --baseline-run runs/old_quick   # other networks
    python lab/benchmarks/ab_chunk.py runs/quick --set bootstrap_from=target     # this checkout against a config change

Both versions' ``Trainer.chunk`` (collect + learn, as ``ramavt train`` runs it) start from the same state: the latest
checkpoint of ``RUN`` (a run of ``--preset``; for ``--seeds N`` that state is copied to N seeds, vmapped as
``--seeds N`` training does). The baseline's package comes from ``git archive BASELINE ramavt_jax`` under another
module name, so both versions live in one process and their calls alternate (same machine load). Both must hold the
same state layout, unless ``--baseline-run`` gives the baseline a run of its own (a run of the baseline's preset,
e.g. when the preset's network changed since): each version then starts from its own run's state. ``--act-only`` adds
a program: this checkout's chunk before learning starts (acting only). ``--set FIELD=VALUE`` (repeatable) adds this
checkout with the preset's fields changed (TrainConfig.override; VALUE read as JSON, else as a string), from the same
state, which the change must keep in the same layout; without ``--baseline`` the reference is this checkout as is.
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

sys.path[:0] = [str(Path(__file__).resolve().parent), str(Path(__file__).resolve().parents[2] / "benchmarks")]
from bench_train import export_package, merge_json  # noqa: E402

from ramavt_jax import presets, train_config  # noqa: E402
from ramavt_jax import train as T  # noqa: E402
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


def _without_average(state):
    """``state`` without the policy's tail average (LearnerState.averaged_params): it changes no training step, and
    revisions before it have no such field."""
    return state.replace(learner=state.learner.replace(averaged_params=None))


def _restore_state(run: Path, trainer, key):
    """The latest state of ``run`` (trained with or without a tail average), without that average."""
    like = _zeros_like_init(trainer, key)
    try:
        return _restore(run, _without_average(like))
    except Exception:  # noqa: BLE001 (the run keeps the average: restore it too, then drop it)
        return _without_average(_restore(run, like))


def _for_trainer(state, trainer):
    """``state`` in ``trainer``'s layout: with a tail average (a copy of the target params) where it keeps one."""
    if trainer.config.run.policy_average_from is None:
        return state
    averaged = jax.tree.map(jnp.copy, state.learner.target_params)
    return state.replace(learner=state.learner.replace(averaged_params=averaged))


def _baseline_preset(name: str):
    """The preset ``name`` of the imported baseline package: its ``presets`` module, or for revisions before it its
    ``train_config`` (or, earlier still, ``train``)."""
    for module in ("presets", "train_config", "train"):
        try:
            found = getattr(importlib.import_module(f"{BASELINE_MODULE}.{module}"), "preset", None)
        except ModuleNotFoundError:
            continue
        if found is not None:
            return found(name)
    raise SystemExit(f"the baseline revision has no preset function to build {name!r} with")


def _baseline_state(baseline_run: Path | None, state, key):
    """The state the baseline starts from: ``state``, or the latest checkpoint of a run of the baseline's own preset,
    restored in this checkout's layout of that run's config."""
    if baseline_run is None:
        return state
    saved = json.loads((baseline_run / "config.json").read_text())["config"]
    return _restore_state(baseline_run, T.Trainer(train_config.TrainConfig.from_dict(saved)), key)


def _parse_setting(parser, text: str):
    """``FIELD=VALUE`` -> (field, value): VALUE as JSON (numbers, true/false), else as a string."""
    field, sep, value = text.partition("=")
    if not sep or not field:
        parser.error(f"--set takes FIELD=VALUE, got {text!r}")
    try:
        return field, json.loads(value)
    except json.JSONDecodeError:
        return field, value


def _zeros_like_init(trainer, key):
    return jax.tree.map(lambda x: jnp.zeros(x.shape, x.dtype), jax.eval_shape(trainer.init, key))


def _recast(state, template):
    return jax.tree.unflatten(jax.tree.structure(template), jax.tree.leaves(state))


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("run", type=Path, help="a run folder of --preset with checkpoints")
    p.add_argument("--baseline", default=None, help="git revision to compare with (e.g. a commit or a tag)")
    p.add_argument(
        "--baseline-run",
        type=Path,
        default=None,
        help="a run of the baseline's preset whose state the baseline starts from (default: RUN)",
    )
    p.add_argument("--preset", default="quick", choices=sorted(presets.PRESETS))
    p.add_argument("--seeds", type=int, default=1)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--act-only", action="store_true")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="FIELD=VALUE",
        help="also time this checkout with these preset fields changed (repeatable: one program)",
    )
    p.add_argument("--out", default=str(Path(__file__).resolve().parent / "results_ab_chunk.json"))
    a = p.parse_args(argv)
    if a.seeds < 1 or a.rounds < 1:
        p.error("--seeds and --rounds must be >= 1")
    if a.baseline is None and not a.set:
        p.error("give --baseline REV, --set FIELD=VALUE or both")
    if a.baseline_run is not None and a.baseline is None:
        p.error("--baseline-run needs --baseline")
    changes = dict(_parse_setting(p, text) for text in a.set)
    reference = a.baseline or "this"
    key = jax.random.PRNGKey(0)
    with tempfile.TemporaryDirectory() as tmp:
        trainers = {"this": T.Trainer(presets.preset(a.preset))}
        state = _restore_state(a.run, trainers["this"], key)
        states = {"this": _for_trainer(state, trainers["this"])}
        if changes:
            name = "this, " + ", ".join(a.set)
            trainers[name] = T.Trainer(presets.preset(a.preset, **changes))
            states[name] = _for_trainer(state, trainers[name])
        if a.baseline is not None:
            base_train = import_baseline(a.baseline, Path(tmp))
            trainers[a.baseline] = base_train.Trainer(_baseline_preset(a.preset))
            states[a.baseline] = _recast(
                _baseline_state(a.baseline_run, state, key), jax.eval_shape(trainers[a.baseline].init, key)
            )
        if a.act_only:  # learning_starts above the restored step count: the chunk only collects
            trainers["this, acting only"] = T.Trainer(
                presets.preset(a.preset, learning_starts=presets.preset(a.preset).replay.capacity_steps)
            )
            states["this, acting only"] = _for_trainer(
                state.replace(env_steps=jnp.zeros_like(state.env_steps)), trainers["this, acting only"]
            )
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
            print(
                f"round {r + 1}: "
                + ", ".join(f"{k} {v[-1]:.2f} s" for k, v in times.items())
                + f" (load {os.getloadavg()[0]:.2f})",
                flush=True,
            )
    med = {k: statistics.median(v) for k, v in times.items()}
    for k, v in med.items():
        print(f"{k}: median chunk {v:.2f} s, {med[reference] / v:.2f}x {reference}")
    merge_json(
        a.out,
        f"{a.preset}_seeds{a.seeds}_vs_{reference}" + "".join(f"_{t}" for t in a.set),
        dict(
            run=str(a.run),
            baseline_run=str(a.baseline_run or a.run),
            env_steps=int(state.env_steps),
            chunk_s=times,
            median_s=med,
            loadavg_start=load0,
            loadavg_end=os.getloadavg(),
            jax=jax.__version__,
        ),
    )


if __name__ == "__main__":
    main()
