"""Host-side reads of a training run's RunnerState, which may be sharded over devices and, when several seeds are
trained as one program, stacked over seeds (a leading [seeds] axis on every leaf): one seed's part, a counter as a host
int, one seed's network params as host arrays."""

from __future__ import annotations

import jax
import numpy as np

from ramavt_jax import distributed

__all__ = ["host_int", "seed_slice", "seed_params"]


def host_int(x) -> int:
    """A counter of the (possibly sharded, possibly [seeds]-stacked) state as a host int (seeds share it: first)."""
    return int(np.asarray(distributed.local_copy(x)).reshape(-1)[0])


def seed_slice(tree, k: int, num_seeds: int):
    """Seed ``k``'s part of a [seeds]-stacked pytree (the tree itself when one seed was trained)."""
    return tree if num_seeds == 1 else jax.tree.map(lambda x: x[k], tree)


def seed_params(state, k: int, num_seeds: int, which: str = "online"):
    """Host copy of seed ``k``'s network params from a (possibly [seeds]-stacked) RunnerState: the online net's
    (``which='online'``), the target net's (``'target'``) or their tail average (``'averaged'``; see
    RunConfig.policy_params)."""
    return distributed.local_copy(seed_slice(state.learner.policy_params(which), k, num_seeds))
