"""Scale-out on JAX's own machinery: a 1-D device mesh, ``NamedSharding`` of the trainer state, multi-host start-up.

One config runs unchanged on 1 CPU, 8 forced CPU devices, several GPUs or several hosts::

    mesh = make_mesh()                      # all visible devices (every process's), axis 'data'; None if only one
    shardings = runner_shardings(abstract_runner_state, mesh)
    chunk = jax.jit(trainer.chunk, in_shardings=shardings, out_shardings=(shardings, replicated(mesh)))

Placement (GSPMD partitions the one jitted program; XLA inserts the collectives):

* the acting envs (``actor``: env state, observation, recurrent state) and the replay rows (``replay.experience``,
  one row per env) are split along the env axis over the ``'data'`` mesh axis, so each device steps, renders and
  stores ``num_envs / devices`` envs. The env step itself runs under ``jax.shard_map`` (each device its own envs):
  left to GSPMD, the renderer's batch-wide work list would be all-gathered and each device would render the
  whole batch;
* params, target params (and their tail average), optimiser state, PRNG key and counters are replicated;
* each sampled learner batch is split along its window axis (when ``batch_size`` divides), so every device
  computes the gradient of its windows and XLA all-reduces (averages) them before the replicated Adam step.

Because the program is the same one the single-device run compiles, a sharded run equals the unsharded run with
the same global batch up to float summation order (``tests/test_distributed.py`` checks both equality and that
data really lands on every device).

Multi-host: call :func:`initialize` (coordinator address, process count and id from arguments or the environment
variables ``JAX_COORDINATOR_ADDRESS``, ``JAX_NUM_PROCESSES``, ``JAX_PROCESS_ID``) before anything touches a device;
``jax.devices()`` then lists every process's devices and the mesh spans them all. CPU processes talk over gloo.
"""

from __future__ import annotations

import os
from typing import Any

import jax
import numpy as np
from jax._src import distributed as jax_distributed  # the coordination-service client (no public handle)
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

__all__ = [
    "P",
    "DATA_AXIS",
    "initialize",
    "make_mesh",
    "replicated",
    "runner_shardings",
    "check_divisible",
    "check_seeds_divisible",
    "constrain_envs",
    "constrain_batch",
    "local_copy",
    "is_primary",
    "barrier",
    "ShardingError",
]

DATA_AXIS = "data"


class ShardingError(ValueError):
    """A batch that must be split over devices does not divide by the device count."""


# ============================================================================================ multi-host
def initialize(
    coordinator_address: str | None = None,
    num_processes: int | None = None,
    process_id: int | None = None,
    timeout_s: int = 300,
) -> bool:
    """Join a multi-process JAX job (``jax.distributed.initialize``). Arguments left ``None`` are read from
    ``JAX_COORDINATOR_ADDRESS`` / ``JAX_NUM_PROCESSES`` / ``JAX_PROCESS_ID``. Returns False (and does nothing)
    when neither gives a coordinator address, i.e. a plain single-process run. Must run before any device is used.
    """
    env = os.environ
    address = coordinator_address or env.get("JAX_COORDINATOR_ADDRESS") or None
    if address is None:
        if num_processes not in (None, 1) or process_id not in (None, 0):
            raise ValueError(
                "num_processes / process_id were given without a coordinator address "
                "(--coordinator-address host:port or JAX_COORDINATOR_ADDRESS)"
            )
        return False
    if num_processes is None and env.get("JAX_NUM_PROCESSES"):
        num_processes = int(env["JAX_NUM_PROCESSES"])
    if process_id is None and env.get("JAX_PROCESS_ID"):
        process_id = int(env["JAX_PROCESS_ID"])
    if num_processes is None or process_id is None:
        raise ValueError(
            f"coordinator address {address!r} given, but the process count and id are missing: pass "
            "--num-processes and --process-id (or JAX_NUM_PROCESSES / JAX_PROCESS_ID)"
        )
    if not (isinstance(num_processes, int) and num_processes >= 1 and 0 <= process_id < num_processes):
        raise ValueError(
            f"need num_processes >= 1 and 0 <= process_id < num_processes, got {num_processes}, {process_id}"
        )
    if ":" not in address:
        raise ValueError(f"coordinator address must be host:port, got {address!r}")
    jax.distributed.initialize(
        coordinator_address=address,
        num_processes=num_processes,
        process_id=process_id,
        initialization_timeout=timeout_s,
    )
    return True


def barrier(name: str, timeout_s: int = 600) -> None:
    """Block until every process of a multi-host job reaches ``name``; a no-op in a single-process run.

    Goes through JAX's coordination service (its timeout is ours to set), not through gloo: gloo's first
    collective gives up after a fixed 30 s, and two processes can reach it further apart than that when start-up
    and compilation run on a loaded machine."""
    if jax.process_count() == 1:
        return
    jax_distributed.global_state.client.wait_at_barrier(name, timeout_in_ms=timeout_s * 1000)


def is_primary() -> bool:
    """Whether this process writes logs, plots and evaluation files (process 0)."""
    return jax.process_index() == 0


# ============================================================================================ mesh
def make_mesh(num_devices: int | None = None) -> Mesh | None:
    """A 1-D mesh over the first ``num_devices`` of ``jax.devices()`` (all of them by default, every process's);
    None when that is a single device (the plain unsharded program)."""
    devices = jax.devices()
    n = len(devices) if num_devices in (None, 0) else num_devices
    if not 1 <= n <= len(devices):
        raise ValueError(f"num_devices={num_devices} but {len(devices)} device(s) are visible")
    if n == 1:
        return None
    if jax.process_count() > 1 and n != len(devices):
        raise ValueError("a multi-host run must use every device (num_devices=None)")
    return Mesh(np.array(devices[:n]), (DATA_AXIS,))


def replicated(mesh: Mesh) -> NamedSharding:
    return NamedSharding(mesh, P())


def check_divisible(num_envs: int, mesh: Mesh | None) -> None:
    """Clear error when the env batch cannot be split evenly over the mesh."""
    if mesh is None:
        return
    n = mesh.devices.size
    if num_envs % n:
        ok = [k * n for k in range(max(1, num_envs // n), num_envs // n + 3)]
        raise ShardingError(
            f"num_envs={num_envs} does not divide over {n} devices; the envs and replay rows are "
            f"split evenly along the env axis. Use a multiple of {n} (e.g. {ok}) or fewer devices "
            f"(--devices)"
        )


def _split_axis(ndim: int, axis: int) -> P:
    """Leaf of rank ``ndim`` split over 'data' along ``axis`` (replicated when it has no such axis)."""
    if ndim <= axis:
        return P()
    return P(*[DATA_AXIS if i == axis else None for i in range(ndim)])


def _env_axis_spec(path: tuple, ndim: int) -> P:
    """Partition spec of one RunnerState leaf: env-axis leaves split over 'data', everything else replicated."""
    names = [getattr(p, "name", getattr(p, "key", None)) for p in path]
    if names and names[0] == "actor":
        env_axis = 1 if ("net_state" in names and names[-1] != "frames") else 0  # net_state: [layers, N, ...]
    elif names[:2] == ["replay", "experience"]:
        env_axis = 0  # flashbax rows: [num_envs, time, ...]
    else:
        return P()
    return _split_axis(ndim, env_axis)


def runner_shardings(abstract_state: Any, mesh: Mesh, seed_axis: bool = False) -> Any:
    """NamedSharding per RunnerState leaf (``abstract_state`` from ``jax.eval_shape``).

    One seed: env-axis leaves split over 'data', the rest replicated. ``seed_axis`` (vmapped seeds, every leaf
    [seeds, ...]): the seeds are split over 'data' instead, so each device trains its own seeds whole and the
    devices never talk (a sweep needs no gradient averaging)."""
    if seed_axis:
        return jax.tree.map(lambda leaf: NamedSharding(mesh, P(DATA_AXIS)), abstract_state)
    return jax.tree_util.tree_map_with_path(
        lambda path, leaf: NamedSharding(mesh, _env_axis_spec(path, len(leaf.shape))), abstract_state
    )


def check_seeds_divisible(num_seeds: int, mesh: Mesh | None) -> None:
    if mesh is None or num_seeds == 1:
        return
    n = mesh.devices.size
    if num_seeds % n:
        raise ShardingError(
            f"{num_seeds} seeds on {n} devices: several seeds are split over the devices whole "
            f"(each device trains num_seeds / devices seeds), so num_seeds must be a multiple of {n}; "
            f"or train one seed over all devices, or pass --devices 1"
        )


# ============================================================================================ in-program hints
def constrain_envs(tree: Any, mesh: Mesh | None, env_axis: int = 0) -> Any:
    """Keep per-env leaves ([..., N at env_axis, ...]) split over 'data' inside scans (a hint for GSPMD)."""
    if mesh is None:
        return tree

    return jax.tree.map(
        lambda x: jax.lax.with_sharding_constraint(x, NamedSharding(mesh, _split_axis(x.ndim, env_axis))), tree
    )


def constrain_batch(tree: Any, mesh: Mesh | None, batch_size: int, batch_axis: int = 0) -> Any:
    """Split a sampled learner batch (B at ``batch_axis``) over 'data' when B divides: data-parallel gradients."""
    if mesh is None or batch_size % mesh.devices.size:
        return tree
    return constrain_envs(tree, mesh, batch_axis)


# ============================================================================================ host side
def local_copy(tree: Any) -> Any:
    """Host numpy copy of a pytree whose leaves are fully addressable or fully replicated (multi-host params)."""

    def one(x):
        if isinstance(x, jax.Array) and not x.is_fully_addressable:
            if not x.is_fully_replicated:
                raise ValueError("local_copy: a leaf is split across processes; gather it first")
            return np.asarray(x.addressable_data(0))
        return np.asarray(x)

    return jax.tree.map(one, tree)
