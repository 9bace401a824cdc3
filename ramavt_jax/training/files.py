"""How the package writes files: strict-JSON text (no NaN / Infinity tokens) and whole-or-nothing replacement.

Every file the package writes goes through :func:`replace_files` (or its one-file forms :func:`replace_atomic` and
:func:`write_atomic`): a crash or a full disk leaves the old files or the new ones, and an OSError is one
:class:`WriteError` line naming the file. The two appends of the run folder (metrics rows, the lock file) are in
:mod:`ramavt_jax.training.run_folder`.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "to_strict_json",
    "dumps",
    "WriteError",
    "write_error",
    "fsync_file",
    "replace_files",
    "replace_atomic",
    "write_atomic",
]


# ============================================================================================ strict JSON
def to_strict_json(x: Any) -> Any:
    """``x`` with every non-finite float replaced by None (JSON null), recursively."""
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: to_strict_json(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [to_strict_json(v) for v in x]
    return x


def dumps(x: Any, **kwargs) -> str:
    """Strict JSON text (no NaN / Infinity tokens, which jq and browsers reject)."""
    return json.dumps(to_strict_json(x), allow_nan=False, **kwargs)


# ============================================================================================ whole-or-nothing writes
class WriteError(OSError):
    """A file could not be written (a full disk, a missing permission); the message names it and says what was kept."""

    def __str__(self) -> str:
        return str(self.strerror)


def write_error(path: Path, e: OSError, kept: str) -> WriteError:
    """The WriteError of ``e``, raised while writing ``path``, in one line; ``kept`` says what was left on the disk."""
    return WriteError(e.errno, f"cannot write {path}: {e.strerror or e}; {kept}")


def fsync_file(path: str | os.PathLike) -> None:
    """Flush the file ``path`` to the disk (its data, whoever wrote it)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_folder(folder: Path) -> None:
    """Flush a folder's entries (a rename into it) to the disk; a file system that cannot is left as it is."""
    try:
        fsync_file(folder)
    except OSError:
        pass


def replace_files(writes: dict) -> list[Path]:
    """Every file the project writes goes through here. ``{path: write}``: ``write(tmp)`` writes each file under a
    name unique to this process beside its ``path`` (same suffix: the format), which is flushed to the disk; only
    when every one is written whole are they renamed over their paths, and the folders flushed. A crash or a full
    disk at any byte leaves the old files or the new ones (files written together, such as tables.md and
    results.json, agree), and two processes writing one path each leave a whole file, never a mix. An OSError is a
    WriteError naming the file, the earlier files left as they were."""
    paths = [Path(p) for p in writes]
    temps = [p.with_name(f".{p.stem}.{os.getpid()}.tmp{p.suffix}") for p in paths]
    done = 0
    try:
        for path, tmp, write in zip(paths, temps, writes.values()):
            try:
                write(tmp)
                fsync_file(tmp)
            except OSError as e:
                raise write_error(path, e, "the files there were left as they were") from None
        for path, tmp in zip(paths, temps):
            try:
                os.replace(tmp, path)
            except OSError as e:
                raise write_error(
                    path, e, f"{done} of the {len(paths)} file(s) written together were replaced"
                ) from None
            done += 1
        for folder in dict.fromkeys(p.parent for p in paths):
            _fsync_folder(folder)
    finally:
        for tmp in temps:
            tmp.unlink(missing_ok=True)
    return paths


def replace_atomic(path: str | os.PathLike, write) -> Path:
    """``write(tmp)`` one file and put it in place of ``path``, whole or not at all (:func:`replace_files`)."""
    return replace_files({path: write})[0]


def write_atomic(path: Path, text: str) -> None:
    """Write the text file ``path`` whole or not at all (:func:`replace_files`)."""
    replace_atomic(path, lambda tmp: tmp.write_text(text))
