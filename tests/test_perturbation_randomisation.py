"""Perturbation randomisation (training): `EnvParams.perturb_prob` applies each configured Table II perturbation
(actuator noise, time delay, frame-averaging blur) in a share of the episodes, drawn per perturbation and episode
(`randomisation.perturbed`), and evaluation flies the Table II settings whatever a run was trained with."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ramavt_jax import env, randomisation, render
from ramavt_jax.evaluation import rollouts

RES = 16
TABLE2 = dict(actuator_noise=0.3, delay_max=0.5, blur_frames=3)


@pytest.fixture(scope="module")
def blur_env():
    return env.TrackingEnv(
        env.EnvConfig(camera=render.CameraConfig(resolution=RES), targets=("Satellite-v0",), frame_history=3)
    )


@pytest.fixture(scope="module")
def episode(blur_env):
    """A jitted function of (key, params): (obs [T, H, W, 1], sim_time [T], chaser_pos [T, 3], perturbed [T, 3])
    of one 6-step episode flying a fixed command."""

    def run(key, params):
        k_reset, k_steps = jax.random.split(key)
        obs, state = blur_env.reset(k_reset, params)

        def body(state, k):
            obs, state, *_ = blur_env.step_env(k, state, jnp.asarray(5), params)
            return state, (obs, state.sim_time, state.chaser_pos, state.perturbed)

        return jax.lax.scan(body, state, jax.random.split(k_steps, 6))[1]

    return jax.jit(run)


def _params(tracking_env, **overrides):
    return tracking_env.default_params(init_z_min=4.0, init_z_max=4.5, init_xy_std=0.2, **overrides)


def test_draws_are_independent_per_perturbation_at_the_asked_share(blur_env):
    params = _params(blur_env, perturb_prob=0.5)
    flags = jax.vmap(randomisation.perturbed, in_axes=(0, None))(jax.random.split(jax.random.key(0), 4000), params)
    flags = np.asarray(flags)
    assert set(np.unique(flags)) == {0.0, 1.0}
    np.testing.assert_allclose(flags.mean(0), 0.5, atol=0.03)  # 4000 draws: 3 sigma is 0.024
    assert abs(flags.all(1).mean() - 0.125) < 0.02  # all three in an eighth: independent, not one switch
    assert abs((~flags.any(1).astype(bool)).mean() - 0.125) < 0.02
    for share in (0.0, 1.0):
        at = jax.vmap(randomisation.perturbed, in_axes=(0, None))(
            jax.random.split(jax.random.key(1), 64), params.replace(perturb_prob=jnp.asarray(share))
        )
        np.testing.assert_array_equal(np.asarray(at), share)


@pytest.mark.slow
def test_share_zero_flies_the_unperturbed_episode_and_one_the_perturbed(blur_env, episode):
    key = jax.random.key(3)
    clean = episode(key, _params(blur_env))
    never = episode(key, _params(blur_env, perturb_prob=0.0, **TABLE2))
    always = episode(key, _params(blur_env, **TABLE2))  # the default share, 1: every episode, as before the field
    for a, b in zip(clean[:3], never[:3]):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    np.testing.assert_array_equal(np.asarray(never[3]), 0.0)
    np.testing.assert_array_equal(np.asarray(always[3]), 1.0)
    for a, b in zip(clean[:3], always[:3]):
        assert not np.allclose(np.asarray(a), np.asarray(b))


def test_each_flag_switches_only_its_perturbation(blur_env, episode):
    """Over episodes at share 0.5: the step lasts exactly dt where the delay is off (longer where on), the
    observation is the newest frame where blur is off, and the flags hold for the whole episode."""
    params = _params(blur_env, perturb_prob=0.5, **TABLE2)
    clean_params = _params(blur_env)
    seen = set()
    for key in jax.random.split(jax.random.key(5), 12):
        obs, sim_time, chaser_pos, flags = (np.asarray(x) for x in episode(key, params))
        clean_obs, clean_time, clean_pos, _ = (np.asarray(x) for x in episode(key, clean_params))
        assert (flags == flags[0]).all(), "the draws hold for the whole episode"
        noise, delay, blur = flags[0].astype(bool)
        seen.add((noise, delay, blur))
        steps = np.diff(np.concatenate([[0.0], sim_time]))
        if delay:
            assert (steps > 0.1 + 1e-6).any()
        else:
            np.testing.assert_allclose(steps, 0.1, atol=1e-6)
        if not delay and not blur:  # only the command noise may differ from the clean episode
            assert noise == (not np.allclose(chaser_pos, clean_pos))
        if not (noise or delay):
            np.testing.assert_array_equal(chaser_pos, clean_pos)
            np.testing.assert_array_equal(blur, not np.allclose(obs, clean_obs))
    assert len(seen) >= 4, f"12 episodes at share 0.5 drew only {seen}"


@pytest.mark.slow
def test_a_new_episode_draws_its_own_perturbations(blur_env):
    """Auto-reset: with every episode one step long, each step's state is a fresh episode whose draws are those of
    its own reset key (env.step splits its key into physics, observation, reset and first-frame keys; the reset key
    into the episode's draws, env.episode_keys)."""
    params = _params(blur_env, perturb_prob=0.5, max_steps=1, **TABLE2)
    step = jax.jit(blur_env.step)
    _, state = blur_env.reset(jax.random.key(7), params)
    seen = set()
    for key in jax.random.split(jax.random.key(8), 8):
        _, state, _, _, truncated, _ = step(key, state, jnp.asarray(5), params)
        assert bool(truncated)
        expected = randomisation.perturbed(env.episode_keys(jax.random.split(key, 4)[2])["perturbed"], params)
        np.testing.assert_array_equal(np.asarray(state.perturbed), np.asarray(expected))
        seen.add(tuple(np.asarray(state.perturbed)))
    assert len(seen) > 1


def test_evaluation_sets_the_perturbations_itself(blur_env):
    """A run trained with the perturbations drawn flies Table I without them and Table II's 'all' with all three in
    every episode (the params as evaluation.tables.evaluate_setting builds them)."""
    trained = {"actuator_noise": 0.3, "delay_max": 0.5, "blur_frames": 3, "perturb_prob": 0.5, "target_spin_std": 0.2}
    assert rollouts.run_env_overrides(trained) == {"target_spin_std": 0.2}
    for setting, expected in (("none", (0.0, 0.0, 1, 1.0)), ("all", (0.3, 0.5, 3, 1.0))):
        params = blur_env.eval_params(**rollouts.run_env_overrides(trained), **rollouts.perturbation_overrides(setting))
        got = tuple(
            np.asarray(getattr(params, f)).item()
            for f in ("actuator_noise", "delay_max", "blur_frames", "perturb_prob")
        )
        np.testing.assert_allclose(got, expected, rtol=1e-6, err_msg=setting)
        assert float(params.target_spin_std) == pytest.approx(0.2)


def test_bad_share_is_refused(blur_env):
    for bad in (-0.1, 1.5):
        with pytest.raises(ValueError, match="perturb_prob"):
            blur_env.default_params(perturb_prob=bad)
