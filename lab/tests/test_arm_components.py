"""lab/arm_components.py: the loss terms of the arms that the package keeps no config field for, against numbers
worked out by hand (the shared window of tests/test_losses.py: B=1, T=2 transitions, A=2)."""

import jax.numpy as jnp
import numpy as np

from lab import arm_components
from ramavt_jax import env as env_lib
from ramavt_jax.losses import PRIORITY_KEY, LossBatch, TDConfig, td_term

Q_ONLINE = np.array([[[1.0, 2.0], [4.0, 3.0], [5.0, 0.0]]], np.float32)  # [1, 3, 2]
Q_TARGET = np.array([[[0.0, 0.0], [1.0, 5.0], [2.0, 7.0]]], np.float32)  # [1, 3, 2]
FALSE2 = np.zeros((1, 2), bool)


def _batch(actions, rewards=(1.0, -1.0)) -> LossBatch:
    return LossBatch(
        q=jnp.asarray(Q_ONLINE),
        q_target=jnp.asarray(Q_TARGET),
        action=jnp.asarray([actions], jnp.int32),
        reward=jnp.asarray([rewards], jnp.float32),
        terminated=jnp.asarray(FALSE2),
        truncated=jnp.asarray(FALSE2),
        mask=jnp.ones((1, 2)),
    )


def test_advantage_learning_lowers_the_targets_of_worse_actions():
    """Plain-max targets [3.5, 2.5] (r + 0.5 max Q_tg(obs t+1)); the gaps at the taken actions, from the target
    net at obs t: actions [0, 1] take the best (gaps 0, 0: targets unchanged, loss that of the TD term); actions
    [1, 0] leave gaps [0, 5 - 1 = 4] -> targets [3.5, 2.5 - 0.5 * 4 = 0.5]."""
    cfg = TDConfig(gamma=0.5, n_step=1, double_q=False)
    term = arm_components.advantage_learning_term(cfg, 0.5)
    loss, metrics = term(_batch([0, 1]))
    np.testing.assert_allclose(loss, td_term(cfg)(_batch([0, 1]))[0], rtol=1e-6)
    _, metrics = term(_batch([1, 0]))
    q_taken = np.array([2.0, 4.0])  # Q_on(obs0)[1], Q_on(obs1)[0]
    np.testing.assert_allclose(metrics[PRIORITY_KEY][0], np.array([3.5, 0.5]) - q_taken, rtol=1e-6)


def test_the_command_cost_is_the_td_term_on_shaped_rewards():
    """Each reward less cost * reward_scale * the command's size (0 holding still, 1 along an axis)."""
    cfg = TDConfig(gamma=0.5, n_step=1, double_q=False)
    sizes = np.linalg.norm(np.asarray(env_lib.ACTIONS), axis=-1)
    hold, move = int(np.argmin(sizes)), int(np.argmax(sizes == 1.0))
    term = arm_components.command_cost_term(cfg, 0.05, 0.1)
    batch = _batch([hold, move]).replace(q=jnp.zeros((1, 3, 11)), q_target=jnp.zeros((1, 3, 11)))
    shaped = batch.replace(reward=jnp.asarray([[1.0, -1.0 - 0.05 * 0.1]]))
    np.testing.assert_allclose(term(batch)[0], td_term(cfg)(shaped)[0], rtol=1e-6)
    assert sizes[hold] == 0.0
