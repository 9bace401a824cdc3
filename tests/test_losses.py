"""Losses against numbers worked out by hand (written out in each test)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ramavt_jax.losses import (
    PRIORITY_KEY,
    LossBatch,
    TDConfig,
    aux_term,
    n_step_targets,
    sequence_td_loss,
    sequence_td_targets,
    td_term,
)


def _loss(jit, q_online, q_target, actions, rewards, terminated, truncated, mask, cfg):
    fn = jax.jit(sequence_td_loss) if jit else sequence_td_loss
    args = [jnp.asarray(a) for a in (q_online, q_target, actions, rewards, terminated, truncated, mask)]
    return fn(*args, cfg)


# Shared tiny batch: B=1, T=2 transitions, 3 observations, A=2.
Q_ONLINE = np.array([[[1.0, 2.0], [4.0, 3.0], [5.0, 0.0]]], np.float32)  # [1, 3, 2]
Q_TARGET = np.array([[[0.0, 0.0], [1.0, 5.0], [2.0, 7.0]]], np.float32)  # [1, 3, 2]
ACTIONS = np.array([[0, 1]], np.int32)
REWARDS = np.array([[1.0, -1.0]], np.float32)
FALSE2 = np.zeros((1, 2), bool)
ONES2 = np.ones((1, 2), np.float32)


@pytest.mark.parametrize("jit", [False, True])
def test_one_step_mse_plain_max(jit):
    # q_taken = [Q_on(obs0)[0], Q_on(obs1)[1]] = [1, 3]
    # targets = r + 0.5 * max Q_tg(obs t+1) = [1 + 0.5*5, -1 + 0.5*7] = [3.5, 2.5]
    # td = [2.5, -0.5]; loss = mean(0.5 td^2) = 0.5 * (6.25 + 0.25) / 2 = 1.625
    cfg = TDConfig(gamma=0.5, n_step=1, double_q=False)
    loss, aux = _loss(jit, Q_ONLINE, Q_TARGET, ACTIONS, REWARDS, FALSE2, FALSE2, ONES2, cfg)
    np.testing.assert_allclose(aux["q_taken"], [[1.0, 3.0]])
    np.testing.assert_allclose(aux["target"], [[3.5, 2.5]])
    np.testing.assert_allclose(aux["td_error"], [[2.5, -0.5]])
    np.testing.assert_allclose(loss, 1.625, rtol=1e-6)


@pytest.mark.parametrize("jit", [False, True])
def test_double_q(jit):
    # argmax_a Q_on(obs1) = 0 (4 > 3), argmax_a Q_on(obs2) = 0 (5 > 0)
    # values from the target net: Q_tg(obs1)[0] = 1, Q_tg(obs2)[0] = 2 (plain max would take 5 and 7)
    # targets = [1 + 0.5*1, -1 + 0.5*2] = [1.5, 0.0]; td = [0.5, -3]; loss = 0.5 * (0.25 + 9) / 2 = 2.3125
    cfg = TDConfig(gamma=0.5, n_step=1, double_q=True)
    loss, aux = _loss(jit, Q_ONLINE, Q_TARGET, ACTIONS, REWARDS, FALSE2, FALSE2, ONES2, cfg)
    np.testing.assert_allclose(aux["target"], [[1.5, 0.0]])
    np.testing.assert_allclose(loss, 2.3125, rtol=1e-6)


def test_mask_zeroes_transitions():
    # plain max, td = [2.5, -0.5]; mask [1, 0] -> loss = 0.5 * 6.25 / 1 = 3.125
    cfg = TDConfig(gamma=0.5, double_q=False)
    loss, _ = _loss(False, Q_ONLINE, Q_TARGET, ACTIONS, REWARDS, FALSE2, FALSE2, np.array([[1.0, 0.0]]), cfg)
    np.testing.assert_allclose(loss, 3.125, rtol=1e-6)
    loss, _ = _loss(False, Q_ONLINE, Q_TARGET, ACTIONS, REWARDS, FALSE2, FALSE2, np.zeros((1, 2)), cfg)
    assert float(loss) == 0.0
    # masked transition gets no gradient
    grad = jax.grad(
        lambda q: sequence_td_loss(
            q, jnp.asarray(Q_TARGET), ACTIONS, REWARDS, FALSE2, FALSE2, jnp.array([[1.0, 0.0]]), cfg
        )[0]
    )(jnp.asarray(Q_ONLINE))
    np.testing.assert_allclose(grad, [[[-2.5, 0.0], [0.0, 0.0], [0.0, 0.0]]])


def test_gradients_only_through_q_online_taken_actions():
    # double-Q case, td = [0.5, -3], loss = sum(0.5 td^2) / 2 -> dL/dq_taken = -td / 2 = [-0.25, 1.5]
    cfg = TDConfig(gamma=0.5, double_q=True)

    def f(q_on, q_tg):
        return sequence_td_loss(q_on, q_tg, ACTIONS, REWARDS, FALSE2, FALSE2, ONES2, cfg)[0]

    g_on, g_tg = jax.grad(f, argnums=(0, 1))(jnp.asarray(Q_ONLINE), jnp.asarray(Q_TARGET))
    np.testing.assert_allclose(g_on, [[[-0.25, 0.0], [0.0, 1.5], [0.0, 0.0]]], rtol=1e-6)
    np.testing.assert_array_equal(g_tg, np.zeros_like(Q_TARGET))


def test_n_step_targets_terminal_in_middle():
    # T=5, n=3, gamma 0.5, terminal at t=2 -> discounts d = [0.5, 0.5, 0, 0.5, 0.5], q_boot = [10..50]
    # G0 = 1 + 0.5*2 + 0.25*3 + 0.25*0*30      = 2.75   (stops at the terminal t=2)
    # G1 = 2 + 0.5*3 + 0.5*0*30                 = 3.5
    # G2 = 3 + 0*30                             = 3
    # G3 = 4 + 0.5*5 + 0.25*50                  = 19     (window end: bootstrap from the last value)
    # G4 = 5 + 0.5*50                           = 30
    r = jnp.array([1.0, 2.0, 3.0, 4.0, 5.0])
    d = jnp.array([0.5, 0.5, 0.0, 0.5, 0.5])
    v = jnp.array([10.0, 20.0, 30.0, 40.0, 50.0])
    expected = [2.75, 3.5, 3.0, 19.0, 30.0]
    np.testing.assert_allclose(n_step_targets(r, d, v, 3), expected)
    stop = jnp.array([False, False, True, False, False])
    np.testing.assert_allclose(jax.jit(n_step_targets, static_argnums=3)(r, d, v, 3, stop), expected)
    # n = 1 is one-step: r + d v = [6, 12, 3, 24, 30]
    np.testing.assert_allclose(n_step_targets(r, d, v, 1), [6.0, 12.0, 3.0, 24.0, 30.0])


def test_n_step_loss_terminal_in_middle():
    # Same numbers through the loss with A = 1 (so max/argmax is trivial): Q_tg(obs t+1) = q_boot[t]
    q_target = np.array([[[0.0], [10.0], [20.0], [30.0], [40.0], [50.0]]], np.float32)
    q_online = np.zeros((1, 6, 1), np.float32)
    terminated = np.array([[False, False, True, False, False]])
    cfg = TDConfig(gamma=0.5, n_step=3, double_q=True)
    loss, aux = _loss(
        True,
        q_online,
        q_target,
        np.zeros((1, 5), np.int32),
        np.array([[1.0, 2, 3, 4, 5]]),
        terminated,
        np.zeros((1, 5), bool),
        np.ones((1, 5)),
        cfg,
    )
    np.testing.assert_allclose(aux["target"], [[2.75, 3.5, 3.0, 19.0, 30.0]], rtol=1e-6)
    # loss = mean(0.5 * target^2) since q_taken = 0
    expected = 0.5 * (2.75**2 + 3.5**2 + 9 + 19**2 + 30**2) / 5
    np.testing.assert_allclose(loss, expected, rtol=1e-6)


@pytest.mark.parametrize("jit", [False, True])
def test_truncation_bootstraps_from_next_obs(jit):
    # T=2, gamma 0.9, plain max. Q_tg(obs1) = [3, 7], Q_tg(obs2) = [100, 0]; rewards [1, 2]
    q_target = np.array([[[0.0, 0.0], [3.0, 7.0], [100.0, 0.0]]], np.float32)
    q_online = np.zeros((1, 3, 2), np.float32)
    a, r = np.zeros((1, 2), np.int32), np.array([[1.0, 2.0]], np.float32)
    truncated = np.array([[True, False]])
    # truncated at t=0: target0 = 1 + 0.9 * 7 = 7.3 (bootstrap from obs1, the final obs); target1 = 2 + 0.9*100
    cfg1 = TDConfig(gamma=0.9, n_step=1, double_q=False)
    _, aux = _loss(jit, q_online, q_target, a, r, FALSE2, truncated, ONES2, cfg1)
    np.testing.assert_allclose(aux["target"], [[7.3, 92.0]], rtol=1e-6)
    # terminated instead: target0 = 1
    _, aux = _loss(jit, q_online, q_target, a, r, truncated, FALSE2, ONES2, cfg1)
    np.testing.assert_allclose(aux["target"], [[1.0, 92.0]], rtol=1e-6)
    # both set: terminated wins -> 1
    _, aux = _loss(jit, q_online, q_target, a, r, truncated, truncated, ONES2, cfg1)
    np.testing.assert_allclose(aux["target"], [[1.0, 92.0]], rtol=1e-6)
    # n = 3: truncation still stops accumulation at t=0 -> 7.3 (crossing would give 1 + 0.9*2 + 0.81*100 = 83.8)
    cfg3 = TDConfig(gamma=0.9, n_step=3, double_q=False)
    _, aux = _loss(jit, q_online, q_target, a, r, FALSE2, truncated, ONES2, cfg3)
    np.testing.assert_allclose(aux["target"], [[7.3, 92.0]], rtol=1e-6)
    _, aux = _loss(jit, q_online, q_target, a, r, FALSE2, FALSE2, ONES2, cfg3)
    np.testing.assert_allclose(aux["target"], [[83.8, 92.0]], rtol=1e-6)


def test_batch_rows_independent():
    # Two rows: row 1 = the double-Q case, row 0 = the same with its mask zeroed -> loss = row 1 only: 2.3125
    cfg = TDConfig(gamma=0.5, double_q=True)
    cat = lambda x: np.concatenate([x, x])  # noqa: E731
    loss, aux = _loss(
        False,
        cat(Q_ONLINE),
        cat(Q_TARGET),
        cat(ACTIONS),
        cat(REWARDS),
        cat(FALSE2),
        cat(FALSE2),
        np.array([[0.0, 0.0], [1.0, 1.0]]),
        cfg,
    )
    np.testing.assert_allclose(loss, 2.3125, rtol=1e-6)
    np.testing.assert_allclose(aux["target"], [[1.5, 0.0], [1.5, 0.0]])


def test_bad_config():
    with pytest.raises(ValueError, match="n_step"):
        TDConfig(n_step=0)
    with pytest.raises(ValueError, match="gamma"):
        TDConfig(gamma=1.5)


def test_importance_weights_scale_each_window():
    """Window weights (prioritised replay) multiply that window's elementwise losses; the mean stays over the
    unmasked transitions. Two copies of the shared window: by hand, td = [2.5, -0.5] in each."""
    cfg = TDConfig(gamma=0.5, n_step=1, double_q=False)
    two = lambda a: np.concatenate([a, a])  # noqa: E731
    args = [jnp.asarray(two(a)) for a in (Q_ONLINE, Q_TARGET, ACTIONS, REWARDS, FALSE2, FALSE2, ONES2)]
    plain, _ = sequence_td_loss(*args, cfg)
    ones, _ = sequence_td_loss(*args, cfg, jnp.ones(2))
    weighted, aux = sequence_td_loss(*args, cfg, jnp.asarray([1.0, 0.25]))
    np.testing.assert_allclose(ones, plain, rtol=1e-7)
    np.testing.assert_allclose(plain, 1.625, rtol=1e-6)
    np.testing.assert_allclose(weighted, (1.0 + 0.25) * 0.5 * (6.25 + 0.25) / 4, rtol=1e-6)
    np.testing.assert_allclose(aux["td_error"], [[2.5, -0.5], [2.5, -0.5]])  # the errors are not weighted


def _batch(**fields) -> LossBatch:
    """The shared window as a LossBatch (the loss terms' input)."""
    base = dict(
        q=jnp.asarray(Q_ONLINE),
        q_target=jnp.asarray(Q_TARGET),
        action=jnp.asarray(ACTIONS),
        reward=jnp.asarray(REWARDS),
        terminated=jnp.asarray(FALSE2),
        truncated=jnp.asarray(FALSE2),
        mask=jnp.asarray(ONES2),
    )
    return LossBatch(**{**base, **fields})


def test_the_td_term_is_the_td_loss_of_its_batch_and_reports_its_errors():
    """td_term: sequence_td_loss of the batch's fields (the double-Q case by hand: 2.3125), logged as td_loss, its
    TD errors under PRIORITY_KEY; the targets alone are sequence_td_targets'."""
    cfg = TDConfig(gamma=0.5, n_step=1, double_q=True)
    loss, metrics = jax.jit(td_term(cfg))(_batch())
    np.testing.assert_allclose(loss, 2.3125, rtol=1e-6)
    np.testing.assert_allclose(metrics["td_loss"], 2.3125, rtol=1e-6)
    np.testing.assert_allclose(metrics[PRIORITY_KEY], [[0.5, -3.0]], rtol=1e-6)
    targets = sequence_td_targets(*(jnp.asarray(a) for a in (Q_ONLINE, Q_TARGET, REWARDS, FALSE2, FALSE2)), cfg)
    np.testing.assert_allclose(targets, [[1.5, 0.0]])


def test_the_aux_term_is_the_weighted_squared_error_of_the_aux_head_at_the_trained_obs():
    """aux_term(weight, K): the masked mean over the T trained obs of the squared error summed over the K entries of
    the sown head against the stored label; the last obs (the bootstrap one) and masked steps do not count."""
    head = np.zeros((1, 3, 3), np.float32)
    label = np.zeros((1, 3, 6), np.float32)
    head[0, 0] = [1.0, 0.0, 0.0]  # error 1 at obs 0
    head[0, 1] = [0.0, 2.0, 0.0]  # error 4 at obs 1 (masked below)
    head[0, 2] = [9.0, 9.0, 9.0]  # the bootstrap obs: not trained
    label[0, :, 3:] = 5.0  # the relative velocity, beyond K = 3 entries: not read
    batch = _batch(intermediates={"aux": (jnp.asarray(head),)}, privileged=jnp.asarray(label))
    loss, metrics = aux_term(2.0, 3)(batch)
    np.testing.assert_allclose(metrics["aux_loss"], (1.0 + 4.0) / 2, rtol=1e-6)
    np.testing.assert_allclose(loss, 2.0 * (1.0 + 4.0) / 2, rtol=1e-6)
    masked = aux_term(1.0, 3)(batch.replace(mask=jnp.asarray([[1.0, 0.0]])))[1]["aux_loss"]
    np.testing.assert_allclose(masked, 1.0, rtol=1e-6)
