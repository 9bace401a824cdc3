"""Quantile (distributional) values, QR-DQN style: the loss's fixed point, its targets against the expected-value
loss, the network's head, and the trainer's use of both (NetworkConfig.quantiles)."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from ramavt_jax import losses, presets
from ramavt_jax import train as T
from ramavt_jax.network import NetworkConfig, init_params, initial_state, make_network

SMOKE = presets.preset("smoke")
QCFG = SMOKE.override(network=dataclasses.replace(SMOKE.network, quantiles=8))


def test_quantile_huber_is_minimised_at_the_quantiles():
    """Minimising the summed quantile Huber loss (small kappa) over N free values puts value i at the
    (2i + 1) / 2N quantile of the samples."""
    samples = jax.random.gamma(jax.random.PRNGKey(0), 2.0, (4000,))  # skewed, so mean-based answers fail
    n = 5
    taus = (jnp.arange(n) + 0.5) / n
    loss = lambda th: losses.quantile_huber(samples[None, :] - th[:, None], taus, 0.01).mean(-1).sum()  # noqa
    opt = optax.adam(0.05)

    @jax.jit
    def fit(theta):
        def step(carry, _):
            th, st = carry
            upd, st = opt.update(jax.grad(loss)(th), st)
            return (optax.apply_updates(th, upd), st), None

        return jax.lax.scan(step, (theta, opt.init(theta)), None, length=1500)[0][0]

    theta = fit(jnp.full((n,), float(samples.mean())))
    np.testing.assert_allclose(np.asarray(theta), np.quantile(np.asarray(samples), np.asarray(taus)), atol=0.05)


def _window_values(key, b=3, t=6, a=4):
    ks = jax.random.split(key, 6)
    q_online, q_target = jax.random.normal(ks[0], (b, t + 1, a)), jax.random.normal(ks[1], (b, t + 1, a))
    actions = jax.random.randint(ks[2], (b, t), 0, a)
    rewards = jax.random.normal(ks[3], (b, t))
    terminated = jax.random.uniform(ks[4], (b, t)) < 0.15
    truncated = (jax.random.uniform(ks[5], (b, t)) < 0.15) & ~terminated
    return q_online, q_target, actions, rewards, terminated, truncated


@pytest.mark.parametrize("double_q", [True, False])
def test_quantile_targets_average_to_the_expected_value_targets(double_q):
    """Quantiles spread symmetrically about the expected-value network's Q: their n-step targets average to
    sequence_td_loss's targets (the n-step return is linear), and so do the logged Q and TD error."""
    q_online, q_target, actions, rewards, terminated, truncated = _window_values(jax.random.PRNGKey(1))
    spread = jnp.linspace(-1.0, 1.0, 6)  # mean zero
    z_online, z_target = q_online[..., None] + spread, q_target[..., None] + 0.5 * spread
    mask = jnp.ones(actions.shape, bool)
    cfg = losses.TDConfig(gamma=0.9, n_step=3, double_q=double_q)
    _, expected = losses.sequence_td_loss(q_online, q_target, actions, rewards, terminated, truncated, mask, cfg)
    loss, got = losses.sequence_quantile_loss(z_online, z_target, actions, rewards, terminated, truncated, mask, cfg)
    for name in ("target", "q_taken", "td_error"):
        np.testing.assert_allclose(np.asarray(got[name]), np.asarray(expected[name]), atol=1e-5)
    assert np.isfinite(float(loss)) and float(loss) > 0
    # the dispatch by the targets' rank
    batch = losses.TDBatch(
        q_target=z_target, action=actions, reward=rewards, terminated=terminated, truncated=truncated, mask=mask
    )
    np.testing.assert_allclose(float(losses.td_loss(z_online, batch, cfg)[0]), float(loss), rtol=1e-6)


def test_masked_transitions_do_not_count():
    q_online, q_target, actions, rewards, terminated, truncated = _window_values(jax.random.PRNGKey(2))
    z_online, z_target = q_online[..., None] + jnp.arange(4.0), q_target[..., None] + jnp.arange(4.0)
    cfg = losses.TDConfig(gamma=0.9, n_step=2)
    mask = jnp.zeros(actions.shape, bool).at[:, 2].set(True)
    grad = jax.grad(
        lambda z: losses.sequence_quantile_loss(z, z_target, actions, rewards, terminated, truncated, mask, cfg)[0]
    )(z_online)
    moved = np.abs(np.asarray(grad)).sum(axis=(2, 3))  # [B, T+1]
    assert (moved[:, 2] > 0).all() and moved[:, [0, 1, 3, 4, 5, 6]].sum() == 0


def test_config_checks():
    with pytest.raises(ValueError, match="quantiles must be 0"):
        NetworkConfig(quantiles=1)
    with pytest.raises(ValueError, match="quantiles and dueling"):
        NetworkConfig(quantiles=8, dueling=True)
    with pytest.raises(ValueError, match="does not combine with learner.value_rescale"):
        QCFG.override(value_rescale=True)


def test_network_acts_on_the_mean_of_its_quantiles():
    net = make_network(QCFG.network)
    params = init_params(QCFG.network, jax.random.PRNGKey(0), QCFG.env.obs_shape)
    obs = jax.random.uniform(jax.random.PRNGKey(1), (2, 3, *QCFG.env.obs_shape))
    reset = jnp.zeros((2, 3), bool).at[:, 0].set(True)
    (q, _), sown = net.apply(params, obs, reset, initial_state(QCFG.network, 2), mutable=["intermediates"])
    z = sown["intermediates"]["quantiles"][0]
    assert z.shape == (2, 3, 11, 8) and q.shape == (2, 3, 11)
    np.testing.assert_allclose(np.asarray(q), np.asarray(z.mean(-1)), atol=1e-6)
    assert float(z.std(-1).mean()) > 0  # distinct quantiles from the start


@pytest.mark.slow  # a trainer of its own to compile (about 11 s); the quantile network and loss are tested above
def test_trainer_trains_a_quantile_network():
    """One iteration with updates: the target net's quantiles feed the loss, which is finite and moves the head."""
    cfg = QCFG.override(learning_starts=0)
    tr = T.Trainer(cfg)
    state = jax.jit(tr.init)(jax.random.PRNGKey(3))
    new, metrics = jax.jit(tr.iteration)(state)
    assert int(metrics.updates) > 0 and np.isfinite(float(metrics.loss_sum))
    moved = jnp.abs(new.learner.params["q"]["kernel"] - state.learner.params["q"]["kernel"]).sum()
    assert float(moved) > 0
    batch = tr.replay.sample(new.replay, jax.random.PRNGKey(4))
    prepared = tr.prepare(new.learner.params, new.learner.target_params, batch, jax.random.PRNGKey(5))
    assert prepared.td.q_target.shape == (cfg.replay.batch_size, cfg.replay.train_len + 1, 11, 8)


def test_the_threshold_is_the_configs_quantile_kappa():
    """LearnerConfig.quantile_kappa reaches the loss: far below the errors the loss is about their weighted mean
    magnitude, at a threshold far above them their weighted half-square over the threshold."""
    q_online, q_target, actions, rewards, terminated, truncated = _window_values(jax.random.PRNGKey(3))
    z_online, z_target = q_online[..., None] + jnp.arange(4.0), q_target[..., None] + jnp.arange(4.0)
    mask = jnp.ones(actions.shape, bool)
    loss = lambda kappa: float(
        losses.sequence_quantile_loss(  # noqa: E731
            z_online,
            z_target,
            actions,
            rewards,
            terminated,
            truncated,
            mask,
            QCFG.override(quantile_kappa=kappa).learner.td,
        )[0]
    )
    assert QCFG.learner.td.quantile_kappa == 0.05
    small, large = loss(1e-4), loss(1e3)
    assert 1e-4 < large < small * 1e-2  # quadratic over a huge threshold: tiny
    np.testing.assert_allclose(loss(2e-4), small, rtol=1e-3)  # linear regime: the threshold barely matters
