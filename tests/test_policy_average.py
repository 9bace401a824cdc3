"""Tail averaging of the policy (RunConfig.policy_average_from): the averaged params are the uniform mean of the
target params at the ends of the chunks after S, the target params up to it, and change no training step; a run
extended on resume keeps the same mean; a run folder serves them as `policy_params='averaged'`, and a run without
them refuses that in one line."""

import jax
import numpy as np
import pytest

from ramavt_jax import cli, presets
from ramavt_jax.evaluation.runs import load_policy
from ramavt_jax.train import Trainer
from ramavt_jax.training import program

SMOKE = presets.preset("smoke")  # 4 chunks
AVERAGED = SMOKE.override(policy_average_from=2, policy_params="averaged")  # the mean of chunks 3 and 4


@pytest.fixture(scope="module")
def chunk_by_chunk():
    """(RunnerState after each of the 4 chunks, with averaging; the same without), one jitted chunk each."""
    runs = []
    for cfg in (AVERAGED, SMOKE):
        trainer = Trainer(cfg)
        step, state, states = jax.jit(trainer.chunk), trainer.init(jax.random.PRNGKey(3)), []
        for _ in range(cfg.num_chunks):
            state, _ = step(state)
            states.append(jax.device_get(state))
        runs.append(states)
    return runs


def _leaves(tree):
    return [np.asarray(x) for x in jax.tree.leaves(tree)]


@pytest.mark.slow
def test_averaged_params_are_the_mean_of_the_last_chunks_target_params(chunk_by_chunk):
    states, _ = chunk_by_chunk
    for s in states[:2]:  # before the window: the target params themselves
        for a, t in zip(_leaves(s.learner.averaged_params), _leaves(s.learner.target_params)):
            np.testing.assert_array_equal(a, t)
    last_two = [_leaves(s.learner.target_params) for s in states[2:]]
    assert any(not np.allclose(a, b) for a, b in zip(*last_two))  # the two chunks differ: a real mean
    for got, a, b in zip(_leaves(states[-1].learner.averaged_params), *last_two):
        np.testing.assert_allclose(got, (a + b) / 2, rtol=1e-6, atol=1e-7)


def test_averaging_changes_no_training_step(chunk_by_chunk):
    averaged, plain = chunk_by_chunk
    assert plain[-1].learner.averaged_params is None
    for a, b in zip(
        _leaves(averaged[-1].replace(learner=averaged[-1].learner.replace(averaged_params=None))), _leaves(plain[-1])
    ):
        np.testing.assert_array_equal(a, b)


def test_the_compiled_chunk_is_shared_across_run_lengths():
    """The average's window counts from the run's start and no schedule spans the run, so runs of any length share
    one compiled chunk."""
    longer = AVERAGED.override(total_env_steps=2 * AVERAGED.run.total_env_steps)
    assert program._cache_key(longer) == program._cache_key(AVERAGED)
    assert program._cache_key(AVERAGED) != program._cache_key(SMOKE)


@pytest.mark.slow
def test_an_extended_run_keeps_averaging_the_same_window(tmp_path):
    """Trained for 3 chunks, then resumed with a length of 5: the mean of chunks 3-5, as a 5-chunk run has."""
    from ramavt_jax.training import driver

    short = AVERAGED.override(total_env_steps=3 * AVERAGED.env_steps_per_chunk, eval_episodes=0)
    driver.run(short, tmp_path / "ext", progress=False)
    extended = driver.run(
        short.override(total_env_steps=5 * AVERAGED.env_steps_per_chunk), tmp_path / "ext", progress=False
    )
    whole = driver.run(
        short.override(total_env_steps=5 * AVERAGED.env_steps_per_chunk), tmp_path / "whole", progress=False
    )
    for a, b in zip(_leaves(extended.state.learner.averaged_params), _leaves(whole.state.learner.averaged_params)):
        np.testing.assert_array_equal(a, b)


@pytest.mark.slow
def test_a_run_folder_serves_its_averaged_params(averaged_run, every_chunk_run):
    run = load_policy(averaged_run, log=lambda *_: None)  # conftest.py: averaged over chunks 3-4
    assert run.config.run.policy_params == "averaged"
    target = load_policy(averaged_run, policy_params="target", log=lambda *_: None)
    assert any(not np.allclose(a, b) for a, b in zip(_leaves(run.params), _leaves(target.params)))
    with pytest.raises(
        ValueError,
        match="keeps no averaged params: .* needs a run trained with "
        r"--run.policy-average-from S \(or use the 'target' params\)$",
    ):
        load_policy(every_chunk_run, policy_params="averaged", log=lambda *_: None)  # conftest.py: trained without


@pytest.mark.parametrize("command", ["eval", "curve"])
def test_asking_a_run_without_an_average_for_it_is_one_line_before_any_compile(
    command, every_chunk_run, tmp_path, capsys
):
    args = {"eval": ["eval", "--policy", "checkpoint", "--no-baselines"], "curve": ["curve", "--no-baselines"]}[command]
    with pytest.raises(SystemExit) as e:
        cli.main([*args, "--run", str(every_chunk_run), "--policy-params", "averaged", "--out", str(tmp_path / "o")])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "keeps no averaged params" in err and "--run.policy-average-from S" in err
