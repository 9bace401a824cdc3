"""ramavt_jax: vectorised JAX active visual tracking of tumbling space objects (RAMAVT successor).

Functional API: ``from ramavt_jax import env, render, network, targets, dynamics``.
"""

__version__ = "0.1.0"
