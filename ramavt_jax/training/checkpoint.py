"""Training checkpoints with orbax-checkpoint: the whole RunnerState (params, optimizer state, target params,
replay buffer, env/actor state, RNG key, counters) plus JSON metadata (config, step counters).

Saves are synchronous (a checkpoint on disk is complete when ``save`` returns), written atomically by orbax
(a temporary directory renamed at the end), and older ones are pruned to ``keep``. A save that fails (a full disk)
removes its temporary directory and is one CheckpointWriteError line, without orbax's thread tracebacks. Before a
restore the stored arrays' shapes are compared with the state read into: a config that no longer fits the
checkpoint (an edited network, resolution or observation mode) is one CheckpointError line, for ``ramavt train``
and ``ramavt eval`` alike. Resuming restores every leaf bit-for-bit, so a resumed run continues exactly like an
uninterrupted one.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import shutil
import sys
from pathlib import Path
from typing import Any

import jax
import numpy as np
import orbax.checkpoint as ocp
from etils import epath

from ramavt_jax.training import files, run_folder

__all__ = ["CheckpointStore", "CheckpointNotFoundError", "CheckpointError", "CheckpointWriteError", "has_checkpoint"]


class CheckpointNotFoundError(FileNotFoundError):
    """No checkpoint where one was required."""


class CheckpointError(ValueError):
    """A checkpoint exists but cannot be used (no step loads, or it holds another state)."""


class CheckpointWriteError(files.WriteError):
    """A checkpoint could not be written (a full disk); the checkpoints before it are kept."""


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
# of each env's episode change nothing where a run configures no perturbation, as no run written before them did,
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


class _DropThreadErrors(logging.Filter):
    """Drops the errors orbax's writer threads log, each with a traceback, while a failing save winds down: the
    save's own exception says the same in one line."""

    def filter(self, record: logging.LogRecord) -> bool:
        return record.levelno < logging.ERROR


@contextlib.contextmanager
def _quiet_save():
    """While a save runs: the closed-loop noise of its failed writes is dropped (for good, as after a failed
    restore) and its threads' error logs are held back."""
    _quiet_after_failed_restore()
    logger, quiet = logging.getLogger("absl"), _DropThreadErrors()
    logger.addFilter(quiet)
    try:
        yield
    finally:
        logger.removeFilter(quiet)


def _os_error(e: BaseException) -> tuple[int | None, str]:
    """(errno, reason) of a failed write: an OSError's own, or the OS error code tensorstore puts in its text."""
    if isinstance(e, OSError) and e.errno:
        return e.errno, e.strerror or str(e)
    code = re.search(r"os_error_code='?(\d+)", str(e))
    if code:
        return int(code[1]), os.strerror(int(code[1]))
    return None, _first_line(e)


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
        try:
            with _quiet_save():
                self.manager.save(
                    int(step),
                    args=ocp.args.Composite(state=ocp.args.StandardSave(flat), meta=ocp.args.JsonSave(meta)),
                    force=force,
                )
                self.manager.wait_until_finished()
        except Exception as e:  # noqa: BLE001 (orbax and tensorstore raise ValueError, OSError, ... for a full disk)
            for tmp in self.directory.glob(f"{int(step)}.orbax-checkpoint-tmp*"):
                shutil.rmtree(tmp, ignore_errors=True)  # the space it took, back
            number, reason = _os_error(e)
            kept = [s for s in self.all_steps() if s != int(step)]
            raise CheckpointWriteError(
                number,
                f"cannot write checkpoint {step} in {self.directory}: {reason}; "
                + (f"the checkpoints before it are kept (newest: {max(kept)})" if kept else "no checkpoint was kept"),
            ) from None

    def _check_shapes(self, step: int, like: Any, pairs, meta: dict, config: dict | None) -> None:
        """CheckpointError (one line) when an array to read, ``(leaf index in like, index in the checkpoint)``, is
        stored with another shape than ``like`` gives it: the state is read with a config that does not fit the
        checkpoint. ``config``: the config dict read with, to name the fields in which the checkpoint's differs. A
        step whose shapes cannot be read is left to the restore (a damaged step)."""
        try:
            tree = ocp.PyTreeCheckpointHandler().metadata(epath.Path(self.directory / str(int(step)) / "state"))
            shapes = {k: tuple(v.shape) for k, v in dict(getattr(tree, "tree", tree)).items()}
        except Exception:  # noqa: BLE001 (a damaged step: the restore reports it)
            return
        leaves, paths = jax.tree.leaves(like), _paths(like)
        for i, j in pairs:
            have, want = shapes.get(_leaf_key(j)), tuple(np.shape(leaves[i]))
            if have is None or have == want:
                continue
            differs = ""
            if config is not None and isinstance(meta.get("config"), dict):
                fields = [
                    k
                    for k in run_folder.config_differences(meta["config"], config, run_folder.default_json())
                    if k not in run_folder.RESUMABLE_FIELDS
                ]
                differs = f"; the checkpoint's config differs in {', '.join(fields[:4])}" if fields else ""
            raise CheckpointError(
                f"checkpoint {step} in {self.directory} does not fit the config it is read with: {paths[i]} is "
                f"stored as {list(have)}, the config makes it {list(want)}{differs}. The run's config.json was "
                f"edited (network, camera resolution or observation mode): restore it, or train the folder afresh "
                f"with --no-resume"
            )

    def restore(self, like: Any, step: int | None = None, config: dict | None = None) -> tuple[Any, dict]:
        """Restore into the structure/shapes/dtypes of ``like`` (a pytree of arrays). Returns (state, meta).
        ``config``: the config dict the state is built from (a checkpoint that does not fit it names the fields in
        which the checkpoint's config differs)."""
        step = self.latest_step() if step is None else step
        if step is None:
            raise CheckpointNotFoundError(f"no checkpoint found in {self.directory}")
        leaves, treedef = jax.tree.flatten(like)
        meta = self.read_meta(step)
        saved = _saved_indices(like, meta, f"checkpoint {step} in {self.directory}")
        stored = [(i, j) for i, j in enumerate(saved) if j is not None and np.size(leaves[i]) > 0]
        self._check_shapes(step, like, stored, meta, config)
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

    def restore_newest_loadable(self, like: Any, log=print, config: dict | None = None) -> tuple[Any, dict, int]:
        """Restore the newest step that loads, newest first. A step that fails (a truncated or missing file) is
        reported in one line and deleted, so the run continues from the older one. Returns (state, meta, step)."""
        (state, meta), step = self._newest_loadable(lambda s: self.restore(like, s, config), log, delete=True)
        return state, meta, step

    def restore_subtree_newest_loadable(
        self, like: Any, pick, log=print, config: dict | None = None
    ) -> tuple[Any, dict, int]:
        """:meth:`restore_subtree` and :meth:`read_meta` of the newest step that loads (a reader's fallback: the
        damaged steps are reported in one line and left on disk). Returns (sub-tree, meta, step)."""
        (sub, meta), step = self._newest_loadable(
            lambda s: (self.restore_subtree(like, pick, s, config), self.read_meta(s)), log, delete=False
        )
        return sub, meta, step

    def restore_subtree(self, like: Any, pick, step: int | None = None, config: dict | None = None) -> Any:
        """Restore only ``pick(like)`` (a sub-tree of the saved state, e.g. the network params) from ``step``
        (default the latest) without reading the other arrays (``config`` as in :meth:`restore`)."""
        step = self.latest_step() if step is None else step
        leaves, treedef = jax.tree.flatten(like)
        where = f"checkpoint {step} in {self.directory}"
        meta = self.read_meta(step)
        saved = _saved_indices(like, meta, where)
        wanted = jax.tree.leaves(pick(jax.tree.unflatten(treedef, list(range(len(leaves))))))
        if any(saved[i] is None for i in wanted):
            raise CheckpointError(f"{where} predates a leaf asked for: it was written by an earlier code version")
        self._check_shapes(step, like, [(i, saved[i]) for i in wanted if np.size(leaves[i]) > 0], meta, config)
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
