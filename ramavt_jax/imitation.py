"""Learning from the true-state look-ahead: its actions, for envs that fly it (ActingConfig.teacher_envs) and as
labels of the agent's own steps (LearnerConfig.expert_margin_weight, NetworkConfig.policy_head), and DQfD's
large-margin loss and a policy head's cross-entropy towards them.

The look-ahead (:func:`ramavt_jax.baselines.mpc_policy` at horizon 1: each of the 11 commands simulated one step on
the noise-free model, the best kept) reads the simulator state, so it is a teacher for training only: the trained
policy still acts from its images. Labelling the states the agent itself visits, rather than only the teacher's own,
is DAgger's way round the drift of a student away from the states its teacher showed it.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import optax

from ramavt_jax import baselines
from ramavt_jax import env as env_lib
from ramavt_jax.losses import masked_mean

__all__ = [
    "NO_LABEL",
    "look_ahead_teacher",
    "teacher_actions",
    "unseen_yet",
    "stored_labels",
    "large_margin_loss",
    "margin_terms",
    "policy_terms",
]

NO_LABEL = -1  # a stored label the margin loss skips (a step whose image cannot show what the label knows)


def look_ahead_teacher(config: env_lib.EnvConfig) -> baselines.Policy:
    """The true-state one-step look-ahead of the env ``config`` (the ceiling at horizon 1)."""
    return baselines.mpc_policy(config, horizon=1, branch=1)


def teacher_actions(
    teacher: baselines.Policy, env_state: env_lib.EnvState, params: env_lib.EnvParams, key: jax.Array
) -> jax.Array:
    """[N] int32 the teacher's action for each of the N envs of ``env_state`` (leaves [N, ...]); the key only feeds
    the teacher's noise-free model, so the actions depend on the states alone."""
    n = jax.tree.leaves(env_state)[0].shape[0]
    act = lambda k, s: teacher.act(k, None, None, s, params)[0]  # noqa: E731
    return jax.vmap(act)(jax.random.split(key, n), env_state).astype(jnp.int32)


def unseen_yet(env_state: env_lib.EnvState, camera: env_lib.CameraConfig) -> jax.Array:
    """[N] bool for the N envs of ``env_state`` (leaves [N, ...]): the target is out of view now and has been lost at
    every step of the episode so far (lost_steps == steps; 'lost' also counts a target in view but too far, rare at
    these distances). The images so far are blank, so no policy of images can know where the target is."""
    position = jax.vmap(env_lib.relative_position)(env_state) / env_state.scale[:, None]  # [N, 3] stand-off units
    in_view = jax.vmap(lambda p: env_lib.in_view(p, camera))(position)
    return ~in_view & (env_state.lost_steps == env_state.steps)


def stored_labels(
    taught: jax.Array, env_state: env_lib.EnvState, camera: env_lib.CameraConfig, blind_label: str
) -> jax.Array:
    """[N] int32 the labels to store for the teacher's actions ``taught`` [N], where the target is
    :func:`unseen_yet` replaced as LearnerConfig.blind_label says: 'teacher' keeps them, 'none' stores NO_LABEL
    (those steps left to the TD loss) and 'retreat' stores env.RETREAT (backing off shrinks the bearing of a target in
    any direction, so it searches without knowing where the target is)."""
    if blind_label == "teacher":
        return taught
    blind = {"none": NO_LABEL, "retreat": env_lib.RETREAT}[blind_label]
    return jnp.where(unseen_yet(env_state, camera), blind, taught).astype(jnp.int32)


def large_margin_loss(
    q: jax.Array, expert_action: jax.Array, mask: jax.Array, margin: float, weights: jax.Array | None = None
) -> jax.Array:
    """DQfD's large-margin classification loss (Hester et al. 2018), masked mean over steps of
    ``max_a [Q(s, a) + margin * (a != a_E)] - Q(s, a_E)``: zero once the expert's action leads every other by
    ``margin``, else the shortfall of the worst violator, so its gradient raises Q(s, a_E) and lowers that action's.

    Args:
      q: ``[B, T, A]`` Q values at the trained observations.
      expert_action: ``[B, T]`` int, the teacher's action there.
      mask: ``[B, T]`` which steps count (the TD loss's mask).
      margin: how far, in Q's units (scaled rewards), the expert's action must lead.
      weights: ``[B]`` importance weights of the windows (a prioritised replay's, as the TD loss takes them), or None.
    """
    expert = jax.nn.one_hot(expert_action, q.shape[-1], dtype=q.dtype)  # [B, T, A]
    q_expert = (q * expert).sum(-1)
    return masked_mean(jnp.max(q + margin * (1.0 - expert), axis=-1) - q_expert, mask, weights)


def margin_terms(
    q: jax.Array, expert_action: jax.Array, mask: jax.Array, margin: float, weights: jax.Array | None = None
) -> tuple[jax.Array, jax.Array]:
    """(:func:`large_margin_loss`, the share of the masked steps whose greedy action is the expert's, a constant to
    log); shapes as there. Steps labelled NO_LABEL are masked out of both."""
    mask = mask * (expert_action != NO_LABEL)
    agreement = jax.lax.stop_gradient((jnp.argmax(q, axis=-1) == expert_action).astype(q.dtype))
    return large_margin_loss(q, expert_action, mask, margin, weights), masked_mean(agreement, mask)


def policy_terms(
    logits: jax.Array, expert_action: jax.Array, mask: jax.Array, weights: jax.Array | None = None
) -> tuple[jax.Array, jax.Array]:
    """(the masked mean cross-entropy of a policy head's ``logits`` [B, T, A] against the labels ``expert_action``
    [B, T], the share of the masked steps whose argmax is the label, a constant to log); ``mask`` [B, T] and
    ``weights`` [B] as in :func:`large_margin_loss`. Steps labelled NO_LABEL are masked out of both."""
    mask = mask * (expert_action != NO_LABEL)
    labels = jnp.maximum(expert_action, 0)  # a NO_LABEL step is masked out; any action keeps the lookup in range
    cross_entropy = optax.softmax_cross_entropy_with_integer_labels(logits, labels)
    agreement = jax.lax.stop_gradient((jnp.argmax(logits, axis=-1) == expert_action).astype(logits.dtype))
    return masked_mean(cross_entropy, mask, weights), masked_mean(agreement, mask)
