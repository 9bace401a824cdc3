"""Evaluation: summary statistics against hand computations, the early-exit episode runner, `ramavt eval` output
files for baselines, custom MJCF targets and trained runs, and clear errors."""

import json
import os
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ramavt_jax import baselines, render
from ramavt_jax import env as env_lib
from ramavt_jax.cli import evaluate as cli_eval
from ramavt_jax.evaluation import episode_program, pretrained, report, rollouts, runs
from ramavt_jax.evaluation import tables as tables_lib
from ramavt_jax.greedy import BLIND_SEARCHES

TINY = dict(resolution=16, speed_steps=5, seed=0)

PROBE_XML = """<mujoco model="probe"><worldbody>
  <body name="probe">
    <geom type="box" size="0.6 0.5 0.4" density="250" rgba="0.8 0.6 0.2 1"/>
    <geom type="sphere" size="0.3" pos="0 0 0.6" density="400"/>
  </body>
</worldbody></mujoco>"""


def _stats(length, ret, term, trunc=None, target=None):
    n = len(length)
    return episode_program.EpisodeStats(
        length=jnp.array(length, jnp.int32),
        episode_return=jnp.array(ret, jnp.float32),
        terminated=jnp.array(term, bool),
        target_index=jnp.array(target or [0] * n, jnp.int32),
        truncated=None if trunc is None else jnp.array(trunc, bool),
    )


def test_summary_matches_hand_computation():
    s = rollouts.summarise(
        _stats(
            [10, 1000, 500, 21], [-50.0, 300.0, 20.5, -80.0], [True, False, False, True], [False, True, False, False]
        )
    )
    assert s.episodes == 4
    assert s.length_mean == pytest.approx((10 + 1000 + 500 + 21) / 4)
    assert (s.length_min, s.length_max) == (10, 1000)
    assert s.return_mean == pytest.approx((-50 + 300 + 20.5 - 80) / 4)
    assert (s.return_min, s.return_max) == (pytest.approx(-80.0), pytest.approx(300.0))
    assert s.length_std == pytest.approx(np.std([10, 1000, 500, 21], ddof=1))  # sample, not population
    assert s.return_ci_low < s.return_mean < s.return_ci_high and np.isnan(s.error_mean)  # no tracking sums given
    # lost = ended by termination; truncated = reached max_steps; the 500-step one (run cut short) is neither
    assert s.lost_fraction == pytest.approx(0.5)
    assert s.truncated_fraction == pytest.approx(0.25)
    # without truncation flags every episode not lost counts as truncated (the old EpisodeStats)
    old = rollouts.summarise(_stats([5, 1000], [1.0, 2.0], [True, False]))
    assert (old.lost_fraction, old.truncated_fraction) == (0.5, 0.5)
    both = rollouts.concat_stats(
        [_stats([5], [1.0], [True], [False]), _stats([7, 9], [2.0, 3.0], [False, False], [True, False])]
    )
    np.testing.assert_array_equal(both.length, [5, 7, 9])
    np.testing.assert_array_equal(both.truncated, [False, True, False])
    assert rollouts.summarise(both).length_mean == pytest.approx(7.0)


@pytest.mark.slow
def test_episode_starts_are_the_states_run_episodes_starts_from():
    """Two targets drawn at random per episode: the starts' target draws are the episodes', and the recorded first
    step is one step on from them (the target moves < 0.1 m in a step; the starts lie metres apart)."""
    config = env_lib.EnvConfig(camera=render.CameraConfig(resolution=16), targets=("Satellite-v2", "Rocket-v1"))
    tracking_env = env_lib.TrackingEnv(config)
    params, key = tracking_env.eval_params(max_steps=2), jax.random.PRNGKey(7)
    starts = rollouts.episode_starts(tracking_env, params, key, 12)
    stats, rec = rollouts.run_episodes(tracking_env, baselines.random_policy(), params, key, 12, record=True)
    np.testing.assert_array_equal(np.asarray(starts.target_index), np.asarray(stats.target_index))
    assert 0 < int(np.asarray(starts.target_index).sum()) < 12
    moved = np.linalg.norm(np.asarray(rec.target_pos)[0] - np.asarray(starts.target_pos), axis=-1)
    assert moved.max() < 0.1 < np.linalg.norm(np.diff(np.asarray(starts.target_pos), axis=0), axis=-1).min()


def test_a_run_trained_on_wider_starts_is_evaluated_on_the_benchmarks_starts():
    trained = {"init_xy_std": 2.0, "init_z_min": 1.0, "init_z_max": 20.0, "target_spin_std": 0.2}
    assert rollouts.run_env_overrides(trained) == {"target_spin_std": 0.2}


@pytest.mark.slow
def test_early_exit_runner_matches_recorded_scan():
    config = env_lib.EnvConfig(camera=render.CameraConfig(resolution=16), targets=("Satellite-v2",))
    tracking_env = env_lib.TrackingEnv(config)
    params = tracking_env.eval_params(max_steps=60, lost_patience=3)
    pol = baselines.random_policy()
    key = jax.random.PRNGKey(3)
    fast, _ = rollouts.run_episodes(tracking_env, pol, params, key, 6)
    full, rec = rollouts.run_episodes(tracking_env, pol, params, key, 6, record=True)
    for a, b in zip(jax.tree.leaves(fast), jax.tree.leaves(full)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(rec.alive).sum(0), np.asarray(fast.length))
    np.testing.assert_allclose(
        (np.asarray(rec.reward) * np.asarray(rec.alive)).sum(0), fast.episode_return, rtol=1e-5, atol=1e-4
    )
    assert bool(jnp.all(fast.terminated ^ fast.truncated))  # every episode ended exactly one way
    # the tracking sums against the recorded positions (a catalogue target: stand-off scale 1, so metres)
    alive = np.asarray(rec.alive)
    distance = np.linalg.norm(np.asarray(rec.rel_pos) - np.asarray(params.desired_pos), axis=-1)
    np.testing.assert_allclose(fast.tracking.error, (distance * alive).sum(0), rtol=1e-4)
    np.testing.assert_array_equal(fast.tracking.within_half, ((distance <= 0.5) & alive).sum(0))
    np.testing.assert_array_equal(fast.tracking.within_quarter, ((distance <= 0.25) & alive).sum(0))
    s = rollouts.summarise(fast)
    assert s.error_mean == pytest.approx(np.mean((distance * alive).sum(0) / alive.sum(0)), rel=1e-4)
    assert s.error_ci_low <= s.error_mean <= s.error_ci_high


@pytest.mark.slow
def test_a_settings_episodes_do_not_depend_on_the_other_settings_requested():
    """The 'none' setting's episodes (hence every summary number) are the same evaluated alone (Table I) and among
    the five perturbation settings (Tables I + II). The depth tracker reads its images, so a frame history that
    changed with the request would show too. Both calls build equal envs, so the rollout compiles once."""
    camera = render.CameraConfig(resolution=8)
    entry = tables_lib.Entry("depth", "baseline", baselines.make_policy("depth", camera), env_lib.EnvConfig(camera))
    run = lambda tables, targets, only=(): tables_lib.run_suite(
        [entry], targets, 2, 15, seed=0, tables=tables, speed_steps=0, log=lambda _: None, only_settings=only
    )["rows"][0]["settings"]
    alone = run((1,), ("Satellite-v2", "Asteroid-v4"))
    together = run((1, 2), ("Satellite-v2", "Asteroid-v4"))
    picked = run((1, 2), ("Satellite-v2", "Asteroid-v4"), only=("all",))  # `ramavt eval --tables 1 2 --settings all`
    assert set(together) == set(rollouts.PERTURBATIONS) and set(picked) == {"none", "all"}
    assert alone["none"]["overall"] == together["none"]["overall"] == picked["none"]["overall"]
    assert alone["none"]["per_target"] == together["none"]["per_target"]
    assert picked["all"]["per_target"] == together["all"]["per_target"]
    # and the settings do differ from each other (the check above is not vacuous)
    assert together["all"]["overall"]["return_mean"] != together["none"]["overall"]["return_mean"]


def test_settings_for_picks_table2_settings_and_keeps_the_clean_one():
    assert tables_lib.settings_for((1,)) == ["none"]
    assert tables_lib.settings_for((1, 2)) == list(rollouts.PERTURBATIONS)
    assert set(tables_lib.settings_for((1, 2), ("all",))) == {"none", "all"}
    for tables, only in (((1,), ("all",)), ((1, 2), ("blurr",))):
        with pytest.raises(ValueError, match="with Table II"):
            tables_lib.settings_for(tables, only)


def test_perturbation_settings():
    assert rollouts.perturbation_overrides("none") == {}
    assert rollouts.perturbation_overrides("all") == {"actuator_noise": 0.3, "delay_max": 0.5, "blur_frames": 3}
    assert rollouts.perturbation_overrides("time_delay", {"delay_max": 0.2}) == {"delay_max": 0.2}
    with pytest.raises(ValueError, match="unknown perturbation"):
        rollouts.perturbation_overrides("wind")


def test_target_specs_and_unknown_target(tmp_path):
    from ramavt_jax import targets

    assert rollouts.resolve_targets("test") == targets.TEST_TARGETS
    assert rollouts.resolve_targets("Satellite-v1, Satellite-v1,Rocket-v0") == ("Satellite-v1", "Rocket-v0")
    path = tmp_path / "probe.xml"
    path.write_text(PROBE_XML)
    assert rollouts.resolve_targets(f"Capsule-v2,{path}") == ("Capsule-v2", str(path))
    with pytest.raises(ValueError, match="unknown target 'Sputnik-v9': not in the catalogue .*splits train, val, test"):
        rollouts.resolve_targets("Satellite-v2,Sputnik-v9")
    with pytest.raises(ValueError, match="Did you mean Satellite-v1"):
        rollouts.resolve_targets("Satelite-v1")
    with pytest.raises(ValueError, match="is a folder"):
        rollouts.resolve_targets(str(tmp_path))
    with pytest.raises(ValueError, match="target file nope.xml does not exist"):
        cli_eval.eval_cmd(policy="random", baselines=False, targets="nope.xml", out=tmp_path / "e")
    with pytest.raises(ValueError, match="needs at least one --run"):
        cli_eval.eval_cmd(policy="checkpoint", baselines=False, out=tmp_path / "e")


def test_eval_random_writes_tables(tmp_path):
    out = tmp_path / "eval"
    result = cli_eval.eval_cmd(
        policy="random",
        baselines=False,
        targets="Satellite-v2,Asteroid-v4",
        episodes=3,
        max_steps=15,
        tables=(1,),
        out=out,
        **TINY,
    )
    md, js = (out / "tables.md").read_text(), json.loads((out / "results.json").read_text())
    assert "## Table I" in md and "## Table II" not in md and "| random |" in md
    assert js["settings"]["episodes_per_target"] == 3 and js["settings"]["seed"] == 0
    assert js["settings"]["targets"] == ["Satellite-v2", "Asteroid-v4"]
    (row,) = js["rows"]
    overall = row["settings"]["none"]["overall"]
    assert overall["episodes"] == 6 and overall["length_max"] <= 15
    per = row["settings"]["none"]["per_target"]
    assert overall["length_mean"] == pytest.approx(
        (per["Satellite-v2"]["length_mean"] + per["Asteroid-v4"]["length_mean"]) / 2
    )
    assert row["speed_hz"] > 0
    assert result["rows"][0]["name"] == "random"


@pytest.mark.slow
def test_eval_mpc_perturbations_custom_target_and_figures(tmp_path):
    path = tmp_path / "probe.xml"
    path.write_text(PROBE_XML)
    out = tmp_path / "eval"
    cli_eval.eval_cmd(
        policy="mpc",
        baselines=False,
        targets=f"Satellite-v2,{path}",
        episodes=2,
        max_steps=12,
        tables=(1, 2),
        out=out,
        figures=True,
        resolution=16,
        speed_steps=0,
    )
    js = json.loads((out / "results.json").read_text())
    (row,) = js["rows"]
    assert set(row["settings"]) == set(rollouts.PERTURBATIONS)
    assert set(row["settings"]["none"]["per_target"]) == {"Satellite-v2", str(path)}
    # the ceiling never loses a target within 12 steps; a fraction of a non-positive ceiling (12 steps of approach
    # cost more than they earn) is left out rather than read backwards
    overall = row["settings"]["none"]["overall"]
    assert overall["length_min"] == 12
    assert overall["ceiling_fraction"] == (pytest.approx(1.0) if overall["return_mean"] > 0 else None)
    assert 0.0 <= overall["within_quarter_fraction"] <= overall["within_half_fraction"] <= 1.0
    assert overall["error_mean"] > 0 and row["info"] == {"variant": "mpc", "horizon": baselines.MPC_HORIZON}
    assert overall["return_ci_low"] <= overall["return_mean"] <= overall["return_ci_high"]
    md = (out / "tables.md").read_text()
    assert "## Table II" in md and md.count("| mpc ceiling (true state) |") >= 6
    assert "| error (m) | <= 0.25 m % | <= 0.5 m % | lost % | of ceiling % |" in md
    assert js["figures"]
    for p in js["figures"].values():
        assert os.path.getsize(p) > 0
    assert any(p.endswith("_frames.png") for p in js["figures"].values())


def _fake_run(run_dir, seed=0):
    """A run folder in driver.run's layout (config.json, checkpoints/<step>, metrics.jsonl) without training:
    the initial RunnerState with perturbed params, saved by the trainer's CheckpointStore. Seconds, not minutes."""
    from ramavt_jax import presets, train
    from ramavt_jax.network import init_params
    from ramavt_jax.training.checkpoint import CheckpointStore

    cfg = presets.preset("smoke", eval_episodes=0)
    # the RunnerState's structure without compiling the trainer: zeros everywhere but the network parameters
    abstract = jax.eval_shape(train.Trainer(cfg).init, jax.ShapeDtypeStruct((2,), jnp.uint32))
    state = jax.tree.map(lambda x: np.zeros(x.shape, x.dtype), abstract)
    params = init_params(cfg.network, jax.random.PRNGKey(seed), cfg.env.obs_shape)["params"]
    # the target net's params differ from the online ones, so a test sees which set was read
    target = init_params(cfg.network, jax.random.PRNGKey(seed + 100), cfg.env.obs_shape)["params"]
    state = state.replace(learner=state.learner.replace(params=params, target_params=target), chunk=np.int32(3))
    run_dir.mkdir(parents=True)
    (run_dir / "config.json").write_text(json.dumps({"seed": seed, "config": cfg.to_dict()}, default=str))
    meta = {"config": cfg.to_dict(), "seed": seed, "chunk": 3, "env_steps": 960, "updates": 5}
    store = CheckpointStore(run_dir / "checkpoints")
    store.save(3, state, json.loads(json.dumps(meta, default=str)))
    store.close()
    lines = [
        json.dumps(
            {
                "chunk": c,
                "env_steps": 320 * c,
                "episode_length": 10.0 * c,
                "episode_return": -c,
                "loss": 1.0 / c,
                "q_mean": 0.1 * c,
            }
        )
        for c in (1, 2, 3)
    ]
    (run_dir / "metrics.jsonl").write_text("\n".join(lines) + "\n")
    return run_dir, params


def test_eval_checkpoint_run(tmp_path):
    run_dir, params = _fake_run(tmp_path / "runs" / "smoke_s0")
    loaded = runs.load_policy(run_dir)
    for a, b in zip(jax.tree.leaves(loaded.params), jax.tree.leaves(params)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert loaded.step == 3 and loaded.config.network.variant == "origin" and loaded.meta["env_steps"] == 960
    out = tmp_path / "eval"
    cli_eval.eval_cmd(
        policy="checkpoint",
        run=(run_dir,),
        baselines=False,
        targets="Satellite-v2",
        episodes=1,
        max_steps=8,
        tables=(1, 3),
        out=out,
        speed_steps=0,
        blind_search="retreat",
    )
    js = json.loads((out / "results.json").read_text())
    assert js["rows"][0]["info"]["variant"] == "origin" and js["rows"][0]["speed_hz"] is None
    assert js["rows"][0]["info"]["blind_search"] == "retreat"
    md = (out / "tables.md").read_text()
    assert "## Table III" in md and "| smoke_s0 | origin |" in md
    assert "run `" in md and "checkpoint step 3" in md and "online params" in md


@pytest.mark.slow
def test_an_ensemble_row_flies_the_runs_together_and_of_one_run_twice_equals_it(tmp_path):
    """--ensemble adds one row; two copies of one run fly as that run does (the mean of equal Q values), while
    one --run folder alone is a one-line usage error."""
    first, _ = _fake_run(tmp_path / "runs" / "a" / "seed_0")
    copy, _ = _fake_run(tmp_path / "runs" / "b" / "seed_0")
    out = tmp_path / "eval"
    cli_eval.eval_cmd(
        policy="checkpoint",
        run=(first, copy),
        ensemble=True,
        baselines=False,
        targets="Satellite-v2",
        episodes=2,
        max_steps=30,
        tables=(1,),
        out=out,
        speed_steps=0,
    )
    rows = json.loads((out / "results.json").read_text())["rows"]
    assert [r["name"] for r in rows] == ["a/seed_0", "b/seed_0", "ensemble of 2: a, b"]
    single, together = rows[0]["settings"]["none"]["overall"], rows[2]["settings"]["none"]["overall"]
    assert together == pytest.approx(single) and together["length_mean"] > 1
    assert "flying together, greedy on their mean output" in (out / "tables.md").read_text()
    with pytest.raises(cli_eval.UsageError, match=r"^--ensemble needs at least two --run folders, got 1$"):
        cli_eval.eval_cmd(policy="checkpoint", run=(first,), ensemble=True, out=tmp_path / "eval1")
    saved = json.loads((copy / "config.json").read_text())
    saved["config"]["env_params"] = [["init_xy_std", 2.0]]
    (copy / "config.json").write_text(json.dumps(saved))
    with pytest.raises(cli_eval.UsageError, match=r"^--ensemble: .*b/seed_0 has another network, env, env settings"):
        cli_eval.eval_cmd(policy="checkpoint", run=(first, copy), ensemble=True, out=tmp_path / "eval2")


def test_load_policy_reads_the_parameter_set_the_config_or_the_caller_names(tmp_path):
    run_dir, online = _fake_run(tmp_path / "run")
    target = runs.load_policy(run_dir, policy_params="target")
    assert target.config.run.policy_params == "target"  # the returned config records the set that was read
    assert any(
        not np.array_equal(np.asarray(a), np.asarray(b))
        for a, b in zip(jax.tree.leaves(target.params), jax.tree.leaves(online))
    )
    # a run whose config says 'target' gets the same set by default
    saved = json.loads((run_dir / "config.json").read_text())
    saved["config"]["run"]["policy_params"] = "target"
    (run_dir / "config.json").write_text(json.dumps(saved))
    default = runs.load_policy(run_dir)
    for a, b in zip(jax.tree.leaves(default.params), jax.tree.leaves(target.params)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert runs.load_policy(run_dir, policy_params="online").config.run.policy_params == "online"


@pytest.mark.slow
def test_load_policy_of_a_real_training_run(tmp_path):
    from ramavt_jax import presets
    from ramavt_jax.experiment import train_and_evaluate

    cfg = presets.preset("smoke", eval_episodes=0)
    summary = train_and_evaluate(cfg, tmp_path / "smoke_s0", seed=0, progress=False)
    loaded = runs.load_policy(tmp_path / "smoke_s0")
    for a, b in zip(jax.tree.leaves(loaded.params), jax.tree.leaves(summary.state.learner.params)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert loaded.step == summary["chunks_done"]
    out = tmp_path / "eval"
    cli_eval.eval_cmd(
        policy="checkpoint",
        run=(tmp_path / "smoke_s0",),
        baselines=False,
        targets="Satellite-v2",
        episodes=1,
        max_steps=8,
        tables=(1, 3),
        out=out,
        figures=True,
        speed_steps=0,
    )
    figures = json.loads((out / "results.json").read_text())["figures"]
    assert any(k.endswith("attention") for k in figures) and "training_curves" in figures
    for p in figures.values():
        assert os.path.getsize(p) > 0


def test_missing_run_is_a_clear_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="config.json"):
        runs.load_policy(tmp_path / "no_run")


def test_markdown_handles_skipped_tables():
    result = {
        "settings": {
            "seed": 1,
            "episodes_per_target": 1,
            "targets": ["X"],
            "max_steps": 5,
            "perturbation_values": rollouts.PERTURBATION_VALUES,
            "speed_steps": 0,
            "tables": [1],
        },
        "machine": tables_lib.machine_info(),
        "rows": [],
        "wall_s": 1.0,
    }
    md = report.to_markdown(result)
    assert "Table I" in md and "959.1" in md  # the paper's numbers are always shown for comparison


def test_the_shipped_agents_row_names_how_it_was_trained():
    """The shipped agent is described by its own record (command, seed, parameter set), not as a run folder."""
    from ramavt_jax.cli import evaluate as cli_eval

    entry = cli_eval._pretrained_entry(pretrained.DEFAULT_AGENT)
    row = {
        "name": entry.name,
        "kind": entry.kind,
        "info": entry.info,
        "resolution": 32,
        "obs_mode": "depth",
        "settings": {},
    }
    result = {
        "settings": {
            "seed": 1,
            "episodes_per_target": 1,
            "targets": ["X"],
            "max_steps": 5,
            "perturbation_values": rollouts.PERTURBATION_VALUES,
            "speed_steps": 0,
            "tables": [],
        },
        "machine": tables_lib.machine_info(),
        "rows": [row],
        "wall_s": 1.0,
    }
    line = next(x for x in report.to_markdown(result).splitlines() if x.startswith(f"- {entry.name}"))
    agent = pretrained.load()
    assert "None" not in line and f"`{agent.info['command']}`" in line
    assert f"{agent.config.run.policy_params} params" in line


def test_the_shipped_agent_flies_the_blind_search_asked_for():
    """The shipped agent's row flies the blind search asked for: with 'retreat' it backs off while every frame is
    blank, then its own greedy action; the row records the search. (The search's mechanics against a policy that
    does not retreat by itself: test_train.py.)"""
    learned, retreat = (cli_eval._pretrained_entry(pretrained.DEFAULT_AGENT, search) for search in BLIND_SEARCHES)
    assert (learned.info["blind_search"], retreat.info["blind_search"]) == BLIND_SEARCHES
    shape = tuple(learned.env_config.obs_shape)
    frames = jnp.zeros((4, *shape)).at[2:].set(jax.random.uniform(jax.random.PRNGKey(3), (2, *shape)))
    flown = {}
    for entry in (learned, retreat):
        state, flown[entry.info["blind_search"]] = entry.policy.init(jax.random.PRNGKey(0)), []
        for t, frame in enumerate(frames):
            action, state = entry.policy.act(jax.random.PRNGKey(t), state, frame, None, None)
            flown[entry.info["blind_search"]].append(int(action))
    assert flown["retreat"][:2] == [env_lib.RETREAT] * 2
    # trained with the blind label 'retreat', the agent's own greedy action on blank frames is that search too
    assert flown["learned"][:2] == [env_lib.RETREAT] * 2


def test_eval_hands_the_blind_search_to_the_shipped_agent(tmp_path, monkeypatch):
    """`ramavt eval --policy pretrained --blind-search retreat` builds the shipped agent's row with that search."""
    asked = []

    class Built(Exception):
        pass

    def entry(name, search="learned"):
        asked.append((name, search))
        raise Built

    monkeypatch.setattr(cli_eval, "_pretrained_entry", entry)
    with pytest.raises(Built):
        cli_eval.eval_cmd(
            policy="pretrained",
            baselines=False,
            targets="Satellite-v2",
            episodes=1,
            max_steps=8,
            tables=(1,),
            out=tmp_path / "eval",
            speed_steps=0,
            blind_search="retreat",
        )
    assert asked == [(pretrained.DEFAULT_AGENT, "retreat")]


@pytest.mark.parametrize("name", ["quick", "paper", "smoke"])
def test_config_json_round_trips_to_the_same_train_config(name):
    from ramavt_jax.augment import AugmentConfig
    from ramavt_jax.presets import preset
    from ramavt_jax.train_config import TrainConfig

    cfg = preset(
        name,
        env_params=(("dist_weight", 0.5), ("lost_patience", 10)),
        augment=True,
        augment_config=AugmentConfig(crop=True, flip=False, rot90=False),
        state_dtype="bfloat16",
    )
    text = json.dumps({"seed": 0, "config": cfg.to_dict()}, default=str)
    loaded = TrainConfig.from_dict(json.loads(text)["config"])
    assert loaded == cfg and type(loaded.learner.augment_config) is AugmentConfig
    assert set(json.loads(text)["config"]) == {"env", "env_params", "network", "acting", "replay", "learner", "run"}


def test_the_shipped_config_jsons_load_as_the_presets_they_were_trained_with():
    """The shipped agent's config.json reads back into the config it was trained with: the general preset at 1.5x
    its env steps, the policy averaged over the last 12 chunks (without its end-of-training evaluation); it is an
    ensemble of that command's five seeds."""
    from ramavt_jax.presets import preset
    from ramavt_jax.train_config import TrainConfig

    record = json.loads((Path(pretrained.AGENTS_DIR) / pretrained.DEFAULT_AGENT / "config.json").read_text())
    trained_with = preset("general", total_env_steps=2_304_000, policy_average_from=60, eval_episodes=0)
    assert TrainConfig.from_dict(record["config"]) == trained_with
    assert record["info"]["members"] == 5 and record["info"]["seeds"] == [0, 1, 2, 3, 4]


def test_seed_params_picks_one_seed_of_the_named_set():
    from types import SimpleNamespace

    from ramavt_jax.train_state import LearnerState
    from ramavt_jax.training import host_state

    w = np.arange(6.0).reshape(2, 3)  # [seeds, ...]
    learner = LearnerState(params={"w": w}, target_params={"w": -w}, opt_state=None, updates=0)
    state = SimpleNamespace(learner=learner)
    np.testing.assert_array_equal(host_state.seed_params(state, 1, 2, "target")["w"], -w[1])
    np.testing.assert_array_equal(host_state.seed_params(state, 1, 2)["w"], w[1])
    with pytest.raises(KeyError):
        learner.policy_params("ema")


def test_final_evaluation_draws_only_each_splits_targets_with_one_rollout_program_per_policy(monkeypatch):
    """Every split runs in one env with per-split target draws (traced), so the jitted rollout, cached on (env,
    policy, steps), compiles once per policy instead of once per policy and split. Each split's key comes from its
    name: validation and test episodes never share a key, and a split's key does not depend on the others."""
    from ramavt_jax import presets
    from ramavt_jax import targets as targets_lib
    from ramavt_jax.evaluation import final

    cfg = presets.preset("smoke", eval_episodes=12, eval_max_steps=2)
    calls = []

    def record(tracking_env, policy, params, key, num_episodes, num_steps):
        calls.append((tracking_env, policy, num_steps, np.asarray(params.target_probs), jax.random.key_data(key)))
        ret = {"greedy": 3.0, "mpc": 4.0}.get(policy.name, 0.0)
        return _stats([2] * num_episodes, [ret] * num_episodes, [False] * num_episodes), None

    monkeypatch.setattr(final.rollouts, "run_episodes", record)
    results = final.final_evaluation(cfg, {}, jax.random.PRNGKey(1), log=lambda _: None)
    assert len({(id(env), id(policy), steps) for env, policy, steps, _, _ in calls}) == 3  # greedy, random, mpc
    names = calls[0][0].config.targets
    splits = [cfg.env.targets] * 3 + [targets_lib.VAL_TARGETS] * 3 + [targets_lib.TEST_TARGETS] * 3
    for (_, _, _, probs, _), members in zip(calls, splits, strict=True):
        np.testing.assert_allclose(probs, [1 / len(members) if n in members else 0.0 for n in names], rtol=1e-6)
    assert {s: sorted(r) for s, r in results.items()} == {
        s: ["greedy", "mpc", "random"] for s in ("train", "val", "test")
    }
    for split, first in (("train", 0), ("val", 3), ("test", 6)):  # the ceiling flies the greedy policy's episodes
        np.testing.assert_array_equal(calls[first][4], calls[first + 2][4])
        assert results[split]["greedy"]["ceiling_fraction"] == pytest.approx(0.75)
    keys = [tuple(np.asarray(k).ravel()) for *_, k in calls]
    assert len({k for i, k in enumerate(keys) if i % 3 != 2}) == 6  # greedy and random: no two splits share a key
    root = jax.random.PRNGKey(1)
    assert keys[6] == tuple(
        np.asarray(jax.random.key_data(jax.random.fold_in(final.split_key(root, "test"), 0))).ravel()
    )
    assert final.split_key(root, "val").tolist() != final.split_key(root, "test").tolist()


def test_statistics_intervals_iqm_and_probability_of_improvement():
    from ramavt_jax.evaluation import statistics

    rng = np.random.default_rng(0)
    values = rng.normal(10.0, 2.0, size=400)
    low, high = statistics.bootstrap_ci(values)
    # the mean's 95 % interval is about +-1.96 sigma / sqrt(n) = +-0.196 around the sample mean
    assert low < values.mean() < high and 0.3 < high - low < 0.5
    # stratified by a label that explains most of the spread: a narrower interval than the pooled one
    strata = np.repeat([0, 1], 200)
    split = np.concatenate([rng.normal(0.0, 0.1, 200), rng.normal(10.0, 0.1, 200)])
    pooled, stratified = statistics.bootstrap_ci(split), statistics.bootstrap_ci(split, strata)
    assert stratified[1] - stratified[0] < 0.2 * (pooled[1] - pooled[0])
    assert np.isnan(statistics.bootstrap_ci([1.0])[0]) and np.isnan(statistics.sample_std([1.0]))
    scores = np.arange(12.0).reshape(4, 3)  # 4 seeds x 3 targets
    assert statistics.iqm(scores) == pytest.approx(np.mean(np.sort(scores.ravel())[3:9]))
    better = scores + 100.0
    assert statistics.probability_of_improvement(better, scores) == pytest.approx(1.0)
    assert statistics.probability_of_improvement(scores, better) == pytest.approx(0.0)
    cmp = statistics.compare_arms({"a": better, "b": scores})
    assert cmp["probability_of_improvement"] == {"a>b": pytest.approx(1.0), "b>a": pytest.approx(0.0)}
    assert cmp["iqm"]["a"]["ci_low"] <= cmp["iqm"]["a"]["iqm"] <= cmp["iqm"]["a"]["ci_high"]


def _suite_row(name, returns_per_target, kind="checkpoint", run_dir=None, variant="ramavt"):
    per_target = {
        t: {
            "return_mean": r,
            "length_mean": 1000.0,
            "error_mean": 0.5,
            "lost_fraction": 0.0,
            "within_half_fraction": 0.5,
        }
        for t, r in returns_per_target.items()
    }
    overall = {k: float(np.mean([o[k] for o in per_target.values()])) for k in next(iter(per_target.values()))}
    return {
        "name": name,
        "kind": kind,
        "info": {"run_dir": run_dir, "variant": variant},
        "settings": {"none": {"overall": overall, "per_target": per_target}},
    }


def test_seed_folders_of_a_sweep_are_one_arm_compared_with_every_other():
    from ramavt_jax.evaluation import seeds

    targets = ["A", "B"]
    rows = [
        _suite_row(f"sweep/seed_{k}", {"A": 100.0 + k, "B": 200.0 + k}, run_dir=f"runs/sweep/seed_{k}")
        for k in range(3)
    ]
    rows += [
        _suite_row("other/seed_0", {"A": 0.0, "B": 0.0}, run_dir="runs/other/seed_0"),
        _suite_row("solo", {"A": 50.0, "B": 50.0}, run_dir="runs/solo"),
        _suite_row("mpc ceiling", {"A": 400.0, "B": 400.0}, kind="baseline", variant="mpc"),
    ]
    result = {"settings": {"targets": targets}, "rows": rows}
    assert list(seeds.arms(result)) == ["sweep (seeds)", "other (seeds)", "solo", "mpc ceiling"]
    summary = seeds.summarise_arms(result)
    sweep = summary["arms"]["sweep (seeds)"]
    assert sweep["runs"] == 3 and sweep["return_mean"] == pytest.approx(151.0)
    assert sweep["return_ci_low"] <= 151.0 <= sweep["return_ci_high"]
    assert sweep["ceiling_fraction"] == pytest.approx(151.0 / 400.0)
    assert sweep["return_sample_std_over_runs"] == pytest.approx(1.0)
    assert summary["probability_of_improvement"]["sweep (seeds)>solo"] == pytest.approx(1.0)
    assert summary["probability_of_improvement"]["solo>sweep (seeds)"] == pytest.approx(0.0)
    md = seeds.arms_md(result)
    assert "| sweep (seeds) | 3 | 151.0 |" in md and "P(sweep (seeds) > solo) = 1.00" in md


def test_a_fraction_of_a_non_positive_ceiling_is_left_out():
    row = _suite_row("agent", {"A": 300.0, "B": 100.0})
    for ceiling, expected in ((400.0, 0.5), (-50.0, None), (0.0, None)):
        mpc = _suite_row("mpc ceiling", {"A": ceiling, "B": ceiling}, kind="baseline", variant="mpc")
        tables_lib.add_ceiling_fractions([mpc, row])
        got = row["settings"]["none"]["overall"]["ceiling_fraction"]
        assert got == (pytest.approx(expected) if expected is not None else None), (ceiling, got)
