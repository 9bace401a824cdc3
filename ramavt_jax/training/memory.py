"""Memory planned before allocating: how many bytes a device can still take, and a one-line refusal naming the
size and the setting to change when a plan does not fit.

A plan that does not fit must be refused before XLA allocates: an allocation far beyond the host's RAM does not
fail on Linux (overcommit), it pages until the process stops responding, to signals too.
"""

from __future__ import annotations

import os

import jax

__all__ = ["MemoryPlanError", "available_bytes", "tree_bytes", "human", "check_fits", "FRACTION"]

FRACTION = 0.9  # of the available memory a plan may use (XLA's temporaries and the host's own need the rest)


class MemoryPlanError(ValueError):
    """A planned allocation does not fit in the memory available."""


def _host_available() -> int | None:
    """Bytes of RAM the host can still hand out: MemAvailable of /proc/meminfo, else free pages (os.sysconf)."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


_CGROUP_LIMITS = ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes")  # v2, v1


def _cgroup_available(limits=_CGROUP_LIMITS) -> int | None:
    """Bytes the process's control group (a container, a batch job) may still use: its limit minus its usage, or
    None without a limit. A container's /proc/meminfo shows the host's RAM, far more than the container may take."""
    for path in limits:
        try:
            text = open(path).read().strip()
        except OSError:
            continue
        if text == "max" or not text.isdigit() or int(text) >= 2**60:  # v1 writes a huge number for "no limit"
            return None
        usage_file = path.replace("memory.max", "memory.current").replace("limit_in_bytes", "usage_in_bytes")
        try:
            usage = int(open(usage_file).read().strip())
        except (OSError, ValueError):
            usage = 0
        return max(int(text) - usage, 0)
    return None


def _limit() -> int | None:
    """``RAMAVT_MEMORY_GB``: a cap on the memory a plan may count on (a machine shared with other jobs)."""
    text = os.environ.get("RAMAVT_MEMORY_GB", "").strip()
    if not text:
        return None
    try:
        gib = float(text)
    except ValueError:
        raise MemoryPlanError(f"RAMAVT_MEMORY_GB must be a number of GiB, got {text!r}") from None
    if not gib > 0 or gib == float("inf"):
        raise MemoryPlanError(f"RAMAVT_MEMORY_GB must be a finite number of GiB > 0, got {text!r}")
    return int(gib * 2**30)


def available_bytes(device=None) -> int | None:
    """Bytes ``device`` (default: the first local one) can still allocate, or None when unknown. An accelerator
    reports its own limit (``device.memory_stats()``); a CPU device uses the host's RAM. ``RAMAVT_MEMORY_GB``
    caps either."""
    found, limit = _device_available(device or jax.local_devices()[0]), _limit()
    return found if limit is None else limit if found is None else min(found, limit)


def _device_available(device) -> int | None:
    if device.platform != "cpu":
        try:
            stats = device.memory_stats() or {}
        except Exception:  # noqa: BLE001 (not every backend implements memory_stats)
            stats = {}
        if "bytes_limit" in stats:
            return int(stats["bytes_limit"]) - int(stats.get("bytes_in_use", 0))
        return None
    host, group = _host_available(), _cgroup_available()
    return host if group is None else group if host is None else min(host, group)


def tree_bytes(tree) -> int:
    """Bytes of a pytree of arrays or ``jax.ShapeDtypeStruct`` (e.g. from ``jax.eval_shape``)."""
    return int(sum(int(x.size) * x.dtype.itemsize for x in jax.tree.leaves(tree)))


def human(n: float) -> str:
    """``n`` bytes as a short size: '812 MiB', '212.3 GiB'."""
    for unit, size in (("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= size:
            return f"{n / size:.1f} {unit}"
    return f"{int(n)} B"


def check_fits(need: int, what: str, advice: str, device=None) -> int | None:
    """Raise MemoryPlanError (one line: ``what`` needs ``need`` bytes, the device has so much; ``advice``) when
    ``need`` exceeds FRACTION of :func:`available_bytes`; returns the bytes available (None: unknown, not checked)."""
    device = device or jax.local_devices()[0]
    avail = available_bytes(device)
    if avail is not None and need > FRACTION * avail:
        where = "the host's RAM" if device.platform == "cpu" else f"{device.platform} device {device.id}"
        raise MemoryPlanError(f"{what} needs {human(need)}, but {where} has {human(avail)} available; {advice}")
    return avail
