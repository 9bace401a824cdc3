"""Argument checks the commands run before any compile: one-line errors naming the input and what is valid."""

from __future__ import annotations

import math
from pathlib import Path

from ramavt_jax.training import run_folder

__all__ = ["UsageError", "positive", "finite", "output_file", "output_folder", "keeps_policy_params"]


MAX_EPISODES = 1_000_000  # episodes per target: the episode counters are 32-bit
MAX_STEPS = 1_000_000  # an episode's length: EnvParams.max_steps's range (env_config.RANGES)


class UsageError(ValueError):
    """A bad command-line argument."""


def positive(name: str, value: int, minimum: int = 1, maximum: int | None = None) -> int:
    """An integer flag: at least ``minimum`` and, where given, at most ``maximum`` (a count that a 32-bit counter
    or the simulator's ranges must hold)."""
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise UsageError(f"{name} must be an integer >= {minimum}, got {value!r}")
    if maximum is not None and value > maximum:
        raise UsageError(f"{name} must be an integer in [{minimum}, {maximum}], got {value}")
    return value


def finite(name: str, value: float, minimum: float = 0.0) -> float:
    """A float flag: a finite number >= ``minimum`` (a NaN passes every comparison-free path to the simulator)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < minimum:
        raise UsageError(f"{name} must be a finite number >= {minimum:g}, got {value!r}")
    return value


def keeps_policy_params(run_dir: Path, policy_params: str | None) -> None:
    """A run folder asked for its tail average (``--policy-params averaged``) was trained keeping one
    (evaluation.runs.check_policy_params, as a UsageError)."""
    # imported here: `ramavt train` loads this module at start-up (its clock counts imports) and needs none of it
    from ramavt_jax.evaluation.runs import check_policy_params

    try:
        check_policy_params(run_dir, policy_params)
    except ValueError as e:
        raise UsageError(f"--run {e}") from None


def output_folder(path: Path, flag: str = "--out") -> Path:
    """``path`` is (or can be created as) a writable folder; it is created (one home: run_folder.check_writable)."""
    try:
        return run_folder.check_writable(path, flag)
    except run_folder.RunFolderError as e:
        raise UsageError(str(e)) from None


def output_file(path: Path, suffixes: tuple[str, ...], flag: str = "--out") -> Path:
    """``path`` has one of ``suffixes`` and its folder is writable (created if missing)."""
    path = Path(path)
    if path.suffix.lower() not in suffixes:
        raise UsageError(f"{flag} {path}: the file name must end in {' or '.join(suffixes)}")
    if path.is_dir():
        raise UsageError(f"{flag} {path} is a folder; give a file name ending in {' or '.join(suffixes)}")
    output_folder(path.parent if str(path.parent) else Path("."), f"folder of {flag}")
    return path
