"""Per-chunk training records: aggregated from the chunk's metrics, appended to each seed's metrics.jsonl (strict
JSON), mirrored to TensorBoard and a progress bar."""

from __future__ import annotations

import math
import os
import time
from pathlib import Path

import jax
import numpy as np

from ramavt_jax.train_config import TrainConfig
from ramavt_jax.train_state import ChunkMetrics
from ramavt_jax.training import files
from ramavt_jax.training import run_folder as folders

__all__ = ["aggregate", "divergence", "process_start_time", "Log"]


def aggregate(m: ChunkMetrics, wall_s: float, env_steps: int) -> dict:
    """Per-chunk record from the per-iteration sums of one chunk (host numpy); ``env_steps`` taken in the chunk. The
    loss terms' metrics (losses.LossTerm: td_loss, aux_loss, ...) are averaged over the chunk's updates."""
    m = jax.tree.map(np.asarray, m)
    episodes = int(m.episodes.sum())
    updates = int(m.updates.sum())

    def ratio(a, b):
        return float(a) / b if b else float("nan")

    return {
        "env_steps": int(m.env_steps[-1]),
        "episodes": episodes,
        "episode_length": ratio(m.episode_length_sum.sum(), episodes),
        "episode_return": ratio(m.episode_return_sum.sum(), episodes),
        "updates": updates,
        "loss": ratio(m.loss_sum.sum(), updates),
        **{name: ratio(total.sum(), updates) for name, total in m.term_sums.items()},  # the loss terms' metrics
        "q_mean": ratio(m.q_sum.sum(), updates),
        "grad_norm": ratio(m.grad_norm_sum.sum(), updates),
        "epsilon": float(m.epsilon[-1]),
        "wall_s": wall_s,
        "env_steps_per_s": env_steps / wall_s,
        "updates_per_s": updates / wall_s,
    }


_IMPORTED_AT = time.time()


def _started_after_boot(stat: str, ticks_per_s: float) -> float:
    """Seconds after boot at which a process started, from its ``/proc/<pid>/stat`` line (field 22, in clock
    ticks)."""
    after_name = stat.rsplit(")", 1)[1].split()  # the command name may hold spaces and ')'
    return int(after_name[19]) / ticks_per_s


def process_start_time() -> float:
    """The epoch second this process started, so that a clock from it counts imports and start-up. On Linux from
    /proc (the seconds since boot less the process's start in clock ticks since boot; 10 ms resolution), so a process
    that re-executed itself (the ``ramavt`` launcher does, for huge-page malloc) counts from its first start;
    elsewhere, or when /proc cannot be read, this module's import (after jax's, which it then leaves out)."""
    now = time.time()
    try:
        with open("/proc/uptime") as f:
            uptime = float(f.read().split()[0])
        with open("/proc/self/stat") as f:
            since_start = uptime - _started_after_boot(f.read(), os.sysconf("SC_CLK_TCK"))
    except (OSError, ValueError, IndexError):
        return _IMPORTED_AT
    return min(now - since_start, _IMPORTED_AT)


def divergence(record: dict, max_loss: float | None = None) -> str | None:
    """Why a chunk's record shows a diverging learner, in a few words naming the figure (``'grad_norm=nan is not a
    finite number'``, ``'loss=6.2e+29 is above run.max_loss=1e+10'``), or None for a healthy one (and for a chunk
    without gradient steps, whose loss is NaN by construction)."""
    if not record["updates"] > 0:
        return None
    for name in ("loss", "q_mean", "grad_norm"):
        value = record.get(name)
        if value is not None and not math.isfinite(value):
            return f"{name}={value} is not a finite number"
    if max_loss is not None and record["loss"] > max_loss:
        return f"loss={record['loss']:.3g} is above run.max_loss={max_loss:g}"
    return None


class Log:
    """Per-seed metric files and TensorBoard writers, and the progress bar (primary process only)."""

    def __init__(
        self,
        config: TrainConfig,
        dirs: list[Path],
        resumed_at: int | None,
        primary: bool,
        progress: bool,
        saved_rows: list | None = None,
    ):
        """``resumed_at``: the restored chunk (its earlier records are kept, later ones dropped), None = fresh.
        ``saved_rows``: per folder, the rows its checkpoints hold (or a function reading them): a row of a chunk up
        to ``resumed_at`` that the file lost is rebuilt from them, or refused in one line (run_folder.resumed_rows);
        None (resuming from another folder's checkpoints): the file's rows are kept as they are."""
        self.primary = primary
        self.paths = [d / folders.METRICS_FILE for d in dirs]
        if resumed_at is None:
            self.records = [[] for _ in self.paths]
        elif saved_rows is None:
            self.records = [[r for r in folders.read_metrics(p) if r["chunk"] <= resumed_at] for p in self.paths]
        else:
            log = print if primary else (lambda msg: None)
            self.records = [folders.resumed_rows(p, resumed_at, rows, log) for p, rows in zip(self.paths, saved_rows)]
        self.writers = [None] * len(dirs)
        self.bar = None
        if not primary:
            return
        for p, recs in zip(self.paths, self.records):
            folders.write_metrics(p, recs)
        if config.run.tensorboard:
            from tensorboardX import SummaryWriter

            self.writers = [SummaryWriter(str(d / "tb")) for d in dirs]
        if progress:
            from tqdm.auto import tqdm

            n, start = len(dirs), resumed_at or 0
            self.bar = tqdm(
                total=config.run.total_env_steps * n,
                initial=start * config.env_steps_per_chunk * n,
                unit="step",
                unit_scale=True,
                dynamic_ncols=True,
                desc="train",
            )

    def add(self, k: int, record: dict) -> None:
        self.records[k].append(record)
        if self.primary:
            folders.append_metrics(self.paths[k], record)
        if self.writers[k] is not None:
            for name, v in record.items():
                if isinstance(v, (int, float)) and math.isfinite(v):
                    self.writers[k].add_scalar(f"train/{name}", v, record["env_steps"])

    def rows_since(self, k: int, chunk: int | None) -> list[dict]:
        """Folder ``k``'s rows of the chunks after ``chunk`` (None: all), as strict JSON (a checkpoint keeps them)."""
        return [files.to_strict_json(r) for r in self.records[k] if chunk is None or r["chunk"] > chunk]

    def sync(self) -> None:
        """Flush the rows appended so far to the disk: called before each checkpoint, so that no checkpoint exists
        whose rows a power cut could take."""
        if self.primary:
            for p in self.paths:
                folders.sync_metrics(p)

    def advance(self, steps: int) -> None:
        if self.bar is not None:
            self.bar.update(steps)
            r = self.records[0][-1]
            self.bar.set_postfix(
                ep_len=f"{r['episode_length']:.0f}", loss=f"{r['loss']:.3g}", eps=f"{r['epsilon']:.2f}"
            )

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None
        for w in self.writers:
            if w is not None:
                w.close()
