"""Labels from the simulator's state, for training only, in one place: the expert's action at each step (the
true-state one-step look-ahead's, through a *labeller*), the large-margin loss term that learns from it, and the
true tracking state that the auxiliary loss fits.

The look-ahead (:func:`ramavt_jax.baselines.mpc_policy` at horizon 1: each of the 11 commands simulated one step on
the noise-free model, the best kept) reads the simulator state, so it is a teacher for training only: the trained
policy still acts from its images. Labelling the states the agent itself visits, rather than only a teacher's own,
is DAgger's way round the drift of a student away from the states its teacher showed it.

Extension point: a *labeller* is a function ``(env_state, env_params, key) -> [N] int32`` of N envs' states
(leaves [N, ...]); ``Trainer(labeller=...)`` stores its labels beside every observation (``LossBatch.expert_action``)
for the loss terms to read. :func:`look_ahead_labeller` is the default whenever the margin loss is on.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

from ramavt_jax import baselines
from ramavt_jax import env as env_lib
from ramavt_jax.losses import LossBatch, LossTerm, masked_mean

__all__ = [
    "NO_LABEL",
    "BLIND_LABELS",
    "EXPERT_MARGIN",
    "TRUE_STATE_SIZE",
    "Labeller",
    "look_ahead_labeller",
    "unseen_yet",
    "true_tracking_state",
    "large_margin_loss",
    "margin_term",
]

NO_LABEL = -1  # a stored label the margin loss skips (a step whose image cannot show what the label knows)
# What a labeller stores before the target is first in view (LearnerConfig.blind_label): the look-ahead's action,
# no label, or env.RETREAT.
BLIND_LABELS = ("teacher", "none", "retreat")
EXPERT_MARGIN = 0.05  # how far the labelled action must lead every other, in Q's units (scaled rewards)
TRUE_STATE_SIZE = 6  # true_tracking_state: the tracking error [3], then the relative velocity [3]

# (env_state with leaves [N, ...], env_params, key) -> [N] int32 labels (NO_LABEL: none)
Labeller = Callable[[env_lib.EnvState, env_lib.EnvParams, jax.Array], jax.Array]


def unseen_yet(env_state: env_lib.EnvState, camera: env_lib.CameraConfig) -> jax.Array:
    """[N] bool for the N envs of ``env_state`` (leaves [N, ...]): the target is out of view now and has been lost at
    every step of the episode so far (lost_steps == steps; 'lost' also counts a target in view but too far, rare at
    these distances). The images so far are blank, so no policy of images can know where the target is."""
    position = jax.vmap(env_lib.relative_position)(env_state) / env_state.scale[:, None]  # [N, 3] stand-off units
    in_view = jax.vmap(lambda p: env_lib.in_view(p, camera))(position)
    return ~in_view & (env_state.lost_steps == env_state.steps)


def look_ahead_labeller(config: env_lib.EnvConfig, blind_label: str = "teacher") -> Labeller:
    """The labeller of the true-state one-step look-ahead on the env ``config`` (the ceiling at horizon 1; the key
    only feeds its noise-free model, so the labels depend on the states alone). Where the target is
    :func:`unseen_yet`, ``blind_label`` says what is stored: 'teacher' the look-ahead's action as everywhere,
    'none' NO_LABEL (those steps left to the TD loss), 'retreat' env.RETREAT (backing off shrinks the bearing of a
    target in any direction, so it searches without knowing where the target is)."""
    if blind_label not in BLIND_LABELS:
        raise ValueError(f"blind_label must be one of {BLIND_LABELS}, got {blind_label!r}")
    teacher = baselines.mpc_policy(config, horizon=1, branch=1)

    def labeller(env_state: env_lib.EnvState, params: env_lib.EnvParams, key: jax.Array) -> jax.Array:
        n = jax.tree.leaves(env_state)[0].shape[0]
        act = lambda k, s: teacher.act(k, None, None, s, params)[0]  # noqa: E731
        taught = jax.vmap(act)(jax.random.split(key, n), env_state).astype(jnp.int32)  # [N]
        if blind_label == "teacher":
            return taught
        blind = {"none": NO_LABEL, "retreat": env_lib.RETREAT}[blind_label]
        return jnp.where(unseen_yet(env_state, config.camera), blind, taught).astype(jnp.int32)

    return labeller


def true_tracking_state(env_state: env_lib.EnvState, env_params: env_lib.EnvParams) -> jax.Array:
    """[TRUE_STATE_SIZE] One env's true tracking state in stand-off distances (metres / (k * desired_pos[2])): where
    the target centre is minus where it should be (camera frame), then the target's velocity relative to the chaser
    (camera frame, per second). The auxiliary loss's label is its first NetworkConfig.aux_outputs entries."""
    p = env_params
    error = (env_lib.relative_position(env_state) / env_state.scale - p.desired_pos) / p.desired_pos[2]
    velocity = env_lib.HILL_FROM_CAM.T @ (env_state.target_vel - env_state.chaser_vel)
    return jnp.concatenate([error, velocity / env_state.scale / p.desired_pos[2]])


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


def margin_term(weight: float, margin: float = EXPERT_MARGIN) -> LossTerm:
    """DQfD's large-margin loss towards the labels as a loss term: ``weight`` times :func:`large_margin_loss` of the
    batch's Q at the trained observations against ``expert_action``, steps labelled NO_LABEL masked out; metrics
    ``margin_loss`` (unweighted) and ``expert_agreement``, the share of the labelled trained steps whose greedy action
    is the label (a constant)."""

    def margin_loss(batch: LossBatch) -> tuple[jax.Array, dict]:
        q, expert = batch.q[:, :-1], batch.expert_action
        mask = batch.mask * (expert != NO_LABEL)
        agreement = jax.lax.stop_gradient((jnp.argmax(q, axis=-1) == expert).astype(q.dtype))
        loss = large_margin_loss(q, expert, mask, margin, batch.weight)
        return weight * loss, {"margin_loss": loss, "expert_agreement": masked_mean(agreement, mask)}

    return margin_loss
