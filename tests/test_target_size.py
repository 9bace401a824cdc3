"""Targets of any size: the stand-off rule (small targets held closer, large ones farther), size randomisation,
and that a small and a large user model both make a trackable, visible task."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ramavt_jax import baselines, env, render, targets
from ramavt_jax.evaluation import rollouts

RES = 32
STEPS = 150
NUM_ENVS = 32  # every vmapped reset: one compile


def _write(path, geoms: str) -> str:
    path.write_text(
        f'<mujoco model="{path.stem}"><option gravity="0 0 0"/><worldbody><body name="target">'
        f"<freejoint/>{geoms}</body></worldbody></mujoco>"
    )
    return str(path)


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    """A 0.3 m cubesat (a cube of side 0.346 m: bounding radius 0.3 m) and a 12 m satellite (bus and two wings)."""
    folder = tmp_path_factory.mktemp("sizes")
    cubesat = _write(folder / "cubesat.xml", '<geom type="box" size="0.1732 0.1732 0.1732" density="300"/>')
    big = _write(
        folder / "big_satellite.xml",
        '<geom type="box" size="3 3 4" density="50"/>'
        '<geom type="box" pos="0 7.26 0" size="1.5 4.5 0.03" density="100"/>'
        '<geom type="box" pos="0 -7.26 0" size="1.5 4.5 0.03" density="100"/>',
    )
    return cubesat, big


@pytest.fixture(scope="module")
def size_env(models):
    return env.TrackingEnv(env.EnvConfig(camera=render.CameraConfig(resolution=RES), targets=models))


@pytest.fixture(scope="module")
def vreset(size_env):
    return jax.jit(jax.vmap(size_env.reset, in_axes=(0, None)))


def _params(tracking_env, **overrides):
    """Default params with fields replaced by Python floats, checked: the leaves keep the default's types, so one
    compiled reset serves every variant."""
    return env.validate_params(tracking_env.default_params().replace(**overrides), tracking_env.config)


def _k(radius, params) -> float:
    model = targets.select(params.catalogue, 0).replace(bound_radius=jnp.float32(radius))
    return float(env.standoff_scale(model, params))


# ------------------------------------------------------------------------------------------------ the rule
def test_standoff_rule(size_env, models):
    p = size_env.default_params()
    assert _k(0.3, p) == pytest.approx(0.6)  # held at 3 m: looks like a 0.5 m target at 5 m
    assert _k(0.45, p) == pytest.approx(0.9)
    assert _k(0.15, p) == pytest.approx(0.3) and _k(0.05, p) == pytest.approx(0.3)  # the floor: never closer than 1.5 m
    for radius in (0.5, 0.56, 1.0, 2.4, 2.5):  # catalogue sizes: the nominal 5 m, exactly
        assert _k(radius, p) == 1.0
    assert _k(12.0, p) == pytest.approx(4.8)
    assert _k(0.3, size_env.default_params(standoff_min_scale=0.7)) == pytest.approx(0.7)
    assert _k(0.3, size_env.default_params(standoff_min_radius=0.6)) == pytest.approx(0.5)
    radii = size_env.default_params().catalogue.bound_radius
    np.testing.assert_allclose(radii, [0.3, 12.0], rtol=1e-3)


def test_bad_size_params_fail_in_one_line(size_env):
    bad = [
        (dict(standoff_min_radius=0.0), "standoff_min_radius"),
        (dict(standoff_min_scale=0.0), "standoff_min_scale"),
        (dict(standoff_min_scale=1.5), "standoff_min_scale"),
        (dict(size_scale_min=0.0), "size_scale_min"),
        (dict(size_scale_min=-1.0, size_scale_max=1.0), "size_scale_min"),
        (dict(size_scale_min=2.0, size_scale_max=1.0), "size_scale_max must be >= size_scale_min"),
    ]
    for overrides, match in bad:
        with pytest.raises(ValueError, match=match) as err:
            size_env.default_params(**overrides)
        assert "\n" not in str(err.value) and str(err.value).startswith("EnvParams.")


def _chaser_step(tracking_env, params, index: int) -> tuple[np.ndarray, float]:
    """Chaser velocity [3] (Hill frame, m/s) after one noise-free +x command from rest, and the episode's k."""
    params = tracking_env.pinned(params.replace(actuator_noise=0.0, delay_max=0.0), index)
    state = tracking_env.initial_state(jax.random.key(index), params)
    moved = tracking_env.transition(jax.random.key(7), state, jnp.int32(1), params)
    return np.asarray(moved.chaser_vel), float(state.scale)


@pytest.mark.slow
def test_command_speed_follows_the_stand_off_only_when_asked(size_env, models):
    """Power 0: one action gives the chaser `speed` m/s at every size. Power 1: k times that at a target held
    farther than nominal (k > 1), the same share of its stand-off per second; a small target (k < 1) and a catalogue
    target (k = 1) keep `speed` exactly under either power."""
    fixed, scaled = size_env.default_params(speed_standoff_power=0.0), size_env.default_params(speed_standoff_power=1.0)
    for index, k_expected, gain in ((0, 0.6, 1.0), (1, 4.8, 4.8)):
        step_fixed, k = _chaser_step(size_env, fixed, index)
        step_scaled, _ = _chaser_step(size_env, scaled, index)
        assert k == pytest.approx(k_expected, rel=1e-3)
        assert np.linalg.norm(step_fixed) == pytest.approx(float(fixed.speed), rel=1e-5)
        np.testing.assert_allclose(step_scaled, gain * step_fixed, rtol=1e-3)
    catalogue_env = env.TrackingEnv(env.EnvConfig(camera=render.CameraConfig(resolution=RES), targets=("Capsule-v1",)))
    step_0, _ = _chaser_step(catalogue_env, catalogue_env.default_params(speed_standoff_power=0.0), 0)
    step_1, _ = _chaser_step(catalogue_env, catalogue_env.default_params(speed_standoff_power=1.0), 0)
    np.testing.assert_array_equal(step_0, step_1)
    with pytest.raises(ValueError, match="EnvParams.speed_standoff_power must be in \\[0, 1\\]"):
        size_env.default_params(speed_standoff_power=2.0)


def test_small_standoff_power_gives_a_small_target_the_catalogue_dynamics_in_stand_off_units(size_env):
    """Power 1: the 0.3 m cubesat (k = 0.6) gets k times the command speed and k times the drift of power 0 (same
    key), the 12 m satellite (k = 4.8) and its drift are untouched."""
    plain, scaled = size_env.default_params(), size_env.default_params(small_standoff_power=1.0)
    for index, gain in ((0, 0.6), (1, 1.0)):
        step_plain, k = _chaser_step(size_env, plain, index)
        step_scaled, _ = _chaser_step(size_env, scaled, index)
        np.testing.assert_allclose(step_scaled, gain * step_plain, rtol=1e-3)
        drift = [
            size_env.initial_state(jax.random.key(5), size_env.pinned(p, index)).target_vel for p in (plain, scaled)
        ]
        np.testing.assert_allclose(np.asarray(drift[1]), gain * np.asarray(drift[0]), rtol=1e-3)
        assert np.linalg.norm(np.asarray(drift[0])) > 0.0
    with pytest.raises(ValueError, match="EnvParams.small_standoff_power must be in"):
        size_env.default_params(small_standoff_power=-0.5)


def test_speed_rule_is_an_evaluation_field():
    """A run trained with another speed rule is evaluated under the table's, like every other row."""
    assert rollouts.run_env_overrides({"speed_standoff_power": 1.0, "small_standoff_power": 1.0, "speed": 0.5}) == {
        "speed": 0.5
    }


# ------------------------------------------------------------------------------------------------ possible tasks
@pytest.mark.slow
def test_small_and_large_user_targets_are_tracked_by_the_ceiling(size_env):
    """From the env's own initial states, the mpc ceiling holds the 0.3 m cubesat (k = 0.6) and the 12 m satellite
    (k = 4.8) in view and within the lost distance, and brings each to the desired point (or, from far away, ever
    closer to it)."""
    policy = baselines.mpc_policy(size_env.config)
    params = size_env.eval_params(max_steps=STEPS)
    for index in (0, 1):
        k = float(env.standoff_scale(targets.select(params.catalogue, index), params))
        stats, rec = rollouts.run_episodes(
            size_env, policy, size_env.pinned(params, index), jax.random.key(index), 3, record=True
        )
        assert np.all(np.asarray(stats.length) == STEPS) and not np.any(np.asarray(stats.terminated))
        rel = np.asarray(rec.rel_pos)  # [T, N, 3]
        error = np.linalg.norm(rel - np.asarray(params.desired_pos) * k, axis=-1) / k  # stand-off units
        assert np.all(error < float(params.lost_distance))
        assert np.all(np.asarray(rec.in_view)[30:]), np.asarray(rec.in_view).all(axis=1)
        # near the desired point at the end, or (the 12 m satellite, which may start 58 m away, at 4.8 m/s or, with
        # speed_standoff_power 0, 1 m/s) coming closer all the time
        closing = np.all(np.diff(error[-100:], axis=0) < 0.0, axis=0)
        assert np.all((error[-1] < 0.5) | closing), (index, error[0], error[-1])


def _coverage(vreset, tracking_env, index, **overrides) -> tuple[float, float]:
    """Mean share of the target's pixels at the desired position over 32 attitudes, and the stand-off scale."""
    p = _params(tracking_env, init_xy_std=0.0, init_z_min=5.0, init_z_max=5.0001, **overrides)
    obs, state = vreset(jax.random.split(jax.random.key(0), NUM_ENVS), tracking_env.pinned(p, index))
    return float((np.asarray(obs) > 0).mean()), float(state.scale[0])


@pytest.mark.slow
def test_small_target_fills_more_of_the_view(size_env, vreset):
    """At the desired position a small target covers the pixels of a 0.5 m target at 5 m (a 0.3 m cube: about 15
    of 1024 at 32 x 32) where the old rule (k = 1 for every target up to 2.5 m) left it about 4; the 12 m satellite
    covers several per cent."""
    small, k_small = _coverage(vreset, size_env, 0)
    old_small, k_old = _coverage(vreset, size_env, 0, standoff_min_radius=1e-3)  # small branch off: k = 1
    big, k_big = _coverage(vreset, size_env, 1)
    assert k_small == pytest.approx(0.6, rel=1e-4) and k_old == 1.0 and k_big == pytest.approx(4.8, rel=1e-3)
    assert small >= 0.01, small
    assert old_small < 0.01 and small > 2.5 * old_small, (small, old_small)
    assert big >= 0.04, big


# ------------------------------------------------------------------------------------------------ randomisation
def test_size_randomisation(size_env, vreset):
    keys = jax.random.split(jax.random.key(1), NUM_ENVS)
    both = jnp.array([0.5, 0.5], jnp.float32)  # the default draw, typed as pinned() types it: no second compile
    default = size_env.default_params().replace(target_probs=both)
    obs_d, st_d = vreset(keys, default)
    ones = _params(size_env, size_scale_min=1.0, size_scale_max=1.0, target_probs=both)
    obs_1, st_1 = vreset(keys, ones)  # the default episodes, bit for bit
    for a, b in zip(jax.tree.leaves((obs_d, st_d)), jax.tree.leaves((obs_1, st_1))):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    own = jax.vmap(targets.select, in_axes=(None, 0))(default.catalogue, st_d.target_index)
    for a, b in zip(jax.tree.leaves(own), jax.tree.leaves(st_d.target)):  # geometry times exactly 1.0
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))

    p = _params(size_env, size_scale_min=0.5, size_scale_max=2.0, target_probs=both)
    obs_r, st_r = vreset(keys, p)
    base = np.asarray(default.catalogue.bound_radius)[np.asarray(st_r.target_index)]
    factor = np.asarray(st_r.target.bound_radius) / base
    assert np.all((factor >= 0.5 * (1 - 1e-5)) & (factor <= 2.0 * (1 + 1e-5))), factor
    assert factor.min() < 0.7 and factor.max() > 1.4 and np.mean(factor < 1.0) == pytest.approx(0.5, abs=0.2)
    np.testing.assert_allclose(
        np.asarray(st_r.target.geom_size)[:, 0, 0] / np.asarray(st_d.target.geom_size)[:, 0, 0], factor, rtol=1e-5
    )
    k = np.asarray(jax.vmap(env.standoff_scale, in_axes=(0, None))(st_r.target, p))
    np.testing.assert_array_equal(np.asarray(st_r.scale), k)
    radius = np.asarray(st_r.target.bound_radius)
    expected = np.where(radius < 0.5, np.maximum(0.3, radius / 0.5), np.maximum(1.0, 2.0 * radius / 5.0))
    np.testing.assert_allclose(k, expected, rtol=1e-5)
    assert np.any(k < 1.0) and np.any(k > 1.0)
    # the size draw leaves every other draw of the episode as it was
    for name in ("target_index", "target_vel", "target_quat", "target_omega"):
        np.testing.assert_array_equal(np.asarray(getattr(st_r, name)), np.asarray(getattr(st_d, name)))
    np.testing.assert_allclose(
        np.asarray(st_r.target_pos) / k[:, None],
        np.asarray(st_d.target_pos) / np.asarray(st_d.scale)[:, None],
        rtol=1e-5,
        atol=1e-6,
    )


def test_size_scale_prob_resizes_that_share_of_the_episodes(size_env, vreset):
    """With size_scale_prob 0.5 about half the episodes keep the model's own size exactly; the others draw the same
    factor as with prob 1 (one key per draw), and every other draw of the episode is unchanged."""
    keys = jax.random.split(jax.random.key(2), NUM_ENVS)
    both = jnp.array([0.5, 0.5], jnp.float32)
    always = _params(size_env, size_scale_min=0.5, size_scale_max=0.9, target_probs=both)
    half = _params(size_env, size_scale_min=0.5, size_scale_max=0.9, size_scale_prob=0.5, target_probs=both)
    (_, st_all), (_, st_half) = vreset(keys, always), vreset(keys, half)
    base = np.asarray(always.catalogue.bound_radius)[np.asarray(st_half.target_index)]
    kept = np.asarray(st_half.target.bound_radius) == base
    assert 0.2 < kept.mean() < 0.8, kept.mean()
    np.testing.assert_array_equal(
        np.asarray(st_half.target.bound_radius)[~kept], np.asarray(st_all.target.bound_radius)[~kept]
    )
    assert not np.any(np.asarray(st_all.target.bound_radius) == base)  # factors in [0.5, 0.9]: none kept
    np.testing.assert_array_equal(np.asarray(st_half.target_quat), np.asarray(st_all.target_quat))
    with pytest.raises(ValueError, match="EnvParams.size_scale_prob must be in \\[0, 1\\]"):
        size_env.default_params(size_scale_prob=1.5)


def test_size_randomisation_is_for_training_only():
    from ramavt_jax.presets import preset

    pairs = (("size_scale_max", 2.0), ("size_scale_min", 0.5), ("size_scale_prob", 0.5), ("target_spin_std", 0.2))
    cfg = preset("smoke", env_params=pairs)  # a training preset may set them (ramavt train --env-params ...)
    assert rollouts.run_env_overrides(cfg.env_params) == {"target_spin_std": 0.2}  # evaluation: the models' sizes


@pytest.mark.slow
def test_eval_records_the_stand_off_rules_it_flew(tmp_path):
    """`ramavt eval --speed-standoff-power 0 --small-standoff-power 1` flies those rules for every row and writes them
    beside the numbers (results.json and tables.md)."""
    import json

    from ramavt_jax import cli

    out = tmp_path / "eval"
    cli.main(
        [
            "eval",
            "--policy",
            "random",
            "--targets",
            "Satellite-v2@12m",
            "--episodes",
            "1",
            "--max-steps",
            "3",
            "--tables",
            "1",
            "--resolution",
            "8",
            "--speed-steps",
            "0",
            "--speed-standoff-power",
            "0",
            "--small-standoff-power",
            "1",
            "--out",
            str(out),
        ]
    )
    task = json.loads((out / "results.json").read_text())["settings"]["eval_params"]
    assert task["speed_standoff_power"] == 0.0 and task["small_standoff_power"] == 1.0
    assert task["size_scale_min"] == task["size_scale_max"] == 1.0 and task["dist_weight"] == 1.0
    assert "command speed x max(1, k) ** 0 x min(1, k) ** 1" in (out / "tables.md").read_text()
