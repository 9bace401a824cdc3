"""Figures layer: episode pictures and videos (``episode``), training curves with seed bands (``training``) and held-out
return against wall time (``curve``).

Above the evaluation layer; matplotlib is imported lazily (``pyplot()``), with the file-only Agg backend.
"""

from __future__ import annotations


def pyplot():
    """matplotlib.pyplot on the non-interactive Agg backend (figures are only written to files)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt
