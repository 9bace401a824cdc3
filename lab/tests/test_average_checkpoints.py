"""lab/average_checkpoints.py: the written run folder's policy is the mean of the chosen chunks' policy params,
`ramavt eval` reads it, and a missing chunk is refused."""

import jax
import numpy as np
import pytest

from lab import average_checkpoints  # noqa: E402
from ramavt_jax import cli
from ramavt_jax.evaluation.runs import load_policy


@pytest.fixture(scope="module")
def smoke_run(every_chunk_run):
    return every_chunk_run  # conftest.py


def test_average_is_the_mean_of_the_chunks_policy_params(smoke_run, tmp_path):
    out = tmp_path / "avg"
    average_checkpoints.main([str(smoke_run), "--chunks", "2", "4", "--out", str(out)])
    averaged = load_policy(out, log=lambda *_: None)
    assert averaged.step == 4 and averaged.config == load_policy(smoke_run, log=lambda *_: None).config
    chunks = [jax.tree.leaves(load_policy(smoke_run, step=s, log=lambda *_: None).params) for s in (2, 3, 4)]
    assert any(not np.allclose(a, b) for a, b in zip(chunks[0], chunks[2]))  # the chunks differ: a real mean
    for got, *per_chunk in zip(jax.tree.leaves(averaged.params), *chunks):
        np.testing.assert_allclose(got, np.mean(per_chunk, axis=0), rtol=1e-6, atol=1e-7)
    other = {"online": "target", "target": "online"}[averaged.config.run.policy_params]
    both = load_policy(out, policy_params=other, log=lambda *_: None)  # both sets are the mean
    for a, b in zip(jax.tree.leaves(both.params), jax.tree.leaves(averaged.params)):
        np.testing.assert_array_equal(a, b)


def test_missing_chunk_is_refused(smoke_run, tmp_path):
    with pytest.raises(SystemExit, match=r"no checkpoint of chunk\(s\) \[5, 6\]"):
        average_checkpoints.main([str(smoke_run), "--chunks", "3", "6", "--out", str(tmp_path / "x")])
    with pytest.raises(SystemExit, match="exists: name a new folder"):
        average_checkpoints.main([str(smoke_run), "--chunks", "2", "3", "--out", str(smoke_run)])
    assert (smoke_run / "config.json").is_file()  # the run is left as it was
    with pytest.raises(SystemExit, match="need 1 <= FIRST <= LAST"):
        average_checkpoints.main([str(smoke_run), "--chunks", "4", "2", "--out", str(tmp_path / "y")])


def test_a_run_that_checkpoints_its_replay_is_averaged_without_it(tmp_path):
    run = tmp_path / "with_replay"
    cli.main(
        [
            "train",
            "--preset",
            "smoke",
            "--no-progress",
            "--out",
            str(run),
            "--run.eval-episodes",
            "0",
            "--run.checkpoint-every-chunks",
            "1",
            "--run.keep-checkpoints",
            "100",
        ]
    )
    out = tmp_path / "avg"
    average_checkpoints.main([str(run), "--chunks", "3", "4", "--out", str(out)])
    averaged = load_policy(out, log=lambda *_: None)
    assert averaged.step == 4 and not averaged.config.run.checkpoint_replay
    chunks = [jax.tree.leaves(load_policy(run, step=s, log=lambda *_: None).params) for s in (3, 4)]
    for got, a, b in zip(jax.tree.leaves(averaged.params), *chunks):
        np.testing.assert_allclose(got, (a + b) / 2, rtol=1e-6, atol=1e-7)


def test_a_tail_averaged_run_is_averaged_over_its_target_params(averaged_run, tmp_path):
    """A run acting with its tail average (policy_params 'averaged') is averaged over what that average is made of,
    the target params; so the script's mean of chunks 3-4 is the run's own average from chunk 2 on (conftest.py)."""
    out = tmp_path / "avg"
    average_checkpoints.main([str(averaged_run), "--chunks", "3", "4", "--out", str(out)])
    script = load_policy(out, log=lambda *_: None)
    own = load_policy(averaged_run, log=lambda *_: None)
    assert own.config.run.policy_params == "averaged"
    for a, b in zip(jax.tree.leaves(script.params), jax.tree.leaves(own.params)):
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7)
