"""Figures layer: episode pictures and videos (``episode``), training curves with seed bands (``training``) and held-out
return against wall time (``curve``).

Above the evaluation layer; matplotlib is imported lazily (``pyplot()``), with the file-only Agg backend.
"""

from __future__ import annotations

from pathlib import Path


def pyplot():
    """matplotlib.pyplot on the non-interactive Agg backend (figures are only written to files)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, out, dpi: int = 110) -> Path:
    """Write ``fig`` to ``out`` (its folder created), close it, and return the path."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi)
    pyplot().close(fig)
    return out
