"""Pretrained agents: export from a run folder, load by name, the shipped agent's provenance and behaviour."""

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
