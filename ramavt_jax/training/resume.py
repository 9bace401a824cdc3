"""A training run's folders opened and its checkpoints restored, before the first chunk: the folders checked
(writable, not locked by another process, the same config when resuming) and locked, the checkpoint folder each
seed resumes from, and the restored RunnerState of every seed with the metrics rows its checkpoints hold.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import jax
import numpy as np

from ramavt_jax.train_config import TrainConfig
from ramavt_jax.training import run_folder as folders
from ramavt_jax.training.checkpoint import CheckpointError, CheckpointNotFoundError, CheckpointStore, has_checkpoint
from ramavt_jax.training.host_state import host_int, seed_slice
from ramavt_jax.training.program import _Program

__all__ = ["RunFolders", "open_folders", "restore"]


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


@dataclasses.dataclass
class RunFolders:
    """The folders of one training run: ``out``, each seed's run folder with the checkpoint folder it resumes from
    (None: a fresh start), and the lock :func:`open_folders` took."""

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


def open_folders(
    config_json: dict, out: Path, seed: int, num_seeds: int, resume, primary: bool, held=None
) -> RunFolders:
    """Check ``out`` (writable, not locked, same config when resuming) before anything is written into it;
    ``held``: its lock, taken by the caller."""
    seeds = [seed + k for k in range(num_seeds)]
    dirs = folders.seed_folders(out, seeds)
    if held is None:
        folders.check_writable(out)
    lock = folders.lock_folder(out) if primary and held is None else None
    try:
        sources = [_resolve_resume(resume, d / folders.CHECKPOINTS, None if num_seeds == 1 else d.name) for d in dirs]
        if any(s is None for s in sources) and any(s is not None for s in sources):
            raise CheckpointNotFoundError(
                f"only some seed folders in {out} have checkpoints "
                f"({[str(s) for s in sources]}); resume them together or use --no-resume"
            )
        for s, d, src in zip(seeds, dirs, sources):
            if src is not None and (d / folders.CONFIG_FILE).is_file():
                folders.check_config(d, config_json, s, folders.default_json())
    except BaseException:
        if lock is not None:
            lock.close()
        raise
    return RunFolders(out, seeds, dirs, sources, lock)


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


def restore(prog: _Program, state, config: TrainConfig, config_json: dict, f: RunFolders, log):
    """The checkpointed RunnerState of every seed (newest loadable step), placed like ``state``, and per seed a
    function reading the metrics rows its checkpoints hold (run_folder.resumed_rows)."""
    num_seeds = len(f.seeds)
    loaded, rows = [], []
    for k, src in enumerate(f.sources):
        like = seed_slice(state, k, num_seeds)
        like = like if config.run.checkpoint_replay else like.replace(replay=None)
        store = CheckpointStore(src, create=False)
        st, meta, step = store.restore_newest_loadable(like, log, config_json)
        rows.append(lambda store=store, step=step: _saved_rows(store, step))
        saved = meta.get("config", {})
        diff = {
            k: v
            for k, v in folders.config_differences(saved, config_json, folders.default_json()).items()
            if k not in folders.RESUMABLE_FIELDS
        }
        if diff:
            raise CheckpointError(
                f"the checkpoint in {src} was written with another config (differs in "
                f"{', '.join(diff)}); train into a new --out or start afresh with --no-resume"
            )
        loaded.append(st)
    if len({host_int(st.chunk) for st in loaded}) > 1:
        raise CheckpointError(
            f"the seed folders in {f.out} were checkpointed at different chunks; resume them with --no-resume"
        )
    if num_seeds > 1:
        loaded = [jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *loaded)]
    restored = loaded[0]
    if not config.run.checkpoint_replay:
        restored = restored.replace(replay=state.replay)
    return (restored if prog.shardings is None else jax.device_put(restored, prog.shardings)), rows
