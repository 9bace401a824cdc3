"""scripts/centre_estimator.py: recorded episodes line up with the env, the visible centroid is greedy's, the
desired point scores the error itself, and a few updates fit the labels better than guessing the desired point."""

import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from ramavt_jax import env as env_lib
from ramavt_jax import greedy

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
import centre_estimator  # noqa: E402

CAMERA = env_lib.CameraConfig(resolution=16)


@pytest.fixture(scope="module")
def episodes():
    return centre_estimator.collect(("Asteroid-v0", "Capsule-v0"), 2, 40, jax.random.PRNGKey(0), CAMERA)


def test_recorded_episodes_have_their_shapes_and_the_centroid_is_greedys(episodes):
    eps = episodes
    assert eps.obs.shape == (4, 40, 16, 16, 1) and eps.label.shape == (4, 40, 3) and eps.action.shape == (4, 40)
    assert np.array_equal(np.asarray(eps.target), [0, 0, 1, 1])
    tracking_env = env_lib.TrackingEnv(env_lib.EnvConfig(camera=CAMERA, targets=("Asteroid-v0",)))
    params = tracking_env.eval_params()
    obs, state = tracking_env.reset(jax.random.PRNGKey(3), params)
    one = centre_estimator.Episodes(obs=obs[None, None], action=np.zeros((1, 1), int), label=np.zeros((1, 1, 3)),
                                    alive=np.ones((1, 1), bool), target=np.zeros(1, int))
    seen = centre_estimator.visible_centroid(one, CAMERA)[0, 0]
    np.testing.assert_allclose(seen, greedy.visible_tracking_state(state, params, CAMERA)[:3], atol=2e-3)


def test_guessing_the_desired_point_misses_by_the_error_and_training_does_better(episodes):
    eps = episodes
    names = ("Asteroid-v0", "Capsule-v0")
    zero = centre_estimator.errors_by_target(np.zeros(eps.label.shape), eps, names, skip=5)
    exact = centre_estimator.errors_by_target(np.asarray(eps.label), eps, names, skip=5)
    norms = np.linalg.norm(np.asarray(eps.label)[:2, 5:], axis=-1)[np.asarray(eps.alive)[:2, 5:]] * 5.0
    assert abs(zero["Asteroid-v0"]["3d"] - norms.mean()) < 1e-4 and zero["Asteroid-v0"]["3d"] > 0.5
    assert all(row["3d"] == 0.0 for row in exact.values())
    params, losses = centre_estimator.train(eps, window=20, frames_per_update=80, updates=60, seed=0)
    assert np.mean(losses[-10:]) < 0.5 * np.mean(losses[:4]), losses
    fitted = centre_estimator.errors_by_target(centre_estimator.estimate(params, eps, chunk=20), eps, names, skip=5)
    assert fitted["Asteroid-v0"]["3d"] < zero["Asteroid-v0"]["3d"]
