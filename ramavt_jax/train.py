"""Recurrent DQN training (R2D2-style) for the tracking task: the jitted trainer. Its config lives in
:mod:`ramavt_jax.train_config`, the named presets in :mod:`ramavt_jax.presets`, its state containers in
:mod:`ramavt_jax.train_state`.

API (purejaxrl shape)::

    cfg = presets.preset("quick")                       # or TrainConfig(...), frozen and validated
    train = make_train(cfg)                             # pure function of a key
    out = jax.jit(train)(jax.random.PRNGKey(0))         # {'runner_state': RunnerState, 'metrics': ChunkMetrics}
    outs = jax.jit(jax.vmap(make_train(cfg)))(keys)     # several seeds at once (small configs)
    summary = training.driver.run(cfg, "runs/quick")    # host driver: logs, checkpoints (ramavt_jax/training/)

One *iteration* = every env acts ``rollout_steps`` steps (epsilon-greedy, next-step auto-reset), the chunk goes to
the sequence replay, then the learner does ``updates_per_iteration`` gradient steps (none before
``learning_starts``). One *chunk* = ``iterations_per_chunk`` iterations in one ``lax.scan`` inside one jitted
call; the host only logs, evaluates and checkpoints between chunks.

Learner: sample ``batch_size`` windows of ``burn_in + train_len + 1`` stored steps; from the stored recurrent
state run ``burn_in`` steps through the online net under ``stop_gradient`` (the target net runs over the whole
window from the same stored state, also without gradient), then the masked double-Q / n-step (or lambda-return) TD loss
(:mod:`ramavt_jax.losses`) over the ``train_len`` transitions after burn-in. With ``bootstrap_from='online'`` the
targets bootstrap from the trained pass's own values under ``stop_gradient`` and the target pass is skipped.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import optax

from ramavt_jax import distributed, imitation
from ramavt_jax import env as env_lib
from ramavt_jax import replay as replay_lib
from ramavt_jax.augment import augment_batch
from ramavt_jax.greedy import privileged_of, privileged_size, standoff_signal, unbatch_state
from ramavt_jax.losses import TDBatch, masked_mean, sequence_priority, td_loss
from ramavt_jax.network import (
    TRUE_STATE_SIZE,
    init_params,
    initial_state,
    make_network,
    record_action,
    window_start_frames,
)
from ramavt_jax.train_config import TrainConfig
from ramavt_jax.train_state import (
    ActorState,
    ChunkMetrics,
    EpisodeStats,
    LearnerState,
    LearnStats,
    PreparedBatch,
    RolloutCarry,
    RunnerState,
    average_policy,
)

__all__ = ["Trainer", "make_train"]


def _raw_key(key: jax.Array) -> jax.Array:
    if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
        return jax.random.key_data(key)
    return key


# ============================================================================================ trainer
class Trainer:
    """Pure pieces of training for one config: ``init(key)``, ``chunk(state)``, ``train(key)`` (vmappable).

    ``mesh`` (a 1-D ``jax.sharding.Mesh``, see :mod:`ramavt_jax.distributed`): the program keeps the envs and the
    sampled learner batch split over its devices (sharding hints only; the maths is unchanged). The caller jits
    with :func:`distributed.runner_shardings` as in/out shardings.
    """

    def __init__(
        self,
        config: TrainConfig,
        tracking_env: env_lib.TrackingEnv | None = None,
        mesh=None,
        debug_nan_at_update: int = -1,
    ):
        """``debug_nan_at_update`` (a test hook, not configuration): the loss and gradients become NaN from this
        gradient step on (-1 = off)."""
        distributed.check_divisible(config.acting.num_envs, mesh)
        self.config, self.mesh, self.debug_nan_at_update = config, mesh, debug_nan_at_update
        self.env = tracking_env if tracking_env is not None else env_lib.TrackingEnv(config.env)
        self.env_params = self.env.default_params(**dict(config.env_params))
        self.obs_shape = tuple(config.env.obs_shape)
        self.net = make_network(config.network)
        learner = config.learner
        self.td = learner.td
        # learning rate of gradient step k (a float when constant: the optimiser state then has no step count)
        self.learning_rate = (
            learner.lr
            if learner.lr_final is None
            else optax.cosine_decay_schedule(
                learner.lr, max(config.total_updates, 1), alpha=learner.lr_final / learner.lr
            )
        )
        # the target net's step towards the online net at gradient step k (LearnerConfig.polyak_tau_start)
        hold, end = learner.polyak_tau_decay
        self.polyak_tau = (
            (lambda k: learner.polyak_tau)
            if learner.polyak_tau_start is None
            else optax.linear_schedule(
                learner.polyak_tau_start, learner.polyak_tau, transition_steps=max(end - hold, 1), transition_begin=hold
            )
        )
        lr_tx = optax.adam(self.learning_rate, eps=learner.adam_eps)
        self.optimizer = (
            optax.chain(optax.clip_by_global_norm(learner.max_grad_norm), lr_tx) if learner.max_grad_norm > 0 else lr_tx
        )
        self.augment_fn = functools.partial(augment_batch, config=learner.augment_config) if learner.augment else None
        # the look-ahead flies teacher_envs envs; with a margin loss or a policy head it labels every env's steps
        self.labels = bool(learner.expert_margin_weight) or config.network.policy_head  # (stored in the replay)
        self.replay = replay_lib.make_replay(config.replay, config.acting.num_envs, self._example_transition())
        self.taught_envs = config.acting.num_envs if self.labels else config.acting.teacher_envs
        self.teacher = imitation.look_ahead_teacher(self.env.config) if self.taught_envs else None

    # ---------------------------------------------------------------- helpers
    def _example_transition(self) -> replay_lib.Transition:
        s = initial_state(self.config.network, 1, self.obs_shape)
        return replay_lib.Transition(
            obs=jnp.zeros(self.obs_shape),
            action=jnp.zeros((), jnp.int32),
            reward=jnp.zeros(()),
            terminated=jnp.zeros((), bool),
            truncated=jnp.zeros((), bool),
            is_first=jnp.zeros((), bool),
            recurrent_state=unbatch_state(s).replace(frames=None),
            privileged=jnp.zeros((self._privileged_size,)) if self._privileged_size else None,
            standoff=jnp.ones(()) if self.config.network.reads_standoff else None,
            expert_action=jnp.zeros((), jnp.int32) if self.labels else None,
        )

    def _per_device(self, batched_fn):
        """Run a function of per-env arrays ([N, ...] in and out) on each device's own envs (``jax.shard_map``).
        Needed for the env step: left to the automatic partitioner, the renderer's batch-wide work list is
        all-gathered and every device re-renders the whole batch (measured 0.1-0.7x of one device, see
        benchmarks/RESULTS.md). The keys are split globally first, so every env draws what it would unsharded."""
        if self.mesh is None:
            return batched_fn
        spec = distributed.P(distributed.DATA_AXIS)
        return jax.shard_map(batched_fn, mesh=self.mesh, in_specs=spec, out_specs=spec, check_vma=False)

    def _shard_batch(self, batch: replay_lib.SequenceBatch) -> replay_lib.SequenceBatch:
        """Split a sampled batch over the mesh along B (data-parallel gradients) when B divides. The start state is
        in the network's layout, B on axis 1."""
        b = self.config.replay.batch_size
        rest = distributed.constrain_batch(batch.replace(start_state=None), self.mesh, b)
        return rest.replace(start_state=distributed.constrain_batch(batch.start_state, self.mesh, b, batch_axis=1))

    def _shard_actor(self, actor: ActorState) -> ActorState:
        if self.mesh is None:
            return actor
        m, ns = self.mesh, actor.net_state
        return actor.replace(
            env_state=distributed.constrain_envs(actor.env_state, m),
            obs=distributed.constrain_envs(actor.obs, m),
            is_first=distributed.constrain_envs(actor.is_first, m),
            net_state=jax.tree.map(lambda x: distributed.constrain_envs(x, m, 1), ns.replace(frames=None)).replace(
                frames=distributed.constrain_envs(ns.frames, m)
            ),
        )

    def epsilon(self, env_steps: jax.Array) -> jax.Array:
        """The exploration rate after ``env_steps``: [] shared by all envs, or [N] one per env with a ladder
        (ActingConfig.eps_ladder)."""
        c = self.config.acting
        frac = jnp.clip(env_steps / max(c.eps_decay_steps, 1), 0.0, 1.0) if c.eps_decay_steps else 1.0
        end = c.eps_end
        if c.eps_ladder:
            end = c.eps_end ** (1.0 + c.eps_ladder * jnp.arange(c.num_envs) / max(c.num_envs - 1, 1))
        return c.eps_start + (end - c.eps_start) * frac

    def q_values(self, params, obs, reset, state, actions=None, standoff=None, privileged=None):
        """Online/target forward: obs [B, T, H, W, C], reset [B, T], actions [B, T] (taken; read by prev_action
        networks), standoff [B, T] (greedy.standoff_signal), privileged [B, T, K] (the stored true state; read by
        state_input networks) -> (q [B, T, A], state); with NetworkConfig.policy_head q is the logits, Q sown."""
        return self.net.apply(
            {"params": params},
            obs,
            reset,
            state,
            actions=actions,
            standoff=standoff,
            true_state=self._state_input(privileged),
        )

    @property
    def _privileged_size(self) -> int:
        """K, the entries kept per obs (greedy.privileged_of): six for a state_input network (twelve when its input is
        not the centre's true state), else the auxiliary head's outputs (0: nothing kept)."""
        return privileged_size(self.config.network, self.config.learner.aux_weight)

    def _state_input(self, privileged):
        """A state_input network's input [B, T, 6], the last six kept entries [B, T, K]; None for other networks."""
        reads = self.config.network.state_input and privileged is not None
        return privileged[..., -TRUE_STATE_SIZE:] if reads else None

    # ---------------------------------------------------------------- init
    def init(self, key: jax.Array) -> RunnerState:
        c, n = self.config, self.config.acting.num_envs
        key = _raw_key(key)
        key, k_net, k_env = jax.random.split(key, 3)
        params = init_params(c.network, k_net, self.obs_shape)["params"]
        learner = LearnerState(
            params=params,
            target_params=jax.tree.map(jnp.copy, params),
            opt_state=self.optimizer.init(params),
            updates=jnp.zeros((), jnp.int32),
            averaged_params=(None if c.run.policy_average_from is None else jax.tree.map(jnp.copy, params)),
        )
        obs, env_state = self._per_device(jax.vmap(lambda k: self.env.reset(k, self.env_params)))(
            jax.random.split(k_env, n)
        )
        actor = self._shard_actor(
            ActorState(
                env_state=env_state,
                obs=obs,
                is_first=jnp.ones((n,), bool),
                net_state=initial_state(c.network, n, self.obs_shape),
            )
        )
        return RunnerState(
            learner=learner,
            actor=actor,
            replay=self.replay.init(),
            key=key,
            env_steps=jnp.zeros((), jnp.int32),
            chunk=jnp.zeros((), jnp.int32),
        )

    # ---------------------------------------------------------------- acting
    def act_step(self, params, actor: ActorState, epsilon: jax.Array, key: jax.Array):
        """One epsilon-greedy step of all envs, epsilon [] or [N]: (actor, Transition [N, ...] (state [layers, N,
        units]), stats)."""
        c = self.config.acting
        if self.taught_envs:  # runs without the look-ahead keep the plain split below, and so their draws
            key, k_teach = jax.random.split(key)
        k_eps, k_rand, k_env = jax.random.split(key, 3)
        standoff = (
            jax.vmap(lambda s: standoff_signal(self.config.network, s, self.env_params))(actor.env_state)
            if self.config.network.reads_standoff
            else None
        )  # [N]
        kept, state_of = self._privileged_size, privileged_of(self.config.network, self.env.config.camera)
        privileged = jax.vmap(state_of, (0, None))(actor.env_state, self.env_params)[:, :kept] if kept else None
        q, net_state = self.q_values(
            params,
            actor.obs[:, None],
            actor.is_first[:, None],
            actor.net_state,
            standoff=None if standoff is None else standoff[:, None],
            privileged=None if privileged is None else privileged[:, None],
        )
        greedy = jnp.argmax(q[:, 0], axis=-1).astype(jnp.int32)
        explore = jax.random.uniform(k_eps, (c.num_envs,)) < epsilon
        action = jnp.where(explore, jax.random.randint(k_rand, (c.num_envs,), 0, env_lib.NUM_ACTIONS), greedy)
        taught = (
            imitation.teacher_actions(
                self.teacher, jax.tree.map(lambda x: x[: self.taught_envs], actor.env_state), self.env_params, k_teach
            )
            if self.taught_envs
            else None
        )  # [taught_envs]
        if c.teacher_envs:
            action = action.at[: c.teacher_envs].set(taught[: c.teacher_envs])
        obs, env_state, reward, terminated, truncated, info = self._per_device(
            jax.vmap(lambda k, s, a: self.env.step(k, s, a, self.env_params))
        )(jax.random.split(k_env, c.num_envs), actor.env_state, action)
        # the replay keeps the state but its frame histories (drlavt, frame_difference), which burn-in rebuilds
        transition = replay_lib.Transition(
            obs=actor.obs,
            action=action,
            reward=reward,
            terminated=terminated,
            truncated=truncated,
            is_first=actor.is_first,
            recurrent_state=actor.net_state.replace(frames=None),
            privileged=privileged,
            standoff=standoff,
            expert_action=imitation.stored_labels(
                taught, actor.env_state, self.env.config.camera, self.config.learner.blind_label
            )
            if self.labels
            else None,
        )
        new_actor = ActorState(
            env_state=env_state, obs=obs, is_first=info["is_first"], net_state=record_action(net_state, action)
        )
        done = (terminated | truncated) & (jnp.arange(c.num_envs) >= c.teacher_envs)  # the agent's episodes only
        stats = EpisodeStats(
            episodes=done.sum(),
            length_sum=jnp.where(done, info["episode_length"], 0).sum(),
            return_sum=jnp.where(done, info["episode_return"], 0.0).sum(),
        )
        return new_actor, transition, stats

    def rollout(self, params, actor: ActorState, env_steps: jax.Array, key: jax.Array):
        """``rollout_steps`` acting steps. Returns (actor, chunk [N, T, ...] in replay layout, summed stats, the last
        step's exploration rate averaged over envs)."""
        c = self.config.acting

        def body(carry: RolloutCarry, k):
            eps = self.epsilon(carry.env_steps)
            actor, tr, stats = self.act_step(params, carry.actor, eps, k)
            return RolloutCarry(actor=actor, env_steps=carry.env_steps + c.num_envs), (tr, stats, eps)

        last, (traj, stats, eps) = jax.lax.scan(
            body, RolloutCarry(actor=actor, env_steps=env_steps), jax.random.split(key, c.rollout_steps)
        )
        return last.actor, replay_lib.chunk_to_storage(traj), jax.tree.map(jnp.sum, stats), eps[-1].mean()

    # ---------------------------------------------------------------- learning
    def _target_values(self, params, obs, reset, state, actions, standoff, privileged):
        """The target net's values over a window: q [B, L, A], or its quantiles [B, L, A, N] for a quantile network
        (NetworkConfig.quantiles), which the quantile loss takes; a policy head's network sows its Q."""
        network = self.config.network
        if not (network.quantiles or network.policy_head):
            return self.q_values(params, obs, reset, state, actions, standoff, privileged)[0]
        _, sown = self.net.apply(
            {"params": params},
            obs,
            reset,
            state,
            actions=actions,
            standoff=standoff,
            true_state=self._state_input(privileged),
            mutable=["intermediates"],
        )
        return sown["intermediates"]["quantiles" if network.quantiles else "q_values"][0]

    def prepare(self, params, target_params, batch: replay_lib.SequenceBatch, key: jax.Array) -> PreparedBatch:
        """Everything the loss needs that takes no gradient: (augmented) observations, the target net's Q over the
        window (None with LearnerConfig.bootstrap_from = 'online') and the online net's state after burn-in, both run
        from the window's stored start state."""
        c, sg = self.config, jax.lax.stop_gradient
        burn, obs = batch.burn_in, batch.obs
        if self.augment_fn is not None:
            obs = self.augment_fn(key, obs)
        state = batch.start_state.replace(frames=window_start_frames(c.network, obs))
        standoff, privileged = batch.standoff, batch.privileged  # [B, L] and [B, L, K], either may be None
        steps = lambda x, part: jax.tree.map(lambda a: a[:, part], x)  # noqa: E731 (optional inputs: None stays None)
        q_target = None  # bootstrap_from='online': trained_loss takes the trained pass's values
        if c.learner.bootstrap_from == "target":
            q_target = sg(
                self._target_values(target_params, obs, batch.reset, state, batch.action, standoff, privileged)
            )[:, burn:]
        if burn:
            _, state = self.q_values(
                params,
                obs[:, :burn],
                batch.reset[:, :burn],
                state,
                batch.action[:, :burn],
                steps(standoff, slice(None, burn)),
                steps(privileged, slice(None, burn)),
            )
        terminated, truncated = batch.terminated[:, burn:], batch.truncated[:, burn:]
        if c.learner.bootstrap_lost:  # see LearnerConfig.bootstrap_lost
            terminated, truncated = jnp.zeros_like(terminated), truncated | terminated
        reward, action = batch.reward[:, burn:], batch.action[:, burn:]
        if c.learner.command_cost:  # see LearnerConfig.command_cost
            reward = reward - c.learner.command_cost * jnp.linalg.norm(jnp.asarray(env_lib.ACTIONS), axis=-1)[action]
        td = TDBatch(
            q_target=q_target,
            action=action,
            reward=sg(reward * c.learner.reward_scale),
            terminated=terminated,
            truncated=truncated,
            mask=batch.loss_mask[:, burn:],
            weight=batch.weights,
        )
        trained = slice(burn, None)
        return PreparedBatch(
            obs=obs[:, trained],
            reset=batch.reset[:, trained],
            state=sg(state),
            td=td,
            privileged=steps(privileged, trained),
            standoff=steps(standoff, trained),
            expert_action=steps(batch.expert_action, trained),
        )

    def trained_loss(self, params, prepared: PreparedBatch):
        """TD loss over the trained part of the window, plus aux_weight times the auxiliary head's squared error,
        expert_margin_weight times the large-margin loss (imitation.large_margin_loss) and policy_weight times a
        policy head's cross-entropy (imitation.policy_terms), gradient w.r.t. params only. Returns (loss, aux); aux
        holds q_mean, aux_loss, margin_loss and policy_loss (unweighted, 0 without), expert_agreement (of the acting
        head) and with a prioritised replay each window's priority [B] (losses.sequence_priority)."""
        (q_online, _), sown = self.net.apply(
            {"params": params},
            prepared.obs,
            prepared.reset,
            prepared.state,
            actions=prepared.td.action,
            standoff=prepared.standoff,
            true_state=self._state_input(prepared.privileged),
            mutable=["intermediates"],
        )
        mask, learner, expert = prepared.td.mask.astype(jnp.float32), self.config.learner, prepared.expert_action
        logits, policy_loss = q_online, jnp.zeros(())
        if self.config.network.policy_head:  # the returned values are the policy's logits; Q is sown
            q_online = sown["intermediates"]["q_values"][0]
        margin_loss, agreement = (
            imitation.margin_terms(
                q_online[:, :-1], expert, mask, learner.expert_margin, prepared.td.weight
            )  # on Q (a quantile network's mean)
            if learner.expert_margin_weight
            else (jnp.zeros(()), jnp.zeros(()))
        )
        if self.config.network.quantiles:  # the quantile loss (losses.sequence_quantile_loss)
            q_online = sown["intermediates"]["quantiles"][0]
        td = prepared.td
        if td.q_target is None:  # LearnerConfig.bootstrap_from = 'online': this pass's own values, as constants
            td = td.replace(q_target=jax.lax.stop_gradient(q_online))
        loss, aux = td_loss(q_online, td, self.td)
        loss = loss + learner.expert_margin_weight * margin_loss
        if self.config.network.policy_head:  # its agreement, the acting head's, is the one logged
            policy_loss, agreement = imitation.policy_terms(logits[:, :-1], expert, mask, prepared.td.weight)
            loss = loss + learner.policy_weight * policy_loss
        aux_loss = jnp.zeros(())
        if learner.aux_weight:  # the aux head's squared error at the trained obs (LearnerConfig)
            label = prepared.privileged[:, :-1, : self.config.network.aux_outputs]
            miss = jnp.square(sown["intermediates"]["aux"][0][:, :-1] - label).sum(-1)
            aux_loss = masked_mean(miss, mask)
            loss = loss + learner.aux_weight * aux_loss
        aux = dict(
            aux,
            q_mean=masked_mean(aux["q_taken"], mask),
            aux_loss=aux_loss,
            margin_loss=margin_loss,
            expert_agreement=agreement,
            policy_loss=policy_loss,
        )
        if self.config.replay.prioritised:  # uniform sampling needs no priorities
            td_error = jax.lax.stop_gradient(aux["td_error"])
            aux["priority"] = sequence_priority(td_error, mask, self.config.replay.priority_max_share)
        return loss, aux

    def loss(self, params, target_params, batch: replay_lib.SequenceBatch, key: jax.Array):
        """Masked loss of one sampled batch (trained_loss): burn-in without gradient, then the loss over the
        ``train_len`` transitions after it. Returns (loss, aux)."""
        return self.trained_loss(params, self.prepare(params, target_params, batch, key))

    def update(self, learner: LearnerState, replay_state, key: jax.Array):
        """One gradient step on a fresh sample. Returns (learner, replay_state, LearnStats): the replay state holds
        the sampled windows' new priorities when sampling is prioritised (ReplayConfig.priority_exponent)."""
        c = self.config.learner
        k_sample, k_aug = jax.random.split(key)
        batch = self._shard_batch(self.replay.sample(replay_state, k_sample))
        prepared = self.prepare(learner.params, learner.target_params, batch, k_aug)
        (loss, aux), grads = jax.value_and_grad(self.trained_loss, has_aux=True)(learner.params, prepared)
        if self.debug_nan_at_update >= 0:
            poison = learner.updates >= self.debug_nan_at_update
            loss = jnp.where(poison, jnp.nan, loss)
            grads = jax.tree.map(lambda g: jnp.where(poison, jnp.nan, g), grads)
        updates, opt_state = self.optimizer.update(grads, learner.opt_state, learner.params)
        params = optax.apply_updates(learner.params, updates)
        n = learner.updates + 1
        if c.target_update == "polyak":
            target = optax.incremental_update(params, learner.target_params, self.polyak_tau(learner.updates))
        else:
            target = optax.periodic_update(params, learner.target_params, n, c.target_period)
        new = learner.replace(params=params, target_params=target, opt_state=opt_state, updates=n)
        if batch.indices is not None:
            replay_state = self.replay.set_priorities(replay_state, batch, aux["priority"])
        return (
            new,
            replay_state,
            LearnStats(
                loss=loss,
                aux_loss=aux["aux_loss"],
                q_mean=aux["q_mean"],
                margin_loss=aux["margin_loss"],
                expert_agreement=aux["expert_agreement"],
                policy_loss=aux["policy_loss"],
                grad_norm=optax.tree.norm(grads),
                updates=jnp.ones((), jnp.int32),
            ),
        )

    def learn(self, learner: LearnerState, replay_state, env_steps: jax.Array, key: jax.Array):
        """``updates_per_iteration`` steps if the replay is ready, else none. Returns (learner, replay_state,
        summed LearnStats); only a prioritised buffer's sum tree changes (SequenceReplay.sampling_state), so only it
        is carried through the updates."""
        c, replay = self.config, self.replay
        ready = (env_steps >= c.learner.learning_starts) & replay.can_sample(replay_state)

        def one_update(carry, k):
            learner, sampling = carry
            learner, state, stats = self.update(learner, replay.with_sampling_state(replay_state, sampling), k)
            return (learner, replay.sampling_state(state)), stats

        def do(carry):
            carry, stats = jax.lax.scan(one_update, carry, jax.random.split(key, c.updates_per_iteration))
            return carry, jax.tree.map(jnp.sum, stats)

        def skip(carry):
            return carry, LearnStats.zeros()

        (learner, sampling), stats = jax.lax.cond(ready, do, skip, (learner, replay.sampling_state(replay_state)))
        return learner, replay.with_sampling_state(replay_state, sampling), stats

    def iteration(self, runner: RunnerState) -> tuple[RunnerState, ChunkMetrics]:
        key, k_act, k_learn = jax.random.split(runner.key, 3)
        actor, chunk, stats, eps = self.rollout(runner.learner.params, runner.actor, runner.env_steps, k_act)
        actor = self._shard_actor(actor)
        chunk = distributed.constrain_envs(chunk, self.mesh)
        replay_state = self.replay.add(runner.replay, chunk)
        env_steps = runner.env_steps + self.config.env_steps_per_iteration
        learner, replay_state, learned = self.learn(runner.learner, replay_state, env_steps, k_learn)
        metrics = ChunkMetrics(
            episodes=stats.episodes,
            episode_length_sum=stats.length_sum,
            episode_return_sum=stats.return_sum,
            loss_sum=learned.loss,
            aux_loss_sum=learned.aux_loss,
            q_sum=learned.q_mean,
            margin_loss_sum=learned.margin_loss,
            expert_agreement_sum=learned.expert_agreement,
            policy_loss_sum=learned.policy_loss,
            grad_norm_sum=learned.grad_norm,
            updates=learned.updates,
            epsilon=eps,
            env_steps=env_steps,
        )
        runner = runner.replace(learner=learner, actor=actor, replay=replay_state, key=key, env_steps=env_steps)
        return runner, metrics

    def chunk(self, runner: RunnerState) -> tuple[RunnerState, ChunkMetrics]:
        """``iterations_per_chunk`` iterations in one lax.scan (jit this; metrics are [iterations])."""
        runner, metrics = jax.lax.scan(
            lambda r, _: self.iteration(r), runner, None, length=self.config.run.iterations_per_chunk
        )
        chunk = runner.chunk + 1
        averaged = average_policy(runner.learner, chunk, self.config.run.policy_average_from)
        return runner.replace(chunk=chunk, learner=averaged), metrics

    def train(self, key: jax.Array) -> dict:
        """Whole run (init + all chunks) as one pure function: {'runner_state', 'metrics' [chunks, iterations]}."""
        runner = self.init(key)
        runner, metrics = jax.lax.scan(lambda r, _: self.chunk(r), runner, None, length=self.config.num_chunks)
        return {"runner_state": runner, "metrics": metrics}


def make_train(config: TrainConfig, tracking_env: env_lib.TrackingEnv | None = None, mesh=None):
    """purejaxrl-style: returns ``train(key) -> {'runner_state', 'metrics'}``; jit it, vmap it over seeds."""
    return Trainer(config, tracking_env, mesh).train
