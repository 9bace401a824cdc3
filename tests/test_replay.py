"""Sequence replay: contiguity, stored state, quantisation, wrap-around, masks, memory and validation."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

from ramavt_jax.replay import (
    ReplayConfig,
    SequenceBatch,
    Transition,
    chunk_to_storage,
    loss_mask,
    make_replay,
    memory_bytes,
)

N_ENVS, H, W, C = 3, 4, 5, 4
LAYERS, UNITS = 2, 3


@struct.dataclass
class FakeLSTMState:
    h: jax.Array  # [layers, B, units] (network layout)
    c: jax.Array


def actor_state(env, g):
    """State the fake actor has *before* consuming obs g of env (network layout without the batch axis)."""
    env, g = np.asarray(env, np.float32), np.asarray(g, np.float32)
    layer = np.arange(LAYERS, dtype=np.float32)[:, None]
    unit = np.arange(UNITS, dtype=np.float32)[None, :]
    h = env[..., None, None] * 1000.0 + g[..., None, None] + 0.25 * layer + 0.0625 * unit  # [..., layers, units]
    return h, -h


def noise(env, g):
    """A deterministic float in [0, 1) per (env, step, pixel) to measure the quantisation error."""
    idx = np.arange(H * W, dtype=np.float64).reshape(H, W)
    return np.mod(np.sin(env * 12.9898 + g * 78.233 + idx * 3.7) * 43758.5453, 1.0)


def episode_flags(env, g):
    """Next-step autoreset episodes of length 4 + env transitions (5 + env stored steps, the last one the final
    obs).  Episodes end alternately by termination and truncation."""
    period = 5 + env
    k = g % period
    ep = g // period
    is_first = k == 0
    ends = k == period - 2  # transition into the final obs
    terminated = ends & (ep % 2 == 0)
    truncated = ends & (ep % 2 == 1)
    return is_first, terminated, truncated


def make_chunk(g0, t_chunk):
    """Time-major chunk as an acting scan would stack it: leaves [T, N, ...], state [T, layers, N, units]."""
    g = np.arange(g0, g0 + t_chunk)[:, None] * np.ones((1, N_ENVS), int)  # [T, N]
    env = np.ones((t_chunk, 1), int) * np.arange(N_ENVS)[None, :]
    obs = np.zeros((t_chunk, N_ENVS, H, W, C), np.float32)
    obs[..., 0] = (env / 255.0)[..., None, None]
    obs[..., 1] = ((g % 256) / 255.0)[..., None, None]
    obs[..., 2] = ((g // 256) / 255.0)[..., None, None]
    obs[..., 3] = noise(env[..., None, None], g[..., None, None])
    is_first, terminated, truncated = episode_flags(env, g)
    h, c = actor_state(env, g)  # [T, N, layers, units]
    state = FakeLSTMState(h=jnp.asarray(np.moveaxis(h, 1, 2)), c=jnp.asarray(np.moveaxis(c, 1, 2)))
    return Transition(
        obs=jnp.asarray(obs),
        action=jnp.asarray((g + env) % 11, jnp.int32),
        reward=jnp.asarray(env * 1000.0 + g, jnp.float32),
        terminated=jnp.asarray(terminated),
        truncated=jnp.asarray(truncated),
        is_first=jnp.asarray(is_first),
        recurrent_state=state,
    )


EXAMPLE = Transition(
    obs=jnp.zeros((H, W, C), jnp.float32),
    action=jnp.zeros((), jnp.int32),
    reward=jnp.zeros((), jnp.float32),
    terminated=jnp.zeros((), bool),
    truncated=jnp.zeros((), bool),
    is_first=jnp.zeros((), bool),
    recurrent_state=FakeLSTMState(h=jnp.zeros((LAYERS, UNITS)), c=jnp.zeros((LAYERS, UNITS))),
)


def fill(replay, state, num_chunks, t_chunk):
    for i in range(num_chunks):  # eager: per-op compilation is shared between tests, faster than jit here
        state = replay.add(state, chunk_to_storage(make_chunk(i * t_chunk, t_chunk)))
    return state


def decode(batch):
    obs = np.asarray(batch.obs)
    env = np.rint(obs[..., 0, 0, 0] * 255).astype(int)  # [B, L]
    g = np.rint(obs[..., 0, 0, 1] * 255).astype(int) + 256 * np.rint(obs[..., 0, 0, 2] * 255).astype(int)
    return env, g


def sample_many(replay, state, n_keys=20):
    """Several samples joined along B (axis 0, except axis 1 of the start state, which is in network layout)."""
    keys = jax.random.split(jax.random.key(0), n_keys)
    batches = [replay.sample(state, k) for k in keys]
    joined = jax.tree.map(lambda *x: np.concatenate(x), *[b.replace(start_state=None) for b in batches])
    start = jax.tree.map(lambda *x: np.concatenate(x, axis=1), *[b.start_state for b in batches])
    return joined.replace(start_state=start)


@pytest.fixture(scope="module")
def filled():
    cfg = ReplayConfig(capacity_steps=N_ENVS * 400, burn_in=0, train_len=8, period=1, batch_size=32)
    replay = make_replay(cfg, N_ENVS, EXAMPLE)
    state = fill(replay, replay.init(), num_chunks=6, t_chunk=20)  # 120 steps per env, no wrap
    return replay, state, sample_many(replay, state)


def test_sequences_contiguous_single_env(filled):
    replay, state, batch = filled
    env, g = decode(batch)
    L = replay.config.sequence_length
    assert env.shape == (20 * 32, L) and batch.obs.dtype == jnp.float32
    assert (env == env[:, :1]).all(), "a window mixes envs"
    np.testing.assert_array_equal(g, g[:, :1] + np.arange(L)[None, :])
    assert g.min() >= 0 and g.max() <= 119
    assert len(np.unique(env[:, 0])) == N_ENVS  # all envs get sampled
    # every field belongs to the same (env, step); transitions are the window's first L-1 steps
    np.testing.assert_array_equal(batch.reward, (env * 1000.0 + g)[:, :-1])
    np.testing.assert_array_equal(batch.action, ((g + env) % 11)[:, :-1])
    is_first, terminated, truncated = episode_flags(env, g)
    np.testing.assert_array_equal(batch.reset, is_first)
    np.testing.assert_array_equal(batch.terminated, terminated[:, :-1])
    np.testing.assert_array_equal(batch.truncated, truncated[:, :-1])
    np.testing.assert_array_equal(batch.loss_mask, ~is_first[:, 1:])  # burn_in 0: only episode crossings masked
    assert batch.terminated.any() and batch.truncated.any() and batch.reset.any()


def test_stored_state_matches_actor(filled):
    _, state, batch = filled
    env, g = decode(batch)
    h, c = actor_state(env[:, 0], g[:, 0])  # [B, layers, units]
    s0 = batch.start_state  # network layout [layers, B, units]
    assert isinstance(s0, FakeLSTMState)  # the stored pytree type comes back
    np.testing.assert_array_equal(s0.h, np.moveaxis(h, 0, 1))
    np.testing.assert_array_equal(s0.c, np.moveaxis(c, 0, 1))
    assert s0.h.dtype == jnp.float32
    h_all, _ = actor_state(np.arange(N_ENVS)[:, None], np.arange(120)[None, :])  # every stored step [N, T, l, u]
    np.testing.assert_array_equal(state.experience.recurrent_state.h[:, :120], h_all)


def test_sample_is_a_typed_sequence_batch():
    burn_in, L, B = 3, 7, 16
    cfg = ReplayConfig(capacity_steps=N_ENVS * 32, burn_in=burn_in, train_len=L - 1 - burn_in, batch_size=B)
    replay = make_replay(cfg, N_ENVS, EXAMPLE)
    state = fill(replay, replay.init(), num_chunks=2, t_chunk=12)
    batch = jax.jit(replay.sample)(state, jax.random.key(2))
    assert isinstance(batch, SequenceBatch) and batch.burn_in == burn_in
    assert batch.obs.shape == (B, L, H, W, C) and batch.obs.dtype == jnp.float32
    assert batch.reset.shape == (B, L) and batch.reset.dtype == jnp.bool_
    for x, dtype in (
        (batch.action, jnp.int32),
        (batch.reward, jnp.float32),
        (batch.terminated, jnp.bool_),
        (batch.truncated, jnp.bool_),
        (batch.loss_mask, jnp.bool_),
    ):
        assert x.shape == (B, L - 1) and x.dtype == dtype
    assert batch.start_state.h.shape == batch.start_state.c.shape == (LAYERS, B, UNITS)
    assert not batch.loss_mask[:, :burn_in].any() and batch.loss_mask[:, burn_in:].any()
    np.testing.assert_array_equal(batch.loss_mask, loss_mask(batch.reset, burn_in))


def test_privileged_state_travels_with_its_observation():
    """Transition.privileged (per-step simulator state for auxiliary losses) comes back beside its own obs."""
    cfg = ReplayConfig(capacity_steps=N_ENVS * 40, burn_in=0, train_len=5, batch_size=8)
    replay = make_replay(cfg, N_ENVS, EXAMPLE.replace(privileged=jnp.zeros((3,))))
    state = replay.init()
    for i in range(2):
        chunk = make_chunk(i * 15, 15)
        env, g = np.broadcast_arrays(np.arange(N_ENVS)[None, :], np.arange(i * 15, i * 15 + 15)[:, None])
        label = jnp.asarray(np.stack([env, g, 0.5 + 0 * g], -1), jnp.float32)  # [T, N, 3]
        state = replay.add(state, chunk_to_storage(chunk.replace(privileged=label)))
    batch = replay.sample(state, jax.random.key(3))
    env, g = decode(batch)
    assert batch.privileged.shape == (8, cfg.sequence_length, 3)
    np.testing.assert_array_equal(batch.privileged, np.stack([env, g, 0.5 + 0 * g], -1))


def test_uint8_round_trip(filled):
    _, _, batch = filled
    env, g = decode(batch)
    expected = noise(env[..., None, None], g[..., None, None])
    err = np.abs(np.asarray(batch.obs[..., 3]) - expected)
    assert err.max() <= 0.5 / 255 + 1e-6
    assert err.max() > 0  # it really is quantised


def test_capacity_wraps_oldest_dropped():
    per_env = 20
    cfg = ReplayConfig(capacity_steps=N_ENVS * per_env, burn_in=0, train_len=4, period=1, batch_size=32)
    replay = make_replay(cfg, N_ENVS, EXAMPLE)
    state = replay.init()
    assert not bool(replay.can_sample(state))
    state = fill(replay, state, num_chunks=1, t_chunk=3)
    assert not bool(replay.can_sample(state))  # 3 < sequence_length steps per env
    state = fill(replay, replay.init(), num_chunks=7, t_chunk=8)  # 56 steps per env, keeps the last 20: 36..55
    assert bool(replay.can_sample(state)) and bool(state.is_full) and int(state.current_index) == 56 % per_env
    assert int(replay.size(state)) == N_ENVS * per_env
    stored_env, stored_g = decode(state.experience.replace(obs=replay_obs(state)))
    assert sorted(stored_g[0].tolist()) == list(range(36, 56))
    batch = sample_many(replay, state, n_keys=40)
    env, g = decode(batch)
    np.testing.assert_array_equal(g, g[:, :1] + np.arange(5)[None, :])  # never crosses the write head
    assert (env == env[:, :1]).all()
    assert g.min() == 36 and g.max() == 55  # oldest dropped, newest present
    assert set(g[:, 0].tolist()) == set(range(36, 52))  # every admissible start (period 1) is drawn
    h, _ = actor_state(env[:, 0], g[:, 0])
    np.testing.assert_array_equal(batch.start_state.h, np.moveaxis(h, 0, 1))


def replay_obs(state):
    return state.experience.obs.astype(jnp.float32) / 255.0


def test_add_and_sample_inside_scan():
    cfg = ReplayConfig(capacity_steps=N_ENVS * 32, burn_in=0, train_len=5, period=2, batch_size=8)
    replay = make_replay(cfg, N_ENVS, EXAMPLE)
    chunks = [chunk_to_storage(make_chunk(i * 4, 4)) for i in range(10)]
    stacked = jax.tree.map(lambda *x: jnp.stack(x), *chunks)

    @jax.jit
    def run(state, key):
        def body(state, xs):
            chunk, k = xs
            state = replay.add(state, chunk)
            batch = replay.sample(state, k)
            return state, (replay.can_sample(state), decode_jnp(batch))

        return jax.lax.scan(body, state, (stacked, jax.random.split(key, 10)))

    state, (can, g) = run(replay.init(), jax.random.key(1))
    assert not bool(can[0]) and bool(can[1]) and bool(can[-1])  # 4 < 6 steps, then 8 >= 6
    g = np.asarray(g)[1:]
    np.testing.assert_array_equal(g, g[..., :1] + np.arange(6))
    last = g[-1]  # buffer holds 8 (40 - 32) .. 39; starts on the period-2 grid from the oldest step
    assert last.min() >= 8 and last.max() <= 39 and ((last[:, 0] - 8) % 2 == 0).all()


def decode_jnp(batch):
    obs = batch.obs
    return jnp.rint(obs[..., 0, 0, 1] * 255).astype(int) + 256 * jnp.rint(obs[..., 0, 0, 2] * 255).astype(int)


@pytest.mark.parametrize("obs_dtype, state_dtype, tol", [("float16", "bfloat16", 1e-3), ("float32", "float32", 0.0)])
def test_other_storage_dtypes(obs_dtype, state_dtype, tol):
    cfg = ReplayConfig(
        capacity_steps=N_ENVS * 16, burn_in=0, train_len=3, batch_size=32, obs_dtype=obs_dtype, state_dtype=state_dtype
    )
    replay = make_replay(cfg, N_ENVS, EXAMPLE)
    state = replay.init()
    assert state.experience.obs.dtype == jnp.dtype(obs_dtype)
    state = fill(replay, state, 2, 8)
    batch = replay.sample(state, jax.random.key(0))
    chunk = make_chunk(0, 16)
    env = np.rint(np.asarray(batch.obs[..., 0, 0, 0]) * 255).astype(int)
    g = np.rint(np.asarray(batch.obs[..., 0, 0, 1]) * 255).astype(int)
    ref = np.asarray(chunk.obs)[g, env]
    assert batch.obs.dtype == jnp.float32 and batch.start_state.h.dtype == jnp.float32
    assert np.abs(np.asarray(batch.obs) - ref).max() <= tol


def test_memory_bytes():
    # 50,000 steps of 64x64x4 uint8 RGBD: per step 16384 (obs) + 4 (int32 action) + 4 (f32 reward)
    # + 3 (bool flags) + state; the flashbax index (int32) and is_full (bool) add 5 bytes.
    cfg = ReplayConfig(capacity_steps=50_000, burn_in=0, train_len=12)
    no_state = memory_bytes(cfg, 50, (64, 64, 4), (0,))
    assert no_state == 50_000 * (16384 + 4 + 4 + 3) + 5 == 819_750_005
    # with the DESIGN network's 2-layer LSTM(512): c and h, [2, 512] float32 each = 8192 bytes per step
    lstm = memory_bytes(cfg, 50, (64, 64, 4), [(2, 512), (2, 512)])
    assert lstm == 50_000 * (16384 + 4 + 4 + 3 + 8192) + 5 == 1_229_350_005
    # pytree form, bfloat16 state halves that part
    tree = FakeLSTMState(h=jax.ShapeDtypeStruct((2, 512), jnp.float32), c=jax.ShapeDtypeStruct((2, 512), jnp.float32))
    cfg16 = ReplayConfig(capacity_steps=50_000, burn_in=0, train_len=12, state_dtype="bfloat16")
    assert memory_bytes(cfg16, 50, (64, 64, 4), tree) == 50_000 * (16384 + 11 + 4096) + 5
    # the small net of the CPU presets (1-layer LSTM 128) at 32x32 depth
    assert memory_bytes(cfg, 50, (32, 32, 1), [(1, 128), (1, 128)]) == 50_000 * (1024 + 11 + 1024) + 5


def test_loss_mask_around_episode_boundary():
    is_first = jnp.array(
        [
            [False, False, False, True, False, False],  # a new episode starts at obs 3
            [True, False, False, False, False, False],  # window starts on a first obs
        ]
    )
    # loss_mask[t]: t >= 2 and obs t+1 is not first. Row 0: transition 2 (obs 2 -> obs 3) crosses -> masked.
    np.testing.assert_array_equal(
        loss_mask(is_first, burn_in=2), [[False, False, False, True, True], [False, False, True, True, True]]
    )
    np.testing.assert_array_equal(loss_mask(is_first, burn_in=0), [[True, True, False, True, True], [True] * 5])
    with pytest.raises(ValueError, match="burn_in"):
        loss_mask(is_first, burn_in=5)


@pytest.mark.parametrize(
    "kwargs, num_envs, match",
    [
        (dict(capacity_steps=50_000), 64, "divisible by num_envs"),
        (dict(capacity_steps=60, burn_in=0, train_len=30), 3, "fewer than sequence_length"),
        (dict(train_len=0), 1, "train_len must be >= 1"),
        (dict(period=0), 1, "period"),
        (dict(burn_in=0, train_len=9, period=11), 1, "period"),
        (dict(batch_size=0), 1, "batch_size"),
        (dict(burn_in=-1), 1, "burn_in"),
        (dict(obs_dtype="int8"), 1, "obs_dtype"),
        (dict(state_dtype="float64"), 1, "state_dtype"),
        (dict(capacity_steps=-5), 1, "capacity_steps"),
        (dict(capacity_steps=100, min_fill_steps=200), 1, "min_fill_steps"),
    ],
)
def test_bad_config(kwargs, num_envs, match):
    with pytest.raises(ValueError, match=match):
        make_replay(ReplayConfig(**kwargs), num_envs, EXAMPLE)


def test_bad_add():
    replay = make_replay(ReplayConfig(capacity_steps=N_ENVS * 16, burn_in=0, train_len=3), N_ENVS, EXAMPLE)
    state = replay.init()
    with pytest.raises(ValueError, match="envs"):
        replay.add(state, jax.tree.map(lambda x: x[:2], chunk_to_storage(make_chunk(0, 4))))
    with pytest.raises(ValueError, match="longer"):
        replay.add(state, chunk_to_storage(make_chunk(0, 17)))


def test_min_fill_steps():
    cfg = ReplayConfig(capacity_steps=N_ENVS * 40, burn_in=0, train_len=3, min_fill_steps=N_ENVS * 10)
    replay = make_replay(cfg, N_ENVS, EXAMPLE)
    assert not bool(replay.can_sample(fill(replay, replay.init(), 1, 8)))  # 8 < 10 per env
    assert bool(replay.can_sample(fill(replay, replay.init(), 2, 8)))


# ------------------------------------------------------------------------------------------- prioritised sequences
def _prioritised(**kw):
    """A prioritised buffer of 3 envs x 60 steps holding 40 steps per env (windows of 6 steps)."""
    cfg = ReplayConfig(
        capacity_steps=N_ENVS * 60, burn_in=0, train_len=5, period=1, batch_size=64, priority_exponent=0.9, **kw
    )
    replay = make_replay(cfg, N_ENVS, EXAMPLE)
    return replay, fill(replay, replay.init(), num_chunks=2, t_chunk=20)  # 40 steps per env, no wrap


def test_uniform_sampling_has_no_priorities(filled):
    replay, state, batch = filled
    assert batch.indices is None and batch.weights is None
    assert replay.sampling_state(state) is None
    assert replay.set_priorities(state, batch, jnp.ones(2)) is state


@pytest.mark.slow
def test_prioritised_windows_are_contiguous_and_start_equally_likely():
    """New windows get the same (largest) priority, so the first samples are uniform over the admissible starts,
    with weights of 1, and every window is still consecutive steps of one env."""
    replay, state = _prioritised()
    batch = replay.sample(state, jax.random.key(1))
    env, g = decode(batch)
    assert np.all(np.diff(g, axis=1) == 1) and np.all(env == env[:, :1])
    np.testing.assert_allclose(np.asarray(batch.weights), 1.0, rtol=1e-5)
    assert batch.indices.shape == (64,)


@pytest.mark.slow
def test_set_priorities_steer_sampling_and_weights():
    from flashbax.buffers import sum_tree

    """A window given 100x the others' priority is drawn about 100 ** 0.9 times as often as each of them, and its
    importance weight is (P_hot / P_other) ** -beta of theirs (theirs is the batch's largest, 1)."""
    replay, state = _prioritised(importance_exponent=0.6)
    first = replay.sample(state, jax.random.key(2))
    items = np.unique(np.asarray(first.indices))
    hot = int(items[0])
    prios = np.where(items == hot, 100.0, 1.0)
    picked = first.replace(indices=jnp.asarray(items), weights=jnp.ones(len(items)))
    state = replay.set_priorities(state, picked, jnp.asarray(prios, jnp.float32))
    stored = np.asarray(jax.vmap(lambda i: sum_tree.get(state.sum_tree_state, i))(jnp.asarray(items)))
    np.testing.assert_allclose(stored, prios**0.9, rtol=1e-5)  # flashbax raises them to the exponent, once
    draws = np.concatenate(
        [np.asarray(replay.sample(state, k).indices) for k in jax.random.split(jax.random.key(3), 40)]
    )
    share = np.mean(draws == hot)
    others = np.mean(draws == items[1])
    assert share > 20 * max(others, 1 / len(draws)), (share, others)
    batch = replay.sample(state, jax.random.key(4))
    idx, w = np.asarray(batch.indices), np.asarray(batch.weights)
    assert (idx == hot).any() and (idx != hot).any()  # a third of the draws are the hot window
    np.testing.assert_allclose(w[idx == hot], (100.0**0.9) ** -0.6, rtol=1e-4)  # the others' weight is 1
    np.testing.assert_allclose(w[idx != hot], 1.0, rtol=1e-5)


def test_sequence_priority_mixes_max_and_mean():
    from ramavt_jax.losses import sequence_priority

    td = jnp.asarray([[1.0, -3.0, 2.0, 10.0], [0.5, 0.5, -0.5, 0.0], [4.0, 4.0, 4.0, 4.0]])
    mask = jnp.asarray([[1, 1, 1, 0], [1, 1, 1, 1], [0, 0, 0, 0]], bool)
    got = np.asarray(sequence_priority(td, mask, 0.9))
    np.testing.assert_allclose(got, [0.9 * 3 + 0.1 * 2.0, 0.9 * 0.5 + 0.1 * 0.375, 0.0], rtol=1e-6)


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(priority_exponent=1.5),
        dict(importance_exponent=-0.1),
        dict(priority_max_share=2.0),
        dict(priority_exponent=True),
    ],
)
def test_bad_priority_config(kwargs):
    name = next(iter(kwargs))
    with pytest.raises(ValueError, match=f"ReplayConfig.{name} must be a number in \\[0, 1\\]"):
        ReplayConfig(**kwargs)


def test_windows_of_priority_zero_get_weight_zero_and_stay_at_zero():
    """A draw that lands on a window of priority 0 (the float32 sum tree's drift; flashbax issue 52) must not train
    (weight 0; the others' largest weight stays 1) nor become drawable (set_priorities leaves it at 0)."""
    import dataclasses

    from flashbax.buffers import sum_tree

    replay, state = _prioritised()

    class DriftedBuffer:  # the real buffer, whose sampled first window comes back with probability 0
        def __getattr__(self, name):
            return getattr(replay.buffer, name)

        def sample(self, state, key):
            out = replay.buffer.sample(state, key)
            return out.replace(probabilities=out.probabilities.at[0].set(0.0))

    drifted = dataclasses.replace(replay, buffer=DriftedBuffer())
    batch = drifted.sample(state, jax.random.key(5))
    lone = int(batch.indices[0])
    assert float(batch.weights[0]) == 0.0 and float(jnp.max(batch.weights)) == pytest.approx(1.0)
    zeroed = replay.buffer.set_priorities(state, batch.indices[:1], jnp.zeros(1))  # as the drifted tree had it
    assert float(sum_tree.get(zeroed.sum_tree_state, lone)) == 0.0
    others = batch.indices != lone
    after = replay.set_priorities(
        zeroed, batch.replace(weights=jnp.where(others, batch.weights, 0.0)), jnp.full(batch.indices.shape, 3.0)
    )
    assert float(sum_tree.get(after.sum_tree_state, lone)) == 0.0
    assert float(sum_tree.get(after.sum_tree_state, int(batch.indices[others][0]))) == pytest.approx(3.0**0.9)
