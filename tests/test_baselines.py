"""Baselines over whole episodes: the oracle is the upper bound, the depth tracker comes close, random ends early."""

import jax
import numpy as np
import pytest

from ramavt_jax import baselines, env, render, targets
from ramavt_jax.evaluation import rollouts as evaluate


@pytest.fixture(scope="module")
def oracle_results():
    # The oracle reads the true state, so a tiny image keeps rendering cheap; 100 episodes per target.
    config = env.EnvConfig(camera=render.CameraConfig(resolution=8), targets=targets.ALL_TARGETS)
    policy = baselines.oracle_policy()
    return evaluate.evaluate_per_target(config, policy, jax.random.key(0), episodes_per_target=100)


def test_oracle_tracks_every_catalogue_target(oracle_results):
    lengths = {name: s.length_mean for name, s in oracle_results.items()}
    print("oracle mean episode length per target:", lengths)
    assert len(lengths) == len(targets.ALL_TARGETS)
    assert all(s.episodes == 100 for s in oracle_results.values())
    for name, mean in lengths.items():
        assert mean >= 990.0, f"oracle lost {name}: mean length {mean}"


def test_random_ends_early_and_depth_tracker_comes_close(oracle_results):
    names = ("Satellite-v2", "Capsule-v2", "Asteroid-v5")
    config = env.EnvConfig(camera=render.CameraConfig(resolution=32), targets=names)
    depth = evaluate.evaluate_per_target(config, baselines.make_policy("depth", config.camera), jax.random.key(1), 8)
    rand = evaluate.evaluate_per_target(config, baselines.random_policy(), jax.random.key(2), 8)
    depth_mean = np.mean([s.length_mean for s in depth.values()])
    rand_mean = np.mean([s.length_mean for s in rand.values()])
    oracle_mean = np.mean([oracle_results[n].length_mean for n in names])
    print(f"mean episode length: oracle {oracle_mean:.1f}, depth tracker {depth_mean:.1f}, random {rand_mean:.1f}")
    assert rand_mean < 0.5 * oracle_mean
    assert depth_mean >= 0.9 * oracle_mean
    # the classical tracker's position estimate is biased (it sees the surface, not the centre of mass)
    depth_return = np.mean([s.return_mean for s in depth.values()])
    oracle_return = np.mean([oracle_results[n].return_mean for n in names])
    assert depth_return < oracle_return


def test_quantise_velocity_picks_nearest_command():
    assert int(baselines.quantise_velocity(np.array([0.9, 0.1, 0.0]), 1.0)) == 1
    assert int(baselines.quantise_velocity(np.array([0.0, 0.0, -0.7]), 1.0)) == 6
    assert int(baselines.quantise_velocity(np.array([-0.8, -0.9, 0.0]), 1.0)) == 10
    assert int(baselines.quantise_velocity(np.array([0.1, 0.0, 0.1]), 1.0)) == 0


def test_depth_estimate_recovers_centred_sphere():
    # a sphere of radius 0.5 at 5 m on the boresight: centroid at the image centre, mean depth just under 5 m
    xml = """<mujoco><worldbody><body><freejoint/><geom type="sphere" size="0.5"/></body></worldbody></mujoco>"""
    import tempfile, os

    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "ball.xml")
        open(path, "w").write(xml)
        target = targets.load(path)
    cam = render.CameraConfig(resolution=64)
    frame = render.render(target, np.array([0.0, 0.0, 5.0]), np.eye(3), cam, render.default_lighting(), False)
    depth = render.to_observation(frame, "depth", cam.far)[..., 0]
    position, seen = baselines.estimate_position(depth, cam)
    assert bool(seen)
    np.testing.assert_allclose(position[:2], 0.0, atol=0.02)
    assert 4.5 < float(position[2]) < 5.0


def test_unknown_policy():
    with pytest.raises(ValueError, match="unknown baseline"):
        baselines.make_policy("telepathy", render.CameraConfig())
