"""The `ramavt` script's entry point: starts the process with huge-page malloc, then runs the command line.

XLA on CPU allocates fresh temporaries on every call, and first touches of fresh pages are slow on VMs. glibc (2.35
and later) can back malloc's arenas with transparent huge pages, but reads that setting (``GLIBC_TUNABLES``) only
when a process starts. So the script re-executes itself once with ``glibc.malloc.hugetlb=1`` added, before anything
heavy is imported: alone, the quick preset's learner update ran 13-19 % faster that way on our idle 2-core VM
(benchmarks/RESULTS.md); a whole quick run was not measurably faster than an earlier one without it. The arithmetic
is unchanged. ``RAMAVT_HUGEPAGES=0`` turns this off; a tunable already set is left as it is.
"""

from __future__ import annotations

import os
import sys

TUNABLE = "glibc.malloc.hugetlb=1"


def huge_page_environment(environ: dict[str, str], platform: str = sys.platform) -> dict[str, str] | None:
    """The environment to re-execute with, or None when the process should run as it is (not Linux, opted out,
    or a hugetlb tunable already set, e.g. by the re-executed process itself)."""
    tunables = environ.get("GLIBC_TUNABLES", "")
    if not platform.startswith("linux") or environ.get("RAMAVT_HUGEPAGES", "1") == "0" or "hugetlb" in tunables:
        return None
    return {**environ, "GLIBC_TUNABLES": ":".join(t for t in (tunables, TUNABLE) if t)}


def console() -> None:
    """The `ramavt` script."""
    env = huge_page_environment(dict(os.environ))
    if env is not None:
        try:
            os.execve(sys.executable, [sys.executable, *sys.argv], env)
        except OSError:
            pass  # cannot re-execute (an unusual launcher): run without huge pages
    from ramavt_jax.cli import main

    main()
