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
    """Write ``fig`` to ``out`` (its folder created; whole or not at all, files.replace_atomic), close it, and
    return the path."""
    from ramavt_jax.training.files import replace_atomic

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    try:
        replace_atomic(out, lambda tmp: fig.savefig(tmp, dpi=dpi))
    finally:
        pyplot().close(fig)
    return out
