"""Centre-offset randomisation: `targets.shifted` renders the model moved off the point it spins about, with bounds
that still enclose it, and the env's draw (`randomisation.centre_offset`) stays in its ball, keeps the episode's
other draws and its stand-off, and is for training only."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ramavt_jax import env, randomisation, render, rotations, targets
from ramavt_jax.evaluation import rollouts

CAM = render.CameraConfig(resolution=48)


def _render_at(target, positions, poses, tile=render.renderer.DEFAULT_TILE):
    batch = jax.tree.map(lambda x: jnp.broadcast_to(x, (positions.shape[0],) + x.shape), target)
    return render.render_batch(batch, positions, poses, CAM, render.default_lighting(), shade=False, tile=tile)


def _poses(n: int = 4):
    rng = np.random.default_rng(1)
    q = jnp.asarray(rng.normal(size=(n, 4)), jnp.float32)
    positions = jnp.asarray([[0.2, -0.1, 4.0 + i] for i in range(n)], jnp.float32)
    return positions, jax.vmap(lambda v: rotations.quat_to_mat(v / jnp.linalg.norm(v)))(q)


def test_shifted_target_is_the_model_seen_from_the_moved_point():
    """Geometry moved by d in the body frame, posed at p with rotation R, is the model posed at p + R d."""
    model, offset = targets.load("Satellite-v0"), jnp.asarray([0.5, -0.3, 0.2])
    positions, poses = _poses()
    got = _render_at(targets.shifted(model, offset), positions, poses)
    want = _render_at(model, positions + jnp.einsum("bij,j->bi", poses, offset), poses)
    assert np.asarray(want.hit).sum() > 200
    np.testing.assert_array_equal(np.asarray(got.hit), np.asarray(want.hit))
    np.testing.assert_allclose(np.asarray(got.depth), np.asarray(want.depth), atol=1e-4)
    unmoved = _render_at(model, positions, poses)
    assert (np.asarray(unmoved.hit) != np.asarray(got.hit)).sum() > 50  # the offset does move what is seen


def test_shifted_bounds_enclose_what_is_rendered():
    """The recomputed bound_radius reaches every geom's bounding sphere about the new positions, and the tiled
    renderer with tight tiles draws what it draws with bounds far too large."""
    target = targets.shifted(targets.load("Station-v0"), jnp.asarray([-0.6, 0.4, 0.3]))
    reach = np.linalg.norm(np.asarray(target.geom_pos), axis=-1) + np.asarray(target.geom_rbound)
    assert float(target.bound_radius) == pytest.approx(reach[np.asarray(target.geom_mask)].max(), rel=1e-6)
    assert float(target.bound_radius) > float(targets.load("Station-v0").bound_radius)
    loose = target.replace(geom_rbound=target.geom_rbound * 3.0, bound_radius=target.bound_radius * 3.0)
    positions, poses = _poses(2)
    got, want = _render_at(target, positions, poses, tile=2), _render_at(loose, positions, poses, tile=2)
    np.testing.assert_array_equal(np.asarray(got.hit), np.asarray(want.hit))


# ------------------------------------------------------------------------------------------------ the env's draw
@pytest.fixture(scope="module")
def offset_env():
    return env.TrackingEnv(
        env.EnvConfig(camera=render.CameraConfig(resolution=16), targets=("Satellite-v0", "Asteroid-v0"))
    )


def _params(tracking_env, **overrides):
    return env.validate_params(tracking_env.default_params().replace(**overrides), tracking_env.config)


@pytest.mark.slow
def test_offset_draw_stays_in_its_ball_and_keeps_the_other_draws(offset_env):
    vstate = jax.jit(jax.vmap(offset_env.initial_state, in_axes=(0, None)))
    keys = jax.random.split(jax.random.key(5), 64)
    plain = vstate(keys, _params(offset_env, offset_max=0.0))
    off = vstate(keys, _params(offset_env, offset_max=0.4, offset_prob=0.0))
    default = vstate(keys, offset_env.default_params())
    for a, b, c in zip(jax.tree.leaves(plain), jax.tree.leaves(off), jax.tree.leaves(default)):  # bit for bit
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        np.testing.assert_array_equal(np.asarray(a), np.asarray(c))

    state = vstate(keys, _params(offset_env, offset_max=0.4, offset_prob=0.5))
    moved = np.asarray(state.target.geom_pos) - np.asarray(plain.target.geom_pos)  # [N, G, 3]
    mask = np.asarray(plain.target.geom_mask)
    first = moved[:, :1]
    np.testing.assert_allclose(np.where(mask[..., None], moved - first, 0.0), 0.0, atol=1e-5)  # one vector per target
    length = np.linalg.norm(first[:, 0], axis=-1)
    on = length > 0
    assert 0.25 < on.mean() < 0.75, on.mean()
    assert np.all(length <= 0.4 * np.asarray(plain.target.bound_radius) * (1 + 1e-5))
    assert length.max() > 0.25 * np.asarray(plain.target.bound_radius).max() * 0.4
    for name in ("scale", "target_index", "target_pos", "target_vel", "target_quat", "target_omega"):
        np.testing.assert_array_equal(np.asarray(getattr(state, name)), np.asarray(getattr(plain, name)), name)
    for name in ("inertia", "mass", "geom_size", "geom_mat"):
        np.testing.assert_array_equal(np.asarray(getattr(state.target, name)), np.asarray(getattr(plain.target, name)))


def test_centre_offset_is_for_training_only_and_checked(offset_env):
    from ramavt_jax.presets import preset

    cfg = preset("smoke", env_params=(("offset_max", 0.4), ("offset_prob", 0.5), ("target_spin_std", 0.2)))
    assert rollouts.run_env_overrides(cfg.env_params) == {"target_spin_std": 0.2}
    assert float(offset_env.eval_params().offset_max) == 0.0
    with pytest.raises(ValueError, match=r"EnvParams.offset_max must be in \[0, 1\] \(bounding radii; 0: off\)"):
        offset_env.default_params(offset_max=1.5)
    with pytest.raises(ValueError, match=r"EnvParams.offset_prob must be in \[0, 1\]"):
        offset_env.default_params(offset_prob=-0.1)
    _, on = randomisation.centre_offset(jax.random.key(0), jnp.asarray(2.0), offset_env.default_params())
    assert not bool(on)


def test_offsets_are_uniform_in_their_ball_with_directions_and_lengths_drawn_apart(offset_env):
    params = _params(offset_env, offset_max=0.5)
    keys = jax.random.split(jax.random.key(9), 4000)
    offsets, on = jax.vmap(randomisation.centre_offset, in_axes=(0, None, None))(keys, jnp.asarray(2.0), params)
    length = np.linalg.norm(np.asarray(offsets), axis=-1) / 1.0  # the ball's radius: 0.5 * 2 m
    assert np.asarray(on).all()
    assert abs((length < 0.5).mean() - 1 / 8) < 0.03  # uniform in volume: an eighth lies within half the radius
    np.testing.assert_allclose(np.asarray(offsets).mean(axis=0), 0.0, atol=0.05)  # no preferred direction
    unit = np.asarray(offsets) / length[:, None]
    assert abs(np.corrcoef(length, np.abs(unit[:, 0]))[0, 1]) < 0.06  # the length does not follow the direction
