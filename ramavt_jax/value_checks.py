"""Checks of configuration values where they enter, with the field's name in a one-line ``ValueError``: integers
that are ints (not bools) and in range, floats that are finite numbers (a NaN or an infinity slips past range checks,
``inf > 0``, and a string past the type hints of config.json or scripts)."""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["check_ints", "check_floats", "check_finite"]


def check_ints(owner: str, config, lows: dict[str, int]) -> None:
    """``{field: lowest value}`` of a dataclass ``config``: each must be an int (not a bool) and at least that."""
    for name, lo in lows.items():
        v = getattr(config, name)
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
            raise ValueError(f"{owner}: {name} must be an int, got {v!r}")
        if v < lo:
            raise ValueError(f"{owner}: {name} must be >= {lo}, got {v}")


def check_floats(owner: str, config) -> None:
    """Every float field (``float`` or ``float | None``) of a dataclass ``config`` holds a finite number (or None
    where allowed)."""
    for f in dataclasses.fields(config):
        if f.type not in ("float", "float | None"):
            continue
        v = getattr(config, f.name)
        if v is None and f.type == "float | None":
            continue
        if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not np.isfinite(v):
            raise ValueError(f"{owner}: {f.name} must be a finite number, got {v!r}")


def check_finite(name: str, value) -> None:
    """``value`` is a finite number or a list of them (e.g. an EnvParams override such as desired_pos)."""
    try:
        arr = np.asarray(value)
        ok = arr.dtype.kind in "iuf" and bool(np.isfinite(arr).all())
    except (ValueError, TypeError):
        ok = False
    if not ok:
        raise ValueError(f"{name} must be a finite number (or a list of them), got {value!r}")
