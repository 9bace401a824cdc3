"""Value-learning losses for the recurrent DQN (R2D2-style), as pure functions.

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
:func:`sequence_td_loss` takes ``[B, ...]`` arrays, :func:`td_loss` the same arrays named in a :class:`TDBatch`.
"""

from __future__ import annotations

import chex
import jax
import jax.numpy as jnp
from flax import struct

__all__ = [
    "signed_hyperbolic",
    "signed_parabolic",
    "n_step_targets",
    "lambda_targets",
    "TDConfig",
    "TDBatch",
    "sequence_td_loss",
    "quantile_huber",
    "sequence_quantile_loss",
    "td_loss",
    "masked_mean",
]


def signed_hyperbolic(x: jax.Array, eps: float = 1e-3) -> jax.Array:
    """R2D2 value rescaling h(x) = sign(x) (sqrt(|x| + 1) - 1) + eps x.  Any shape, elementwise."""
    # sqrt(|x| + 1) - 1 written as |x| / (sqrt(|x| + 1) + 1): no float32 cancellation for small |x|.
    return x / (jnp.sqrt(jnp.abs(x) + 1.0) + 1.0) + eps * x


def signed_parabolic(x: jax.Array, eps: float = 1e-3) -> jax.Array:
    """Inverse of :func:`signed_hyperbolic`: h^-1(x) = sign(x) (((sqrt(1 + 4 eps (|x| + 1 + eps)) - 1) / 2 eps)^2 - 1).

    Any shape, elementwise.  ``signed_parabolic(signed_hyperbolic(x)) == x`` up to float rounding.
    """
    # With s = sqrt(1 + 4 eps (eps + 1 + |x|)) and z = (s - 1) / (2 eps):  z^2 - 1 = (z - 1)(z + 1) and
    # z - 1 = 2 |x| / (s + 1 + 2 eps), z = 2 (eps + 1 + |x|) / (s + 1).  This form has no float32 cancellation
    # (rlax's literal formula loses ~1e-4 relative accuracy at |x| ~ 1 and all of it at |x| < 1e-3).
    s = jnp.sqrt(1.0 + 4.0 * eps * (eps + 1.0 + jnp.abs(x)))
    z = 2.0 * (eps + 1.0 + jnp.abs(x)) / (s + 1.0)
    return x * 2.0 * (z + 1.0) / (s + 1.0 + 2.0 * eps)


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


def lambda_targets(
    rewards: jax.Array,  # [T]
    discounts: jax.Array,  # [T]
    q_boot: jax.Array,  # [T]
    lam: float,
    stop: jax.Array | None = None,  # [T] bool
) -> jax.Array:  # [T]
    """Peng's Q(lambda) returns over one window, the arguments as in :func:`n_step_targets`::

        G[t] = rewards[t] + discounts[t] * (q_boot[t] if end[t] else (1 - lam) q_boot[t] + lam G[t + 1])

    with ``end[t]`` at the window's last transition and where ``stop[t]``: the mixture over k of the k-step returns
    with weights ``(1 - lam) lam^(k-1)``, the longest one (to the episode or window end) taking the rest. ``lam = 0``
    is the one-step target, ``lam = 1`` the return to the end. No off-policy correction (as PQN and R2D2's n-step).
    """
    chex.assert_rank([rewards, discounts, q_boot], 1)
    chex.assert_equal_shape([rewards, discounts, q_boot])
    T = rewards.shape[0]
    end = jnp.arange(T) == T - 1
    if stop is not None:
        end = end | stop.astype(bool)

    def backward(g_next, step):
        r, d, v, e = step
        g = r + d * jnp.where(e, v, (1.0 - lam) * v + lam * g_next)
        return g, g

    start = jnp.zeros((), jnp.result_type(rewards, discounts, q_boot))  # the carry's dtype: the mixed inputs'
    _, returns = jax.lax.scan(backward, start, (rewards, discounts, q_boot, end), reverse=True)
    return returns


@struct.dataclass
class TDConfig:
    """Configuration of :func:`sequence_td_loss` (all fields static, so it can be a jit argument).

    Attributes:
      gamma: discount per step.
      n_step: number of steps of the bootstrapped return (1 = one-step Q-learning).
      td_lambda: None for n-step returns; else Peng's Q(lambda) returns over the window (:func:`lambda_targets`),
        which take the place of the n-step ones (``n_step`` must then be 1).
      double_q: choose the bootstrap action with the online network, evaluate it with the target network.
        Otherwise bootstrap from ``max_a q_target``.
      value_rescale: R2D2 invertible value rescaling: target = h(n-step return of h^-1(q)); the networks then
        predict rescaled values.
      rescale_eps: the eps of h.
      huber_delta: ``None`` for the squared loss ``0.5 td^2`` ("MSE"); otherwise the Huber loss with this delta
        (``0.5 td^2`` for ``|td| <= delta``, ``delta (|td| - delta / 2)`` beyond), so both agree for small errors.
      advantage_alpha: advantage learning (Bellemare et al. 2016, "Increasing the action gap"): the target of a
        taken action is lowered by ``alpha * (max_a q_target(s, a) - q_target(s, a_taken))``, which widens the gaps
        between the best action's value and the others' (0 = plain Q-learning targets).
      quantile_kappa: the Huber threshold of the quantile loss (:func:`sequence_quantile_loss`), in the targets'
        units. Below it the loss is quadratic and fits expectiles, not quantiles, so it should be small against the
        gaps between the return's quantiles.
    """

    gamma: float = struct.field(pytree_node=False, default=0.99)
    n_step: int = struct.field(pytree_node=False, default=1)
    td_lambda: float | None = struct.field(pytree_node=False, default=None)
    double_q: bool = struct.field(pytree_node=False, default=True)
    value_rescale: bool = struct.field(pytree_node=False, default=False)
    rescale_eps: float = struct.field(pytree_node=False, default=1e-3)
    huber_delta: float | None = struct.field(pytree_node=False, default=None)
    quantile_kappa: float = struct.field(pytree_node=False, default=0.05)
    advantage_alpha: float = struct.field(pytree_node=False, default=0.0)

    def __post_init__(self):
        if not 0.0 <= self.gamma <= 1.0:
            raise ValueError(f"TDConfig.gamma must be in [0, 1], got {self.gamma}")
        if int(self.n_step) != self.n_step or self.n_step < 1:
            raise ValueError(f"TDConfig.n_step must be an integer >= 1, got {self.n_step}")
        if self.td_lambda is not None and not (0.0 <= self.td_lambda <= 1.0 and self.n_step == 1):
            raise ValueError(
                f"TDConfig.td_lambda must be None (n-step returns) or in [0, 1] with n_step=1 (the "
                f"lambda-returns replace the n-step ones), got td_lambda={self.td_lambda}, "
                f"n_step={self.n_step}"
            )
        if self.huber_delta is not None and not self.huber_delta > 0:
            raise ValueError(f"TDConfig.huber_delta must be None (squared loss) or > 0, got {self.huber_delta}")
        if not 0.0 <= self.advantage_alpha < 1.0:
            raise ValueError(f"TDConfig.advantage_alpha must be in [0, 1), got {self.advantage_alpha}")
        if not self.quantile_kappa > 0:
            raise ValueError(f"TDConfig.quantile_kappa must be > 0, got {self.quantile_kappa}")
        if not self.rescale_eps > 0:
            raise ValueError(f"TDConfig.rescale_eps must be > 0, got {self.rescale_eps}")


def _elementwise_loss(td: jax.Array, huber_delta: float | None) -> jax.Array:
    if huber_delta is None:
        return 0.5 * jnp.square(td)
    abs_td = jnp.abs(td)
    quadratic = jnp.minimum(abs_td, huber_delta)
    return 0.5 * jnp.square(quadratic) + huber_delta * (abs_td - quadratic)


def masked_mean(per_step: jax.Array, mask: jax.Array, weights: jax.Array | None = None) -> jax.Array:
    """[] Mean of per_step [B, T] over the transitions in mask [B, T], each window's weighted by weights [B] (None
    for 1); 0 if none is in the mask."""
    mask_f = mask.astype(per_step.dtype)
    per_step = per_step * mask_f if weights is None else per_step * mask_f * weights[:, None]
    return per_step.sum() / jnp.maximum(mask_f.sum(), 1.0)


def _returns(rewards: jax.Array, discounts: jax.Array, q_boot: jax.Array, stop: jax.Array, cfg: TDConfig) -> jax.Array:
    """[T] the bootstrapped returns of one window that cfg asks for: n-step or lambda."""
    if cfg.td_lambda is None:
        return n_step_targets(rewards, discounts, q_boot, cfg.n_step, stop=stop)
    return lambda_targets(rewards, discounts, q_boot, cfg.td_lambda, stop=stop)


def _sequence_targets(
    q_online_t: jax.Array,  # [T, A]  online Q at obs t+1 (for double-Q action selection)
    q_target_t: jax.Array,  # [T, A]  target Q at obs t+1
    r_t: jax.Array,  # [T]
    terminated: jax.Array,  # [T]
    truncated: jax.Array,  # [T]
    cfg: TDConfig,
) -> jax.Array:  # [T]
    """Targets for one sequence (vmapped over the batch by :func:`sequence_td_loss`)."""
    if cfg.double_q:
        a_t = jnp.argmax(q_online_t, axis=-1)
        v_t = jnp.take_along_axis(q_target_t, a_t[:, None], axis=-1)[:, 0]
    else:
        v_t = jnp.max(q_target_t, axis=-1)
    if cfg.value_rescale:
        v_t = signed_parabolic(v_t, cfg.rescale_eps)
    discount_t = cfg.gamma * (1.0 - terminated.astype(v_t.dtype))
    stop = terminated.astype(bool) | truncated.astype(bool)
    target = _returns(r_t.astype(v_t.dtype), discount_t, v_t, stop, cfg)
    if cfg.value_rescale:
        target = signed_hyperbolic(target, cfg.rescale_eps)
    return target


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
    """Masked (double-)Q n-step TD loss over a batch of sequences.

    Args:
      q_online: ``[B, T+1, A]`` online-network Q-values for observations 0..T of each window.  Gradients flow
        through ``q_online[:, t, actions[:, t]]`` only (the action selection at t+1 is not differentiated).
      q_target: ``[B, T+1, A]`` bootstrap values for the same observations (gradient stopped): the target net's, or
        the online pass's own (LearnerConfig.bootstrap_from = 'online').
        ``q_target[:, 0]`` is used by advantage learning only.
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
    chex.assert_rank([q_online, q_target], 3)
    chex.assert_rank([actions, rewards, terminated, truncated, mask], 2)
    chex.assert_equal_shape([q_online, q_target])
    chex.assert_equal_shape([actions, rewards, terminated, truncated, mask])
    B, T = actions.shape
    chex.assert_shape(q_online, (B, T + 1, None))

    q_tm1 = q_online[:, :-1]  # [B, T, A]
    q_taken = jnp.take_along_axis(q_tm1, actions[..., None].astype(jnp.int32), axis=-1)[..., 0]  # [B, T]

    q_online_t = jax.lax.stop_gradient(q_online[:, 1:])  # [B, T, A]
    q_target_t = jax.lax.stop_gradient(q_target[:, 1:])  # [B, T, A]
    target = jax.vmap(_sequence_targets, in_axes=(0, 0, 0, 0, 0, None))(
        q_online_t, q_target_t, rewards, terminated, truncated, cfg
    )
    if cfg.advantage_alpha:
        q_target_tm1 = q_target[:, :-1]
        gap = q_target_tm1.max(-1) - jnp.take_along_axis(q_target_tm1, actions[..., None].astype(jnp.int32), -1)[..., 0]
        target = target - cfg.advantage_alpha * gap
    target = jax.lax.stop_gradient(target)

    td_error = target - q_taken
    loss = masked_mean(_elementwise_loss(td_error, cfg.huber_delta), mask, weights)
    return loss, {"td_error": td_error, "q_taken": q_taken, "target": target}


def quantile_huber(td: jax.Array, taus: jax.Array, kappa: float) -> jax.Array:
    """QR-DQN's quantile Huber loss per pair: ``td [..., N, M]`` (target sample j minus predicted quantile i, on the
    last two axes), ``taus [N]`` the predicted quantiles' fractions -> ``[..., N, M]``. The Huber loss divided by
    kappa, weighted |tau_i - 1(td < 0)|: its minimiser over a quantile is the tau-quantile of the targets."""
    weight = jnp.abs(taus[:, None] - (td < 0).astype(td.dtype))
    return weight * _elementwise_loss(td, kappa) / kappa


def sequence_quantile_loss(
    z_online: jax.Array,  # [B, T+1, A, N]
    z_target: jax.Array,  # [B, T+1, A, N]
    actions: jax.Array,  # [B, T] int
    rewards: jax.Array,  # [B, T]
    terminated: jax.Array,  # [B, T] bool
    truncated: jax.Array,  # [B, T] bool
    mask: jax.Array,  # [B, T] bool or 0/1
    cfg: TDConfig,
    weights: jax.Array | None = None,  # [B]
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """Masked (double-)Q quantile regression loss (QR-DQN, Dabney et al. 2018) over a batch of sequences.

    The networks predict N quantiles of the return per action (fractions ``(2i + 1) / 2N``), Q being their mean. The
    target of transition t is the n-step (or lambda) return of each of the bootstrap quantiles at the bootstrap obs,
    for the action the online net's mean picks there (double-Q) or the target values' (plain), exactly as
    :func:`sequence_td_loss` builds one expected value (the same returns per quantile). Every predicted quantile is
    regressed on every target quantile with :func:`quantile_huber` (kappa = ``cfg.quantile_kappa``), averaged over
    both (QR-DQN sums over the predicted ones: the mean keeps the loss on one quantile's scale, beside other losses).
    The other arguments and ``aux`` are as in :func:`sequence_td_loss`, ``aux`` holding the means (``td_error`` =
    target mean minus Q of the taken action).
    Value rescaling and advantage learning are not defined here (TrainConfig refuses them with quantiles).
    """
    chex.assert_rank([z_online, z_target], 4)
    chex.assert_equal_shape([z_online, z_target])
    B, T = actions.shape
    chex.assert_shape(z_online, (B, T + 1, None, None))
    n = z_online.shape[-1]
    taken = actions[..., None, None].astype(jnp.int32)
    z_taken = jnp.take_along_axis(z_online[:, :-1], taken, axis=2)[:, :, 0]  # [B, T, N]
    q_pick = (z_online[:, 1:] if cfg.double_q else z_target[:, 1:]).mean(-1)  # [B, T, A]; argmax: no gradient
    boot = jnp.take_along_axis(z_target[:, 1:], jnp.argmax(q_pick, -1)[..., None, None], axis=2)[:, :, 0]  # [B, T, N]
    discount = cfg.gamma * (1.0 - terminated.astype(boot.dtype))
    stop = terminated.astype(bool) | truncated.astype(bool)
    per_window = jax.vmap(lambda r, d, z, s: jax.vmap(lambda zq: _returns(r, d, zq, s, cfg), in_axes=1, out_axes=1)(z))
    target = jax.lax.stop_gradient(per_window(rewards.astype(boot.dtype), discount, boot, stop))  # [B, T, N]
    taus = (jnp.arange(n, dtype=z_taken.dtype) + 0.5) / n
    pairs = quantile_huber(target[:, :, None, :] - z_taken[..., None], taus, cfg.quantile_kappa)
    loss = masked_mean(pairs.mean((-2, -1)), mask, weights)
    q_taken, target_mean = z_taken.mean(-1), target.mean(-1)
    return loss, {"td_error": target_mean - q_taken, "q_taken": q_taken, "target": target_mean}


def sequence_priority(td_error: jax.Array, mask: jax.Array, max_share: float) -> jax.Array:
    """``[B]`` priority of each window from its ``[B, T]`` TD errors over the transitions in ``mask``: ``max_share``
    times the largest magnitude plus the rest times the mean one (R2D2's mix; 0 for a window with no trained
    transition)."""
    magnitude = jnp.abs(td_error) * mask
    count = mask.astype(magnitude.dtype).sum(-1)
    return max_share * magnitude.max(-1) + (1 - max_share) * magnitude.sum(-1) / jnp.maximum(count, 1.0)


@struct.dataclass
class TDBatch:
    """The inputs of :func:`sequence_td_loss` that take no gradient, for ``B`` windows of ``T`` transitions.

    Attributes:
      q_target: ``[B, T+1, A]`` bootstrap values (target net, or the online pass under stop_gradient) for
        observations 0..T, or ``[B, T+1, A, N]`` their N quantiles (a quantile network: :func:`td_loss` then takes
        the online net's quantiles too).
      action: ``[B, T]`` int action of transition t.
      reward: ``[B, T]`` reward of transition t (already scaled).
      terminated: ``[B, T]`` bool, obs t+1 is terminal.
      truncated: ``[B, T]`` bool, the time limit ended the episode at obs t+1.
      mask: ``[B, T]`` bool, transition t contributes to the loss.
      weight: ``[B]`` importance weight of each window (prioritised replay); None for 1.
    """

    q_target: jax.Array
    action: jax.Array
    reward: jax.Array
    terminated: jax.Array
    truncated: jax.Array
    mask: jax.Array
    weight: jax.Array | None = None


def td_loss(q_online: jax.Array, batch: TDBatch, cfg: TDConfig) -> tuple[jax.Array, dict[str, jax.Array]]:
    """:func:`sequence_td_loss` of ``q_online`` (``[B, T+1, A]``) against a :class:`TDBatch`, or with quantiles
    (``[B, T+1, A, N]`` both) :func:`sequence_quantile_loss`."""
    if batch.q_target.ndim == 4:
        return sequence_quantile_loss(
            q_online,
            batch.q_target,
            batch.action,
            batch.reward,
            batch.terminated,
            batch.truncated,
            batch.mask,
            cfg,
            batch.weight,
        )
    return sequence_td_loss(
        q_online,
        batch.q_target,
        batch.action,
        batch.reward,
        batch.terminated,
        batch.truncated,
        batch.mask,
        cfg,
        batch.weight,
    )
