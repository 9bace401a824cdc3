"""Tests for ramavt_jax.augment."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ramavt_jax.augment import AugmentConfig, augment_batch, augment_sequence


def _frame(key, h=32, w=32, c=2):
    return jax.random.uniform(key, (h, w, c))


def test_same_draw_for_all_frames():
    cfg = AugmentConfig(flip_prob=0.5)
    seq = jnp.broadcast_to(_frame(jax.random.key(0)), (6, 32, 32, 2))
    for i in range(8):
        out = augment_sequence(jax.random.key(i), seq, cfg)
        assert out.shape == seq.shape
        np.testing.assert_array_equal(out, jnp.broadcast_to(out[0], out.shape))


def test_frames_transformed_identically():
    # two different frames: augmenting the pair together equals augmenting each alone with the same key
    cfg = AugmentConfig(flip_prob=0.5)
    a, b = _frame(jax.random.key(1)), _frame(jax.random.key(2))
    key = jax.random.key(3)
    both = augment_sequence(key, jnp.stack([a, b]), cfg)
    np.testing.assert_allclose(both[0], augment_sequence(key, a[None], cfg)[0], atol=1e-6)
    np.testing.assert_allclose(both[1], augment_sequence(key, b[None], cfg)[0], atol=1e-6)


def test_different_keys_differ_and_range_preserved():
    cfg = AugmentConfig()
    seq = _frame(jax.random.key(0))[None].repeat(3, 0)
    outs = [augment_sequence(jax.random.key(i), seq, cfg) for i in range(6)]
    assert any(not np.allclose(outs[0], o) for o in outs[1:])
    for o in outs:
        assert float(o.min()) >= 0.0 and float(o.max()) <= 1.0


def test_individual_ops():
    x = jnp.arange(16.0).reshape(1, 4, 4, 1) / 15.0
    only_flip = AugmentConfig(crop=False, cutout=False, rot90=False, flip_prob=1.0)
    out = augment_sequence(jax.random.key(0), x, only_flip)
    np.testing.assert_array_equal(out, x[:, ::-1, ::-1])
    off = AugmentConfig(crop=False, cutout=False, flip=False, rot90=False)
    np.testing.assert_array_equal(augment_sequence(jax.random.key(0), x, off), x)
    only_cut = AugmentConfig(crop=False, flip=False, rot90=False, cutout_min=0.5, cutout_max=0.5)
    out = augment_sequence(jax.random.key(0), jnp.ones((2, 8, 8, 1)), only_cut)
    assert int((out[0] == 0).sum()) == 16
    only_rot = AugmentConfig(crop=False, cutout=False, flip=False)
    out, info = augment_sequence(jax.random.key(5), x, only_rot, return_info=True)
    np.testing.assert_array_equal(out, jnp.rot90(x, int(info["rot90_k"]), axes=(1, 2)))


@pytest.mark.slow
def test_jit_and_batch():
    cfg = AugmentConfig()
    obs = jax.random.uniform(jax.random.key(0), (4, 5, 32, 32, 1))
    f = jax.jit(lambda k, o: augment_batch(k, o, cfg))
    out = f(jax.random.key(1), obs)
    assert out.shape == obs.shape
    keys = jax.random.split(jax.random.key(1), 4)
    for i in range(4):
        np.testing.assert_allclose(out[i], augment_sequence(keys[i], obs[i], cfg), atol=1e-6)
    out2, info = jax.jit(lambda k, o: augment_batch(k, o, cfg, return_info=True))(jax.random.key(1), obs)
    assert info["rot90_k"].shape == (4,)


def test_bad_config():
    with pytest.raises(ValueError, match="crop_fraction"):
        AugmentConfig(crop_fraction=0.0)
    with pytest.raises(ValueError, match="cutout"):
        AugmentConfig(cutout_min=0.3, cutout_max=0.1)
    with pytest.raises(ValueError, match="flip_prob"):
        AugmentConfig(flip_prob=1.5)
    with pytest.raises(ValueError, match="square"):
        augment_sequence(jax.random.key(0), jnp.zeros((2, 8, 6, 1)), AugmentConfig())
