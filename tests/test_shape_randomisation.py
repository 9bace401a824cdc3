"""Shape randomisation: `targets.stretched` against MuJoCo's reading of a stretched MJCF, the renderer's bounds
after a stretch, and the env's draw (`randomisation.stretch_factors`), which keeps the volume and the episode's other
draws and is for training only."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ramavt_jax import env, randomisation, render, rotations, targets
from ramavt_jax.evaluation import rollouts

pytest.importorskip("mujoco")

NUM_ENVS = 32


def _model(body: str) -> str:
    return f'<mujoco><option gravity="0 0 0"/><worldbody><body name="target"><freejoint/>{body}</body></worldbody></mujoco>'


TURN_Z = ' euler="0 0 90"'  # 90 degrees (MJCF's default unit) about z: the geom's x is the body's y


def _symmetric_body(s=(1.0, 1.0, 1.0)) -> str:
    """A body symmetric under each axis reflection (so its principal frame is the file's, up to signs) with every
    length stretched by s, as a by-hand reference: its spheres (one turned, which changes only its geom frame) are
    written as ellipsoids once stretched, and a box turned about z stretches its own x by s_y."""
    sx, sy, sz = s
    sphere = (
        '<geom type="sphere" size="0.2" pos="{x} 0 0" euler="30 50 70"/>'
        if s == (1.0, 1.0, 1.0)
        else f'<geom type="ellipsoid" size="{0.2 * sx} {0.2 * sy} {0.2 * sz}" pos="{{x}} 0 0"/>'
    )
    return "".join(
        [
            f'<geom type="box" size="{0.3 * sx} {0.2 * sy} {0.15 * sz}" density="300"/>',
            sphere.format(x=0.9 * sx),
            sphere.format(x=-0.9 * sx),
            f'<geom type="ellipsoid" size="{0.1 * sx} {0.2 * sy} {0.15 * sz}" pos="0 {0.5 * sy} 0"/>',
            f'<geom type="ellipsoid" size="{0.1 * sx} {0.2 * sy} {0.15 * sz}" pos="0 {-0.5 * sy} 0"/>',
            f'<geom type="box" size="{0.04 * sy} {0.3 * sx} {0.05 * sz}" pos="0 0 {0.3 * sz}"{TURN_Z}/>',
            f'<geom type="box" size="{0.04 * sy} {0.3 * sx} {0.05 * sz}" pos="0 0 {-0.3 * sz}"{TURN_Z}/>',
        ]
    )


def _round_body(s=(1.0, 1.0, 1.0)) -> str:
    """A disc (a cylinder along z), a heavy bar along x and two capsules along z at +-y, stretched by s (s_x == s_y)
    by hand; the bar and the capsules put the principal moments in the file's axis order."""
    sx, _, sz = s
    caps = "".join(f'<geom type="capsule" size="{0.1 * sx} {0.3 * sz}" pos="0 {y * sx} 0"/>' for y in (0.7, -0.7))
    return (
        f'<geom type="cylinder" size="{0.3 * sx} {0.05 * sz}" density="300"/>'
        f'<geom type="box" size="{0.8 * sx} {0.05 * sx} {0.05 * sz}" density="20000"/>' + caps
    )


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return tmp_path_factory.mktemp("stretch")


def _load(folder, name: str, body: str) -> targets.TargetModel:
    (folder / f"{name}.xml").write_text(_model(body))
    model = targets.load(folder / f"{name}.xml")
    # A precondition: distinct moments in the file's axis order, so the loader's principal frame is the file's.
    assert np.all(np.diff(np.asarray(model.inertia)) > 0.02 * np.asarray(model.inertia).max()), (name, model.inertia)
    np.testing.assert_allclose(np.abs(np.asarray(model.geom_mat[0])), np.eye(3), atol=1e-6)
    return model


def _assert_same_target(got, want):
    np.testing.assert_array_equal(np.asarray(got.geom_type), np.asarray(want.geom_type))
    for name in ("geom_size", "geom_rbound", "bound_radius", "inertia", "mass"):
        np.testing.assert_allclose(
            np.asarray(getattr(got, name)), np.asarray(getattr(want, name)), rtol=2e-5, atol=1e-6, err_msg=name
        )
    for name in ("geom_pos", "geom_mat"):  # the principal axes' signs are MuJoCo's eigensolver's choice
        np.testing.assert_allclose(
            np.abs(np.asarray(getattr(got, name))), np.abs(np.asarray(getattr(want, name))), atol=1e-6, err_msg=name
        )


def test_stretched_matches_mujoco_on_a_stretched_file(folder):
    """Geoms, bounds, mass and inertia of a stretched target equal the loader's reading of the file stretched by
    hand, where MuJoCo computes mass and inertia (factors with product 1 keep the mass): three different factors,
    spheres (one turned) and boxes turned about z."""
    factors = (1.25, 0.9, 1 / (1.25 * 0.9))
    plain = _load(folder, "plain", _symmetric_body())
    got = targets.stretched(plain, jnp.asarray(factors))
    _assert_same_target(got, _load(folder, "stretched", _symmetric_body(factors)))
    assert not np.allclose(np.asarray(got.inertia), np.asarray(plain.inertia), rtol=1e-2)


def test_stretched_cylinders_match_and_capsule_tips_land_where_stretched(folder):
    """A cylinder along a body axis with equal radial factors stretches exactly. A capsule keeps hemispherical caps:
    its radius takes the radial factor and its tips land where the stretch puts them."""
    a = 1.2
    factors = (a, a, 1 / a**2)
    got = targets.stretched(_load(folder, "round", _round_body()), jnp.asarray(factors))
    want = _load(folder, "round_stretched", _round_body(factors))  # its capsules only keep the axes in order
    np.testing.assert_allclose(np.asarray(got.geom_size[:2]), np.asarray(want.geom_size[:2]), rtol=1e-5)
    capsules = np.asarray(got.geom_size[2:])
    np.testing.assert_allclose(capsules[:, 0], 0.1 * a, rtol=1e-6)
    np.testing.assert_allclose(capsules[:, 0] + capsules[:, 1], 0.4 / a**2, rtol=1e-5)  # the tip: (h + r) s_z


def _render(target, tile=render.renderer.DEFAULT_TILE):
    cam = render.CameraConfig(resolution=48)
    rng = np.random.default_rng(0)
    q = rng.normal(size=(6, 4))
    poses = jax.vmap(lambda v: rotations.quat_to_mat(v / jnp.linalg.norm(v)))(jnp.asarray(q, jnp.float32))
    positions = jnp.asarray([[0.0, 0.0, z] for z in (3.0, 4.0, 5.0, 6.0, 7.0, 8.0)]) + jnp.asarray(
        rng.uniform(-0.6, 0.6, (6, 3)), jnp.float32
    )
    batch = jax.tree.map(lambda x: jnp.broadcast_to(x, (6,) + x.shape), target)
    return render.render_batch(batch, positions, poses, cam, render.default_lighting(), shade=False, tile=tile)


@pytest.mark.slow
def test_stretch_by_ones_renders_the_same_target():
    """Factors of 1 on a model with geoms at every angle (spheres among them, drawn as ellipsoids) render the
    model itself."""
    model = targets.load("Station-v0")
    assert np.any(np.asarray(model.geom_type) == targets.SPHERE)
    np.testing.assert_allclose(
        np.asarray(_render(targets.stretched(model, jnp.ones(3))).depth), np.asarray(_render(model).depth), atol=1e-5
    )


@pytest.mark.parametrize("name", ["Station-v0", "Asteroid-v1"])
@pytest.mark.slow
def test_stretched_bounds_enclose_what_is_rendered(name):
    """The recomputed geom_rbound and bound_radius bound the stretched geoms: the tiled renderer, which skips the
    tiles outside each geom's bounding sphere, draws what the same target draws with bounds far too large."""
    target = targets.stretched(targets.load(name), jnp.asarray([1.4, 0.85, 1 / (1.4 * 0.85)]))
    loose = target.replace(geom_rbound=target.geom_rbound * 3.0, bound_radius=target.bound_radius * 3.0)
    got, want = _render(target, tile=2), _render(loose, tile=2)  # small tiles: a tight culling
    assert np.asarray(want.hit).sum() > 100
    np.testing.assert_array_equal(np.asarray(got.hit), np.asarray(want.hit))
    np.testing.assert_allclose(np.asarray(got.depth), np.asarray(want.depth), atol=1e-5)
    reach = np.linalg.norm(np.asarray(target.geom_pos), axis=-1) + np.asarray(target.geom_rbound)
    assert float(target.bound_radius) == pytest.approx(reach[np.asarray(target.geom_mask)].max(), rel=1e-6)


# ------------------------------------------------------------------------------------------------ the env's draw
@pytest.fixture(scope="module")
def stretch_env():
    return env.TrackingEnv(
        env.EnvConfig(camera=render.CameraConfig(resolution=16), targets=("Satellite-v0", "Asteroid-v0"))
    )


@pytest.fixture(scope="module")
def vstate(stretch_env):
    return jax.jit(jax.vmap(stretch_env.initial_state, in_axes=(0, None)))


def _params(tracking_env, **overrides):
    """Default params with fields replaced by Python floats, checked: one compiled reset serves every variant."""
    return env.validate_params(tracking_env.default_params().replace(**overrides), tracking_env.config)


@pytest.mark.slow
def test_stretch_draw_keeps_the_volume_and_the_other_draws(stretch_env, vstate):
    keys = jax.random.split(jax.random.key(3), NUM_ENVS)
    plain = vstate(keys, _params(stretch_env, stretch_max=1.0))
    off = vstate(keys, _params(stretch_env, stretch_max=1.5, stretch_prob=0.0))
    default = vstate(keys, stretch_env.default_params())
    for a, b, c in zip(jax.tree.leaves(plain), jax.tree.leaves(off), jax.tree.leaves(default)):  # bit for bit
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        np.testing.assert_array_equal(np.asarray(a), np.asarray(c))
    own = jax.vmap(targets.select, in_axes=(None, 0))(stretch_env.default_params().catalogue, plain.target_index)
    for a, b in zip(jax.tree.leaves(own), jax.tree.leaves(plain.target)):  # the models themselves, spheres and all
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))

    p = _params(stretch_env, stretch_max=1.5, stretch_prob=0.5)
    stretch_keys = jax.vmap(lambda k: env.episode_keys(k)["stretch"])(keys)  # the draw's own key in each episode
    factors, on = jax.vmap(randomisation.stretch_factors, in_axes=(0, None))(stretch_keys, p)
    factors, on = np.asarray(factors), np.asarray(on)
    np.testing.assert_allclose(np.prod(factors, axis=1), 1.0, rtol=1e-5)
    assert np.all((factors > 1.5 ** (-4 / 3) * 0.9999) & (factors < 1.5 ** (4 / 3) * 1.0001))
    assert factors.min() < 0.8 and factors.max() > 1.25
    assert 0.2 < on.mean() < 0.8, on.mean()

    state = vstate(keys, p)
    mass_kept = np.asarray(state.target.mass) == np.asarray(plain.target.mass)
    assert mass_kept.all()
    same_inertia = np.all(np.asarray(state.target.inertia) == np.asarray(plain.target.inertia), axis=1)
    np.testing.assert_array_equal(same_inertia, ~on)
    own = jax.vmap(targets.select, in_axes=(None, 0))(p.catalogue, state.target_index)
    want = jax.vmap(targets.stretched)(own, jnp.asarray(factors))
    np.testing.assert_allclose(np.asarray(state.target.inertia)[on], np.asarray(want.inertia)[on], rtol=1e-6)
    for name in ("target_index", "target_vel", "target_quat", "target_omega"):
        np.testing.assert_array_equal(np.asarray(getattr(state, name)), np.asarray(getattr(plain, name)))


@pytest.mark.slow  # 30 s of compiling reset and step for one more env; the draw's test covers initial_state
def test_stretched_episodes_render_and_step(stretch_env):
    """A stretched episode resets and steps under jit like any other (the sphere-to-ellipsoid change included)."""
    p = _params(stretch_env, stretch_max=1.6)
    keys = jax.random.split(jax.random.key(4), 4)
    obs, state = jax.jit(jax.vmap(stretch_env.reset, in_axes=(0, None)))(keys, p)
    assert obs.shape == (4,) + stretch_env.observation_shape and np.isfinite(np.asarray(obs)).all()
    step = jax.jit(jax.vmap(stretch_env.step, in_axes=(0, 0, 0, None)))
    obs, state, reward, *_ = step(keys, state, jnp.zeros(4, jnp.int32), p)
    assert np.isfinite(np.asarray(obs)).all() and np.isfinite(np.asarray(reward)).all()


def test_shape_randomisation_is_for_training_only_and_checked(stretch_env):
    from ramavt_jax.presets import preset

    cfg = preset("smoke", env_params=(("stretch_max", 1.5), ("stretch_prob", 0.5), ("target_spin_std", 0.2)))
    assert rollouts.run_env_overrides(cfg.env_params) == {"target_spin_std": 0.2}
    assert float(stretch_env.eval_params().stretch_max) == 1.0
    with pytest.raises(ValueError, match=r"EnvParams.stretch_max must be >= 1 \(1: off\)"):
        stretch_env.default_params(stretch_max=0.8)
    with pytest.raises(ValueError, match=r"EnvParams.stretch_prob must be in \[0, 1\]"):
        stretch_env.default_params(stretch_prob=2.0)
