"""Recurrent DQN training (R2D2-style) for the tracking task: the jitted trainer. Its config lives in
:mod:`ramavt_jax.train_config`, the named presets in :mod:`ramavt_jax.presets`, its state containers in
:mod:`ramavt_jax.train_state`.

API (purejaxrl shape)::

    cfg = presets.preset("quick")                       # or TrainConfig(...), frozen and validated
    train = make_train(cfg)                             # pure function of a key
    train = make_train(cfg, loss_terms=(...), network_factory=...)  # the extension points (docs/extending.md)
    out = jax.jit(train)(jax.random.PRNGKey(0))         # {'runner_state': RunnerState, 'metrics': ChunkMetrics}
    outs = jax.jit(jax.vmap(make_train(cfg)))(keys)     # several seeds at once (small configs)
    summary = training.driver.run(cfg, "runs/quick")    # host driver: logs, checkpoints (ramavt_jax/training/)

One *iteration* = every env acts ``rollout_steps`` steps (epsilon-greedy, next-step auto-reset), the chunk goes to
the sequence replay, then the learner does ``updates_per_iteration`` gradient steps (none before
``learning_starts``). One *chunk* = ``iterations_per_chunk`` iterations in one ``lax.scan`` inside one jitted
call; the host only logs, evaluates and checkpoints between chunks.

Learner: sample ``batch_size`` windows of ``burn_in + train_len + 1`` stored steps; from the stored recurrent
state run ``burn_in`` steps through the online net under ``stop_gradient`` (the target net runs over the whole
window from the same stored state, also without gradient), then the loss terms over the ``train_len`` transitions
after burn-in: the masked double-Q n-step TD loss, and as the config asks the auxiliary and the large-margin losses
(:func:`default_loss_terms`). With ``bootstrap_from='online'`` the targets bootstrap from the trained pass's own
values under ``stop_gradient`` and the target pass is skipped.

Extension points (brax's ``network_factory``, purejaxrl's variants), each None = built from the config:
``network_factory`` (NetworkConfig -> flax module with QNetwork's call and state), ``loss_terms`` (a tuple of
``losses.LossTerm``: pure functions of a ``losses.LossBatch`` returning (loss, metrics)) and ``labeller``
(``imitation.Labeller``: the expert action stored beside each observation). A lab arm plugs its component in with
them, without a config field.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax

from ramavt_jax import distributed, imitation
from ramavt_jax import env as env_lib
from ramavt_jax import replay as replay_lib
from ramavt_jax.augment import augment_batch
from ramavt_jax.greedy import unbatch_state
from ramavt_jax.losses import PRIORITY_KEY, LossBatch, LossTerm, aux_term, masked_mean, sequence_priority, td_term
from ramavt_jax.network import (
    NetworkConfig,
    init_variables,
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

__all__ = ["ADAM_EPS", "Components", "Trainer", "default_labeller", "default_loss_terms", "make_train"]

ADAM_EPS = 1e-4  # Adam's epsilon


def _raw_key(key: jax.Array) -> jax.Array:
    if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
        return jax.random.key_data(key)
    return key


# ============================================================================================ components
def default_loss_terms(config: TrainConfig) -> tuple[LossTerm, ...]:
    """The loss terms a config asks for: the TD loss (losses.td_term), then DQfD's large-margin loss
    (imitation.margin_term) with learner.expert_margin_weight and the auxiliary loss (losses.aux_term) with
    learner.aux_weight."""
    learner, terms = config.learner, [td_term(config.learner.td)]
    if learner.expert_margin_weight:
        terms.append(imitation.margin_term(learner.expert_margin_weight))
    if learner.aux_weight:
        terms.append(aux_term(learner.aux_weight, config.network.aux_outputs))
    return tuple(terms)


def default_labeller(config: TrainConfig, env_config: env_lib.EnvConfig) -> imitation.Labeller | None:
    """The labeller a config asks for: the true-state look-ahead's (learner.blind_label before the target is first
    in view) when the margin loss is on, else none (no labels computed or stored)."""
    if not config.learner.expert_margin_weight:
        return None
    return imitation.look_ahead_labeller(env_config, config.learner.blind_label)


@dataclasses.dataclass(frozen=True)
class Components:
    """The trainer's extension points as one value, for callers that pass them on (``training.driver.run``); each
    None = built from the config. See :class:`Trainer`."""

    network_factory: Callable[[NetworkConfig], nn.Module] | None = None
    loss_terms: tuple[LossTerm, ...] | None = None
    labeller: imitation.Labeller | None = None

    def kwargs(self) -> dict:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}


# ============================================================================================ trainer
class Trainer:
    """Pure pieces of training for one config: ``init(key)``, ``chunk(state)``, ``train(key)`` (vmappable).

    ``mesh`` (a 1-D ``jax.sharding.Mesh``, see :mod:`ramavt_jax.distributed`): the program keeps the envs and the
    sampled learner batch split over its devices (sharding hints only; the maths is unchanged). The caller jits
    with :func:`distributed.runner_shardings` as in/out shardings.

    Extension points (None: built from the config):

    * ``network_factory``: NetworkConfig -> a flax module called as ``QNetwork`` is (obs [B, T, H, W, C], reset
      [B, T], state, actions=[B, T]) -> (q [B, T, A], state), with the config's ``RecurrentState`` layout
      (network.initial_state); what it sows under 'intermediates' reaches the loss terms. Default
      network.make_network.
    * ``loss_terms``: a tuple of losses.LossTerm, summed; default :func:`default_loss_terms`.
    * ``labeller``: imitation.Labeller, whose labels are stored beside every observation for the terms
      (LossBatch.expert_action); default :func:`default_labeller`.
    """

    def __init__(
        self,
        config: TrainConfig,
        tracking_env: env_lib.TrackingEnv | None = None,
        mesh=None,
        debug_nan_at_update: int = -1,
        network_factory: Callable[[NetworkConfig], nn.Module] | None = None,
        loss_terms: tuple[LossTerm, ...] | None = None,
        labeller: imitation.Labeller | None = None,
    ):
        """``debug_nan_at_update`` (a test hook, not configuration): the loss and gradients become NaN from this
        gradient step on (-1 = off)."""
        distributed.check_divisible(config.acting.num_envs, mesh)
        self.config, self.mesh, self.debug_nan_at_update = config, mesh, debug_nan_at_update
        self.env = tracking_env if tracking_env is not None else env_lib.TrackingEnv(config.env)
        self.env_params = self.env.default_params(**dict(config.env_params))
        self.obs_shape = tuple(config.env.obs_shape)
        self.net = (network_factory or make_network)(config.network)
        self.loss_terms = tuple(default_loss_terms(config) if loss_terms is None else loss_terms)
        self.labeller = default_labeller(config, self.env.config) if labeller is None else labeller
        learner = config.learner
        adam = optax.adam(learner.lr, eps=ADAM_EPS)
        self.optimizer = (
            optax.chain(optax.clip_by_global_norm(learner.max_grad_norm), adam) if learner.max_grad_norm > 0 else adam
        )
        self.augment_fn = functools.partial(augment_batch, config=learner.augment_config) if learner.augment else None
        # the true tracking state kept per obs (Transition.privileged): the auxiliary head's label
        self.privileged_size = config.network.aux_outputs if learner.aux_weight else 0
        self.replay = replay_lib.make_replay(config.replay, config.acting.num_envs, self._example_transition())

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
            privileged=jnp.zeros((self.privileged_size,)) if self.privileged_size else None,
            expert_action=jnp.zeros((), jnp.int32) if self.labeller is not None else None,
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
        """[] The exploration rate after ``env_steps`` (all envs together), shared by all envs."""
        c = self.config.acting
        frac = jnp.clip(env_steps / max(c.eps_decay_steps, 1), 0.0, 1.0) if c.eps_decay_steps else 1.0
        return c.eps_start + (c.eps_end - c.eps_start) * frac

    def q_values(self, params, obs, reset, state, actions=None):
        """Online/target forward: obs [B, T, H, W, C], reset [B, T], actions [B, T] (taken; read by prev_action
        networks) -> (q [B, T, A], state)."""
        return self.net.apply({"params": params}, obs, reset, state, actions=actions)

    # ---------------------------------------------------------------- init
    def init(self, key: jax.Array) -> RunnerState:
        c, n = self.config, self.config.acting.num_envs
        key = _raw_key(key)
        key, k_net, k_env = jax.random.split(key, 3)
        params = init_variables(self.net, c.network, k_net, self.obs_shape)["params"]
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
        """One epsilon-greedy step of all envs, epsilon []: (actor, Transition [N, ...] (state [layers, N, units]),
        stats)."""
        c = self.config.acting
        k_eps, k_rand, k_env, k_label = jax.random.split(key, 4)
        q, net_state = self.q_values(params, actor.obs[:, None], actor.is_first[:, None], actor.net_state)
        greedy = jnp.argmax(q[:, 0], axis=-1).astype(jnp.int32)
        explore = jax.random.uniform(k_eps, (c.num_envs,)) < epsilon
        action = jnp.where(explore, jax.random.randint(k_rand, (c.num_envs,), 0, env_lib.NUM_ACTIONS), greedy)
        kept = self.privileged_size
        privileged = (
            jax.vmap(imitation.true_tracking_state, (0, None))(actor.env_state, self.env_params)[:, :kept]
            if kept
            else None
        )  # [N, K]
        labels = None if self.labeller is None else self.labeller(actor.env_state, self.env_params, k_label)  # [N]
        obs, env_state, reward, terminated, truncated, info = self._per_device(
            jax.vmap(lambda k, s, a: self.env.step(k, s, a, self.env_params))
        )(jax.random.split(k_env, c.num_envs), actor.env_state, action)
        # the replay keeps the state but its frame history ('drlavt'), which burn-in rebuilds
        transition = replay_lib.Transition(
            obs=actor.obs,
            action=action,
            reward=reward,
            terminated=terminated,
            truncated=truncated,
            is_first=actor.is_first,
            recurrent_state=actor.net_state.replace(frames=None),
            privileged=privileged,
            expert_action=labels,
        )
        new_actor = ActorState(
            env_state=env_state, obs=obs, is_first=info["is_first"], net_state=record_action(net_state, action)
        )
        done = terminated | truncated
        stats = EpisodeStats(
            episodes=done.sum(),
            length_sum=jnp.where(done, info["episode_length"], 0).sum(),
            return_sum=jnp.where(done, info["episode_return"], 0.0).sum(),
        )
        return new_actor, transition, stats

    def rollout(self, params, actor: ActorState, env_steps: jax.Array, key: jax.Array):
        """``rollout_steps`` acting steps. Returns (actor, chunk [N, T, ...] in replay layout, summed stats, the last
        step's exploration rate)."""
        c = self.config.acting

        def body(carry: RolloutCarry, k):
            eps = self.epsilon(carry.env_steps)
            actor, tr, stats = self.act_step(params, carry.actor, eps, k)
            return RolloutCarry(actor=actor, env_steps=carry.env_steps + c.num_envs), (tr, stats, eps)

        last, (traj, stats, eps) = jax.lax.scan(
            body, RolloutCarry(actor=actor, env_steps=env_steps), jax.random.split(key, c.rollout_steps)
        )
        return last.actor, replay_lib.chunk_to_storage(traj), jax.tree.map(jnp.sum, stats), eps[-1]

    # ---------------------------------------------------------------- learning
    def prepare(self, params, target_params, batch: replay_lib.SequenceBatch, key: jax.Array) -> PreparedBatch:
        """Everything the loss needs that takes no gradient: (augmented) observations, the target net's Q over the
        window (None with LearnerConfig.bootstrap_from = 'online') and the online net's state after burn-in, both run
        from the window's stored start state, and the trained transitions as a losses.LossBatch."""
        c, sg = self.config, jax.lax.stop_gradient
        burn, obs = batch.burn_in, batch.obs
        if self.augment_fn is not None:
            obs = self.augment_fn(key, obs)
        state = batch.start_state.replace(frames=window_start_frames(c.network, obs))
        q_target = None  # bootstrap_from='online': trained_loss takes the trained pass's values
        if c.learner.bootstrap_from == "target":
            q_target = sg(self.q_values(target_params, obs, batch.reset, state, batch.action)[0])[:, burn:]
        if burn:
            _, state = self.q_values(params, obs[:, :burn], batch.reset[:, :burn], state, batch.action[:, :burn])
        terminated, truncated = batch.terminated[:, burn:], batch.truncated[:, burn:]
        if c.learner.bootstrap_lost:  # see LearnerConfig.bootstrap_lost
            terminated, truncated = jnp.zeros_like(terminated), truncated | terminated
        trained = lambda x: None if x is None else x[:, burn:]  # noqa: E731 (optional fields: None stays None)
        loss_batch = LossBatch(
            q=None,
            q_target=q_target,
            action=batch.action[:, burn:],
            reward=sg(batch.reward[:, burn:] * c.learner.reward_scale),
            terminated=terminated,
            truncated=truncated,
            mask=batch.loss_mask[:, burn:],
            weight=batch.weights,
            privileged=trained(batch.privileged),
            expert_action=trained(batch.expert_action),
        )
        return PreparedBatch(obs=obs[:, burn:], reset=batch.reset[:, burn:], state=sg(state), loss_batch=loss_batch)

    def trained_loss(self, params, prepared: PreparedBatch):
        """The loss terms' sum over the trained part of the window, gradient w.r.t. params only. Returns (loss, aux):
        aux holds q_mean (of the taken actions), the terms' metrics ('terms': {name: []}) and with a prioritised
        replay each window's priority [B] (losses.sequence_priority of the PRIORITY_KEY metric)."""
        batch = prepared.loss_batch
        (q, _), sown = self.net.apply(
            {"params": params},
            prepared.obs,
            prepared.reset,
            prepared.state,
            actions=batch.action,
            mutable=["intermediates"],
        )
        q_target = jax.lax.stop_gradient(q) if batch.q_target is None else batch.q_target  # bootstrap_from='online'
        batch = batch.replace(q=q, q_target=q_target, intermediates=sown.get("intermediates", {}))
        losses, metrics = zip(*(term(batch) for term in self.loss_terms))
        metrics = _merged(metrics)
        td_error = metrics.pop(PRIORITY_KEY, None)
        q_taken = jnp.take_along_axis(q[:, :-1], batch.action[..., None], axis=-1)[..., 0]
        aux = dict(q_mean=masked_mean(jax.lax.stop_gradient(q_taken), batch.mask), terms=metrics)
        if self.config.replay.prioritised:  # uniform sampling needs no priorities
            if td_error is None:
                raise ValueError(f"a prioritised replay needs a loss term that returns the {PRIORITY_KEY!r} metric")
            priority_max_share = self.config.replay.priority_max_share
            aux["priority"] = sequence_priority(jax.lax.stop_gradient(td_error), batch.mask, priority_max_share)
        return sum(losses), aux

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
            target = optax.incremental_update(params, learner.target_params, c.polyak_tau)
        else:
            target = optax.periodic_update(params, learner.target_params, n, c.target_period)
        new = learner.replace(params=params, target_params=target, opt_state=opt_state, updates=n)
        if batch.indices is not None:
            replay_state = self.replay.set_priorities(replay_state, batch, aux["priority"])
        stats = LearnStats(
            loss=loss,
            q_mean=aux["q_mean"],
            grad_norm=optax.tree.norm(grads),
            updates=jnp.ones((), jnp.int32),
            terms=aux["terms"],
        )
        return new, replay_state, stats

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

        def skip(carry):  # no gradient step: zero stats, shaped as the loss terms' metrics are
            stats = jax.eval_shape(self.update, learner, replay_state, key)[2]
            return carry, jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), stats)

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
            q_sum=learned.q_mean,
            grad_norm_sum=learned.grad_norm,
            updates=learned.updates,
            epsilon=eps,
            env_steps=env_steps,
            term_sums=learned.terms,
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


def _merged(metrics: tuple[dict, ...]) -> dict:
    """The loss terms' metrics as one dict; a name given by two terms is refused (one would hide the other)."""
    out = {}
    for m in metrics:
        twice = set(out) & set(m)
        if twice:
            raise ValueError(f"two loss terms return the metric {sorted(twice)[0]!r}; give each its own name")
        out.update(m)
    return out


def make_train(
    config: TrainConfig,
    tracking_env: env_lib.TrackingEnv | None = None,
    mesh=None,
    *,
    network_factory: Callable[[NetworkConfig], nn.Module] | None = None,
    loss_terms: tuple[LossTerm, ...] | None = None,
    labeller: imitation.Labeller | None = None,
):
    """purejaxrl-style: returns ``train(key) -> {'runner_state', 'metrics'}``; jit it, vmap it over seeds. The
    extension points as in :class:`Trainer` (None: built from the config)."""
    components = dict(network_factory=network_factory, loss_terms=loss_terms, labeller=labeller)
    return Trainer(config, tracking_env, mesh, **components).train
