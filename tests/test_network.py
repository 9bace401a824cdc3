"""Tests for ramavt_jax.network / layers: shapes, resets, acting == learning, im2col == lax conv, maps."""

import dataclasses
import functools

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ramavt_jax.layers import CONV_FUNCTIONS, HYBRID_MIN_CHANNELS, PaddedConv, conv2d_patches
from ramavt_jax.network import (
    VARIANTS,
    Encoder,
    NetworkConfig,
    QNetwork,
    attention_maps,
    count_params,
    flops_per_frame,
    init_params,
    init_variables,
    initial_state,
    make_network,
)

SMALL = dict(channels=(8, 16, 16, 16), dense=32, lstm=24, head=16, attention_heads=4, drlavt_dense=(32, 16))


def small(variant="ramavt", **kw):
    return NetworkConfig(variant=variant, **{**SMALL, **kw})


def _setup(cfg, obs_shape=(32, 32, 1), b=2, t=4, seed=0):
    k1, k2 = jax.random.split(jax.random.key(seed))
    variables = init_params(cfg, k1, obs_shape)
    obs = jax.random.uniform(k2, (b, t, *obs_shape))
    return make_network(cfg), variables, obs


@functools.partial(jax.jit, static_argnums=0)
def _apply(cfg, variables, obs, reset, state):
    """make_network(cfg).apply, jitted once per config and shape for the whole module: an eager apply dispatches the
    scans op by op (several times slower than compiling on a 2-core CPU)."""
    return make_network(cfg).apply(variables, obs, reset, state)


def _random_state(cfg, b, obs_shape, seed=1):
    s = initial_state(cfg, b, obs_shape)
    leaves, tree = jax.tree_util.tree_flatten(s)
    keys = jax.random.split(jax.random.key(seed), len(leaves))
    return jax.tree_util.tree_unflatten(tree, [jax.random.uniform(k, x.shape) for k, x in zip(keys, leaves)])


@pytest.mark.parametrize("variant,res,ch", [(v, 32, 1) for v in VARIANTS] + [("ramavt", 84, 3), ("drlavt", 64, 4)])
def test_shapes_small(variant, res, ch):
    cfg = small(variant)
    _, variables, obs = _setup(cfg, (res, res, ch), b=2, t=4)
    state = initial_state(cfg, 2, (res, res, ch))
    q, new = _apply(cfg, variables, obs, jnp.zeros((2, 4), bool), state)
    assert q.shape == (2, 4, cfg.num_actions) and q.dtype == jnp.float32
    assert jax.tree_util.tree_map(jnp.shape, new) == jax.tree_util.tree_map(jnp.shape, state)
    assert np.all(np.isfinite(q))


@pytest.mark.parametrize("variant", VARIANTS)
def test_default_config_params_and_shapes(variant):
    cfg = NetworkConfig(variant=variant)
    counts = {}
    for res in (32, 64, 84, 128, 256):
        shapes = jax.eval_shape(lambda k: init_params(cfg, k, (res, res, 1)), jax.random.key(0))
        counts[res] = count_params(shapes)
        net = make_network(cfg)
        state = initial_state(cfg, 2, (res, res, 1))
        q, _ = jax.eval_shape(net.apply, shapes, jnp.zeros((2, 5, res, res, 1)), jnp.zeros((2, 5), bool), state)
        assert q.shape == (2, 5, 11)
    print(variant, counts)  # parameter counts, reported with -s
    if variant == "ramavt":
        assert 4e6 < counts[64] < 6e6
    if cfg.recurrent:
        assert initial_state(cfg, 3).h.shape == (2, 3, 512)


@pytest.mark.parametrize("variant", ["ramavt", "drlavt"])
def test_reset_equals_fresh_sequence(variant):
    cfg = small(variant)
    b, t, cut = 2, 7, 3
    _, variables, obs = _setup(cfg, b=b, t=t)
    reset = jnp.zeros((b, t), bool).at[:, cut].set(True)
    state = _random_state(cfg, b, obs.shape[2:])  # arbitrary carried state: must not leak past the reset
    apply = functools.partial(_apply, cfg)
    q, _ = apply(variables, obs, reset, state)
    fresh_reset = jnp.zeros((b, t - cut), bool).at[:, 0].set(True)
    q2, _ = apply(variables, obs[:, cut:], fresh_reset, _random_state(cfg, b, obs.shape[2:], seed=7))
    np.testing.assert_allclose(q[:, cut:], q2, atol=1e-5)
    # and the prefix did depend on the carried state (recurrent / stacked variants)
    q3, _ = apply(variables, obs, reset, initial_state(cfg, b, obs.shape[2:]))
    assert not np.allclose(q[:, :cut], q3[:, :cut], atol=1e-6)


@pytest.mark.parametrize("variant", ["ramavt", "drlavt", "origin"])
def test_acting_equals_unroll(variant):
    cfg = small(variant)
    b, t = 3, 8
    _, variables, obs = _setup(cfg, b=b, t=t)
    reset = jnp.zeros((b, t), bool).at[:, 0].set(True).at[1, 4].set(True)
    state0 = initial_state(cfg, b, obs.shape[2:])
    q_seq, s_seq = _apply(cfg, variables, obs, reset, state0)
    step = functools.partial(_apply, cfg, variables)
    s, qs = state0, []
    for i in range(t):
        q, s = step(obs[:, i : i + 1], reset[:, i : i + 1], s)
        qs.append(q)
    np.testing.assert_allclose(jnp.concatenate(qs, 1), q_seq, atol=1e-5)
    for a, bb in zip(jax.tree_util.tree_leaves(s), jax.tree_util.tree_leaves(s_seq)):
        np.testing.assert_allclose(a, bb, atol=1e-5)


@functools.partial(jax.jit, static_argnums=0)
def _apply_actions(cfg, variables, obs, reset, state, actions):
    return make_network(cfg).apply(variables, obs, reset, state, actions=actions)


@pytest.mark.slow
def test_prev_action_acting_equals_unroll_and_episode_starts_hide_it():
    """A prev_action network over a window (actions given) equals acting step by step with the caller recording
    each action in the state; the previous action changes q except at episode starts."""
    cfg = small("origin", prev_action=True)
    b, t = 3, 6
    _, variables, obs = _setup(cfg, b=b, t=t)
    reset = jnp.zeros((b, t), bool).at[:, 0].set(True).at[1, 3].set(True)
    actions = jax.random.randint(jax.random.key(3), (b, t), 0, cfg.num_actions)
    state0 = initial_state(cfg, b)
    assert state0.prev_action.shape == (1, b)
    q_seq, s_seq = _apply_actions(cfg, variables, obs, reset, state0, actions)
    s, qs = state0, []
    for i in range(t):
        q, s = _apply(cfg, variables, obs[:, i : i + 1], reset[:, i : i + 1], s)
        s = s.replace(prev_action=actions[:, i][None])
        qs.append(q)
    np.testing.assert_allclose(jnp.concatenate(qs, 1), q_seq, atol=1e-5)
    for a, bb in zip(jax.tree_util.tree_leaves(s), jax.tree_util.tree_leaves(s_seq)):
        np.testing.assert_allclose(a, bb, atol=1e-5)
    q_other, _ = _apply_actions(cfg, variables, obs, reset, state0, (actions + 1) % cfg.num_actions)
    np.testing.assert_allclose(q_other[:, 0], q_seq[:, 0], atol=1e-6)  # step 0 is an episode start everywhere
    assert not np.allclose(q_other[0, 1], q_seq[0, 1], atol=1e-4)
    # row 1 restarts at step 3: from there on its q cannot depend on the actions before the reset
    q_tail, _ = _apply_actions(cfg, variables, obs, reset, state0, actions.at[1, :3].set(0))
    np.testing.assert_allclose(q_tail[1, 3:], q_seq[1, 3:], atol=1e-6)
    q_short, s_short = _apply_actions(cfg, variables, obs, reset, state0, actions[:, :-1])  # the window's layout
    np.testing.assert_allclose(q_short, q_seq, atol=1e-6)
    np.testing.assert_array_equal(s_short.prev_action, state0.prev_action)  # the last action is not known yet
    with pytest.raises(ValueError, match="actions"):
        _apply(cfg, variables, obs, reset, state0)


@pytest.mark.parametrize("k,s,size,c", [(3, 2, 16, 3), (3, 1, 9, 8), (1, 1, 6, 8), (5, 2, 7, 3)])
def test_conv_impls_equal_flax_conv(k, s, size, c):
    """im2col and hybrid against flax's own conv (outputs and both gradients). The hybrid conv's gradients are the
    im2col conv's, to the bit; its forward is XLA's convolution from HYBRID_MIN_CHANNELS input channels on, else
    the im2col conv's."""
    kx, kk, kg = jax.random.split(jax.random.key(0), 3)
    x = jax.random.normal(kx, (2, size, size, c))
    kernel = jax.random.normal(kk, (k, k, c, 5))
    p = k // 2
    conv = nn.Conv(5, (k, k), strides=(s, s), padding=((p, p), (p, p)), use_bias=False)
    impls = {
        "flax": lambda x, w: conv.apply({"params": {"kernel": w}}, x),
        **{name: functools.partial(CONV_FUNCTIONS[name], stride=s) for name in ("im2col", "hybrid", "lax")},
    }

    @jax.jit  # one program for all outputs and gradients (eager: dozens of small compiles)
    def outputs_and_grads(x, w, g):
        return {
            name: (f(x, w), jax.grad(lambda x, w, f=f: jnp.sum(f(x, w) * g), argnums=(0, 1))(x, w))
            for name, f in impls.items()
        }

    shape = jax.eval_shape(impls["flax"], x, kernel).shape
    assert jax.eval_shape(impls["im2col"], x, kernel).shape == shape
    res = outputs_and_grads(x, kernel, jax.random.normal(kg, shape))
    for name in ("im2col", "hybrid"):
        np.testing.assert_allclose(res[name][0], res["flax"][0], atol=1e-4, rtol=1e-4)
        for a, b in zip(res[name][1], res["flax"][1]):
            np.testing.assert_allclose(a, b, atol=1e-3, rtol=1e-4)
    np.testing.assert_array_equal(res["hybrid"][0], res["lax" if c >= HYBRID_MIN_CHANNELS else "im2col"][0])
    for a, b in zip(res["hybrid"][1], res["im2col"][1]):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("k,size", [(4, 32), (2, 9), (3, 7)])
def test_patch_layer_equals_flax_conv(k, size):
    """A block whose kernel equals its stride is a patch layer: flax's conv with stride k, no padding at the start
    and zeros at the end up to a multiple of k (outputs and both gradients); every conv_impl gives the same layer."""
    kx, kk, kg = jax.random.split(jax.random.key(4), 3)
    x, kernel = jax.random.normal(kx, (2, size, size, 3)), jax.random.normal(kk, (k, k, 3, 5))
    end = -size % k
    conv = nn.Conv(5, (k, k), strides=(k, k), padding=((0, end), (0, end)), use_bias=False)
    flax_conv = lambda x, w: conv.apply({"params": {"kernel": w}}, x)  # noqa: E731
    g = jax.random.normal(kg, jax.eval_shape(flax_conv, x, kernel).shape)
    assert g.shape[1] == -(-size // k)

    @jax.jit
    def outputs_and_grads(x, w):
        return {
            name: (f(x, w), jax.grad(lambda x, w, f=f: jnp.sum(f(x, w) * g), argnums=(0, 1))(x, w))
            for name, f in (("flax", flax_conv), ("patches", conv2d_patches))
        }

    res = outputs_and_grads(x, kernel)
    np.testing.assert_allclose(res["patches"][0], res["flax"][0], atol=1e-4, rtol=1e-4)
    for a, b in zip(res["patches"][1], res["flax"][1]):
        np.testing.assert_allclose(a, b, atol=1e-3, rtol=1e-4)
    layers = {impl: PaddedConv(5, k, k, impl=impl) for impl in CONV_FUNCTIONS}
    for layer in layers.values():
        np.testing.assert_array_equal(layer.apply({"params": {"kernel": kernel}}, x), res["patches"][0])
    cfg = small("ramavt", kernels=(k, 3, 3, 1), strides=(k, 1, 1, 1))
    frames = jax.ShapeDtypeStruct((2, size, size, 1), jnp.float32)
    encoded = jax.eval_shape(lambda f: Encoder(cfg).init_with_output(jax.random.key(0), f)[0], frames)
    h, w, c = cfg.feature_map_shape(size, size)
    assert encoded.shape == (2, h * w * c)


@pytest.mark.parametrize("impl", ["hybrid", "im2col"])
def test_conv_constant_planes_equal_appended_channels(impl):
    """PaddedConv(x, planes) = the same conv over [x, planes broadcast to every frame]: one kernel over C + P
    channels, the planes' share computed once; gradients w.r.t. the kernel agree too."""
    kx, kp = jax.random.split(jax.random.key(3))
    x, planes = jax.random.normal(kx, (3, 9, 9, 2)), jax.random.normal(kp, (9, 9, 2))
    full = jnp.concatenate([x, jnp.broadcast_to(planes, (3, 9, 9, 2))], axis=-1)
    conv = PaddedConv(4, 3, 2, impl=impl)
    variables = conv.init(jax.random.key(1), x, planes)
    assert variables["params"]["kernel"].shape == (3, 3, 4, 4)

    @jax.jit
    def outputs_and_grads(v):
        split = lambda v: jnp.sum(jnp.sin(conv.apply(v, x, planes)))  # noqa: E731
        joined = lambda v: jnp.sum(jnp.sin(conv.apply(v, full)))  # noqa: E731
        return conv.apply(v, x, planes), conv.apply(v, full), jax.grad(split)(v), jax.grad(joined)(v)

    y_split, y_full, g_split, g_full = outputs_and_grads(variables)
    np.testing.assert_allclose(y_split, y_full, atol=1e-5)
    np.testing.assert_allclose(g_split["params"]["kernel"], g_full["params"]["kernel"], atol=1e-4)


@pytest.mark.slow
def test_network_conv_impls_share_params_and_agree():
    cfg = small("ramavt")
    _, variables, obs = _setup(cfg, (33, 33, 2), t=3)
    cfg_orig = dataclasses.replace(cfg, pool_first=False, norm="none")
    assert count_params(jax.eval_shape(lambda k: init_params(cfg_orig, k, (33, 33, 2)), jax.random.key(0))) > 0
    reset = jnp.zeros((2, 3), bool)
    s = initial_state(cfg, 2)
    q1, _ = _apply(cfg, variables, obs, reset, s)
    for impl in ("im2col", "lax"):
        other = dataclasses.replace(cfg, conv_impl=impl)
        v2 = jax.eval_shape(lambda k: init_params(other, k, (33, 33, 2)), jax.random.key(0))
        assert jax.tree_util.tree_structure(v2) == jax.tree_util.tree_structure(variables)
        q2, _ = _apply(other, variables, obs, reset, s)
        np.testing.assert_allclose(q1, q2, atol=1e-4)


@pytest.mark.parametrize("variant", ["ramavt", "se"])
def test_attention_maps(variant):
    cfg = small(variant)
    variables = init_params(cfg, jax.random.key(0), (64, 64, 1))
    obs = jax.random.uniform(jax.random.key(1), (64, 64, 1))
    maps = jax.jit(attention_maps, static_argnums=1)(variables["params"], cfg, obs)
    expected = {f"block{i}" for i in range(1, 5)} | ({"mha"} if cfg.use_mha else set())
    assert set(maps) == expected
    assert maps["block1"].shape == (16, 16) and maps["block4"].shape == (1, 1)
    for m in maps.values():
        assert m.ndim == 2
        np.testing.assert_allclose(float(m.sum()), 1.0, atol=1e-5)
        assert np.all(m >= 0)


@pytest.mark.slow
def test_batchnorm_train_and_eval():
    cfg = small("ramavt", norm="batch")
    net, variables, obs = _setup(cfg, t=4)
    assert "batch_stats" in variables
    reset = jnp.zeros((2, 4), bool)
    s = initial_state(cfg, 2)
    train_apply = jax.jit(lambda v, o, r, s: net.apply(v, o, r, s, train=True, mutable=["batch_stats"]))
    (q, _), upd = train_apply(variables, obs, reset, s)
    assert q.shape == (2, 4, 11)
    changed = jax.tree_util.tree_map(lambda a, b: bool(jnp.any(a != b)), upd["batch_stats"], variables["batch_stats"])
    assert any(jax.tree_util.tree_leaves(changed))
    # running averages: deterministic and frame-local, so sequence 0's q does not depend on what sequence 1 shows
    q_eval, _ = _apply(cfg, variables, obs, reset, s)
    other = obs.at[1].set(jax.random.uniform(jax.random.key(5), obs.shape[1:]))
    q_other, _ = _apply(cfg, variables, other, reset, s)
    np.testing.assert_allclose(q_eval[0], q_other[0], atol=1e-5)
    assert not np.allclose(q_eval[1], q_other[1], atol=1e-5)


@pytest.mark.slow
def test_grad_finite_and_bf16():
    cfg = small("ramavt")
    net, variables, obs = _setup(cfg, t=4)
    reset = jnp.zeros((2, 4), bool)
    s = initial_state(cfg, 2)

    def loss(p):
        q, _ = net.apply({"params": p}, obs, reset, s)
        return jnp.mean(q**2)

    g = jax.jit(jax.grad(loss))(variables["params"])
    assert all(np.all(np.isfinite(x)) for x in jax.tree_util.tree_leaves(g))
    cfg16 = dataclasses.replace(cfg, dtype="bfloat16")
    q16, _ = _apply(cfg16, variables, obs, reset, s)
    q32, _ = _apply(cfg, variables, obs, reset, s)
    assert q16.dtype == jnp.float32
    np.testing.assert_allclose(q16, q32, atol=0.1, rtol=0.1)


def test_flops_and_params_positive():
    cfg = small("ramavt")
    f64 = flops_per_frame(cfg, (64, 64, 1))
    f128 = flops_per_frame(cfg, (128, 128, 1))
    assert 0 < f64 < f128
    assert count_params(jax.eval_shape(lambda k: init_params(cfg, k, (32, 32, 1)), jax.random.key(0))) > 0


@pytest.mark.parametrize(
    "kw,match",
    [
        (dict(variant="foo"), "variant"),
        (dict(norm="group"), "norm"),
        (dict(conv_impl="cudnn"), "conv_impl"),
        (dict(dtype="float16"), "dtype"),
        (dict(channels=(32, 64), kernels=(3, 3, 3, 1)), "same length"),
        (dict(kernels=(3, 4, 3, 1)), "odd"),  # even and not its block's stride (2): neither padding nor patches
        (dict(channels=(32, 64, 128, 0)), "positive"),
        (dict(attention_heads=3), "attention_heads"),
        (dict(lstm_layers=0), "lstm_layers"),
        (dict(num_actions=0), "num_actions"),
        (dict(channels=32), "tuple"),
        (dict(variant="drlavt", prev_action=True), "prev_action"),
        (dict(variant="drlavt", aux_outputs=3), "aux_outputs needs a recurrent variant"),
        (dict(aux_outputs=4), r"aux_outputs must be one of \(0, 3, 6\)"),
    ],
)
def test_bad_config(kw, match):
    with pytest.raises(ValueError, match=match):
        NetworkConfig(**kw)


def test_bad_inputs():
    with pytest.raises(ValueError, match="obs_shape"):
        initial_state(NetworkConfig(variant="drlavt"), 2)
    cfg = small()
    net, variables, obs = _setup(cfg, t=2)
    with pytest.raises(ValueError, match="expected obs"):
        net.apply(variables, obs[:, 0], jnp.zeros((2,), bool), initial_state(cfg, 2))


# ------------------------------------------------------------------------------------------ depth scale visibility
def _encode(cfg, obs):
    from ramavt_jax.network import Encoder

    variables = init_params(cfg, jax.random.key(0), obs.shape[1:])
    return Encoder(cfg).apply({"params": variables["params"]["encoder"]}, obs)


def _silhouette(depth_value: float, res: int = 32) -> jnp.ndarray:
    v, u = jnp.meshgrid(jnp.arange(res), jnp.arange(res), indexing="ij")
    disc = (u - 12.0) ** 2 + (v - 14.0) ** 2 < 30.0
    return jnp.where(disc, depth_value, 0.0)[None, :, :, None]


@pytest.mark.slow
def test_plain_encoder_cannot_see_depth_scale_and_the_cues_fix_it():
    """One silhouette at 5 m and at 10 m (depth values 0.25 and 0.5): bias-free convs and a per-frame LayerNorm give
    the same features (the scale divides out; variant 'origin': SE's sigmoid gates leak a little of the scale);
    the hit-mask / coordinate channels and the pre-norm pooled skip make them differ."""
    near, far = _silhouette(0.25), _silhouette(0.5)
    plain = small("origin", channels=(8, 16, 16), kernels=(3, 3, 3), strides=(2, 1, 1), pools=(True, True, False))
    diff_plain = float(jnp.max(jnp.abs(_encode(plain, near) - _encode(plain, far))))
    assert diff_plain < 1e-4, diff_plain
    for cues in (dict(coord_channels=True), dict(pooled_skip=True)):
        cfg = dataclasses.replace(plain, **cues)
        diff = float(jnp.max(jnp.abs(_encode(cfg, near) - _encode(cfg, far))))
        assert diff > 1e-2, (cues, diff)


@pytest.mark.slow
def test_coordinate_channels_and_skip_shapes():
    from ramavt_jax.network import with_coordinates

    x = with_coordinates(_silhouette(0.3, res=8))
    assert x.shape == (1, 8, 8, 4)
    np.testing.assert_array_equal(np.asarray(x[0, :, :, 1]), np.asarray(x[0, :, :, 0] > 0).astype(np.float32))
    np.testing.assert_allclose(np.asarray(x[0, 0, :, 2]), np.linspace(-1, 1, 8), atol=1e-6)
    np.testing.assert_allclose(np.asarray(x[0, :, 0, 3]), np.linspace(-1, 1, 8), atol=1e-6)
    cfg = small("ramavt", pooled_skip=True, coord_channels=True)
    _, variables, obs = _setup(cfg)
    q, _ = _apply(cfg, variables, obs, jnp.zeros(obs.shape[:2], bool), initial_state(cfg, obs.shape[0]))
    assert q.shape == (*obs.shape[:2], cfg.num_actions) and bool(jnp.all(jnp.isfinite(q)))


def test_coordinate_encoder_equals_plain_encoder_on_appended_channels():
    """coord_channels folds the constant coordinate planes into the first conv: the encoder then gives what the
    same encoder without it gives on the frame with the mask and the planes appended (same parameters)."""
    from ramavt_jax.network import Encoder, with_coordinates

    cfg = small("ramavt", coord_channels=True, pooled_skip=True)
    plain = dataclasses.replace(cfg, coord_channels=False)
    obs = jax.random.uniform(jax.random.key(2), (3, 32, 32, 1)) * (
        jax.random.uniform(jax.random.key(3), (3, 32, 32, 1)) > 0.7
    )
    params = init_params(cfg, jax.random.key(0), obs.shape[1:])["params"]["encoder"]
    folded = jax.jit(Encoder(cfg).apply)({"params": params}, obs)
    appended = jax.jit(Encoder(plain).apply)({"params": params}, with_coordinates(obs))
    np.testing.assert_allclose(folded, appended, atol=1e-5)


@pytest.mark.parametrize("backend", ["cpu", "gpu"])
@pytest.mark.slow
def test_hybrid_conv_vmapped_over_kernels_equals_each_kernel(backend, monkeypatch):
    """vmapped over seeds (kernels batched), the hybrid conv runs one convolution per kernel on CPU instead of XLA's
    grouped convolution (kept on accelerators: the 'gpu' case takes that branch, on the CPU): outputs and kernel
    gradients equal the per-kernel ones; a batch of inputs alone also works."""
    monkeypatch.setattr(jax, "default_backend", lambda: backend)
    kx, kk = jax.random.split(jax.random.key(4))
    x, kernels = jax.random.normal(kx, (3, 2, 6, 6, 8)), jax.random.normal(kk, (3, 3, 3, 8, 4))
    conv = functools.partial(CONV_FUNCTIONS["hybrid"], stride=1)
    loss = lambda k, x: jnp.sum(jnp.sin(conv(x, k)))  # noqa: E731

    @jax.jit
    def batched_and_looped(x, kernels):
        batched = (
            jax.vmap(conv)(x, kernels),
            jax.vmap(jax.grad(loss))(kernels, x),
            jax.vmap(conv, (0, None))(x, kernels[0]),
        )
        looped = [(conv(x[i], kernels[i]), jax.grad(loss)(kernels[i], x[i]), conv(x[i], kernels[0])) for i in range(3)]
        return batched, looped

    batched, looped = batched_and_looped(x, kernels)
    for i in range(3):
        for b, l in zip(batched, looped[i]):
            np.testing.assert_allclose(b[i], l, atol=1e-5)


@pytest.mark.slow
def test_frame_stacking_without_history_still_runs():
    """'drlavt' with frame_stack 1 keeps an empty [B, 0, H, W, C] history."""
    cfg = small("drlavt", frame_stack=1)
    _, variables, obs = _setup(cfg, b=2, t=3)
    q, s = _apply(cfg, variables, obs, jnp.zeros((2, 3), bool), initial_state(cfg, 2, obs.shape[2:]))
    assert q.shape == (2, 3, cfg.num_actions) and s.frames.shape == (2, 0, 32, 32, 1)


def _dueling_head(cfg: NetworkConfig, y: jnp.ndarray) -> jnp.ndarray:
    """A q_head made outside the package: Q = V + A - mean(A) (a value layer beside the default one)."""
    advantage = nn.Dense(cfg.num_actions, name="q")(y)
    return nn.Dense(1, name="value")(y) + advantage - advantage.mean(axis=-1, keepdims=True)


@pytest.mark.parametrize("variant", ["origin", "drlavt"])
def test_a_q_head_from_outside_replaces_the_output_layer_and_keeps_the_rest(variant):
    """QNetwork(config, q_head=...) (a network factory's simplest form): its layers join the params beside the
    unchanged trunk, and Q is what the head makes of the features (here shifting the value output shifts every
    action's Q alike)."""
    cfg = small(variant)
    net = QNetwork(cfg, q_head=_dueling_head)
    b, t = 2, 3
    obs = jax.random.uniform(jax.random.key(5), (b, t, 32, 32, 1))
    reset, state = jnp.zeros((b, t), bool).at[:, 0].set(True), initial_state(cfg, b, obs.shape[2:])
    params = init_variables(net, cfg, jax.random.key(0), (32, 32, 1))["params"]
    plain = init_params(cfg, jax.random.key(0), (32, 32, 1))["params"]
    assert set(params) == set(plain) | {"value"} and params["value"]["kernel"].shape[-1] == 1
    q, _ = jax.jit(net.apply)({"params": params}, obs, reset, state)
    moved = {**params, "value": {**params["value"], "bias": params["value"]["bias"] + 2.0}}
    np.testing.assert_allclose(jax.jit(net.apply)({"params": moved}, obs, reset, state)[0], q + 2.0, atol=1e-5)
