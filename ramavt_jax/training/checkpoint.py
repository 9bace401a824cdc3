"""Training checkpoints with orbax-checkpoint: the whole RunnerState (params, optimizer state, target params,
replay buffer, env/actor state, RNG key, counters) plus JSON metadata (config, step counters).

Saves are synchronous (a checkpoint on disk is complete when ``save`` returns), written atomically by orbax
(a temporary directory renamed at the end), and older ones are pruned to ``keep``. Resuming restores every leaf
bit-for-bit, so a resumed run continues exactly like an uninterrupted one.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

import jax
import numpy as np
import orbax.checkpoint as ocp

__all__ = ["CheckpointStore", "CheckpointNotFoundError", "CheckpointError", "has_checkpoint"]


class CheckpointNotFoundError(FileNotFoundError):
    """No checkpoint where one was required."""


class CheckpointError(ValueError):
    """A checkpoint exists but cannot be used (no step loads, or it holds another state)."""


def has_checkpoint(directory) -> bool:
    """Whether ``directory`` holds at least one finished orbax checkpoint step."""
    directory = Path(directory)
    if not directory.is_dir():
        return False
    return any(p.is_dir() and p.name.isdigit() for p in directory.iterdir())


def _leaf_key(i: int) -> str:
    """The name of leaf ``i`` (in ``jax.tree.leaves`` order) inside a checkpoint."""
    return f"{i:05d}"


# Leaves added to the trainer's state (RunnerState) since earlier checkpoints were written: a checkpoint without
# them loads, and they keep the values of the state restored into. One written before the leaves' paths were
# recorded (no "_leaf_paths" in its meta) is read as holding every current leaf but these. The perturbation draws
# of each env's episode (2026-12-05) change nothing where a run configures no perturbation, as no earlier run did,
# so a resumed run continues as it would have.
ADDED_LEAVES = (".actor.env_state.perturbed",)


def _paths(tree: Any) -> list[str]:
    """The path of every leaf (``jax.tree.leaves`` order), as ``jax.tree_util.keystr`` writes it."""
    return [jax.tree_util.keystr(path) for path, _ in jax.tree_util.tree_flatten_with_path(tree)[0]]


def _flat(tree: Any) -> tuple[dict, int]:
    """Non-empty leaves as {index: array} (orbax refuses zero-size arrays) and the total leaf count."""
    leaves = jax.tree.leaves(tree)
    return {_leaf_key(i): leaf for i, leaf in enumerate(leaves) if np.size(leaf) > 0}, len(leaves)


def _saved_indices(like: Any, meta: dict, where: str) -> list[int | None]:
    """For each leaf of ``like``, the index of the checkpoint's leaf at its path, or None for an ADDED_LEAVES leaf
    the checkpoint predates. Raises CheckpointError when the checkpoint holds another tree."""
    paths = _paths(like)
    saved = meta.get("_leaf_paths")
    if saved is None:  # written before the paths were recorded: the current tree, or it without the leaves added
        count = meta.get("_num_leaves")
        saved = paths if count == len(paths) else [p for p in paths if not p.endswith(ADDED_LEAVES)]
        if count != len(saved):
            raise CheckpointError(
                f"{where} holds a state with {count} arrays, the current code and config expect "
                f"{len(paths)}: it was written by another configuration or code version"
            )
    index = {p: i for i, p in enumerate(saved)}
    differ = sorted(set(saved) ^ {p for p in paths if p in index or not p.endswith(ADDED_LEAVES)})
    if differ:
        raise CheckpointError(
            f"{where} holds another state (it differs at {', '.join(differ[:3])}): it was written "
            f"by another configuration or code version"
        )
    return [index.get(p) for p in paths]


def _first_line(e: BaseException) -> str:
    """The gist of a (possibly very long, multi-line) restore error."""
    text = str(e).strip().splitlines()
    first = text[0].split(" See full TensorStore details")[0] if text else ""
    return f"{type(e).__name__}: {first[:160]}"


def _drop_closed_loop_noise(previous):
    """An unraisable-exception hook that drops asyncio's 'Event loop is closed' and passes the rest to ``previous``."""

    def hook(unraisable) -> None:
        e = unraisable.exc_value
        if isinstance(e, RuntimeError) and str(e) == "Event loop is closed":
            return
        previous(unraisable)

    hook.drops_closed_loop_noise = True
    return hook


def _quiet_after_failed_restore() -> None:
    """After a failed restore, tensorstore's reads still in flight complete into orbax's closed event loop and
    Python reports each as an unraisable 'Event loop is closed' traceback (about 100 per damaged step, some at
    exit). They carry no information: drop them, process-wide, from the first failure on."""
    if not getattr(sys.unraisablehook, "drops_closed_loop_noise", False):
        sys.unraisablehook = _drop_closed_loop_noise(sys.unraisablehook)


class CheckpointStore:
    """A directory of numbered checkpoints (the step is the number of completed chunks)."""

    def __init__(self, directory, keep: int = 2, create: bool = True):
        self.directory = Path(os.path.abspath(directory))
        if not create and not has_checkpoint(self.directory):
            raise CheckpointNotFoundError(
                f"no checkpoint found in {self.directory} (expected numbered step folders written by a "
                f"previous run); check the path or start a fresh run"
            )
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
        meta = dict(meta, _num_leaves=count, _leaf_paths=_paths(state))
        self.manager.save(
            int(step),
            args=ocp.args.Composite(state=ocp.args.StandardSave(flat), meta=ocp.args.JsonSave(meta)),
            force=force,
        )
        self.manager.wait_until_finished()

    def restore(self, like: Any, step: int | None = None) -> tuple[Any, dict]:
        """Restore into the structure/shapes/dtypes of ``like`` (a pytree of arrays). Returns (state, meta)."""
        step = self.latest_step() if step is None else step
        if step is None:
            raise CheckpointNotFoundError(f"no checkpoint found in {self.directory}")
        leaves, treedef = jax.tree.flatten(like)
        meta = self.read_meta(step)
        saved = _saved_indices(like, meta, f"checkpoint {step} in {self.directory}")
        stored = [(i, j) for i, j in enumerate(saved) if j is not None and np.size(leaves[i]) > 0]
        abstract = {_leaf_key(j): ocp.utils.to_shape_dtype_struct(leaves[i]) for i, j in stored}
        restored = self.manager.restore(int(step), args=ocp.args.Composite(state=ocp.args.StandardRestore(abstract)))
        out = list(leaves)
        for i, j in stored:
            out[i] = restored["state"][_leaf_key(j)]
        meta.pop("_num_leaves", None)
        meta.pop("_leaf_paths", None)
        return jax.tree.unflatten(treedef, out), meta

    def _newest_loadable(self, load, log, delete: bool):
        """``(load(step), step)`` for the newest step that loads. A step that fails (a truncated or missing file) is
        reported in one line and, with ``delete``, deleted with every newer one."""
        failures = []
        for step in sorted(self.all_steps(), reverse=True):
            try:
                result = load(step)
            except CheckpointError:
                raise
            except Exception as e:  # noqa: BLE001 (orbax / tensorstore raise many types for damaged files)
                _quiet_after_failed_restore()
                failures.append(f"step {step}: {_first_line(e)}")
                continue
            if delete:
                for bad in [s for s in self.all_steps() if s > step]:
                    self.manager.delete(bad)
            if failures:
                what = "resuming from" if delete else "using"
                kept = "the damaged ones were deleted" if delete else "the damaged ones were left as they are"
                log(
                    f"checkpoint(s) in {self.directory} did not load ({'; '.join(failures)}); {what} step {step} "
                    f"({kept})"
                )
            return result, step
        advice = "start afresh with --no-resume" if delete else "the run has no usable checkpoint"
        raise CheckpointError(
            f"no checkpoint in {self.directory} loads ({'; '.join(failures) or 'none found'}); {advice}"
        )

    def restore_newest_loadable(self, like: Any, log=print) -> tuple[Any, dict, int]:
        """Restore the newest step that loads, newest first. A step that fails (a truncated or missing file) is
        reported in one line and deleted, so the run continues from the older one. Returns (state, meta, step)."""
        (state, meta), step = self._newest_loadable(lambda s: self.restore(like, s), log, delete=True)
        return state, meta, step

    def restore_subtree_newest_loadable(self, like: Any, pick, log=print) -> tuple[Any, dict, int]:
        """:meth:`restore_subtree` and :meth:`read_meta` of the newest step that loads (a reader's fallback: the
        damaged steps are reported in one line and left on disk). Returns (sub-tree, meta, step)."""
        (sub, meta), step = self._newest_loadable(
            lambda s: (self.restore_subtree(like, pick, s), self.read_meta(s)), log, delete=False
        )
        return sub, meta, step

    def restore_subtree(self, like: Any, pick, step: int | None = None) -> Any:
        """Restore only ``pick(like)`` (a sub-tree of the saved state, e.g. the network params) from ``step``
        (default the latest) without reading the other arrays."""
        step = self.latest_step() if step is None else step
        leaves, treedef = jax.tree.flatten(like)
        where = f"checkpoint {step} in {self.directory}"
        saved = _saved_indices(like, self.read_meta(step), where)
        wanted = jax.tree.leaves(pick(jax.tree.unflatten(treedef, list(range(len(leaves))))))
        if any(saved[i] is None for i in wanted):
            raise CheckpointError(f"{where} predates a leaf asked for: it was written by an earlier code version")
        keys = [_leaf_key(saved[i]) for i in wanted]
        abstract = {k: jax.ShapeDtypeStruct(leaves[i].shape, leaves[i].dtype) for k, i in zip(keys, wanted)}
        restored = self.manager.restore(
            int(step), args=ocp.args.Composite(state=ocp.args.PyTreeRestore(abstract, partial_restore=True))
        )["state"]
        _, sub_def = jax.tree.flatten(pick(like))
        return jax.tree.unflatten(sub_def, [restored[k] for k in keys])

    def read_meta(self, step: int | None = None) -> dict:
        step = self.latest_step() if step is None else step
        if step is None:
            raise CheckpointNotFoundError(f"no checkpoint found in {self.directory}")
        restored = self.manager.restore(int(step), args=ocp.args.Composite(meta=ocp.args.JsonRestore()))
        return dict(restored["meta"])

    def close(self) -> None:
        self.manager.close()
