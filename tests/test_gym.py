"""Gymnasium adapters pass gymnasium's own checker and agree with the functional env."""

import warnings

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from ramavt_jax import env, render
from ramavt_jax.gym_adapter import TrackingGymEnv, TrackingVectorEnv

CONFIG = env.EnvConfig(camera=render.CameraConfig(resolution=16), targets=("Satellite-v0",))


def test_check_env_passes():
    import gymnasium

    gym_env = gymnasium.make("ramavt_jax/Tracking-v0", config=CONFIG, render_mode="rgb_array").unwrapped
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no checker warning either (e.g. "the environment has no spec")
        check_env(gym_env, skip_render_check=False)


def test_episode_loop_and_render():
    gym_env = TrackingGymEnv(CONFIG, render_mode="rgb_array")
    obs, info = gym_env.reset(seed=3)
    assert obs.shape == (16, 16, 1) and obs.dtype == np.float32 and "rel_pos" in info
    obs, reward, terminated, truncated, info = gym_env.step(5)
    assert isinstance(reward, float) and isinstance(terminated, bool) and isinstance(truncated, bool)
    assert gym_env.render().shape == (16, 16, 3)
    gym_env.step(np.int64(2))
    gym_env.step(np.array(3))


def test_a_step_after_the_episode_ended_needs_a_reset():
    gym_env = TrackingGymEnv(CONFIG, params=env.TrackingEnv(CONFIG).default_params(max_steps=1))
    gym_env.reset(seed=0)
    assert gym_env.step(0)[3]  # truncated at max_steps
    with pytest.raises(RuntimeError, match="episode has ended.*reset"):
        gym_env.step(0)
    gym_env.reset()
    gym_env.step(0)  # a new episode


@pytest.mark.parametrize("action", [11, -1, 2.7, "3", True, np.float32(1.0), np.array([1])])
def test_non_integer_or_out_of_range_actions_are_rejected(action):
    gym_env = TrackingGymEnv(CONFIG)
    gym_env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action must be an integer in \[0, 10\]"):
        gym_env.step(action)


def test_registered_id_makes_the_env_and_the_vector_env():
    import gymnasium

    gym_env = gymnasium.make("ramavt_jax/Tracking-v0", config=CONFIG)
    assert gym_env.spec is not None and gym_env.spec.id == "ramavt_jax/Tracking-v0"
    obs, _ = gym_env.reset(seed=1)
    assert obs.shape == (16, 16, 1)
    vec = gymnasium.make_vec(
        "ramavt_jax/Tracking-v0", num_envs=2, vectorization_mode="vector_entry_point", config=CONFIG
    )
    assert vec.reset(seed=0)[0].shape == (2, 16, 16, 1)
    with pytest.raises(ValueError, match="integers"):
        vec.step(np.array([0.5, 1.0]))


def test_seeded_reset_is_deterministic():
    a, b = TrackingGymEnv(CONFIG), TrackingGymEnv(CONFIG)
    np.testing.assert_array_equal(a.reset(seed=7)[0], b.reset(seed=7)[0])
    np.testing.assert_array_equal(a.step(1)[0], b.step(1)[0])


@pytest.mark.slow
def test_vector_env_next_step_autoreset():
    vec = TrackingVectorEnv(4, CONFIG, params=env.TrackingEnv(CONFIG).default_params(max_steps=3))
    obs, _ = vec.reset(seed=0)
    assert obs.shape == (4, 16, 16, 1)
    truncs, firsts = [], []
    for _ in range(4):
        obs, reward, terminated, truncated, info = vec.step(np.zeros(4, dtype=np.int64))
        truncs.append(truncated.copy())
        firsts.append(info["is_first"].copy())
    assert np.all(truncs[2]) and not np.any(truncs[3])
    assert np.all(firsts[3]) and not np.any(firsts[2])
    with pytest.raises(ValueError, match="shape"):
        vec.step(np.zeros(3, dtype=np.int64))
