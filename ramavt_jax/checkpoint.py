"""Training checkpoints with orbax-checkpoint: the whole RunnerState (params, optimizer state, target params,
replay buffer, env/actor state, RNG key, counters) plus JSON metadata (config, step counters).

Saves are synchronous (a checkpoint on disk is complete when ``save`` returns), written atomically by orbax
(a temporary directory renamed at the end), and older ones are pruned to ``keep``. Resuming restores every leaf
bit-for-bit, so a resumed run continues exactly like an uninterrupted one.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import jax
import numpy as np
import orbax.checkpoint as ocp

__all__ = ["CheckpointStore", "CheckpointNotFoundError", "has_checkpoint"]


class CheckpointNotFoundError(FileNotFoundError):
    """No checkpoint where one was required."""


def has_checkpoint(directory) -> bool:
    """Whether ``directory`` holds at least one finished orbax checkpoint step."""
    directory = Path(directory)
    if not directory.is_dir():
        return False
    return any(p.is_dir() and p.name.isdigit() for p in directory.iterdir())


def _flat(tree: Any) -> tuple[dict, int]:
    """Non-empty leaves as {index: array} (orbax refuses zero-size arrays) and the total leaf count."""
    leaves = jax.tree.leaves(tree)
    return {f"{i:05d}": leaf for i, leaf in enumerate(leaves) if np.size(leaf) > 0}, len(leaves)


class CheckpointStore:
    """A directory of numbered checkpoints (the step is the number of completed chunks)."""

    def __init__(self, directory, keep: int = 2, create: bool = True):
        self.directory = Path(os.path.abspath(directory))
        if not create and not has_checkpoint(self.directory):
            raise CheckpointNotFoundError(
                f"no checkpoint found in {self.directory} (expected numbered step folders written by a "
                f"previous run); check the path or start a fresh run")
        options = ocp.CheckpointManagerOptions(max_to_keep=keep, create=create, enable_async_checkpointing=False)
        self.manager = ocp.CheckpointManager(self.directory, options=options)

    def latest_step(self) -> int | None:
        return self.manager.latest_step()

    def all_steps(self) -> list[int]:
        return list(self.manager.all_steps())

    def save(self, step: int, state: Any, meta: dict, force: bool = True) -> None:
        """Write ``state`` (any pytree of arrays) and ``meta`` (JSON-serialisable) as checkpoint ``step``."""
        leaves = jax.tree.leaves(state)
        if all(getattr(x, "is_fully_addressable", True) for x in leaves):
            state = jax.tree.map(np.asarray, jax.device_get(state))
        # else: a multi-host run; orbax writes each process's shards of the global arrays itself
        flat, count = _flat(state)
        meta = dict(meta, _num_leaves=count)
        self.manager.save(int(step), args=ocp.args.Composite(state=ocp.args.StandardSave(flat),
                                                             meta=ocp.args.JsonSave(meta)), force=force)
        self.manager.wait_until_finished()

    def restore(self, like: Any, step: int | None = None) -> tuple[Any, dict]:
        """Restore into the structure/shapes/dtypes of ``like`` (a pytree of arrays). Returns (state, meta)."""
        step = self.latest_step() if step is None else step
        if step is None:
            raise CheckpointNotFoundError(f"no checkpoint found in {self.directory}")
        leaves, treedef = jax.tree.flatten(like)
        meta = self.read_meta(step)
        if meta.get("_num_leaves") != len(leaves):
            raise ValueError(f"checkpoint {step} in {self.directory} holds a state with {meta.get('_num_leaves')} "
                             f"arrays, the current run expects {len(leaves)}: it was written by a different "
                             f"configuration or code version")
        flat, _ = _flat(like)
        abstract = jax.tree.map(ocp.utils.to_shape_dtype_struct, flat)
        restored = self.manager.restore(int(step), args=ocp.args.Composite(state=ocp.args.StandardRestore(abstract)))
        data = restored["state"]
        out = [data[f"{i:05d}"] if np.size(leaf) > 0 else leaf for i, leaf in enumerate(leaves)]
        meta.pop("_num_leaves", None)
        return jax.tree.unflatten(treedef, out), meta

    def read_meta(self, step: int | None = None) -> dict:
        step = self.latest_step() if step is None else step
        if step is None:
            raise CheckpointNotFoundError(f"no checkpoint found in {self.directory}")
        restored = self.manager.restore(int(step), args=ocp.args.Composite(meta=ocp.args.JsonRestore()))
        return dict(restored["meta"])

    def close(self) -> None:
        self.manager.close()
