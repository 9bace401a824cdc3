"""Pretrained agents shipped with the package, one folder each (``params.npz``, ``config.json``, ``TRAINING.md``).
Load them with :func:`ramavt_jax.evaluation.pretrained.load`; this package holds data only."""
