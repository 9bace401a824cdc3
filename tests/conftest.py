"""Fixtures shared by several test modules, and the suite's compile cache.

The suite compiles into a private, empty cache folder made for this run (shared by the xdist workers, removed at
the end), never into a user's ``~/.cache`` or a fixed temporary folder: every run pays what a fresh machine pays,
and its time is the time a newcomer sees. Tests are bound by compiling, not by running, so XLA's optimisations are
mostly turned off for them (``jax_disable_most_optimizations``: about 40 % less compile time for the env's step on
a 2-core CPU); the tests compare programs compiled the same way, and the benchmarks measure the optimised ones.
"""

import os
import shutil
import tempfile

import jax
import pytest

from ramavt_jax import cli


def pytest_configure(config):
    os.environ["JAX_DISABLE_MOST_OPTIMIZATIONS"] = "1"  # for the subprocesses tests start
    jax.config.update("jax_disable_most_optimizations", True)
    if not hasattr(config, "workerinput"):  # the controller (or a run without xdist): workers inherit its environment
        folder = tempfile.mkdtemp(prefix="ramavt_test_cache_")
        os.environ["RAMAVT_COMPILE_CACHE"] = folder
        config._ramavt_cache = folder
    jax.config.update("jax_compilation_cache_dir", os.environ["RAMAVT_COMPILE_CACHE"])
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


def pytest_unconfigure(config):
    folder = getattr(config, "_ramavt_cache", None)
    if folder:
        shutil.rmtree(folder, ignore_errors=True)


def _smoke_run_with_every_checkpoint(folder, *flags: str):
    """`ramavt train --preset smoke` into ``folder`` with a checkpoint (parameters only) after each of its 4 chunks."""
    out = folder / "smoke"
    base = ["train", "--preset", "smoke", "--no-progress", "--out", str(out), "--run.eval-episodes", "0"]
    keep = ["--run.checkpoint-every-chunks", "1", "--run.keep-checkpoints", "100", "--run.no-checkpoint-replay"]
    cli.main([*base, *keep, *flags])
    return out


@pytest.fixture(scope="package")
def every_chunk_run(tmp_path_factory):
    """A smoke run with a checkpoint after every chunk; read, never written, by the tests that use it."""
    return _smoke_run_with_every_checkpoint(tmp_path_factory.mktemp("every_chunk"))


@pytest.fixture(scope="package")
def averaged_run(tmp_path_factory):
    """A smoke run like ``every_chunk_run`` that keeps the policy's tail average over chunks 3-4 and acts with it
    (``--run.policy-average-from 2 --run.policy-params averaged``); read, never written."""
    flags = ("--run.policy-average-from", "2", "--run.policy-params", "averaged")
    return _smoke_run_with_every_checkpoint(tmp_path_factory.mktemp("averaged"), *flags)
