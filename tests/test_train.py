"""Trainer: config validation, burn-in gradients, sequence plumbing, stored recurrent state, vmap over seeds, learning."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ramavt_jax import baselines, greedy, presets, train_config, train_state
from ramavt_jax import env as env_lib
from ramavt_jax import replay as replay_lib
from ramavt_jax import train as T
from ramavt_jax.evaluation import rollouts as evaluate
from ramavt_jax.losses import sequence_td_loss
from ramavt_jax.network import NetworkConfig, RecurrentState, init_params, initial_state
from ramavt_jax.render import CameraConfig
from ramavt_jax.train_config import ActingConfig, LearnerConfig, RunConfig

SMOKE = presets.preset("smoke")


@pytest.fixture(scope="module")
def trainer():
    return T.Trainer(SMOKE)


@pytest.fixture(scope="module")
def learner():
    params = init_params(SMOKE.network, jax.random.PRNGKey(0), SMOKE.env.obs_shape)["params"]
    # a target net that differs from the online net, so double-Q and the target path are both exercised
    target = jax.tree.map(lambda p: p * 0.9, params)
    return params, target


@pytest.fixture(scope="module")
def loss_fn(trainer):
    return jax.jit(lambda p, t, b: trainer.loss(p, t, b, jax.random.PRNGKey(0))[0])


# ------------------------------------------------------------------------------------------ config
def test_presets():
    quick, paper = presets.preset("quick"), presets.preset("paper")
    assert quick.env.camera.resolution <= 48 and quick.env.obs_mode == "depth"
    assert quick.env_params == ()  # the original task, not an easier one
    assert paper.env.camera.resolution == 256 and paper.replay.batch_size == 64 and paper.learner.lr == 1e-4
    assert paper.learner.gamma == 0.99 and paper.replay.capacity_steps == 50_000
    assert paper.network == NetworkConfig(variant="ramavt")
    for cfg in (quick, paper, SMOKE):
        assert cfg.updates_per_iteration >= 1 and cfg.num_chunks >= 1
    assert presets.preset("quick", lr=3e-4).learner.lr == 3e-4  # a group field by its own name (not the preset's value)
    robust = presets.preset("robust")  # quick trained under Table II's perturbations, each in half the episodes
    assert robust.override(env=quick.env, env_params={}) == quick and robust.env.frame_history == 3
    assert dict(robust.env_params) == {"actuator_noise": 0.3, "delay_max": 0.5, "blur_frames": 3, "perturb_prob": 0.5}
    general = presets.preset("general")  # robust, trained also on resized targets and wide starts, searching blind
    draws = {"size_scale_min": 0.15, "size_scale_max": 5.0, "init_xy_std": 3.0}
    assert dict(general.env_params) == {**dict(robust.env_params), **draws}
    assert general.override(env_params=dict(robust.env_params), blind_label="teacher") == robust
    assert general.learner.blind_label == "retreat" and general.env.camera.resolution == quick.env.camera.resolution
    with pytest.raises(ValueError, match="unknown preset"):
        presets.preset("huge")


@pytest.mark.parametrize(
    "overrides, message",
    [
        (dict(total_env_steps=1000), "multiple of the env steps per chunk"),
        (dict(capacity_steps=801), "divisible by acting.num_envs"),
        (dict(capacity_steps=64), "steps per env"),
        (dict(eps_start=1.5), r"eps_start must be in \[0, 1\]"),
        (dict(gamma=-0.1), "gamma"),
        (dict(lr=0.0), "lr must be > 0"),
        (dict(blind_label="spiral"), "blind_label must be one of"),
        (dict(aux_weight=1.0), "aux_weight > 0 and network.aux_outputs = 3 or 6 go together"),
        (dict(network=dataclasses.replace(SMOKE.network, aux_outputs=3)), "go together"),
        (dict(n_step=9), "n_step=9 must be <= replay.train_len"),
        (dict(replay_ratio=0.3), "whole number"),
        (dict(target_update="soft"), "target_update"),
        (dict(learning_starts=10_000), "exceeds replay.capacity_steps"),
        (dict(num_envs=0), "num_envs must be >= 1"),
        (dict(batch_size=2.5), "batch_size must be an int"),
        (dict(env=env_lib.EnvConfig(camera=CameraConfig(resolution=16))), "autoreset must be 'next_step'"),
        (
            dict(
                network=NetworkConfig(variant="drlavt", channels=(8,), kernels=(3,), strides=(1,), pools=(True,)),
                burn_in=2,
            ),
            "burn_in must be >= frame_stack - 1",
        ),
        (dict(network=NetworkConfig(norm="batch")), "norm='batch'"),
        (dict(env_params=(("warp_speed", 9.0),)), "env_params"),
        (dict(learner=LearnerConfig(learning_starts=0), num_envs=4.0), "ActingConfig: num_envs must be an int"),
        (dict(warp=9), "unknown field 'warp'"),
    ],
)
def test_invalid_configs_raise_clear_errors(overrides, message):
    with pytest.raises(ValueError, match=message):
        SMOKE.override(**overrides)


@pytest.mark.parametrize(
    "build, message",
    [
        (lambda: ActingConfig(eps_end=2.0), r"^ActingConfig: eps_end must be in \[0, 1\], got 2.0$"),
        (lambda: LearnerConfig(target_update="soft"), r"^LearnerConfig: target_update must be 'polyak' or 'period'"),
        (
            lambda: LearnerConfig(bootstrap_from="both"),
            r"^LearnerConfig: bootstrap_from must be .target. or .online., got .both.$",
        ),
        (lambda: RunConfig(keep_checkpoints=0), r"^RunConfig: keep_checkpoints must be >= 1, got 0$"),
        (
            lambda: RunConfig(policy_params="ema"),
            r"^RunConfig: policy_params must be 'online', 'target' or 'averaged', got 'ema'$",
        ),
        (
            lambda: RunConfig(policy_params="averaged"),
            r"^RunConfig: policy_params='averaged' needs policy_average_from",
        ),
        (lambda: RunConfig(policy_average_from=-1), r"^RunConfig: policy_average_from must be >= 0, got -1$"),
        (lambda: RunConfig(policy_average_from=2.5), r"^RunConfig: policy_average_from must be an int, got 2.5$"),
        (lambda: replay_lib.ReplayConfig(train_len=0), r"^ReplayConfig.train_len must be >= 1, got 0$"),
        (
            lambda: train_config.TrainConfig(replay=replay_lib.ReplayConfig(capacity_steps=64_010)),
            r"^TrainConfig: replay.capacity_steps=64010 must be divisible by acting.num_envs=64$",
        ),
    ],
)
def test_each_group_checks_its_own_values_in_one_line(build, message):
    """A group's bad value fails when the group is built, naming the group; how groups fit, in TrainConfig."""
    with pytest.raises(ValueError, match=message) as e:
        build()
    assert "\n" not in str(e.value)


def test_override_routes_field_names_to_their_groups():
    cfg = SMOKE.override(lr=1e-3, period=2, eval_episodes=0, learner=LearnerConfig(learning_starts=0))
    assert (cfg.learner.lr, cfg.learner.learning_starts, cfg.replay.period, cfg.run.eval_episodes) == (1e-3, 0, 2, 0)
    assert cfg.acting == SMOKE.acting and cfg.network == SMOKE.network
    assert not any(hasattr(cfg, name) for name in ("lr", "debug_nan_at_update"))  # no flat fields, no test hooks


def test_drlavt_with_enough_burn_in_is_accepted():
    net = NetworkConfig(variant="drlavt", channels=(8,), kernels=(3,), strides=(1,), pools=(True,), drlavt_dense=(16,))
    cfg = SMOKE.override(network=net, burn_in=3)
    assert cfg.replay.burn_in == net.frame_stack - 1


@pytest.mark.parametrize(
    "variant, obs_mode, augment, prev_action, aux",
    [
        ("ramavt", "depth", False, False, 0),
        ("drlavt", "depth", False, False, 0),
        ("se", "rgbd", False, False, 0),
        ("mha", "color", True, False, 0),
        ("origin", "depth", True, False, 0),
        ("ramavt", "depth", False, True, 3),
        ("ramavt", "rgbd", True, True, 6),
    ],
)
def test_every_variant_observation_and_augmentation_traces(variant, obs_mode, augment, prev_action, aux):
    """The whole chunk (acting, replay, burn-in learner) traces for each option (abstractly: nothing compiles)."""
    net = NetworkConfig(
        variant=variant,
        channels=(8, 8),
        kernels=(3, 3),
        strides=(1, 1),
        pools=(True, True),
        dense=16,
        lstm=16,
        lstm_layers=2,
        head=16,
        attention_heads=2,
        drlavt_dense=(16,),
        prev_action=prev_action,
        aux_outputs=aux,
    )
    env_cfg = env_lib.EnvConfig(camera=CameraConfig(resolution=16), obs_mode=obs_mode, autoreset="next_step")
    cfg = SMOKE.override(network=net, env=env_cfg, augment=augment, aux_weight=float(aux > 0))
    tr = T.Trainer(cfg)
    state = jax.eval_shape(tr.init, jax.ShapeDtypeStruct((2,), jnp.uint32))
    out, metrics = jax.eval_shape(tr.chunk, state)
    channels = env_lib.OBS_CHANNELS[obs_mode]
    assert out.actor.obs.shape == (cfg.acting.num_envs, 16, 16, channels)
    assert metrics.loss_sum.shape == metrics.term_sums["td_loss"].shape == (cfg.run.iterations_per_chunk,)
    assert ("aux_loss" in metrics.term_sums) == bool(aux)
    assert jax.tree.structure(out) == jax.tree.structure(state)


# ------------------------------------------------------------------------------------------ learner plumbing
def _window(key, cfg, is_first=None, terminated=None):
    """Hand-made sampled windows [B, L, ...] as stored (random obs/actions/rewards, random stored LSTM state)."""
    B, L = cfg.replay.batch_size, cfg.sequence_length
    ks = jax.random.split(key, 5)
    n = cfg.network
    h = 0.5 * jax.random.normal(ks[3], (B, L, n.lstm_layers, n.lstm))
    c = 0.5 * jax.random.normal(ks[4], (B, L, n.lstm_layers, n.lstm))
    z = jnp.zeros((B, L), bool)
    return replay_lib.Transition(
        obs=jax.random.uniform(ks[0], (B, L, *cfg.env.obs_shape)),
        action=jax.random.randint(ks[1], (B, L), 0, 11),
        reward=jax.random.normal(ks[2], (B, L)) * 3.0,
        terminated=z if terminated is None else terminated,
        truncated=z,
        is_first=z if is_first is None else is_first,
        recurrent_state=RecurrentState(h=h, c=c, frames=None),
    )


def _as_batch(window, cfg=SMOKE):
    """The SequenceBatch the replay's sample makes of these windows."""
    return replay_lib.sequence_batch(window, cfg.replay.burn_in)


def test_sampled_batch_carries_the_network_state(trainer):
    """The trainer's replay hands the learner a SequenceBatch whose start state is the network's RecurrentState in
    the network's layout (abstractly: nothing compiles)."""
    cfg = SMOKE
    state = jax.eval_shape(trainer.replay.init)
    batch = jax.eval_shape(trainer.replay.sample, state, jax.ShapeDtypeStruct((2,), jnp.uint32))
    B, L, n = cfg.replay.batch_size, cfg.sequence_length, cfg.network
    assert isinstance(batch, replay_lib.SequenceBatch) and batch.burn_in == cfg.replay.burn_in
    assert batch.obs.shape == (B, L, *cfg.env.obs_shape) and batch.loss_mask.shape == (B, L - 1)
    assert isinstance(batch.start_state, RecurrentState) and batch.start_state.frames is None
    assert batch.start_state.h.shape == batch.start_state.c.shape == (n.lstm_layers, B, n.lstm)


def test_burn_in_gets_no_gradient(trainer, learner, loss_fn):
    params, target = learner
    cfg, burn = SMOKE, SMOKE.replay.burn_in
    window = _window(jax.random.PRNGKey(1), cfg)

    def loss(obs, h):
        stored = window.recurrent_state.replace(h=h)
        return loss_fn(params, target, _as_batch(window.replace(obs=obs, recurrent_state=stored)))

    g_obs, g_h = jax.jit(jax.grad(loss, argnums=(0, 1)))(window.obs, window.recurrent_state.h)
    g_obs, g_h = np.asarray(g_obs), np.asarray(g_h)
    assert np.all(g_obs[:, :burn] == 0.0), "burn-in observations must not receive gradient"
    assert np.all(g_h == 0.0), "the stored recurrent state is an input, not a parameter"
    assert np.all(np.abs(g_obs[:, burn:-1]).sum(axis=(0, 2, 3, 4)) > 0)
    # Rewards reach the loss only through the (stop-gradient) targets: perturb them instead of differentiating.
    base = float(loss_fn(params, target, _as_batch(window)))
    for t in range(cfg.sequence_length):
        changed = float(loss_fn(params, target, _as_batch(window.replace(reward=window.reward.at[:, t].add(5.0)))))
        if t < burn or t == cfg.sequence_length - 1:  # burn-in rewards; the last step is only a bootstrap obs
            assert changed == base, f"reward of step {t} must not enter the loss"
        else:
            assert changed != base, f"reward of trained step {t} must enter the loss"
    # and the parameters do get a gradient
    gp = jax.jit(jax.grad(lambda p: loss_fn(p, target, _as_batch(window))))(params)
    assert sum(float(jnp.abs(x).sum()) for x in jax.tree.leaves(gp)) > 0


def test_loss_masks_the_episode_crossing_and_matches_hand_plumbing(trainer, learner, loss_fn):
    params, target = learner
    cfg, burn = SMOKE, SMOKE.replay.burn_in
    B, L, T_ = cfg.replay.batch_size, cfg.sequence_length, cfg.replay.train_len
    # window: obs 0..L-1. Episode ends at transition burn+1 (obs burn+2 is terminal), obs burn+3 starts a new one.
    is_first = np.zeros((B, L), bool)
    is_first[:, burn + 3] = True
    terminated = np.zeros((B, L), bool)
    terminated[:, burn + 1] = True
    window = _window(jax.random.PRNGKey(3), cfg, jnp.asarray(is_first), jnp.asarray(terminated))
    loss = loss_fn(params, target, _as_batch(window))

    # By hand, from the stored windows: both nets run over the WHOLE window from the stored state of step 0 (one
    # call, no burn-in split).
    h0, c0 = (jnp.moveaxis(x[:, 0], 0, 1) for x in (window.recurrent_state.h, window.recurrent_state.c))
    s0 = RecurrentState(h=h0, c=c0, frames=jnp.zeros((B, 0)))
    q_fn = jax.jit(lambda p: trainer.q_values(p, window.obs, window.is_first, s0)[0])
    q_on, q_tg = q_fn(params), q_fn(target)
    mask = np.ones((B, T_), np.float32)
    mask[:, 2] = 0.0  # transition burn+2: terminal obs -> first obs of the next episode
    expected, _ = sequence_td_loss(
        q_on[:, burn:],
        q_tg[:, burn:],
        window.action[:, burn:-1],
        window.reward[:, burn:-1] * cfg.learner.reward_scale,
        window.terminated[:, burn:-1],
        window.truncated[:, burn:-1],
        jnp.asarray(mask),
        SMOKE.learner.td,
    )
    np.testing.assert_allclose(float(loss), float(expected), rtol=2e-5)

    def perturbed(t, what):
        if what == "reward":
            return _as_batch(window.replace(reward=window.reward.at[:, t].add(10.0)))
        return _as_batch(window.replace(action=(window.action.at[:, t].add(1)) % 11))

    for what in ("reward", "action"):
        same = loss_fn(params, target, perturbed(burn + 2, what))
        assert float(same) == float(loss), f"the crossing transition's {what} must not matter"
        assert float(loss_fn(params, target, perturbed(burn, what))) != float(loss)


@pytest.mark.slow
def test_stored_recurrent_state_is_the_actors_state():
    cfg = SMOKE.override(env_params=(("max_steps", 6),))  # episodes end inside the rollout
    tr = T.Trainer(cfg)
    state = jax.jit(tr.init)(jax.random.PRNGKey(4))
    rollout = jax.jit(tr.rollout)
    params = state.learner.params
    actor, chunk1, _, _ = rollout(params, state.actor, jnp.int32(0), jax.random.PRNGKey(5))
    actor, chunk2, stats, _ = rollout(params, actor, jnp.int32(80), jax.random.PRNGKey(6))
    assert int(stats.episodes) > 0
    stored = chunk2.recurrent_state  # the network's own state type, without the frame history
    assert isinstance(stored, RecurrentState) and stored.frames is None
    h, c = np.asarray(stored.h), np.asarray(stored.c)  # [N, T, layers, units]
    assert np.all(np.asarray(chunk1.recurrent_state.h)[:, 0] == 0.0)  # fresh actors start from zeros
    assert np.abs(h).sum() > 0
    # Recompute the carries by stepping the network from the stored state of the chunk's first step.
    s = RecurrentState(
        h=jnp.moveaxis(stored.h[:, 0], 0, 1),
        c=jnp.moveaxis(stored.c[:, 0], 0, 1),
        frames=jnp.zeros((cfg.acting.num_envs, 0)),
    )
    step = jax.jit(lambda s, o, r: tr.q_values(params, o, r, s)[1])
    for t in range(cfg.acting.rollout_steps):
        s = step(s, chunk2.obs[:, t : t + 1], chunk2.is_first[:, t : t + 1])
        ref_h = np.moveaxis(np.asarray(s.h), 0, 1)
        if t + 1 < cfg.acting.rollout_steps:
            np.testing.assert_allclose(h[:, t + 1], ref_h, atol=1e-5)
            np.testing.assert_allclose(c[:, t + 1], np.moveaxis(np.asarray(s.c), 0, 1), atol=1e-5)
    np.testing.assert_allclose(np.asarray(actor.net_state.h), np.asarray(s.h), atol=1e-5)
    # next-step autoreset layout: an episode end at t -> step t+1 holds the final obs (reward 0, no flags)
    # -> step t+2 is_first
    done = np.asarray(chunk2.terminated | chunk2.truncated)
    first = np.asarray(chunk2.is_first)
    for n, t in zip(*np.nonzero(done[:, :-2])):
        assert first[n, t + 2] and not first[n, t + 1]
        assert float(chunk2.reward[n, t + 1]) == 0.0 and not done[n, t + 1]
    # the stored obs is quantised only when it enters the buffer, not here
    assert chunk2.obs.dtype == jnp.float32


@pytest.mark.slow
def test_auxiliary_loss_labels_are_the_true_tracking_error_and_train_the_aux_head():
    """The stored label of obs t+1 (the tracking error in stand-off distances) reproduces the env's reward for the
    transition into it (1 - w * 5 m * |label| while in view), and the aux loss reaches the aux head."""
    cfg = SMOKE.override(network=dataclasses.replace(SMOKE.network, aux_outputs=3), aux_weight=1.0)
    tr = T.Trainer(cfg)
    state = jax.jit(tr.init)(jax.random.PRNGKey(4))
    params = state.learner.params
    _, chunk, _, _ = jax.jit(tr.rollout)(params, state.actor, jnp.int32(0), jax.random.PRNGKey(5))
    label, reward = np.asarray(chunk.privileged), np.asarray(chunk.reward)  # [N, T, 3], [N, T]
    real = ~np.asarray(chunk.is_first)[:, 1:] & (reward[:, :-1] > -4.0)  # in view, not across an episode end
    assert real.sum() > 10
    expected = 1.0 - float(tr.env_params.dist_weight) * 5.0 * np.linalg.norm(label[:, 1:], axis=-1)
    np.testing.assert_allclose(reward[:, :-1][real], expected[real], atol=1e-4)
    window = _window(jax.random.PRNGKey(1), cfg).replace(
        privileged=jax.random.normal(jax.random.PRNGKey(2), (cfg.replay.batch_size, cfg.sequence_length, 3))
    )
    prepared = tr.prepare(params, params, _as_batch(window, cfg), jax.random.PRNGKey(0))
    (loss_w1, logged_w1), grads = jax.value_and_grad(tr.trained_loss, has_aux=True)(params, prepared)
    assert float(jnp.abs(grads["aux_head"]["kernel"]).sum()) > 0
    # The logged aux loss is the unweighted term the loss adds: the same at weights 1 and 3, where weight 3 adds
    # twice it more.
    loss_w3, logged_w3 = T.Trainer(cfg.override(aux_weight=3.0)).trained_loss(params, prepared)
    aux_w1, aux_w3 = float(logged_w1["terms"]["aux_loss"]), float(logged_w3["terms"]["aux_loss"])
    assert aux_w1 > 0
    np.testing.assert_allclose(aux_w3, aux_w1, rtol=1e-6)
    np.testing.assert_allclose(float(loss_w3 - loss_w1), 2.0 * aux_w1, rtol=1e-5)
    assert (
        "aux_head" not in jax.eval_shape(T.Trainer(SMOKE).init, jax.ShapeDtypeStruct((2,), jnp.uint32)).learner.params
    )


@pytest.mark.slow
def test_six_aux_outputs_add_the_relative_velocity_whose_integral_is_the_errors_change():
    """aux_outputs = 6: labels [N, T, 6], the tracking error as with 3, then the relative velocity in stand-off
    distances per second; the error moves from one obs to the next by the step's mean velocity times dt."""
    cfg = SMOKE.override(network=dataclasses.replace(SMOKE.network, aux_outputs=6), aux_weight=1.0)
    tr = T.Trainer(cfg)
    state = jax.jit(tr.init)(jax.random.PRNGKey(4))
    _, chunk, _, _ = jax.jit(tr.rollout)(state.learner.params, state.actor, jnp.int32(0), jax.random.PRNGKey(5))
    label = np.asarray(chunk.privileged)
    assert label.shape[-1] == 6
    same = ~np.asarray(chunk.is_first)[:, 1:]  # both obs in the same episode
    moved = label[:, 1:, :3] - label[:, :-1, :3]
    mean_velocity = 0.5 * (label[:, 1:, 3:] + label[:, :-1, 3:])
    assert same.sum() > 10 and np.abs(moved[same]).max() > 1e-3  # it moves, so the check can fail
    np.testing.assert_allclose(moved[same], mean_velocity[same] * float(tr.env_params.dt), atol=2e-4)


@pytest.mark.slow
def test_prev_action_is_stored_with_the_state_and_fed_back_by_the_greedy_policy():
    """With a prev_action network the stored state before step t+1 holds the action taken at step t, and the
    greedy policy acts as the network does over the same sequence with its own actions given."""
    cfg = SMOKE.override(network=dataclasses.replace(SMOKE.network, prev_action=True))
    tr = T.Trainer(cfg)
    state = jax.jit(tr.init)(jax.random.PRNGKey(4))
    params = state.learner.params
    _, chunk, _, _ = jax.jit(tr.rollout)(params, state.actor, jnp.int32(0), jax.random.PRNGKey(5))
    stored = np.asarray(chunk.recurrent_state.prev_action)[..., 0]  # [N, T]
    np.testing.assert_array_equal(stored[:, 1:], np.asarray(chunk.action)[:, :-1])
    policy = greedy.greedy_policy(cfg.network, params, cfg.env.obs_shape)
    obs = jax.random.uniform(jax.random.PRNGKey(8), (6, *cfg.env.obs_shape))
    ps, actions = policy.init(jax.random.PRNGKey(0)), []
    for t in range(6):
        a, ps = policy.act(jax.random.PRNGKey(t), ps, obs[t], None, None)
        actions.append(int(a))
    reset = jnp.zeros((1, 6), bool).at[0, 0].set(True)
    q, _ = tr.q_values(params, obs[None], reset, initial_state(cfg.network, 1), jnp.array([actions]))
    assert actions == np.asarray(jnp.argmax(q[0], -1)).tolist()


def test_the_retreat_search_backs_off_until_a_frame_shows_the_target_then_acts_greedily():
    """greedy_policy(search='retreat') commands RETREAT while every frame so far is blank, and from the first frame
    with a target pixel on (blank frames after it included) the network's greedy action, the network having been
    told the commands flown; an unknown search is a one-line error."""
    cfg = SMOKE.override(network=dataclasses.replace(SMOKE.network, prev_action=True))
    tr = T.Trainer(cfg)
    params = jax.jit(tr.init)(jax.random.PRNGKey(4)).learner.params
    visible = jax.random.uniform(jax.random.PRNGKey(8), (6, *cfg.env.obs_shape))
    obs = visible * jnp.array([0, 0, 1, 0, 0, 1], jnp.float32)[:, None, None, None]  # blank, blank, seen, ...
    policy = greedy.greedy_policy(cfg.network, params, cfg.env.obs_shape, search="retreat")
    ps, actions, seen = policy.init(jax.random.PRNGKey(0)), [], []
    for t in range(6):
        a, ps = policy.act(jax.random.PRNGKey(t), ps, obs[t], None, None)
        actions.append(int(a))
        seen.append(bool(ps.seen))
    assert actions[:2] == [env_lib.RETREAT] * 2 and seen == [False, False, True, True, True, True]
    reset = jnp.zeros((1, 6), bool).at[0, 0].set(True)
    q, _ = tr.q_values(params, obs[None], reset, initial_state(cfg.network, 1), jnp.array([actions]))
    assert actions[2:] == np.asarray(jnp.argmax(q[0], -1)).tolist()[2:]
    with pytest.raises(ValueError, match="search must be one of"):
        greedy.greedy_policy(cfg.network, params, cfg.env.obs_shape, search="spiral")


@pytest.mark.slow
def test_an_ensemble_takes_the_argmax_of_its_members_mean_q_each_told_the_commands_flown():
    """greedy_policy(members=2) over two parameter sets: at every step the argmax of the two networks' mean Q, each
    network run over the episode so far from its own memory with the ensemble's commands as its previous actions."""
    cfg = SMOKE.override(network=dataclasses.replace(SMOKE.network, prev_action=True))
    tr = T.Trainer(cfg)
    members = [jax.jit(tr.init)(jax.random.PRNGKey(k)).learner.params for k in (4, 5)]
    obs = jax.random.uniform(jax.random.PRNGKey(8), (6, *cfg.env.obs_shape))
    policy = greedy.greedy_policy(cfg.network, greedy.stack_params(members), cfg.env.obs_shape, members=2)
    ps, actions = policy.init(jax.random.PRNGKey(0)), []
    for t in range(6):
        a, ps = policy.act(jax.random.PRNGKey(t), ps, obs[t], None, None)
        actions.append(int(a))
    reset = jnp.zeros((1, 6), bool).at[0, 0].set(True)
    qs = [tr.q_values(p, obs[None], reset, initial_state(cfg.network, 1), jnp.array([actions]))[0][0] for p in members]
    assert actions == np.asarray(jnp.argmax(qs[0] + qs[1], -1)).tolist()
    for q in qs:  # neither member alone would have flown these commands
        assert actions != np.asarray(jnp.argmax(q, -1)).tolist()
    with pytest.raises(ValueError, match=r"members must be 0 \(one network\) or the leading axis"):
        greedy.greedy_policy(cfg.network, greedy.stack_params(members), cfg.env.obs_shape, members=3)


# ------------------------------------------------------------------------------------------ seeds
@pytest.mark.slow  # two compiles of the whole training function (~2-3 min on 2 cores)
def test_vmapped_seeds_equal_single_seed_runs():
    cfg = SMOKE.override(total_env_steps=640)  # 2 chunks, 8 gradient steps... cheap
    train = T.make_train(cfg)
    keys = jax.random.split(jax.random.PRNGKey(7), 2)
    both = jax.jit(jax.vmap(train))(keys)
    single = jax.jit(train)
    for i in range(2):
        one = single(keys[i])
        np.testing.assert_array_equal(np.asarray(both["metrics"].episodes[i]), np.asarray(one["metrics"].episodes))
        np.testing.assert_array_equal(
            np.asarray(both["runner_state"].replay.experience.action[i]),
            np.asarray(one["runner_state"].replay.experience.action),
        )
        for a, b in zip(
            jax.tree.leaves(both["runner_state"].learner.params), jax.tree.leaves(one["runner_state"].learner.params)
        ):
            np.testing.assert_allclose(np.asarray(a[i]), np.asarray(b), rtol=1e-4, atol=1e-5)
    assert int(both["runner_state"].learner.updates[0]) > 0
    diff = jax.tree.leaves(
        jax.tree.map(lambda x: float(jnp.abs(x[0] - x[1]).max()), both["runner_state"].learner.params)
    )
    assert max(diff) > 0  # the seeds really differ


# ------------------------------------------------------------------------------------------ greedy policy
def test_greedy_policy_matches_the_network_over_a_sequence(trainer, learner):
    params, _ = learner
    policy = greedy.greedy_policy(SMOKE.network, params, SMOKE.env.obs_shape)
    obs = jax.random.uniform(jax.random.PRNGKey(8), (5, *SMOKE.env.obs_shape))
    ps = policy.init(jax.random.PRNGKey(0))
    actions = []
    for t in range(5):
        a, ps = policy.act(jax.random.PRNGKey(t), ps, obs[t], None, None)
        actions.append(int(a))
    q, _ = trainer.q_values(
        params, obs[None], jnp.array([[True, False, False, False, False]]), initial_state(SMOKE.network, 1)
    )
    assert actions == np.asarray(jnp.argmax(q[0], -1)).tolist()


# ------------------------------------------------------------------------------------------ learning
EASY = SMOKE.override(
    # An easy task: a static, non-spinning target near r*, a fast chaser (random actions lose it quickly: any step out
    # of view ends the episode), 200-step episodes. The agent must learn from rewards which motions keep it in view.
    env_params=(
        ("init_xy_std", 0.3),
        ("init_z_max", 6.0),
        ("init_z_min", 4.0),
        ("lost_patience", 0),
        ("max_steps", 200),
        ("speed", 3.0),
        ("target_spin_std", 0.0),
        ("target_vel_std", 0.0),
    ),
    network=NetworkConfig(
        variant="origin",
        channels=(8, 16),
        kernels=(3, 3),
        strides=(1, 1),
        pools=(True, True),
        dense=64,
        lstm=64,
        lstm_layers=1,
        head=64,
    ),
    num_envs=16,
    rollout_steps=16,
    iterations_per_chunk=10,
    total_env_steps=40_960,
    eps_start=1.0,
    eps_end=0.05,
    eps_decay_steps=16_000,
    capacity_steps=8192,
    burn_in=2,
    train_len=8,
    batch_size=16,
    learning_starts=1024,
    replay_ratio=4.0,
    lr=1e-3,
    gamma=0.9,
    n_step=3,
    reward_scale=0.1,
    polyak_tau=0.05,
)


@pytest.mark.slow
def test_learns_an_easy_task():
    # ~25 s of training on 2 idle cores (plus ~20 s compile); measured: random ~100, untrained greedy ~115,
    # trained greedy ~195 of 200 steps.
    out = jax.jit(T.make_train(EASY))(jax.random.PRNGKey(0))
    params = out["runner_state"].learner.params
    tracking_env = env_lib.TrackingEnv(EASY.env)
    env_params = tracking_env.default_params(**dict(EASY.env_params))
    key = jax.random.PRNGKey(123)
    learned = evaluate.summarise(
        evaluate.run_episodes(
            tracking_env, greedy.greedy_policy(EASY.network, params, EASY.env.obs_shape), env_params, key, 64
        )[0]
    )
    rand = evaluate.summarise(evaluate.run_episodes(tracking_env, baselines.random_policy(), env_params, key, 64)[0])
    m = out["metrics"]
    print(
        f"random {rand.length_mean:.1f}, greedy {learned.length_mean:.1f}, training episodes per chunk "
        f"{np.round(np.asarray(m.episode_length_sum.sum(1) / np.maximum(m.episodes.sum(1), 1)), 1)}"
    )
    assert learned.length_mean > 1.5 * rand.length_mean, (learned, rand)
    assert int(out["runner_state"].learner.updates) == EASY.total_updates  # what an lr schedule decays over


def test_bootstrap_lost_turns_terminations_into_bootstrapped_ends(trainer, learner):
    """With bootstrap_lost, a 'target lost' termination is bootstrapped like a time limit (the loss changes), and
    nothing else in the prepared batch does."""
    params, target = learner
    term = jnp.zeros((SMOKE.replay.batch_size, SMOKE.sequence_length), bool).at[:, SMOKE.replay.burn_in + 2].set(True)
    batch = _as_batch(_window(jax.random.PRNGKey(5), SMOKE, terminated=term))
    boot = T.Trainer(SMOKE.override(bootstrap_lost=True))
    plain_prep = trainer.prepare(params, target, batch, jax.random.PRNGKey(0))
    boot_prep = boot.prepare(params, target, batch, jax.random.PRNGKey(0))
    assert isinstance(plain_prep, train_state.PreparedBatch)
    plain, booted = plain_prep.loss_batch, boot_prep.loss_batch
    assert bool(plain.terminated.any()) and not bool(booted.terminated.any())
    np.testing.assert_array_equal(np.asarray(booted.truncated), np.asarray(plain.truncated | plain.terminated))
    np.testing.assert_array_equal(np.asarray(boot_prep.obs), np.asarray(plain_prep.obs))
    for k in ("reward", "action", "mask", "q_target"):
        np.testing.assert_array_equal(np.asarray(getattr(booted, k)), np.asarray(getattr(plain, k)))
    assert float(trainer.trained_loss(params, plain_prep)[0]) != float(boot.trained_loss(params, boot_prep)[0])


# ------------------------------------------------------------------------------------------ prioritised replay
@pytest.mark.slow
def test_prioritised_training_sets_the_sampled_windows_priorities():
    """With ReplayConfig.priority_exponent > 0 the learner writes each sampled window's priority (from its TD errors)
    into the buffer's sum tree: after two chunks the stored priorities are no longer the one that new windows get,
    and the loss stays finite."""
    from flashbax.buffers import sum_tree

    cfg = SMOKE.override(total_env_steps=640, priority_exponent=0.9)
    out = jax.jit(T.make_train(cfg))(jax.random.PRNGKey(3))
    tree = out["runner_state"].replay.sum_tree_state
    assert int(out["runner_state"].learner.updates) > 0 and np.isfinite(np.asarray(out["metrics"].loss_sum)).all()
    stored = np.asarray(jax.vmap(lambda i: sum_tree.get(tree, i))(jnp.arange(tree.capacity)))
    written = stored[stored > 0]
    assert len(np.unique(np.round(written, 6))) > 2, np.unique(written)  # new windows share one; updates differ


# ------------------------------------------------------------------------------------------ online bootstrap
@pytest.mark.slow
def test_online_targets_equal_target_net_targets_when_the_nets_are_equal(trainer, learner):
    """LearnerConfig.bootstrap_from='online' bootstraps from the trained pass's own values under stop_gradient. With
    target params = online params the target-net path bootstraps from the same values (its pass runs from the
    window's stored state through burn-in, as the online one does), so loss and gradients agree; with the nets apart
    they differ, so the comparison can fail. The target net is never read."""
    params, target = learner
    online = T.Trainer(SMOKE.override(bootstrap_from="online"))
    batch = _as_batch(_window(jax.random.PRNGKey(6), SMOKE))
    grad_fns = {tr: jax.jit(jax.value_and_grad(tr.loss, has_aux=True)) for tr in (trainer, online)}
    grad = lambda tr, t: grad_fns[tr](params, t, batch, jax.random.PRNGKey(0))  # noqa: E731
    (loss_t, _), grads_t = grad(trainer, params)
    (loss_o, _), grads_o = grad(online, target)  # the target params are not read
    np.testing.assert_allclose(float(loss_o), float(loss_t), rtol=1e-5)
    for g_o, g_t in zip(jax.tree.leaves(grads_o), jax.tree.leaves(grads_t)):
        np.testing.assert_allclose(np.asarray(g_o), np.asarray(g_t), rtol=1e-4, atol=1e-6)
    assert abs(float(grad(trainer, target)[0][0]) - float(loss_t)) > 1e-4
    # NaN target params: the online-bootstrap loss stays finite (the target pass is skipped, not computed and
    # discarded), the target-net loss does not
    poisoned = jax.tree.map(lambda p: jnp.full_like(p, jnp.nan), params)
    assert online.prepare(params, poisoned, batch, jax.random.PRNGKey(0)).loss_batch.q_target is None
    assert np.isfinite(float(grad(online, poisoned)[0][0])) and not np.isfinite(float(grad(trainer, poisoned)[0][0]))


# ------------------------------------------------------------------------------------------ extension points
def test_a_loss_term_from_outside_joins_the_sum_and_logs_its_metrics(trainer, learner):
    """Trainer(loss_terms=...): the terms' losses add up, each term's metrics reach the logged stats, and a metric
    two terms both return is refused."""
    params, target = learner
    batch = _as_batch(_window(jax.random.PRNGKey(6), SMOKE))
    prepared = trainer.prepare(params, target, batch, jax.random.PRNGKey(0))

    def mean_q(b):  # a term that pulls every value down a little
        loss = 0.5 * jnp.mean(b.q)
        return loss, {"mean_q": loss}

    extended = T.Trainer(SMOKE, loss_terms=T.default_loss_terms(SMOKE) + (mean_q,))
    plain_loss, plain = trainer.trained_loss(params, prepared)
    loss, logged = extended.trained_loss(params, prepared)
    assert set(plain["terms"]) == {"td_loss"} and set(logged["terms"]) == {"td_loss", "mean_q"}
    np.testing.assert_allclose(float(loss), float(plain_loss) + float(logged["terms"]["mean_q"]), rtol=1e-6)
    np.testing.assert_allclose(float(plain_loss), float(plain["terms"]["td_loss"]), rtol=1e-6)
    twice = T.Trainer(SMOKE, loss_terms=(mean_q, mean_q))
    with pytest.raises(ValueError, match="two loss terms return the metric 'mean_q'"):
        twice.trained_loss(params, prepared)
    stats = jax.eval_shape(extended.chunk, jax.eval_shape(extended.init, jax.ShapeDtypeStruct((2,), jnp.uint32)))[1]
    assert set(stats.term_sums) == {"td_loss", "mean_q"}


def test_a_network_factory_builds_the_network_the_trainer_trains_and_the_greedy_policy_flies():
    """Trainer(network_factory=...) and greedy_policy(network_factory=...): a network made outside the package
    (here the QNetwork with a dueling output layer) is initialised, trained and acted with in place of the
    config's, with no config field."""
    import flax.linen as nn

    from ramavt_jax.network import QNetwork

    def dueling(cfg, y):
        advantage = nn.Dense(cfg.num_actions, name="q")(y)
        return nn.Dense(1, name="value")(y) + advantage - advantage.mean(-1, keepdims=True)

    factory = lambda cfg: QNetwork(cfg, q_head=dueling)  # noqa: E731
    tr = T.Trainer(SMOKE, network_factory=factory)
    state = jax.eval_shape(tr.init, jax.ShapeDtypeStruct((2,), jnp.uint32))
    assert "value" in state.learner.params and "value" in state.learner.target_params
    params = jax.jit(tr.init)(jax.random.PRNGKey(0)).learner.params
    policy = greedy.greedy_policy(SMOKE.network, params, SMOKE.env.obs_shape, network_factory=factory)
    obs = jax.random.uniform(jax.random.PRNGKey(8), SMOKE.env.obs_shape)
    action, _ = policy.act(jax.random.PRNGKey(0), policy.init(jax.random.PRNGKey(0)), obs, None, None)
    q, _ = tr.q_values(params, obs[None, None], jnp.ones((1, 1), bool), initial_state(SMOKE.network, 1))
    assert int(action) == int(jnp.argmax(q[0, 0]))
