"""Baselines over whole episodes: the mpc ceiling beats the proportional controller, which tracks every target; the
depth tracker comes close to it, random ends early."""

import jax
import numpy as np
import pytest

from ramavt_jax import baselines, env, render, targets
from ramavt_jax.evaluation import rollouts as evaluate


@pytest.fixture(scope="module")
def proportional_results():
    # The controller reads the true state, so a tiny image keeps rendering cheap; 100 episodes per target.
    config = env.EnvConfig(camera=render.CameraConfig(resolution=8), targets=targets.ALL_TARGETS)
    policy = baselines.proportional_policy()
    return evaluate.evaluate_per_target(config, policy, jax.random.key(0), episodes_per_target=100)


@pytest.mark.slow
def test_proportional_tracks_every_catalogue_target(proportional_results):
    lengths = {name: s.length_mean for name, s in proportional_results.items()}
    print("proportional mean episode length per target:", lengths)
    assert len(lengths) == len(targets.ALL_TARGETS)
    assert all(s.episodes == 100 for s in proportional_results.values())
    for name, mean in lengths.items():
        assert mean >= 990.0, f"proportional lost {name}: mean length {mean}"


@pytest.mark.slow
def test_random_ends_early_and_depth_tracker_comes_close(proportional_results):
    names = ("Satellite-v2", "Capsule-v2", "Asteroid-v5")
    config = env.EnvConfig(camera=render.CameraConfig(resolution=32), targets=names)
    depth = evaluate.evaluate_per_target(config, baselines.make_policy("depth", config.camera), jax.random.key(1), 8)
    rand = evaluate.evaluate_per_target(config, baselines.random_policy(), jax.random.key(2), 8)
    depth_mean = np.mean([s.length_mean for s in depth.values()])
    rand_mean = np.mean([s.length_mean for s in rand.values()])
    prop_mean = np.mean([proportional_results[n].length_mean for n in names])
    print(f"mean episode length: proportional {prop_mean:.1f}, depth tracker {depth_mean:.1f}, random {rand_mean:.1f}")
    assert rand_mean < 0.5 * prop_mean
    assert depth_mean >= 0.9 * prop_mean
    # the classical tracker's position estimate is biased (it sees the surface, not the centre of mass)
    depth_return = np.mean([s.return_mean for s in depth.values()])
    prop_return = np.mean([proportional_results[n].return_mean for n in names])
    assert depth_return < prop_return


def test_quantise_velocity_picks_nearest_command():
    assert int(baselines.quantise_velocity(np.array([0.9, 0.1, 0.0]), 1.0)) == 1
    assert int(baselines.quantise_velocity(np.array([0.0, 0.0, -0.7]), 1.0)) == 6
    assert int(baselines.quantise_velocity(np.array([-0.8, -0.9, 0.0]), 1.0)) == 10
    assert int(baselines.quantise_velocity(np.array([0.1, 0.0, 0.1]), 1.0)) == 0


def test_depth_estimate_recovers_centred_sphere():
    # a sphere of radius 0.5 at 5 m on the boresight: centroid at the image centre, mean depth just under 5 m
    xml = """<mujoco><worldbody><body><freejoint/><geom type="sphere" size="0.5"/></body></worldbody></mujoco>"""
    import os
    import tempfile

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
    with pytest.raises(ValueError, match="renamed 'proportional'"):
        baselines.make_policy("oracle", render.CameraConfig())
    with pytest.raises(ValueError, match="branch"):
        baselines.mpc_policy(env.EnvConfig(), horizon=2, branch=3)


def test_candidate_sequences_are_every_pair():
    seqs = np.asarray(baselines.candidate_sequences(2, num_actions=3))
    assert seqs.shape == (9, 2) and len({tuple(s) for s in seqs}) == 9 and set(seqs.ravel()) == {0, 1, 2}


@pytest.mark.slow
def test_mpc_ceiling_beats_proportional_on_the_same_episodes():
    # Same key, so the same initial states; 4 episodes of 40 steps, an 8x8 image (neither policy looks).
    config = env.EnvConfig(camera=render.CameraConfig(resolution=8), targets=("Satellite-v2",))
    key, overrides = jax.random.key(5), {"max_steps": 40}
    prop = evaluate.evaluate_per_target(config, baselines.make_policy("proportional", config.camera), key, 4, overrides)
    mpc = evaluate.evaluate_per_target(config, baselines.make_policy("mpc", config.camera), key, 4, overrides)
    for name in config.targets:
        print(
            f"{name}: AER mpc {mpc[name].return_mean:.1f} proportional {prop[name].return_mean:.1f}; error (m) "
            f"{mpc[name].error_mean:.2f} {prop[name].error_mean:.2f}"
        )
        assert mpc[name].length_mean == 40  # it does not lose the target
        assert mpc[name].return_mean > prop[name].return_mean + 5.0
        assert mpc[name].error_mean < prop[name].error_mean
