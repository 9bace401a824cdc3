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


def test_export_then_load_gives_the_run_params(tmp_path):
    run(preset("smoke", eval_episodes=0), tmp_path / "run", progress=False)
    pretrained.export(tmp_path / "run", "tiny", command="ramavt train --preset smoke", out_dir=tmp_path / "agents")
    folder = tmp_path / "agents" / "tiny"
    assert {p.name for p in folder.iterdir()} >= {"params.npz", "config.json"}
    original = pretrained.load_policy(tmp_path / "run")
    agent = pretrained.load("tiny", agents_dir=tmp_path / "agents")
    for a, b in zip(jax.tree.leaves(original.params), jax.tree.leaves(agent.params)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert agent.info["command"] == "ramavt train --preset smoke" and agent.config == original.config
    _an_ensemble_of_one_run_twice_acts_as_that_run(tmp_path / "run", tmp_path / "agents")


def _an_ensemble_of_one_run_twice_acts_as_that_run(run_dir, agents_dir):
    """Exported together, two run folders are one agent with their parameters stacked [2, ...] (here in float16);
    two copies of one run act as that run (the mean of equal Q values); runs of other configs are refused."""
    flags = dict(command="ramavt train --preset smoke", out_dir=agents_dir, precision="float16")
    pretrained.export(run_dir, "one16", **flags)
    pretrained.export([run_dir, run_dir], "two16", **flags)
    one, two = pretrained.load("one16", agents_dir=agents_dir), pretrained.load("two16", agents_dir=agents_dir)
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
    other = run_dir.parent / "other"
    shutil.copytree(run_dir, other)
    saved = json.loads((other / "config.json").read_text())
    saved["config"]["env_params"] = [["init_xy_std", 2.0]]
    (other / "config.json").write_text(json.dumps(saved))
    with pytest.raises(ValueError, match=r"other has another network, env, env settings or parameter set than"):
        pretrained.export([run_dir, other], "mixed", **flags)
    assert not (agents_dir / "mixed").exists()


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
