"""How a target is named: a catalogue name or an MJCF path, with an optional size suffix ``@<radius>m``, and the error
every bad name, file or model raises. The loaders in :mod:`ramavt_jax.targets` read these specs."""

from __future__ import annotations

import os
import re
from pathlib import Path


class TargetError(ValueError):
    """A target name, file or model that cannot be used."""


_SIZED = re.compile(r"^(?P<base>.+)@(?P<radius>[^@/\\]*)m$")
MIN_SIZED_RADIUS, MAX_SIZED_RADIUS = 0.01, 1000.0  # m: a bounding radius asked for with NAME@<radius>m


def sized_spec(name_or_path: str | os.PathLike) -> tuple[str, float | None]:
    """``"Satellite-v2@0.3m"`` -> (``"Satellite-v2"``, 0.3): a catalogue name or MJCF path resized so that its
    bounding radius is 0.3 m. Anything without an ``@<radius>m`` suffix, or an existing file, -> (itself, None).
    Raises TargetError for a radius that is not a number in [MIN_SIZED_RADIUS, MAX_SIZED_RADIUS] or a second
    suffix."""
    text = str(name_or_path)
    match = _SIZED.match(text)
    if match is None or Path(text).expanduser().is_file():
        return text, None
    try:
        radius = float(match["radius"])
    except ValueError:
        radius = float("nan")
    if not MIN_SIZED_RADIUS <= radius <= MAX_SIZED_RADIUS:  # False for nan
        raise TargetError(
            f"target {text!r}: the size after '@' must be a bounding radius in metres from "
            f"{MIN_SIZED_RADIUS:g} to {MAX_SIZED_RADIUS:g}, such as '{match['base']}@0.3m'"
        )
    if _SIZED.match(match["base"]) and not Path(match["base"]).expanduser().is_file():
        raise TargetError(f"target {text!r}: one size suffix '@<radius>m' at most")
    return match["base"], float(f"{radius:g}")  # 6 significant digits: what `sized_name` spells is what loads


def sized_name(name_or_path: str | os.PathLike) -> str:
    """The canonical spelling of a target spec: ``"Satellite-v2@.30m"`` -> ``"Satellite-v2@0.3m"``, so that one
    size has one name, and so one set of episodes."""
    base, radius = sized_spec(name_or_path)
    return base if radius is None else f"{base}@{radius:g}m"
