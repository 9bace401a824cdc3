"""Labels from the simulator's state (imitation.py) and the large-margin loss towards them
(LearnerConfig.expert_margin_weight): the loss against a by-hand reference, the labels the trainer stores against
the look-ahead run outside it, a labeller and a loss term plugged in from outside, and the term the trainer's loss
adds."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ramavt_jax import baselines, imitation, presets
from ramavt_jax import env as env_lib
from ramavt_jax import replay as replay_lib
from ramavt_jax import train as T
from ramavt_jax.losses import LossBatch
from ramavt_jax.network import RecurrentState
from ramavt_jax.train_config import LearnerConfig

SMOKE = presets.preset("smoke")


def _reference_margin_loss(q, expert, mask, margin):
    """max_a [Q(s, a) + margin * (a != a_E)] - Q(s, a_E), step by step, averaged over the masked-in steps."""
    total, count = 0.0, 0
    for b in range(q.shape[0]):
        for t in range(q.shape[1]):
            if mask[b, t]:
                raised = [q[b, t, a] + (0.0 if a == expert[b, t] else margin) for a in range(q.shape[2])]
                total, count = total + max(raised) - q[b, t, expert[b, t]], count + 1
    return total / count


def test_large_margin_loss_equals_the_step_by_step_reference():
    q = np.asarray(jax.random.normal(jax.random.PRNGKey(0), (3, 5, 11))) * 0.1
    expert = np.asarray(jax.random.randint(jax.random.PRNGKey(1), (3, 5), 0, 11))
    mask = np.asarray(jax.random.uniform(jax.random.PRNGKey(2), (3, 5)) < 0.7)
    got = imitation.large_margin_loss(jnp.asarray(q), jnp.asarray(expert), jnp.asarray(mask, jnp.float32), 0.05)
    np.testing.assert_allclose(float(got), _reference_margin_loss(q, expert, mask, 0.05), rtol=1e-5)


def test_large_margin_loss_is_zero_once_the_expert_leads_by_the_margin_and_its_gradient_closes_the_gap():
    expert, mask = jnp.array([[2]]), jnp.ones((1, 1))
    leading = jnp.zeros((1, 1, 11)).at[0, 0, 2].set(0.06)  # leads every other action by more than 0.05
    assert float(imitation.large_margin_loss(leading, expert, mask, 0.05)) == 0.0
    behind = jnp.zeros((1, 1, 11)).at[0, 0, 7].set(0.3)  # action 7 leads the expert's by 0.3
    np.testing.assert_allclose(float(imitation.large_margin_loss(behind, expert, mask, 0.05)), 0.35, rtol=1e-6)
    grad = np.asarray(jax.grad(imitation.large_margin_loss)(behind, expert, mask, 0.05))[0, 0]
    assert grad[2] == -1.0 and grad[7] == 1.0 and np.count_nonzero(grad) == 2  # raise the expert's, lower the leader


@pytest.mark.slow
def test_with_the_margin_every_env_stores_the_look_aheads_action_and_without_it_none():
    """With the margin loss every env's stored label is the one-step look-ahead's action on its true state, whatever
    the env flies (epsilon 1: random commands), checked against the look-ahead run env by env outside the trainer;
    without it no labeller runs and no label is stored."""
    cfg = SMOKE.override(expert_margin_weight=1.0)
    trainer, n = T.Trainer(cfg), cfg.acting.num_envs
    state = trainer.init(jax.random.PRNGKey(3))
    step = jax.jit(lambda key: trainer.act_step(state.learner.params, state.actor, jnp.asarray(1.0), key))
    steps = [step(jax.random.PRNGKey(s)) for s in range(3)]  # (actor, transition, stats) each
    look_ahead = baselines.mpc_policy(cfg.env, horizon=1, branch=1)
    act = jax.jit(lambda s: look_ahead.act(jax.random.PRNGKey(0), None, None, s, trainer.env_params)[0])
    expected = np.array([int(act(jax.tree.map(lambda x: x[i], state.actor.env_state))) for i in range(n)])
    for _, transition, _ in steps:
        np.testing.assert_array_equal(np.asarray(transition.expert_action), expected)
    assert len(set(expected.tolist())) > 1  # the envs' states differ enough to ask for different commands
    assert len({tuple(np.asarray(tr.action)) for _, tr, _ in steps}) > 1  # the envs fly their own commands
    plain = T.Trainer(SMOKE)
    assert plain.labeller is None and plain._example_transition().expert_action is None


def test_a_labeller_from_outside_labels_every_step_for_the_loss_terms():
    """Trainer(labeller=...): its labels of the envs' states are what acting stores, with no config field; the
    margin term reads them from the sampled windows (LossBatch.expert_action)."""

    def forward_if_far(env_state, params, key):  # [N]: forward (action 5) when the target is beyond 6 m
        far = jax.vmap(env_lib.relative_position)(env_state)[:, 2] > 6.0
        return jnp.where(far, 5, imitation.NO_LABEL).astype(jnp.int32)

    trainer = T.Trainer(SMOKE, labeller=forward_if_far, loss_terms=(imitation.margin_term(1.0),))
    state = trainer.init(jax.random.PRNGKey(3))
    _, transition, _ = jax.jit(trainer.act_step)(state.learner.params, state.actor, jnp.asarray(0.0), jax.random.key(1))
    far = np.asarray(jax.vmap(env_lib.relative_position)(state.actor.env_state))[:, 2] > 6.0
    np.testing.assert_array_equal(np.asarray(transition.expert_action), np.where(far, 5, imitation.NO_LABEL))
    assert 0 < far.sum() < far.size


def _blind_geometry(env_state) -> np.ndarray:
    """[N] bool, by hand: the target centre outside the 60-degree view (or behind) and lost at every step so far."""
    rel = np.einsum(
        "ji,nj->ni",
        np.asarray(env_lib.HILL_FROM_CAM),
        np.asarray(env_state.target_pos) - np.asarray(env_state.chaser_pos),
    )  # [N, 3] camera frame
    x, y, z = rel.T
    outside = (z <= 0) | (np.abs(x) > np.tan(np.pi / 6) * np.abs(z)) | (np.abs(y) > np.tan(np.pi / 6) * np.abs(z))
    return outside & (np.asarray(env_state.lost_steps) == np.asarray(env_state.steps))


def test_unseen_yet_is_out_of_view_with_every_step_so_far_lost():
    tracking_env = env_lib.TrackingEnv(SMOKE.env)
    params = tracking_env.default_params(init_xy_std=3.0)  # wide starts: many begin out of view
    states = jax.vmap(lambda k: tracking_env.initial_state(k, params))(jax.random.split(jax.random.PRNGKey(0), 64))
    seen_before = np.arange(64) % 3 == 0  # a third lost for 3 of 5 steps so far: in view two steps ago
    states = states.replace(steps=jnp.full(64, 5), lost_steps=jnp.where(seen_before, 3, 5))
    got = np.asarray(imitation.unseen_yet(states, SMOKE.env.camera))
    np.testing.assert_array_equal(got, _blind_geometry(states))
    assert 0 < got.sum() < (~seen_before).sum()  # some blind, some in view, and the seen-before never


def test_the_margin_term_skips_the_steps_without_a_label():
    q = np.asarray(jax.random.normal(jax.random.PRNGKey(0), (3, 6, 11))) * 0.1  # [B, T + 1, A]
    expert = np.array(jax.random.randint(jax.random.PRNGKey(1), (3, 5), 0, 11))
    expert[0, 1:3], expert[2, 4] = imitation.NO_LABEL, imitation.NO_LABEL
    mask = np.asarray(jax.random.uniform(jax.random.PRNGKey(2), (3, 5)) < 0.8)
    zeros = jnp.zeros((3, 5))
    batch = LossBatch(
        q=jnp.asarray(q),
        q_target=jnp.asarray(q),
        action=zeros.astype(jnp.int32),
        reward=zeros,
        terminated=zeros.astype(bool),
        truncated=zeros.astype(bool),
        mask=jnp.asarray(mask),
        expert_action=jnp.asarray(expert),
    )
    loss, metrics = imitation.margin_term(2.0, margin=0.05)(batch)
    labelled = mask & (expert != imitation.NO_LABEL)
    reference = _reference_margin_loss(q[:, :-1], expert, labelled, 0.05)
    np.testing.assert_allclose(float(metrics["margin_loss"]), reference, rtol=1e-5)
    np.testing.assert_allclose(float(loss), 2.0 * reference, rtol=1e-5)
    agreement = (q[:, :-1].argmax(-1) == expert)[labelled].mean()
    np.testing.assert_allclose(float(metrics["expert_agreement"]), agreement, rtol=1e-5)


@pytest.mark.slow
def test_the_blind_label_replaces_the_look_aheads_at_blind_starts_only():
    """blind_label 'retreat': the first step's stored label is RETREAT exactly at the envs whose target starts out of
    view (by hand), and the look-ahead's action elsewhere; 'teacher' stores that action everywhere."""
    cfg = SMOKE.override(expert_margin_weight=1.0, env_params=(("init_xy_std", 3.0),))
    labels = {}
    for blind_label in ("teacher", "retreat"):  # 'none': the same replacement
        trainer = T.Trainer(cfg.override(blind_label=blind_label))
        state = trainer.init(jax.random.PRNGKey(4))
        _, transition, _ = jax.jit(trainer.act_step)(
            state.learner.params, state.actor, jnp.asarray(0.0), jax.random.PRNGKey(5)
        )
        labels[blind_label], blind = np.asarray(transition.expert_action), _blind_geometry(state.actor.env_state)
    assert 0 < blind.sum() < blind.size and (labels["teacher"] >= 0).all()
    np.testing.assert_array_equal(labels["retreat"], np.where(blind, env_lib.RETREAT, labels["teacher"]))
    assert list(env_lib.ACTIONS[env_lib.RETREAT]) == [0, 0, -1]  # the chaser backs off: z grows


def _window(cfg, key):
    """Hand-made sampled windows [B, L, ...] with labels, as the replay stores them, episodes starting at random."""
    B, L, n = cfg.replay.batch_size, cfg.sequence_length, cfg.network
    ks = jax.random.split(key, 7)
    state = RecurrentState(
        h=0.5 * jax.random.normal(ks[3], (B, L, n.lstm_layers, n.lstm)),
        c=0.5 * jax.random.normal(ks[4], (B, L, n.lstm_layers, n.lstm)),
        frames=None,
    )
    z, is_first = jnp.zeros((B, L), bool), (jax.random.uniform(ks[6], (B, L)) < 0.15).at[0, L - 3].set(True)
    return replay_lib.Transition(
        obs=jax.random.uniform(ks[0], (B, L, *cfg.env.obs_shape)),
        action=jax.random.randint(ks[1], (B, L), 0, 11),
        reward=jax.random.normal(ks[2], (B, L)),
        terminated=z,
        truncated=z,
        is_first=is_first,
        recurrent_state=state,
        expert_action=jax.random.randint(ks[5], (B, L), 0, 11),
    )


def test_the_trainers_loss_adds_the_weighted_margin_loss_of_the_trained_steps():
    """The loss at weight w is the plain loss plus w times the margin loss of the trained pass's Q at the trained
    transitions' labels: the burn-in's labels unused, and none of a transition into a new episode."""
    cfg = SMOKE.override(expert_margin_weight=0.5)
    trainer = T.Trainer(cfg, loss_terms=T.default_loss_terms(SMOKE) + (imitation.margin_term(0.5, margin=0.1),))
    burn = cfg.replay.burn_in
    params = trainer.init(jax.random.PRNGKey(0)).learner.params
    window = _window(cfg, jax.random.PRNGKey(1))
    batch = replay_lib.sequence_batch(window, burn)
    np.testing.assert_array_equal(batch.expert_action, window.expert_action[:, :-1])  # transition t's obs t
    prepared = trainer.prepare(params, params, batch, jax.random.PRNGKey(2))
    np.testing.assert_array_equal(prepared.loss_batch.expert_action, batch.expert_action[:, burn:])
    plain_trainer = T.Trainer(SMOKE)

    @jax.jit
    def losses(p):  # one program for the three passes
        plain = plain_trainer.trained_loss(params, p.replace(loss_batch=p.loss_batch.replace(expert_action=None)))[0]
        q = trainer.q_values(params, p.obs, p.reset, p.state, actions=p.loss_batch.action)[0]
        return plain, trainer.trained_loss(params, p), q

    plain, (with_margin, logged), q = losses(prepared)
    mask, labels = np.asarray(prepared.loss_batch.mask), np.asarray(prepared.loss_batch.expert_action)
    q = np.asarray(q[:, :-1])
    assert 0 < mask.sum() < mask.size  # some trained transitions cross into a new episode
    margin = _reference_margin_loss(q, labels, mask, 0.1)
    assert margin > 0
    np.testing.assert_allclose(float(with_margin), float(plain) + 0.5 * margin, rtol=1e-5)
    np.testing.assert_allclose(float(logged["terms"]["margin_loss"]), margin, rtol=1e-5)
    agreement = (q.argmax(-1) == labels)[mask].mean()
    np.testing.assert_allclose(float(logged["terms"]["expert_agreement"]), agreement, rtol=1e-5)


@pytest.mark.parametrize(
    "build, message",
    [
        (
            lambda: LearnerConfig(expert_margin_weight=-1.0),
            r"^LearnerConfig: expert_margin_weight must be >= 0 \(0 = no margin loss\), got -1.0$",
        ),
        (
            lambda: LearnerConfig(blind_label="search"),
            r"^LearnerConfig: blind_label must be one of \('teacher', 'none', 'retreat'\), got 'search'$",
        ),
    ],
)
def test_bad_margin_settings_fail_in_one_line(build, message):
    with pytest.raises(ValueError, match=message):
        build()
