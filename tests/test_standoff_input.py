"""The stand-off scale k as a network input (NetworkConfig.standoff_input): validation, the network's use of it, and
its path from the env through the replay to the learner and the greedy policy."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ramavt_jax import greedy, presets
from ramavt_jax import replay as replay_lib
from ramavt_jax import train as T
from ramavt_jax.network import NetworkConfig, RecurrentState, init_params, initial_state, make_network

SMOKE = presets.preset("smoke")
CFG = SMOKE.override(
    network=dataclasses.replace(SMOKE.network, standoff_input=True),
    env_params=(("size_scale_min", 0.15), ("size_scale_max", 4.0), ("max_steps", 6)),
)


@pytest.fixture(scope="module")
def trainer():
    return T.Trainer(CFG)


@pytest.fixture(scope="module")
def params():
    return init_params(CFG.network, jax.random.PRNGKey(0), CFG.env.obs_shape)["params"]


def test_frame_stacking_variant_refuses_the_input():
    with pytest.raises(ValueError, match="need a recurrent variant"):
        NetworkConfig(variant="drlavt", standoff_input=True)


def test_network_reads_ln_k_and_refuses_a_missing_one(params):
    net, n = make_network(CFG.network), CFG.network
    obs = jax.random.uniform(jax.random.PRNGKey(1), (2, 3, *CFG.env.obs_shape))
    reset = jnp.zeros((2, 3), bool).at[:, 0].set(True)
    state = initial_state(n, 2)
    q = lambda k: net.apply({"params": params}, obs, reset, state, standoff=k)[0]  # noqa: E731
    assert float(jnp.abs(q(jnp.full((2, 3), 0.4)) - q(jnp.ones((2, 3)))).max()) > 1e-4
    for wrong in (None, jnp.ones((2,))):
        with pytest.raises(ValueError, match=r"needs standoff \[B, T\] = \(2, 3\)"):
            q(wrong)
    # without the flag the network has no weights for it and ignores it
    plain = dataclasses.replace(n, standoff_input=False)
    p0 = init_params(plain, jax.random.PRNGKey(0), CFG.env.obs_shape)["params"]
    assert jax.tree.map(jnp.shape, p0["lstm"]) != jax.tree.map(jnp.shape, params["lstm"])  # one input fewer
    plain_q = lambda k: make_network(plain).apply({"params": p0}, obs, reset, state, standoff=k)[0]  # noqa: E731
    np.testing.assert_array_equal(np.asarray(plain_q(None)), np.asarray(plain_q(jnp.full((2, 3), 0.4))))


def test_rollout_stores_each_steps_episode_scale(trainer):
    """The stored k of a step is its episode's: the actor's env scale at the chunk's start, constant within an
    episode, and drawn anew (size randomisation) at episode starts."""
    state = jax.jit(trainer.init)(jax.random.PRNGKey(4))
    actor, chunk, stats, _ = jax.jit(trainer.rollout)(
        state.learner.params, state.actor, jnp.int32(0), jax.random.PRNGKey(5)
    )
    k, first = np.asarray(chunk.standoff), np.asarray(chunk.is_first)  # [N, T]
    assert int(stats.episodes) > 0 and first[:, 1:].any()
    np.testing.assert_array_equal(k[:, 0], np.asarray(state.actor.env_state.scale))
    same_episode = ~first[:, 1:]
    np.testing.assert_array_equal(k[:, 1:][same_episode], k[:, :-1][same_episode])
    assert len(np.unique(k)) > 2 and (k < 1).any()
    example = trainer.replay.init()
    assert example.experience.standoff.dtype == jnp.float32  # stored beside the obs
    assert T.Trainer(SMOKE).replay.init().experience.standoff is None  # and only for networks that read it


def test_learner_feeds_the_windows_scale_to_every_pass(trainer, params):
    """The loss depends on the stored k, and the gradient reaches the LSTM weights that read ln k."""
    b, l = CFG.replay.batch_size, CFG.sequence_length
    n = CFG.network
    ks = jax.random.split(jax.random.PRNGKey(2), 4)
    window = replay_lib.Transition(
        obs=jax.random.uniform(ks[0], (b, l, *CFG.env.obs_shape)),
        action=jax.random.randint(ks[1], (b, l), 0, 11),
        reward=jax.random.normal(ks[2], (b, l)),
        terminated=jnp.zeros((b, l), bool),
        truncated=jnp.zeros((b, l), bool),
        is_first=jnp.zeros((b, l), bool),
        recurrent_state=RecurrentState(
            h=jnp.zeros((b, l, n.lstm_layers, n.lstm)), c=jnp.zeros((b, l, n.lstm_layers, n.lstm)), frames=None
        ),
        standoff=jax.random.uniform(ks[3], (b, 1), minval=0.3, maxval=4.0) * jnp.ones((b, l)),
    )
    batch = replay_lib.sequence_batch(window, CFG.replay.burn_in)
    loss = lambda p, w: trainer.loss(
        p,
        p,
        replay_lib.sequence_batch(w, CFG.replay.burn_in),  # noqa: E731
        jax.random.PRNGKey(0),
    )[0]
    ones = window.replace(standoff=jnp.ones((b, l)))
    assert abs(float(loss(params, window)) - float(loss(params, ones))) > 1e-6
    prepared = trainer.prepare(params, params, batch, jax.random.PRNGKey(0))
    assert prepared.standoff.shape == (b, CFG.replay.train_len + 1)
    grads = jax.grad(lambda p: trainer.trained_loss(p, prepared)[0])(params)
    assert float(sum(jnp.abs(g).sum() for g in jax.tree.leaves(grads["lstm"]))) > 0


def test_greedy_policy_reads_k_from_the_env_state(trainer, params):
    """The greedy policy acts as the network does with the episode's k given per step."""
    env_state = trainer.env.reset(jax.random.PRNGKey(3), trainer.env_params)[1].replace(scale=jnp.float32(0.4))
    policy = greedy.greedy_policy(CFG.network, params, CFG.env.obs_shape)
    obs = jax.random.uniform(jax.random.PRNGKey(8), (5, *CFG.env.obs_shape))
    ps, actions = policy.init(jax.random.PRNGKey(0)), []
    for t in range(5):
        a, ps = policy.act(jax.random.PRNGKey(t), ps, obs[t], env_state, trainer.env_params)
        actions.append(int(a))
    reset = jnp.zeros((1, 5), bool).at[0, 0].set(True)
    q, _ = trainer.q_values(params, obs[None], reset, initial_state(CFG.network, 1), standoff=jnp.full((1, 5), 0.4))
    assert actions == np.asarray(jnp.argmax(q[0], -1)).tolist()


def test_command_gain_is_how_far_a_command_moves_the_view_in_standoff_units(trainer):
    """env.command_gain: 1 / k for small targets, 1 for large ones under the default speed rule, k ** (p - 1) with
    the rule's power p; a command_gain_input network reads it (greedy.standoff_signal)."""
    from ramavt_jax import env as env_lib

    params = trainer.env_params
    state = trainer.env.reset(jax.random.PRNGKey(3), params)[1]
    gain = lambda k, p=params: float(env_lib.command_gain(state.replace(scale=jnp.float32(k)), p))  # noqa: E731
    np.testing.assert_allclose([gain(0.4), gain(1.0), gain(4.8)], [2.5, 1.0, 1.0], rtol=1e-6)
    np.testing.assert_allclose(gain(4.8, params.replace(speed_standoff_power=jnp.float32(0.0))), 1 / 4.8, rtol=1e-6)
    net = dataclasses.replace(CFG.network, standoff_input=False, command_gain_input=True)
    small = state.replace(scale=jnp.float32(0.4))
    assert float(greedy.standoff_signal(net, small, params)) == pytest.approx(2.5)
    assert float(greedy.standoff_signal(CFG.network, small, params)) == pytest.approx(0.4)
    assert greedy.standoff_signal(SMOKE.network, small, params) is None
    with pytest.raises(ValueError, match="two forms of one input"):
        dataclasses.replace(CFG.network, command_gain_input=True)


def test_rollout_stores_the_command_gain_for_a_command_gain_network():
    cfg = CFG.override(network=dataclasses.replace(CFG.network, standoff_input=False, command_gain_input=True))
    tr = T.Trainer(cfg)
    state = jax.jit(tr.init)(jax.random.PRNGKey(4))
    _, chunk, _, _ = jax.jit(tr.rollout)(state.learner.params, state.actor, jnp.int32(0), jax.random.PRNGKey(5))
    k0 = np.asarray(state.actor.env_state.scale)
    np.testing.assert_allclose(np.asarray(chunk.standoff)[:, 0], 1.0 / np.minimum(k0, 1.0), rtol=1e-6)
