"""The large-margin loss towards the true-state look-ahead (LearnerConfig.expert_margin_weight): the loss against a
by-hand reference, the labels the trainer stores against the look-ahead run outside it, and the term the trainer's
loss adds."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ramavt_jax import baselines, imitation, presets
from ramavt_jax import env as env_lib
from ramavt_jax import replay as replay_lib
from ramavt_jax import train as T
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


def test_teacher_envs_fly_the_look_ahead_and_with_the_margin_every_env_stores_its_action():
    """The first teacher_envs envs take the one-step look-ahead's action on their true state, whatever epsilon; the
    rest explore (epsilon 1: random commands). With the margin loss every env's stored label is still the
    look-ahead's action; without it no label is stored and the look-ahead acts for the teacher envs only. Checked
    against the look-ahead run env by env, outside the trainer. Episodes of one step, so that every env ends one in
    the step: the training statistics count the agent's envs only."""
    cfg = SMOKE.override(
        teacher_envs=3,
        expert_margin_weight=1.0,
        env_params=(("max_steps", 1),),
        network=dataclasses.replace(SMOKE.network, prev_action=True),
    )
    trainer, k, n = T.Trainer(cfg), cfg.acting.teacher_envs, cfg.acting.num_envs
    state = trainer.init(jax.random.PRNGKey(3))
    step = jax.jit(lambda key: trainer.act_step(state.learner.params, state.actor, jnp.asarray(1.0), key))
    steps = [step(jax.random.PRNGKey(s)) for s in range(6)]  # (actor, transition, stats) each
    taken = np.stack([np.asarray(tr.action) for _, tr, _ in steps])  # [6, N], all agent envs random
    remembered = np.asarray(steps[0][0].net_state.prev_action)[0]  # [N]: what the LSTM is told it did
    np.testing.assert_array_equal(remembered, taken[0])
    assert [int(stats.episodes) for _, _, stats in steps] == [n - k] * 6
    look_ahead = baselines.mpc_policy(cfg.env, horizon=1, branch=1)
    act = jax.jit(lambda s: look_ahead.act(jax.random.PRNGKey(0), None, None, s, trainer.env_params)[0])
    expected = np.array([int(act(jax.tree.map(lambda x: x[i], state.actor.env_state))) for i in range(n)])
    np.testing.assert_array_equal(taken[:, :k], np.broadcast_to(expected[:k], (6, k)))
    assert len({tuple(row) for row in taken[:, k:]}) > 1  # the agent's envs still explore at epsilon 1
    for _, transition, _ in steps:
        np.testing.assert_array_equal(np.asarray(transition.expert_action), expected)
    assert len(set(expected.tolist())) > 1  # the envs' states differ enough to ask for different commands
    teachers_only = T.Trainer(cfg.override(expert_margin_weight=0.0))
    assert teachers_only.taught_envs == k and teachers_only._example_transition().expert_action is None
    assert T.Trainer(SMOKE).teacher is None  # neither option: no look-ahead in the acting step


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
    taught = jnp.arange(64, dtype=jnp.int32) % 11
    np.testing.assert_array_equal(imitation.stored_labels(taught, states, SMOKE.env.camera, "teacher"), taught)
    for blind_label, replaced in (("none", imitation.NO_LABEL), ("retreat", env_lib.RETREAT)):
        np.testing.assert_array_equal(
            imitation.stored_labels(taught, states, SMOKE.env.camera, blind_label), np.where(got, replaced, taught)
        )


def test_margin_terms_skip_the_steps_without_a_label():
    q = np.asarray(jax.random.normal(jax.random.PRNGKey(0), (3, 5, 11))) * 0.1
    expert = np.array(jax.random.randint(jax.random.PRNGKey(1), (3, 5), 0, 11))
    expert[0, 1:3], expert[2, 4] = imitation.NO_LABEL, imitation.NO_LABEL
    mask = np.asarray(jax.random.uniform(jax.random.PRNGKey(2), (3, 5)) < 0.8)
    loss, agreement = imitation.margin_terms(jnp.asarray(q), jnp.asarray(expert), jnp.asarray(mask, jnp.float32), 0.05)
    labelled = mask & (expert != imitation.NO_LABEL)
    np.testing.assert_allclose(float(loss), _reference_margin_loss(q, expert, labelled, 0.05), rtol=1e-5)
    np.testing.assert_allclose(float(agreement), (q.argmax(-1) == expert)[labelled].mean(), rtol=1e-5)


def test_the_blind_label_replaces_the_look_aheads_at_blind_starts_only():
    """blind_label 'retreat': the first step's stored label is RETREAT exactly at the envs whose target starts out of
    view (by hand), and the look-ahead's action elsewhere; 'teacher' stores that action everywhere."""
    cfg = SMOKE.override(expert_margin_weight=1.0, env_params=(("init_xy_std", 3.0),))
    labels = {}
    for blind_label in ("teacher", "retreat"):  # 'none': the same replacement (stored_labels, above)
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
    cfg = SMOKE.override(expert_margin_weight=0.5, expert_margin=0.1)
    trainer, burn = T.Trainer(cfg), cfg.replay.burn_in
    params = trainer.init(jax.random.PRNGKey(0)).learner.params
    window = _window(cfg, jax.random.PRNGKey(1))
    batch = replay_lib.sequence_batch(window, burn)
    np.testing.assert_array_equal(batch.expert_action, window.expert_action[:, :-1])  # transition t's obs t
    prepared = trainer.prepare(params, params, batch, jax.random.PRNGKey(2))
    np.testing.assert_array_equal(prepared.expert_action, batch.expert_action[:, burn:])
    plain_trainer = T.Trainer(SMOKE)

    @jax.jit
    def losses(p):  # one program for the three passes
        plain = plain_trainer.trained_loss(params, p.replace(expert_action=None))[0]
        q = trainer.q_values(params, p.obs, p.reset, p.state, actions=p.td.action)[0]
        return plain, trainer.trained_loss(params, p), q

    plain, (with_margin, logged), q = losses(prepared)
    mask, labels, q = np.asarray(prepared.td.mask), np.asarray(prepared.expert_action), np.asarray(q[:, :-1])
    assert 0 < mask.sum() < mask.size  # some trained transitions cross into a new episode
    margin = _reference_margin_loss(q, labels, mask, 0.1)
    assert margin > 0
    np.testing.assert_allclose(float(with_margin), float(plain) + 0.5 * margin, rtol=1e-5)
    np.testing.assert_allclose(float(logged["margin_loss"]), margin, rtol=1e-5)
    agreement = (q.argmax(-1) == labels)[mask].mean()
    np.testing.assert_allclose(float(logged["expert_agreement"]), agreement, rtol=1e-5)


def test_policy_terms_are_the_step_by_step_cross_entropy_of_the_labelled_steps():
    logits = np.asarray(jax.random.normal(jax.random.PRNGKey(0), (3, 5, 11)))
    expert = np.array(jax.random.randint(jax.random.PRNGKey(1), (3, 5), 0, 11))
    expert[0, 1:3], expert[2, 4] = imitation.NO_LABEL, imitation.NO_LABEL
    mask = np.asarray(jax.random.uniform(jax.random.PRNGKey(2), (3, 5)) < 0.8)
    loss, agreement = imitation.policy_terms(jnp.asarray(logits), jnp.asarray(expert), jnp.asarray(mask, jnp.float32))
    labelled = mask & (expert != imitation.NO_LABEL)
    nll = [np.log(np.exp(logits[b, t]).sum()) - logits[b, t, expert[b, t]] for b, t in zip(*np.nonzero(labelled))]
    np.testing.assert_allclose(float(loss), np.mean(nll), rtol=1e-5)
    np.testing.assert_allclose(float(agreement), (logits.argmax(-1) == expert)[labelled].mean(), rtol=1e-5)
    grad = np.asarray(
        jax.grad(lambda x: imitation.policy_terms(x, jnp.asarray(expert), jnp.ones((3, 5)))[0])(jnp.asarray(logits))
    )
    assert (grad[0, 1:3] == 0).all() and grad[0, 0, expert[0, 0]] < 0  # unlabelled: no pull; labelled: raised


def test_a_policy_head_acts_and_its_cross_entropy_joins_the_loss_while_q_trains_by_td():
    """With NetworkConfig.policy_head the network returns the head's logits (what acting takes the argmax of) and
    sows Q: the loss is the TD loss of that Q (a network without the head, the same other params), plus the margin
    loss on Q, plus policy_weight times the logits' cross-entropy at the trained transitions' labels; the logged
    agreement is the logits'. Acting stores the look-ahead's labels even without a margin loss."""
    base = SMOKE.override(expert_margin_weight=0.5, expert_margin=0.1)
    cfg = base.override(network=dataclasses.replace(base.network, policy_head=True), policy_weight=2.0)
    trainer, burn = T.Trainer(cfg), cfg.replay.burn_in
    params = trainer.init(jax.random.PRNGKey(0)).learner.params
    q_params = {k: v for k, v in params.items() if k != "policy"}
    assert set(params) - set(q_params) == {"policy"}
    prepared = trainer.prepare(
        params, params, replay_lib.sequence_batch(_window(cfg, jax.random.PRNGKey(1)), burn), jax.random.PRNGKey(2)
    )
    q_trainer = T.Trainer(base)
    q_prepared = q_trainer.prepare(
        q_params, q_params, replay_lib.sequence_batch(_window(cfg, jax.random.PRNGKey(1)), burn), jax.random.PRNGKey(2)
    )
    np.testing.assert_allclose(prepared.td.q_target, q_prepared.td.q_target, rtol=1e-5)  # targets from Q, not logits

    @jax.jit
    def losses(p):
        logits = trainer.q_values(params, p.obs, p.reset, p.state, actions=p.td.action)[0]
        return q_trainer.trained_loss(q_params, p), trainer.trained_loss(params, p), logits

    (q_loss, q_logged), (loss, logged), logits = losses(prepared)
    mask, labels = np.asarray(prepared.td.mask), np.asarray(prepared.expert_action)
    ce, agreement = imitation.policy_terms(logits[:, :-1], jnp.asarray(labels), jnp.asarray(mask, jnp.float32))
    assert float(ce) > 0 and float(q_logged["margin_loss"]) > 0
    np.testing.assert_allclose(float(loss), float(q_loss) + 2.0 * float(ce), rtol=1e-5)
    np.testing.assert_allclose(float(logged["margin_loss"]), float(q_logged["margin_loss"]), rtol=1e-5)
    np.testing.assert_allclose(float(logged["policy_loss"]), float(ce), rtol=1e-5)
    np.testing.assert_allclose(float(logged["expert_agreement"]), float(agreement), rtol=1e-5)
    assert float(q_logged["policy_loss"]) == 0.0

    no_margin = cfg.override(expert_margin_weight=0.0)
    acting = T.Trainer(no_margin)
    state = acting.init(jax.random.PRNGKey(4))
    _, transition, _ = jax.jit(acting.act_step)(
        state.learner.params, state.actor, jnp.asarray(0.0), jax.random.PRNGKey(5)
    )
    assert transition.expert_action is not None and (np.asarray(transition.expert_action) >= 0).all()
    a = state.actor
    logits = acting.q_values(state.learner.params, a.obs[:, None], a.is_first[:, None], a.net_state)[0][:, 0]
    np.testing.assert_array_equal(np.asarray(transition.action), np.asarray(logits.argmax(-1)))  # epsilon 0


@pytest.mark.parametrize(
    "build, message",
    [
        (
            lambda: LearnerConfig(expert_margin_weight=-1.0),
            r"^LearnerConfig: expert_margin_weight must be >= 0 \(0 = no margin loss\), got -1.0$",
        ),
        (lambda: LearnerConfig(expert_margin=0.0), r"^LearnerConfig: expert_margin must be > 0, got 0.0$"),
        (lambda: LearnerConfig(policy_weight=0.0), r"^LearnerConfig: policy_weight must be > 0, got 0.0$"),
        (
            lambda: dataclasses.replace(SMOKE.network, policy_head=True, quantiles=8),
            r"^NetworkConfig: policy_head needs a recurrent variant \(the head reads the LSTM output\) and no quantiles$",
        ),
        (
            lambda: dataclasses.replace(SMOKE.network, policy_head=True, variant="drlavt"),
            r"^NetworkConfig: policy_head needs a recurrent variant \(the head reads the LSTM output\) and no quantiles$",
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
