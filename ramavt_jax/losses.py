"""Value-learning losses for the recurrent DQN (R2D2-style), as pure functions, and the trainer's loss terms.

Conventions (shared with :mod:`ramavt_jax.replay`):

* Time index ``t`` names *transition* t: from observation ``t`` to observation ``t + 1``, taken with
  ``actions[t]``, yielding ``rewards[t]``.  ``terminated[t]`` and ``truncated[t]`` describe that transition.
* Q-value arrays hold one entry per *observation*: a window of ``T`` transitions has ``T + 1`` observations, so
  ``q[:, t]`` is Q(obs t, .) and ``q[:, t + 1]`` is Q(obs t+1, .).  Internally ``_tm1`` names values at obs t
  (the state the action was taken in) and ``_t`` values at obs t+1 (the bootstrap state), as in rlax.
* ``terminated[t]``: obs t+1 is terminal -> no bootstrap (discount 0).
* ``truncated[t]``: the time limit cut the episode at obs t+1 -> bootstrap from Q(obs t+1) with discount gamma.
  This is only correct if obs t+1 is the real final observation of the episode, which the trainer's
  *next-step autoreset* guarantees (see :mod:`ramavt_jax.replay`).
* ``mask[t]`` (0/1) removes transitions from the loss: burn-in, padding, and the artificial transition that
  crosses from an episode's final observation into the first observation of the next episode.  Such a crossing
  transition always follows a terminated or truncated one under next-step autoreset, so n-step accumulation
  (which stops at ``terminated | truncated``) never reaches it.

Batching: the sequence functions are written for one sequence and vmapped over the batch (rlax style);
:func:`sequence_td_loss` takes ``[B, ...]`` arrays.

Loss terms (the trainer's extension point): a *loss term* is a pure function of a :class:`LossBatch` returning
``(loss [], metrics {name: []})``; the trainer sums the terms' losses and logs their metrics per update. The TD loss
(:func:`td_term`) and the auxiliary loss (:func:`aux_term`) are terms, and so is the large-margin expert loss
(``imitation.margin_term``); ``Trainer(loss_terms=...)`` takes any tuple of them (docs/extending.md).
"""

from __future__ import annotations

from collections.abc import Callable

import chex
import jax
import jax.numpy as jnp
from flax import struct

__all__ = [
    "n_step_targets",
    "TDConfig",
    "sequence_td_targets",
    "sequence_td_loss",
    "sequence_priority",
    "masked_mean",
    "LossBatch",
    "LossTerm",
    "PRIORITY_KEY",
    "td_term",
    "aux_term",
]


def n_step_targets(
    rewards: jax.Array,  # [T]
    discounts: jax.Array,  # [T]
    q_boot: jax.Array,  # [T]
    n: int,
    stop: jax.Array | None = None,  # [T] bool
) -> jax.Array:  # [T]
    """n-step bootstrapped returns over one window of ``T`` transitions.

    For transition t let ``e = min(t + n - 1, T - 1, first k >= t with stop[k])`` be the last transition
    accumulated.  Then::

        G[t] = sum_{j=t..e} (prod_{i=t..j-1} discounts[i]) rewards[j]
               + (prod_{i=t..e} discounts[i]) q_boot[e]

    Args:
      rewards: ``[T]`` reward of transition t.
      discounts: ``[T]`` discount of transition t, already ``gamma * (1 - terminated[t])``.
      q_boot: ``[T]`` value estimate of obs t+1 (the state *after* transition t), used for bootstrapping.
      n: static number of steps (>= 1).  Near the window end the return is truncated at the last transition
        and bootstraps from ``q_boot[T - 1]``.
      stop: optional ``[T]`` bool, the episode ended at transition t (``terminated | truncated``): accumulation
        stops there and bootstraps from ``q_boot[t]`` (times ``discounts[t]``, which is 0 if terminated).  Without
        it a terminal still stops the return (its discount is 0) but a truncation would not.

    Returns:
      ``[T]`` targets (no gradient is stopped here; the caller decides).
    """
    chex.assert_rank([rewards, discounts, q_boot], 1)
    chex.assert_equal_shape([rewards, discounts, q_boot])
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    T = rewards.shape[0]
    is_last = jnp.arange(T) == T - 1
    end = is_last if stop is None else (is_last | stop.astype(bool))
    # Backward recursion, one static iteration per extra step:
    #   G1[t] = r[t] + d[t] q_boot[t]
    #   Gk[t] = r[t] + d[t] * (q_boot[t] if end[t] else G(k-1)[t + 1])
    returns = rewards + discounts * q_boot
    for _ in range(n - 1):
        next_returns = jnp.concatenate([returns[1:], returns[-1:]])  # G(k-1)[t+1]; last entry unused
        returns = rewards + discounts * jnp.where(end, q_boot, next_returns)
    return returns


@struct.dataclass
class TDConfig:
    """Configuration of :func:`sequence_td_loss` (all fields static, so it can be a jit argument).

    Attributes:
      gamma: discount per step.
      n_step: number of steps of the bootstrapped return (1 = one-step Q-learning, the paper's DRQN targets).
      double_q: choose the bootstrap action with the online network, evaluate it with the target network.
        Otherwise bootstrap from ``max_a q_target``.
    """

    gamma: float = struct.field(pytree_node=False, default=0.99)
    n_step: int = struct.field(pytree_node=False, default=1)
    double_q: bool = struct.field(pytree_node=False, default=True)

    def __post_init__(self):
        if not 0.0 <= self.gamma <= 1.0:
            raise ValueError(f"TDConfig.gamma must be in [0, 1], got {self.gamma}")
        if int(self.n_step) != self.n_step or self.n_step < 1:
            raise ValueError(f"TDConfig.n_step must be an integer >= 1, got {self.n_step}")


def masked_mean(per_step: jax.Array, mask: jax.Array, weights: jax.Array | None = None) -> jax.Array:
    """[] Mean of per_step [B, T] over the transitions in mask [B, T], each window's weighted by weights [B] (None
    for 1); 0 if none is in the mask."""
    mask_f = mask.astype(per_step.dtype)
    per_step = per_step * mask_f if weights is None else per_step * mask_f * weights[:, None]
    return per_step.sum() / jnp.maximum(mask_f.sum(), 1.0)


def _sequence_targets(
    q_online_t: jax.Array,  # [T, A]  online Q at obs t+1 (for double-Q action selection)
    q_target_t: jax.Array,  # [T, A]  target Q at obs t+1
    r_t: jax.Array,  # [T]
    terminated: jax.Array,  # [T]
    truncated: jax.Array,  # [T]
    cfg: TDConfig,
) -> jax.Array:  # [T]
    """Targets for one sequence (vmapped over the batch by :func:`sequence_td_targets`)."""
    if cfg.double_q:
        a_t = jnp.argmax(q_online_t, axis=-1)
        v_t = jnp.take_along_axis(q_target_t, a_t[:, None], axis=-1)[:, 0]
    else:
        v_t = jnp.max(q_target_t, axis=-1)
    discount_t = cfg.gamma * (1.0 - terminated.astype(v_t.dtype))
    stop = terminated.astype(bool) | truncated.astype(bool)
    return n_step_targets(r_t.astype(v_t.dtype), discount_t, v_t, cfg.n_step, stop=stop)


def sequence_td_targets(
    q_online: jax.Array,  # [B, T+1, A]
    q_target: jax.Array,  # [B, T+1, A]
    rewards: jax.Array,  # [B, T]
    terminated: jax.Array,  # [B, T] bool
    truncated: jax.Array,  # [B, T] bool
    cfg: TDConfig,
) -> jax.Array:  # [B, T]
    """``[B, T]`` (double-)Q n-step targets of the T transitions of each window, gradient stopped; the arguments as
    in :func:`sequence_td_loss`. A loss term with other targets can start from these (docs/extending.md)."""
    chex.assert_rank([q_online, q_target], 3)
    chex.assert_equal_shape([q_online, q_target])
    q_online_t = jax.lax.stop_gradient(q_online[:, 1:])  # [B, T, A]
    q_target_t = jax.lax.stop_gradient(q_target[:, 1:])  # [B, T, A]
    target = jax.vmap(_sequence_targets, in_axes=(0, 0, 0, 0, 0, None))(
        q_online_t, q_target_t, rewards, terminated, truncated, cfg
    )
    return jax.lax.stop_gradient(target)


def sequence_td_loss(
    q_online: jax.Array,  # [B, T+1, A]
    q_target: jax.Array,  # [B, T+1, A]
    actions: jax.Array,  # [B, T] int
    rewards: jax.Array,  # [B, T]
    terminated: jax.Array,  # [B, T] bool
    truncated: jax.Array,  # [B, T] bool
    mask: jax.Array,  # [B, T] bool or 0/1
    cfg: TDConfig,
    weights: jax.Array | None = None,  # [B]
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """Masked (double-)Q n-step TD loss over a batch of sequences: the mean of ``0.5 td^2`` ("MSE").

    Args:
      q_online: ``[B, T+1, A]`` online-network Q-values for observations 0..T of each window.  Gradients flow
        through ``q_online[:, t, actions[:, t]]`` only (the action selection at t+1 is not differentiated).
      q_target: ``[B, T+1, A]`` bootstrap values for the same observations (gradient stopped): the target net's, or
        the online pass's own (LearnerConfig.bootstrap_from = 'online').
      actions: ``[B, T]`` action of transition t (obs t -> obs t+1).
      rewards: ``[B, T]`` reward of transition t.
      terminated: ``[B, T]`` obs t+1 is terminal: no bootstrap.
      truncated: ``[B, T]`` the time limit ended the episode at obs t+1 (its real final observation):
        bootstrap from obs t+1; n-step accumulation stops there.
      mask: ``[B, T]`` 1 where transition t contributes to the loss (0 for burn-in, padding and episode-crossing
        transitions).  Masked transitions still serve as later steps of other transitions' n-step returns only
        if no episode end lies in between, which next-step autoreset guarantees for crossings.
      cfg: :class:`TDConfig`.
      weights: ``[B]`` importance weights of the windows (prioritised replay), multiplying each window's
        elementwise losses; None for 1.

    Returns:
      ``(loss, aux)``: ``loss`` is the mean of the (weighted) elementwise loss over unmasked transitions (0 if none);
      ``aux`` holds ``td_error``, ``q_taken`` and ``target``, each ``[B, T]`` (``td_error = target - q_taken``,
      unmasked values, for logging and priorities).
    """
    chex.assert_rank([actions, rewards, terminated, truncated, mask], 2)
    chex.assert_equal_shape([actions, rewards, terminated, truncated, mask])
    B, T = actions.shape
    chex.assert_shape(q_online, (B, T + 1, None))
    q_taken = jnp.take_along_axis(q_online[:, :-1], actions[..., None].astype(jnp.int32), axis=-1)[..., 0]  # [B, T]
    target = sequence_td_targets(q_online, q_target, rewards, terminated, truncated, cfg)
    td_error = target - q_taken
    loss = masked_mean(0.5 * jnp.square(td_error), mask, weights)
    return loss, {"td_error": td_error, "q_taken": q_taken, "target": target}


def sequence_priority(td_error: jax.Array, mask: jax.Array, max_share: float) -> jax.Array:
    """``[B]`` priority of each window from its ``[B, T]`` TD errors over the transitions in ``mask``: ``max_share``
    times the largest magnitude plus the rest times the mean one (R2D2's mix; 0 for a window with no trained
    transition)."""
    magnitude = jnp.abs(td_error) * mask
    count = mask.astype(magnitude.dtype).sum(-1)
    return max_share * magnitude.max(-1) + (1 - max_share) * magnitude.sum(-1) / jnp.maximum(count, 1.0)


@struct.dataclass
class LossBatch:
    """What a loss term reads from one update: ``B`` sampled windows of ``T`` trained transitions (after burn-in),
    ``A`` actions. Observation-indexed arrays have ``T + 1`` entries (obs t and its successor), transition-indexed
    ones ``T`` (transition t: obs t -> obs t+1, as in :func:`sequence_td_loss`).

    Attributes:
      q: ``[B, T+1, A]`` the online net's values at the trained observations (the gradient flows through them).
      q_target: ``[B, T+1, A]`` bootstrap values, without gradient: the target net's (LearnerConfig.bootstrap_from
        'target') or this pass's own.
      action: ``[B, T]`` int32 action of transition t.
      reward: ``[B, T]`` reward of transition t, scaled (LearnerConfig.reward_scale).
      terminated: ``[B, T]`` bool, obs t+1 is terminal (no bootstrap; LearnerConfig.bootstrap_lost clears it).
      truncated: ``[B, T]`` bool, the episode ended at obs t+1 without a terminal state (bootstrap from it).
      mask: ``[B, T]`` bool, transition t trains (burn-in, padding and episode crossings excluded).
      weight: ``[B]`` importance weight of each window (prioritised replay), or None (1).
      intermediates: what the online pass sowed (flax's 'intermediates' collection), e.g. ``{'aux': ([B, T+1, K],)}``
        for a network with an auxiliary head (NetworkConfig.aux_outputs = K).
      privileged: ``[B, T+1, K]`` the true tracking state per observation (imitation.true_tracking_state's first
        K entries, stored in the replay for the auxiliary loss), or None.
      expert_action: ``[B, T]`` int32 the labeller's action at obs t (imitation.NO_LABEL where there is none), or
        None when the trainer has no labeller.
    """

    q: jax.Array
    q_target: jax.Array
    action: jax.Array
    reward: jax.Array
    terminated: jax.Array
    truncated: jax.Array
    mask: jax.Array
    weight: jax.Array | None = None
    intermediates: dict = struct.field(default_factory=dict)
    privileged: jax.Array | None = None
    expert_action: jax.Array | None = None


# A loss term: LossBatch -> (loss [], {metric name: []}); the trainer adds the losses and logs each metric per
# update (summed per iteration, averaged per chunk in metrics.jsonl). One metric may be an array: PRIORITY_KEY.
LossTerm = Callable[[LossBatch], tuple[jax.Array, dict]]
# The metric a term returns as [B, T] TD errors for a prioritised replay's window priorities (not logged).
PRIORITY_KEY = "td_error"


def td_term(config: TDConfig) -> LossTerm:
    """The TD loss as a term: :func:`sequence_td_loss` of the batch; metrics ``td_loss`` and the TD errors
    (PRIORITY_KEY)."""

    def td_loss(batch: LossBatch) -> tuple[jax.Array, dict]:
        loss, aux = sequence_td_loss(
            batch.q,
            batch.q_target,
            batch.action,
            batch.reward,
            batch.terminated,
            batch.truncated,
            batch.mask,
            config,
            batch.weight,
        )
        return loss, {"td_loss": loss, PRIORITY_KEY: aux["td_error"]}

    return td_loss


def aux_term(weight: float, outputs: int) -> LossTerm:
    """The auxiliary loss as a term: ``weight`` times the masked mean over the trained observations of the squared
    error, summed over its ``outputs`` entries, of the network's auxiliary head (intermediates 'aux' [B, T+1, K])
    against the stored true state (``privileged[..., :outputs]``); metric ``aux_loss`` (unweighted)."""

    def aux_loss(batch: LossBatch) -> tuple[jax.Array, dict]:
        label = batch.privileged[:, :-1, :outputs]
        miss = jnp.square(batch.intermediates["aux"][0][:, :-1] - label).sum(-1)  # [B, T]
        loss = masked_mean(miss, batch.mask)
        return weight * loss, {"aux_loss": loss}

    return aux_loss
