"""The chunk loop of a training run: dispatch the jitted chunks, log one record per chunk (raising on a diverging
learner), checkpoint every ``run.checkpoint_every_chunks`` chunks, and on SIGINT / SIGTERM let the chunk in flight
finish, log it and checkpoint it before stopping (a second Ctrl-C: whatever is complete is saved).
"""

from __future__ import annotations

import dataclasses
import time

import jax
import numpy as np

from ramavt_jax import distributed
from ramavt_jax.train_config import TrainConfig
from ramavt_jax.train_state import TrainingDivergedError
from ramavt_jax.training import run_folder as folders
from ramavt_jax.training.host_state import host_int, seed_slice
from ramavt_jax.training.interrupts import StopSignals, TrainingInterrupted
from ramavt_jax.training.metrics import Log, aggregate, divergence
from ramavt_jax.training.program import _Program
from ramavt_jax.training.resume import RunFolders

__all__ = ["ChunkLoop", "train_chunks"]


@dataclasses.dataclass
class ChunkLoop:
    """What the chunk loop needs and updates."""

    config: TrainConfig
    prog: _Program
    f: RunFolders
    log: Log
    stores: list
    config_json: dict
    chunk_no: int  # host mirror of state.chunk (each compiled chunk adds one): no device read per chunk
    last_saved: int | None
    clock_start: float  # epoch second from which the records' since_start_s count (see driver.run)

    def save(self, state) -> None:
        """Checkpoint ``state`` as chunk ``chunk_no`` in every seed folder, after flushing the metrics rows to the
        disk; each checkpoint holds its seed's rows since the previous checkpoint, which a resume rebuilds when the
        file lost them (call inside StopSignals.writing: a second Ctrl-C waits until the checkpoint is whole)."""
        num_seeds = len(self.f.seeds)
        self.log.sync()
        for k, (s, store) in enumerate(zip(self.f.seeds, self.stores)):
            if (store.directory / str(self.chunk_no)).is_dir():  # already written whole (orbax renames at the end)
                continue
            one = seed_slice(state, k, num_seeds)
            meta = {
                "config": self.config_json,
                "seed": s,
                "chunk": self.chunk_no,
                "env_steps": host_int(one.env_steps),
                "updates": host_int(one.learner.updates),
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
            record = {"chunk": self.chunk_no, **aggregate(seed_slice(m, k, num_seeds), wall, c.env_steps_per_chunk)}
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


def _save_on_interrupt(loop: ChunkLoop, state, pending) -> None:
    """After a second Ctrl-C: let the chunk in flight finish (XLA cannot cancel it), log it when its metrics are
    at hand, and checkpoint the state when every chunk it covers has its row (and its parameters are finite)."""
    jax.block_until_ready(state)
    done = host_int(state.chunk)  # may be one ahead of the host mirror: the chunk in flight
    if done == loop.chunk_no + 1 and pending is not None:
        loop.chunk_no = done
        loop.record(distributed.local_copy(pending[0]), time.time() - pending[1])
    if done == loop.chunk_no and loop.chunk_no != loop.last_saved and _finite_params(state):
        loop.save(state)


def _finite_params(state) -> bool:
    return all(
        bool(np.isfinite(np.asarray(x)).all()) for x in jax.tree.leaves(distributed.local_copy(state.learner.params))
    )


def train_chunks(loop: ChunkLoop, state, end: int, stop: StopSignals, say):
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
