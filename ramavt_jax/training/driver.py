"""Host-side training driver: :func:`run` trains a config into a run folder and returns its :class:`RunSummary`.

It opens the folder and restores its checkpoints (:mod:`ramavt_jax.training.resume`), compiles the jitted chunks of
:class:`ramavt_jax.train.Trainer` (:mod:`ramavt_jax.training.program`), runs them (:mod:`ramavt_jax.training.chunk_loop`:
one record per chunk as strict JSONL, optional TensorBoard, tqdm; orbax checkpoints; clean stops on SIGINT /
SIGTERM) and summarises the run. The run folder's layout, lock and config check are in
:mod:`ramavt_jax.training.run_folder`. The final greedy evaluation (``eval.json``) and the curves
(``training_curves.png``) are written by the layers above (the ``ramavt train`` command runs :func:`run`, then
:func:`ramavt_jax.evaluation.final.evaluate_run`, then the plot).
"""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np

from ramavt_jax import distributed
from ramavt_jax.train_config import TrainConfig
from ramavt_jax.training import files
from ramavt_jax.training import run_folder as folders
from ramavt_jax.training.checkpoint import CheckpointStore
from ramavt_jax.training.chunk_loop import ChunkLoop, train_chunks
from ramavt_jax.training.host_state import host_int, seed_slice
from ramavt_jax.training.interrupts import StopSignals, TrainingInterrupted
from ramavt_jax.training.metrics import Log
from ramavt_jax.training.program import _compiled, _Program
from ramavt_jax.training.resume import RunFolders, open_folders, restore

__all__ = ["run", "RunSummary", "read_metrics", "TrainingInterrupted"]

read_metrics = folders.read_metrics


# ============================================================================================ summary
class RunSummary(dict):
    """The JSON-friendly summary of a run; the final RunnerState (params, replay, ...) is ``.state`` (with a leading
    [seeds] axis when several seeds were trained together)."""

    state: Any = None


def _start(
    config: TrainConfig, f: RunFolders, num_devices, tracking_env, say, debug_nan_at_update: int, components=None
):
    """Compile (or reuse) the program and build the initial or restored state; (program, state, mesh)."""
    mesh = distributed.make_mesh(num_devices)
    if mesh is not None and len(f.seeds) == 1:
        distributed.check_divisible(config.acting.num_envs, mesh)
    distributed.check_seeds_divisible(len(f.seeds), mesh)
    t = time.time()
    where = "1 device" if mesh is None else f"{mesh.devices.size} devices"
    say(
        f"compiling the training chunk ({config.network.variant}, {config.env.obs_shape}, {len(f.seeds)} seed(s), "
        f"{where}) ..."
    )
    prog = _compiled(config, tracking_env, len(f.seeds), mesh, debug_nan_at_update, components)
    say(f"compiled in {time.time() - t:.1f} s")
    keys = (
        np.stack([np.asarray(jax.random.PRNGKey(s)) for s in f.seeds])
        if len(f.seeds) > 1
        else jax.random.PRNGKey(f.seeds[0])
    )
    return prog, prog.init(keys), mesh


def run(
    config: TrainConfig,
    out_dir,
    seed: int = 0,
    resume=True,
    progress: bool = True,
    max_chunks: int | None = None,
    tracking_env=None,
    num_seeds: int = 1,
    num_devices: int | None = None,
    debug_nan_at_update: int = -1,
    clock_start: float | None = None,
    lock: folders.RunLock | None = None,
    components=None,
) -> RunSummary:
    """Train ``config`` into ``out_dir``; returns a :class:`RunSummary` (a JSON-friendly dict: counters, timings,
    memory, the last metrics record) whose ``.state`` is the final RunnerState.

    num_seeds: > 1 trains seeds ``seed .. seed + num_seeds - 1`` as ONE jitted program (vmap over seeds, each
      with its own envs and replay) into ``out_dir/seed_<k>/`` (each folder is a complete single-seed run folder).
      The summary's ``seeds`` lists the per-seed summaries.
    num_devices: devices to split the envs and replay over (default: all visible, every process's in a
      multi-host run); 1 = the plain single-device program.
    resume: True resumes from the run folder's checkpoints when present (the config must match config.json except
      for ``run_folder.RESUMABLE_FIELDS``: a larger total_env_steps extends the run; a damaged newest checkpoint
      falls back to the newest that loads); False starts fresh (existing checkpoints are deleted); a path resumes
      from that checkpoint folder (error if none is there).
    max_chunks: stop after this many chunks in this call (a checkpoint is saved), e.g. to split a run.
    debug_nan_at_update: a test hook: the loss becomes NaN from this gradient step on (-1 = off).
    components: the trainer's extension points (train.Components: a network factory, loss terms, a labeller; None =
      built from the config), for experiments that plug in a component without a config field.
    clock_start: the epoch second from which each metrics record's ``since_start_s`` (and the summary's
      ``startup_s``, to the first chunk's dispatch) count: ``ramavt train`` passes its process's start, so that
      imports, compiling and building the state are counted; None = the start of this call.
    lock: the lock of ``out_dir`` (``run_folder.lock_folder``), held by the caller, who lets it go after what it
      does with the run (``ramavt train``: the final evaluation and plots); None = this call takes it and lets it
      go when training ends.
    Raises TrainingDivergedError on a diverging learner (a loss, mean Q or gradient norm that is not finite, or a
    loss above ``config.run.max_loss``; the last good checkpoint is kept), RunFolderError when the
    folder is locked by another process, not writable or holds another config. SIGINT / SIGTERM: the chunk in
    flight is logged and checkpointed, then TrainingInterrupted (a KeyboardInterrupt) is raised. In a multi-host
    run only process 0 writes logs; every process takes part in checkpointing.
    """
    if isinstance(num_seeds, bool) or not isinstance(num_seeds, int) or num_seeds < 1:
        raise ValueError(f"num_seeds must be an int >= 1, got {num_seeds!r}")
    clock_start = time.time() if clock_start is None else clock_start
    primary = distributed.is_primary()
    say = (lambda msg: print(msg, flush=True)) if (progress and primary) else (lambda msg: None)
    config_json = json.loads(json.dumps(config.to_dict(), default=str))
    distributed.make_mesh(num_devices)  # a bad device count fails before the folder is touched
    f = open_folders(config_json, Path(out_dir), seed, num_seeds, resume, primary, lock)
    try:
        with StopSignals(say if primary else (lambda msg: None)) as stop:
            return _run_locked(
                config,
                f,
                config_json,
                resume,
                max_chunks,
                tracking_env,
                num_devices,
                progress,
                primary,
                stop,
                say,
                debug_nan_at_update,
                clock_start,
                components,
            )
    finally:
        if f.lock is not None:
            f.lock.close()


def _run_locked(
    config,
    f: RunFolders,
    config_json,
    resume,
    max_chunks,
    tracking_env,
    num_devices,
    progress,
    primary,
    stop: StopSignals,
    say,
    debug_nan_at_update: int,
    clock_start: float,
    components=None,
) -> RunSummary:
    stop.hard_exit = "while compiling or allocating"
    prog, state, mesh = _start(config, f, num_devices, tracking_env, say, debug_nan_at_update, components)
    jax.block_until_ready(state)  # the allocation is done before a signal is deferred
    distributed.barrier("ramavt_compiled")  # processes compile at different speeds; the next step is collective
    saved_rows = None
    if f.resuming:
        stop.hard_exit = "while restoring the checkpoint"  # reads (a damaged step cut off mid-delete is skipped again)
        state, saved_rows = restore(prog, state, config, config_json, f, print if primary else (lambda msg: None))
    stop.hard_exit = None  # from here on files are written: a signal is deferred to the next safe point
    if stop.signum is not None:  # came while the run folder was checked, before compiling began
        raise TrainingInterrupted(f"{stop.name} before training began: nothing was trained or written", stop.signum)
    if resume is False and not f.resuming and primary:
        for d in f.dirs:
            if (d / folders.CHECKPOINTS).is_dir():
                shutil.rmtree(d / folders.CHECKPOINTS)
    start = host_int(state.chunk)
    for d in f.dirs if primary else ():
        d.mkdir(parents=True, exist_ok=True)
    # a resume first settles its metrics rows (rebuilt from the checkpoint, or refused in one line)
    rows = saved_rows if f.resuming and f.own_checkpoints else None
    log = Log(config, f.dirs, start if f.resuming else None, primary, progress, rows)
    if primary:
        for s, d in zip(f.seeds, f.dirs):
            files.write_atomic(d / folders.CONFIG_FILE, json.dumps({"seed": s, "config": config_json}, indent=1))
    stores = [CheckpointStore(d / folders.CHECKPOINTS, keep=config.run.keep_checkpoints) for d in f.dirs]
    loop = ChunkLoop(config, prog, f, log, stores, config_json, start, start if f.resuming else None, clock_start)
    end = config.num_chunks if max_chunks is None else min(config.num_chunks, start + max_chunks)
    train_t0 = time.time()
    try:
        state = train_chunks(loop, state, end, stop, say)
    finally:
        log.close()
    train_s = time.time() - train_t0
    if loop.chunk_no != loop.last_saved:
        with stop.writing():
            loop.save(state)
    for store in stores:
        store.close()
    return _summary(config, f, loop, state, prog, mesh, train_s, train_t0 - clock_start)


def _summary(
    config, f: RunFolders, loop: ChunkLoop, state, prog: _Program, mesh, train_s: float, startup_s: float
) -> RunSummary:
    num_seeds = len(f.seeds)
    per_seed = []
    for k, (s, d) in enumerate(zip(f.seeds, f.dirs)):
        per_seed.append(
            {
                "seed": s,
                "chunks_done": loop.chunk_no,
                "num_chunks": config.num_chunks,
                "env_steps": host_int(seed_slice(state.env_steps, k, num_seeds)),
                "updates": host_int(seed_slice(state.learner.updates, k, num_seeds)),
                "train_wall_s": train_s,
                "compile_s": prog.compile_s,
                "startup_s": startup_s,
                "last": loop.log.records[k][-1] if loop.log.records[k] else None,
                "out_dir": str(d),
            }
        )
    if num_seeds == 1:
        summary = per_seed[0]
    else:
        summary = {
            k: v
            for k, v in per_seed[0].items()
            if k in ("chunks_done", "num_chunks", "train_wall_s", "compile_s", "startup_s")
        }
        summary.update(out_dir=str(f.out), seeds=per_seed)
    summary.update(
        memory=prog.memory,
        devices=1 if mesh is None else int(mesh.devices.size),
        processes=jax.process_count(),
        finished=loop.chunk_no >= config.num_chunks,
    )
    summary = RunSummary(summary)
    summary.state = state
    return summary
