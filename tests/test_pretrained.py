"""Pretrained agents: export from a run folder, load by name, the shipped agent's provenance and behaviour."""

import json
import shutil

import jax
import numpy as np
import pytest

from ramavt_jax import targets
from ramavt_jax.evaluation import pretrained, rollouts
from ramavt_jax.presets import preset
from ramavt_jax.training.driver import run


@pytest.fixture(scope="module")
def smoke_run(tmp_path_factory):
    """A `smoke` preset run folder; read, never written, by the tests of this module."""
    folder = tmp_path_factory.mktemp("pretrained") / "run"
    run(preset("smoke", eval_episodes=0), folder, progress=False)
    return folder


def test_export_then_load_gives_the_run_params(smoke_run, tmp_path):
    pretrained.export(smoke_run, "tiny", command="ramavt train --preset smoke", out_dir=tmp_path / "agents")
    folder = tmp_path / "agents" / "tiny"
    assert {p.name for p in folder.iterdir()} >= {"params.npz", "config.json"}
    original = pretrained.load_policy(smoke_run)
    agent = pretrained.load("tiny", agents_dir=tmp_path / "agents")
    for a, b in zip(jax.tree.leaves(original.params), jax.tree.leaves(agent.params)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert agent.info["command"] == "ramavt train --preset smoke" and agent.config == original.config


def test_an_ensemble_of_one_run_twice_acts_as_that_run(smoke_run, tmp_path):
    """Exported together, two run folders are one agent with their parameters stacked [2, ...] (here stored in
    float16); two copies of one run act as that run (the mean of equal Q values); runs of other configs, or a
    one-run ensemble, are refused."""
    agents = tmp_path / "agents"
    flags = dict(command="ramavt train --preset smoke", out_dir=agents, precision="float16")
    pretrained.export(smoke_run, "one16", **flags)
    pretrained.export([smoke_run, smoke_run], "two16", info={"members": 7}, **flags)  # notes cannot overwrite
    with np.load(agents / "two16" / "params.npz") as stored:
        assert {stored[k].dtype for k in stored.files} == {np.dtype(np.float16)}
    one, two = pretrained.load("one16", agents_dir=agents), pretrained.load("two16", agents_dir=agents)
    assert (one.members, two.members, two.info["members"], two.info["precision"]) == (0, 2, 2, "float16")
    for a, b in zip(jax.tree.leaves(one.params), jax.tree.leaves(two.params)):
        assert b.shape == (2, *a.shape) and a.dtype == b.dtype == np.float32
        np.testing.assert_array_equal(np.asarray(b), np.stack([np.asarray(a)] * 2))
    tracking_env = rollouts.env_lib.TrackingEnv(one.config.env)
    params = tracking_env.eval_params(max_steps=20)
    key = jax.random.PRNGKey(3)
    stats_one, _ = rollouts.run_episodes(tracking_env, one.policy, params, key, 2, 20)
    stats_two, _ = rollouts.run_episodes(tracking_env, two.policy, params, key, 2, 20)
    np.testing.assert_array_equal(np.asarray(stats_one.episode_return), np.asarray(stats_two.episode_return))
    other = tmp_path / "other"
    shutil.copytree(smoke_run, other)
    saved = json.loads((other / "config.json").read_text())
    saved["config"]["env_params"] = [["init_xy_std", 2.0]]
    (other / "config.json").write_text(json.dumps(saved))
    with pytest.raises(ValueError, match=r"other has another network, env, env settings or parameter set than"):
        pretrained.export([smoke_run, other], "mixed", **flags)
    with pytest.raises(ValueError, match=r"^an ensemble needs at least two run folders, got 1$"):
        pretrained.export([smoke_run], "alone", **flags)
    assert not (agents / "mixed").exists() and not (agents / "alone").exists()


def test_unknown_agent_is_a_one_line_error(tmp_path):
    with pytest.raises(pretrained.PretrainedError, match="no pretrained agent 'nope'"):
        pretrained.load("nope", agents_dir=tmp_path)


@pytest.mark.skipif(pretrained.DEFAULT_AGENT not in pretrained.available(), reason="no agent shipped")
def test_shipped_agent_was_trained_on_the_training_split_and_tracks_a_held_out_target():
    agent = pretrained.load()
    trained_on = set(agent.config.env.targets)
    assert trained_on <= set(targets.TRAIN_TARGETS) and not trained_on & set(targets.TEST_TARGETS)
    assert agent.info.get("command", "").startswith("ramavt train")
    tracking_env = rollouts.env_lib.TrackingEnv(
        agent.config.env.__class__(
            camera=agent.config.env.camera, obs_mode=agent.config.env.obs_mode, targets=("Capsule-v2",)
        )
    )
    params = tracking_env.eval_params(max_steps=200)
    stats, _ = rollouts.run_episodes(tracking_env, agent.policy, params, jax.random.PRNGKey(0), 4, 200)
    assert float(np.mean(stats.length)) >= 150, np.asarray(stats.length)
