"""Host-side training driver: runs the jitted chunks of :class:`ramavt_jax.train.Trainer`, logs one record per
chunk (strict JSONL, optional TensorBoard, tqdm), checkpoints (orbax) and stops cleanly on SIGINT / SIGTERM.

The run folder's layout, lock and config check are in :mod:`ramavt_jax.training.run_folder`. The final greedy
evaluation (``eval.json``) and the curves (``training_curves.png``) are written by the layers above (the
``ramavt train`` command runs :func:`run`, then :func:`ramavt_jax.evaluation.final.evaluate_run`, then the plot).
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np

from ramavt_jax import distributed
from ramavt_jax.train_config import TrainConfig
from ramavt_jax.train_state import TrainingDivergedError
from ramavt_jax.training import files
from ramavt_jax.training import run_folder as folders
from ramavt_jax.training.checkpoint import CheckpointError, CheckpointNotFoundError, CheckpointStore, has_checkpoint
from ramavt_jax.training.interrupts import StopSignals, TrainingInterrupted
from ramavt_jax.training.metrics import Log, aggregate, divergence
from ramavt_jax.training.program import _compiled, _Program

__all__ = ["run", "lock_folder", "RunSummary", "aggregate", "read_metrics", "TrainingInterrupted"]

read_metrics = folders.read_metrics


# ============================================================================================ summary
class RunSummary(dict):
    """The JSON-friendly summary of a run; the final RunnerState (params, replay, ...) is ``.state`` (with a leading
    [seeds] axis when several seeds were trained together)."""

    state: Any = None


# ============================================================================================ folders and resume
def _host_int(x) -> int:
    """A counter of the (possibly sharded, possibly [seeds]-stacked) state as a host int (seeds share it: first)."""
    return int(np.asarray(distributed.local_copy(x)).reshape(-1)[0])


def _seed_slice(tree, k: int, num_seeds: int):
    return tree if num_seeds == 1 else jax.tree.map(lambda x: x[k], tree)


def _resolve_resume(resume, ckpt_dir: Path, subdir: str | None = None) -> Path | None:
    """True: the run folder's checkpoints if any; False: fresh; a path: that checkpoint folder (must exist; for
    several seeds its ``seed_<k>`` sub-folders)."""
    if resume is True:
        return ckpt_dir if has_checkpoint(ckpt_dir) else None
    if resume is False or resume is None:
        return None
    path = Path(resume) / subdir if subdir else Path(resume)
    for cand in (path, path / folders.CHECKPOINTS):
        if has_checkpoint(cand):
            return cand
    raise CheckpointNotFoundError(
        f"resume={str(resume)!r}: no checkpoint there (looked in {path} and "
        f"{path / folders.CHECKPOINTS}); start afresh with --no-resume"
    )


def _default_json() -> dict:
    """TrainConfig's default values as a config dict (fields missing from an older config.json take these)."""
    return json.loads(json.dumps(TrainConfig().to_dict(), default=str))


@dataclasses.dataclass
class _Folders:
    out: Path
    seeds: list[int]
    dirs: list[Path]
    sources: list[Path | None]  # checkpoint folder to resume each seed from
    lock: Any  # RunLock of the primary process taken by run (released when training ends), or None

    @property
    def resuming(self) -> bool:
        return self.sources[0] is not None

    @property
    def own_checkpoints(self) -> bool:
        """Resuming from the folders' own checkpoints (their metrics rows must cover them), not another's."""
        return all(src == d / folders.CHECKPOINTS for src, d in zip(self.sources, self.dirs))


def lock_folder(out) -> folders.RunLock:
    """The run folder ``out``, created if needed and checked writable, locked against a second command (one-line
    RunFolderError otherwise). ``ramavt train`` holds it through the training, the final evaluation and the plots
    (experiment.train_and_evaluate passes it to :func:`run`)."""
    folders.check_writable(out)
    return folders.RunLock(Path(out))


def _open_folders(
    config_json: dict, out: Path, seed: int, num_seeds: int, resume, primary: bool, held=None
) -> _Folders:
    """Check ``out`` (writable, not locked, same config when resuming) before anything is written into it;
    ``held``: its lock, taken by the caller."""
    seeds = [seed + k for k in range(num_seeds)]
    dirs = folders.seed_folders(out, seeds)
    if held is None:
        folders.check_writable(out)
    lock = lock_folder(out) if primary and held is None else None
    try:
        sources = [_resolve_resume(resume, d / folders.CHECKPOINTS, None if num_seeds == 1 else d.name) for d in dirs]
        if any(s is None for s in sources) and any(s is not None for s in sources):
            raise CheckpointNotFoundError(
                f"only some seed folders in {out} have checkpoints "
                f"({[str(s) for s in sources]}); resume them together or use --no-resume"
            )
        for s, d, src in zip(seeds, dirs, sources):
            if src is not None and (d / folders.CONFIG_FILE).is_file():
                folders.check_config(d, config_json, s, _default_json())
    except BaseException:
        if lock is not None:
            lock.close()
        raise
    return _Folders(out, seeds, dirs, sources, lock)


def _saved_rows(store: CheckpointStore, step: int) -> list[dict]:
    """The metrics rows the checkpoints up to ``step`` hold (each its chunks since the one before it; none in a
    checkpoint written before they were kept, or one whose metadata no longer reads)."""
    found = {}
    for s in store.all_steps():
        if s <= step:
            try:
                meta = store.read_meta(s)
            except Exception:  # noqa: BLE001 (a damaged step: its rows are not there to rebuild from)
                continue
            found.update({r["chunk"]: r for r in meta.get("metrics") or ()})
    return [found[c] for c in sorted(found)]


def _restore(prog: _Program, state, config: TrainConfig, config_json: dict, f: _Folders, log):
    """The checkpointed RunnerState of every seed (newest loadable step), placed like ``state``, and per seed a
    function reading the metrics rows its checkpoints hold (run_folder.resumed_rows)."""
    num_seeds = len(f.seeds)
    loaded, rows = [], []
    for k, src in enumerate(f.sources):
        like = _seed_slice(state, k, num_seeds)
        like = like if config.run.checkpoint_replay else like.replace(replay=None)
        store = CheckpointStore(src, create=False)
        st, meta, step = store.restore_newest_loadable(like, log, config_json)
        rows.append(lambda store=store, step=step: _saved_rows(store, step))
        saved = meta.get("config", {})
        diff = {
            k: v
            for k, v in folders.config_differences(saved, config_json, _default_json()).items()
            if k not in folders.RESUMABLE_FIELDS
        }
        if diff:
            raise CheckpointError(
                f"the checkpoint in {src} was written with another config (differs in "
                f"{', '.join(diff)}); train into a new --out or start afresh with --no-resume"
            )
        loaded.append(st)
    if len({_host_int(st.chunk) for st in loaded}) > 1:
        raise CheckpointError(
            f"the seed folders in {f.out} were checkpointed at different chunks; resume them with --no-resume"
        )
    if num_seeds > 1:
        loaded = [jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *loaded)]
    restored = loaded[0]
    if not config.run.checkpoint_replay:
        restored = restored.replace(replay=state.replay)
    return (restored if prog.shardings is None else jax.device_put(restored, prog.shardings)), rows


@dataclasses.dataclass
class _Loop:
    """What the chunk loop needs and updates."""

    config: TrainConfig
    prog: _Program
    f: _Folders
    log: Log
    stores: list
    config_json: dict
    chunk_no: int  # host mirror of state.chunk (each compiled chunk adds one): no device read per chunk
    last_saved: int | None
    clock_start: float  # epoch second from which the records' since_start_s count (see run)

    def save(self, state) -> None:
        """Checkpoint ``state`` as chunk ``chunk_no`` in every seed folder, after flushing the metrics rows to the
        disk; each checkpoint holds its seed's rows since the previous checkpoint, which a resume rebuilds when the
        file lost them (call inside StopSignals.writing: a second Ctrl-C waits until the checkpoint is whole)."""
        num_seeds = len(self.f.seeds)
        self.log.sync()
        for k, (s, store) in enumerate(zip(self.f.seeds, self.stores)):
            if (store.directory / str(self.chunk_no)).is_dir():  # already written whole (orbax renames at the end)
                continue
            one = _seed_slice(state, k, num_seeds)
            meta = {
                "config": self.config_json,
                "seed": s,
                "chunk": self.chunk_no,
                "env_steps": _host_int(one.env_steps),
                "updates": _host_int(one.learner.updates),
                "metrics": self.log.rows_since(k, self.last_saved),
            }
            store.save(self.chunk_no, one if self.config.run.checkpoint_replay else one.replace(replay=None), meta)
        self.last_saved = self.chunk_no

    def record(self, m, wall: float) -> None:
        """Log the metrics of the chunk just finished (raises TrainingDivergedError on a diverging learner: a loss,
        mean Q or gradient norm that is not finite, or a loss above run.max_loss)."""
        c, num_seeds = self.config, len(self.f.seeds)
        since_start = time.time() - self.clock_start
        for k in range(num_seeds):
            record = {"chunk": self.chunk_no, **aggregate(_seed_slice(m, k, num_seeds), wall, c.env_steps_per_chunk)}
            record["trained_frames_per_s"] = record["updates_per_s"] * c.replay.batch_size * c.replay.train_len
            record["compile_s"] = self.prog.compile_s
            record["since_start_s"] = since_start
            record["started_at"] = self.clock_start  # epoch second: tells one process's records from a resume's
            if num_seeds > 1:
                record["seeds_in_program"] = num_seeds
            why = divergence(record, c.run.max_loss)
            if why is not None:
                where = (
                    f"the last good checkpoint is chunk {self.last_saved} in {self.f.dirs[k] / folders.CHECKPOINTS}"
                    if self.last_saved is not None
                    else "no checkpoint was saved yet"
                )
                raise TrainingDivergedError(
                    f"training diverged at chunk {record['chunk']} (seed {self.f.seeds[k]}, env step "
                    f"{record['env_steps']}): {why} (loss={record['loss']:.3g}, mean Q={record['q_mean']:.3g}, "
                    f"grad_norm={record['grad_norm']:.3g}). The diverged state was NOT saved; {where}. Try a lower "
                    f"learner.lr (now {c.learner.lr}), gradient clipping (learner.max_grad_norm) or a smaller "
                    f"learner.reward_scale; --run.max-loss sets the bound on the loss."
                )
            self.log.add(k, record)
        self.log.advance(c.env_steps_per_chunk * num_seeds)


def _save_on_interrupt(loop: _Loop, state, pending) -> None:
    """After a second Ctrl-C: let the chunk in flight finish (XLA cannot cancel it), log it when its metrics are
    at hand, and checkpoint the state when every chunk it covers has its row (and its parameters are finite)."""
    jax.block_until_ready(state)
    done = _host_int(state.chunk)  # may be one ahead of the host mirror: the chunk in flight
    if done == loop.chunk_no + 1 and pending is not None:
        loop.chunk_no = done
        loop.record(distributed.local_copy(pending[0]), time.time() - pending[1])
    if done == loop.chunk_no and loop.chunk_no != loop.last_saved and _finite_params(state):
        loop.save(state)


def _finite_params(state) -> bool:
    return all(
        bool(np.isfinite(np.asarray(x)).all()) for x in jax.tree.leaves(distributed.local_copy(state.learner.params))
    )


def _train_chunks(loop: _Loop, state, end: int, stop: StopSignals, say):
    """Run chunks until ``end`` or a stop signal (then the chunk in flight is logged and saved first). A chunk's
    rows and checkpoint are written inside ``stop.writing()``: a second Ctrl-C waits until they are whole."""
    every = loop.config.run.checkpoint_every_chunks
    pending = None  # the metrics of the chunk dispatched and not yet logged, with its start
    try:
        while loop.chunk_no < end:
            t = time.time()
            state, m = loop.prog.chunk(state)
            pending = (m, t)
            m = distributed.local_copy(m)  # the one host sync per chunk (a Ctrl-C lands here)
            with stop.writing():
                loop.chunk_no += 1
                pending = None
                loop.record(m, time.time() - t)
                if (every and loop.chunk_no % every == 0) or stop.signum is not None:
                    loop.save(state)
            if stop.signum is not None:
                raise TrainingInterrupted(
                    f"{stop.name}: checkpoint of chunk {loop.chunk_no} saved under "
                    f"{loop.f.out}; run the same command again to resume",
                    stop.signum,
                )
    except TrainingInterrupted:
        loop.log.close()
        raise
    except KeyboardInterrupt:  # a second Ctrl-C (or one outside the main thread): save what is complete
        with stop.writing(stop_after=False):  # a further Ctrl-C cannot cut this checkpoint short either
            if any(getattr(x, "is_deleted", lambda: False)() for x in jax.tree.leaves(state)):
                loop.log.close()
                last = f"chunk {loop.last_saved} in {loop.f.out}"
                say(f"\ninterrupted while a chunk was dispatched; last checkpoint: {last}")
                raise
            _save_on_interrupt(loop, state, pending)
            loop.log.close()
        say(f"\ninterrupted: checkpoint of chunk {loop.last_saved} saved under {loop.f.out}; run again to resume")
        raise
    return state


def _start(config: TrainConfig, f: _Folders, num_devices, tracking_env, say, debug_nan_at_update: int, components=None):
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
    lock: the lock of ``out_dir`` (:func:`lock_folder`), held by the caller, who lets it go after what it does
      with the run (``ramavt train``: the final evaluation and plots); None = this call takes it and lets it go
      when training ends.
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
    f = _open_folders(config_json, Path(out_dir), seed, num_seeds, resume, primary, lock)
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
    f: _Folders,
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
        state, saved_rows = _restore(prog, state, config, config_json, f, print if primary else (lambda msg: None))
    stop.hard_exit = None  # from here on files are written: a signal is deferred to the next safe point
    if stop.signum is not None:  # came while the run folder was checked, before compiling began
        raise TrainingInterrupted(f"{stop.name} before training began: nothing was trained or written", stop.signum)
    if resume is False and not f.resuming and primary:
        for d in f.dirs:
            if (d / folders.CHECKPOINTS).is_dir():
                shutil.rmtree(d / folders.CHECKPOINTS)
    start = _host_int(state.chunk)
    for d in f.dirs if primary else ():
        d.mkdir(parents=True, exist_ok=True)
    # a resume first settles its metrics rows (rebuilt from the checkpoint, or refused in one line)
    rows = saved_rows if f.resuming and f.own_checkpoints else None
    log = Log(config, f.dirs, start if f.resuming else None, primary, progress, rows)
    if primary:
        for s, d in zip(f.seeds, f.dirs):
            files.write_atomic(d / folders.CONFIG_FILE, json.dumps({"seed": s, "config": config_json}, indent=1))
    stores = [CheckpointStore(d / folders.CHECKPOINTS, keep=config.run.keep_checkpoints) for d in f.dirs]
    loop = _Loop(config, prog, f, log, stores, config_json, start, start if f.resuming else None, clock_start)
    end = config.num_chunks if max_chunks is None else min(config.num_chunks, start + max_chunks)
    train_t0 = time.time()
    try:
        state = _train_chunks(loop, state, end, stop, say)
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
    config, f: _Folders, loop: _Loop, state, prog: _Program, mesh, train_s: float, startup_s: float
) -> RunSummary:
    num_seeds = len(f.seeds)
    per_seed = []
    for k, (s, d) in enumerate(zip(f.seeds, f.dirs)):
        per_seed.append(
            {
                "seed": s,
                "chunks_done": loop.chunk_no,
                "num_chunks": config.num_chunks,
                "env_steps": _host_int(_seed_slice(state.env_steps, k, num_seeds)),
                "updates": _host_int(_seed_slice(state.learner.updates, k, num_seeds)),
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


def seed_params(state, k: int, num_seeds: int, which: str = "online"):
    """Host copy of seed ``k``'s network params from a (possibly [seeds]-stacked) RunnerState: the online net's
    (``which='online'``), the target net's (``'target'``) or their tail average (``'averaged'``; see
    RunConfig.policy_params)."""
    return distributed.local_copy(_seed_slice(state.learner.policy_params(which), k, num_seeds))
