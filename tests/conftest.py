"""Fixtures shared by several test modules."""

import pytest

from ramavt_jax import cli


@pytest.fixture(scope="package")
def every_chunk_run(tmp_path_factory):
    """A smoke run trained by `ramavt train` with a checkpoint (parameters only) after every one of its 4 chunks;
    read, never written, by the tests that use it."""
    out = tmp_path_factory.mktemp("every_chunk") / "smoke"
    cli.main(["train", "--preset", "smoke", "--no-progress", "--out", str(out), "--run.eval-episodes", "0",
              "--run.checkpoint-every-chunks", "1", "--run.keep-checkpoints", "100", "--run.no-checkpoint-replay"])
    return out


@pytest.fixture(scope="package")
def averaged_run(tmp_path_factory):
    """A smoke run like ``every_chunk_run`` that keeps the policy's tail average over chunks 3-4 and acts with it
    (``--run.policy-average-from 2 --run.policy-params averaged``); read, never written."""
    out = tmp_path_factory.mktemp("averaged") / "smoke"
    cli.main(["train", "--preset", "smoke", "--no-progress", "--out", str(out), "--run.eval-episodes", "0",
              "--run.checkpoint-every-chunks", "1", "--run.keep-checkpoints", "100", "--run.no-checkpoint-replay",
              "--run.policy-average-from", "2", "--run.policy-params", "averaged"])
    return out
