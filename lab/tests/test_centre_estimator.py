"""lab/centre_estimator.py: recorded episodes pair each frame with the state it was drawn from, the visible
centroid is lab.surface's, the desired point scores the error itself, a few updates fit the labels better than guessing
the desired point, and networks the fit cannot train are refused."""

import jax
import numpy as np
import pytest

from lab import centre_estimator  # noqa: E402
from lab.surface import visible_tracking_state
from ramavt_jax import env as env_lib
from ramavt_jax.imitation import true_tracking_state

CAMERA = env_lib.CameraConfig(resolution=16)
TARGETS = ("Asteroid-v0", "Capsule-v0")
KEY = jax.random.PRNGKey(0)


@pytest.fixture(scope="module")
def episodes():
    return centre_estimator.collect(TARGETS, 2, 40, KEY, CAMERA)


def _first_states():
    """The reset states of the first target's episodes, drawn with collect's keys: (obs [2, H, W, C], states)."""
    tracking_env = env_lib.TrackingEnv(env_lib.EnvConfig(camera=CAMERA, targets=TARGETS))
    params = tracking_env.pinned(tracking_env.eval_params(max_steps=40), 0)
    k_reset = jax.random.split(jax.random.fold_in(KEY, 0), 3)[0]
    obs, states = jax.jit(jax.vmap(tracking_env.reset, in_axes=(0, None)))(jax.random.split(k_reset, 2), params)
    return obs, states, params


def test_each_recorded_frame_comes_with_the_state_it_was_drawn_from(episodes):
    eps = episodes
    assert eps.obs.shape == (4, 40, 16, 16, 1) and eps.label.shape == (4, 40, 3) and eps.action.shape == (4, 40)
    assert np.array_equal(np.asarray(eps.target), [0, 0, 1, 1])
    obs, states, params = _first_states()
    np.testing.assert_allclose(np.asarray(eps.obs[:2, 0], np.float32), obs, atol=1e-3)
    true = jax.vmap(true_tracking_state, in_axes=(0, None))(states, params)
    np.testing.assert_allclose(eps.label[:2, 0], true[:, :3], atol=1e-6)
    assert not np.allclose(eps.label[:2, 1], true[:, :3], atol=1e-4)  # the label moves with the frame
    seen = centre_estimator.visible_centroid(eps, CAMERA)[:2, 0]  # from the stored float16 frames
    expected = jax.jit(jax.vmap(lambda s: visible_tracking_state(s, params, CAMERA)))(states)[:, :3]
    np.testing.assert_allclose(seen, expected, atol=2e-3)


def test_guessing_the_desired_point_misses_by_the_error_and_the_exact_error_by_nothing(episodes):
    eps = episodes
    standoff = float(env_lib.TrackingEnv().eval_params().desired_pos[2])  # m per stand-off distance
    zero = centre_estimator.errors_by_target(np.zeros(eps.label.shape), eps, TARGETS, skip=5)
    exact = centre_estimator.errors_by_target(np.asarray(eps.label), eps, TARGETS, skip=5)
    norms = np.linalg.norm(np.asarray(eps.label)[:2, 5:], axis=-1)[np.asarray(eps.alive)[:2, 5:]] * standoff
    assert abs(zero["Asteroid-v0"]["3d"] - norms.mean()) < 1e-4 and zero["Asteroid-v0"]["3d"] > 0.5
    assert all(row["3d"] == 0.0 for row in exact.values())


@pytest.mark.slow  # a fit of a diagnostic script (about 11 s); errors_by_target is tested above by default
def test_training_does_better_than_guessing_the_desired_point(episodes):
    eps = episodes
    zero = centre_estimator.errors_by_target(np.zeros(eps.label.shape), eps, TARGETS, skip=5)
    params, losses = centre_estimator.train(eps, window=20, frames_per_update=80, updates=60, seed=0)
    assert np.mean(losses[-10:]) < 0.5 * np.mean(losses[:4]), losses
    fitted = centre_estimator.errors_by_target(centre_estimator.estimate(params, eps, chunk=20), eps, TARGETS, skip=5)
    assert fitted["Asteroid-v0"]["3d"] < zero["Asteroid-v0"]["3d"]


@pytest.mark.parametrize("overrides", [{"aux_outputs": 6}, {"norm": "batch"}])
def test_a_network_the_fit_cannot_train_is_refused(overrides):
    with pytest.raises(ValueError, match="estimator"):
        centre_estimator.estimator_network(overrides)


def test_fewer_frames_per_update_than_a_window_are_refused(episodes):
    with pytest.raises(ValueError, match="at least one window"):
        centre_estimator.train(episodes, window=20, frames_per_update=0, updates=1, seed=0)


def test_a_run_without_a_three_entry_aux_head_is_refused(every_chunk_run, episodes):
    with pytest.raises(ValueError, match="aux head"):  # the smoke preset's network has none
        centre_estimator.agent_rows([str(every_chunk_run)], episodes, TARGETS, skip=5)
