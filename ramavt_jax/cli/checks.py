"""Argument checks the commands run before any compile: one-line errors naming the input and what is valid."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["UsageError", "positive", "output_file", "output_folder"]


class UsageError(ValueError):
    """A bad command-line argument."""


def positive(name: str, value: int, minimum: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise UsageError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return value


def output_folder(path: Path, flag: str = "--out") -> Path:
    """``path`` is (or can be created as) a writable folder; it is created."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise UsageError(f"{flag} {path} is a file, not a folder; choose a folder path")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UsageError(f"cannot create the {flag} folder {path}: {e.strerror}") from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise UsageError(f"the {flag} folder {path} is not writable; choose another folder")
    return path


def output_file(path: Path, suffixes: tuple[str, ...], flag: str = "--out") -> Path:
    """``path`` has one of ``suffixes`` and its folder is writable (created if missing)."""
    path = Path(path)
    if path.suffix.lower() not in suffixes:
        raise UsageError(f"{flag} {path}: the file name must end in {' or '.join(suffixes)}")
    if path.is_dir():
        raise UsageError(f"{flag} {path} is a folder; give a file name ending in {' or '.join(suffixes)}")
    output_folder(path.parent if str(path.parent) else Path("."), f"folder of {flag}")
    return path
