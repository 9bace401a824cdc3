"""The trainer's named containers (flax.struct pytrees): the learner's and the actors' state, the whole runner
state a chunk carries and checkpoints, the per-iteration metrics, and the batch a loss sees. Shapes in the field
comments; ``N`` envs, ``B`` sampled windows, ``T`` trained steps."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import optax
from flax import struct

from ramavt_jax import env as env_lib
from ramavt_jax.losses import TDBatch
from ramavt_jax.network import RecurrentState

__all__ = [
    "TrainingDivergedError",
    "LearnerState",
    "ActorState",
    "RolloutCarry",
    "RunnerState",
    "ChunkMetrics",
    "EpisodeStats",
    "LearnStats",
    "PreparedBatch",
]


class TrainingDivergedError(RuntimeError):
    """The loss (or mean Q) became NaN/inf; the state that produced it is not checkpointed."""


@struct.dataclass
class LearnerState:
    params: Any
    target_params: Any
    opt_state: Any
    updates: jax.Array  # [] int32 gradient steps taken
    # the uniform mean of target_params at the ends of the chunks after RunConfig.policy_average_from (equal to
    # target_params up to it); None when that is None
    averaged_params: Any = None

    def policy_params(self, which: str):
        """The parameter set a trained policy acts with (RunConfig.policy_params): 'online', 'target' or
        'averaged'."""
        if which == "averaged" and self.averaged_params is None:
            raise ValueError("policy_params='averaged' needs a run trained with run.policy_average_from set")
        return {"online": self.params, "target": self.target_params, "averaged": self.averaged_params}[which]


@struct.dataclass
class ActorState:
    """The acting envs ([N] leading axis everywhere, except in ``net_state``'s leaves other than frames:
    [layers, N, ...])."""

    env_state: env_lib.EnvState
    obs: jax.Array  # [N, H, W, C] current observation (not yet consumed by the network)
    is_first: jax.Array  # [N] bool, obs is an episode's first observation
    net_state: RecurrentState  # state BEFORE consuming obs


@struct.dataclass
class RolloutCarry:
    """What a rollout's lax.scan carries from one acting step to the next."""

    actor: ActorState
    env_steps: jax.Array  # [] int32, all envs together


@struct.dataclass
class RunnerState:
    learner: LearnerState
    actor: ActorState
    replay: Any  # flashbax TrajectoryBufferState
    key: jax.Array  # raw uint32[2] PRNG key (checkpoint friendly)
    env_steps: jax.Array  # [] int32, all envs together
    chunk: jax.Array  # [] int32 chunks completed


@struct.dataclass
class ChunkMetrics:
    """Per-iteration sums ([iterations] per chunk; the host aggregates)."""

    episodes: jax.Array  # episodes completed
    episode_length_sum: jax.Array
    episode_return_sum: jax.Array  # unscaled env reward
    loss_sum: jax.Array
    aux_loss_sum: jax.Array  # the auxiliary head's unweighted squared error per update, summed
    margin_loss_sum: jax.Array  # the large-margin loss per update, unweighted, summed (0 without it)
    expert_agreement_sum: jax.Array  # share of trained steps whose greedy action is the label, per update, summed
    policy_loss_sum: jax.Array  # the policy head's cross-entropy per update, unweighted, summed (0 without the head)
    q_sum: jax.Array  # mean taken Q per update, summed
    grad_norm_sum: jax.Array
    updates: jax.Array  # gradient steps done this iteration
    epsilon: jax.Array  # exploration rate at the iteration's last step, averaged over envs (ActingConfig.eps_ladder)
    env_steps: jax.Array  # at the end of the iteration


@struct.dataclass
class EpisodeStats:
    """Episodes that ended in one acting step, or (summed) in a rollout: all ``[]``."""

    episodes: jax.Array
    length_sum: jax.Array
    return_sum: jax.Array  # unscaled env reward


@struct.dataclass
class LearnStats:
    """One gradient step (``update``), or the sums over an iteration's steps (``learn``): all ``[]``."""

    loss: jax.Array  # the TD loss plus the weighted auxiliary, margin and policy losses
    aux_loss: jax.Array  # the auxiliary head's squared error, unweighted (0 without the head)
    margin_loss: jax.Array  # the large-margin loss, unweighted (0 without it: LearnerConfig.expert_margin_weight)
    expert_agreement: jax.Array  # share of the trained steps whose greedy action is the look-ahead's (0 without)
    policy_loss: jax.Array  # the policy head's cross-entropy, unweighted (0 without it: NetworkConfig.policy_head)
    q_mean: jax.Array  # mean taken Q over the trained transitions
    grad_norm: jax.Array
    updates: jax.Array  # int32 gradient steps

    @classmethod
    def zeros(cls) -> LearnStats:
        """No gradient step (the replay not yet ready)."""
        z = jnp.zeros(())
        return cls(
            loss=z,
            aux_loss=z,
            margin_loss=z,
            expert_agreement=z,
            policy_loss=z,
            q_mean=z,
            grad_norm=z,
            updates=jnp.zeros((), jnp.int32),
        )


@struct.dataclass
class PreparedBatch:
    """Everything the loss of ``B`` sampled windows needs that takes no gradient (``T = train_len``).

    obs: ``[B, T+1, H, W, C]`` (augmented) observations after burn-in; reset: ``[B, T+1]`` bool; state: the online
    net's ``RecurrentState`` after burn-in (h, c ``[layers, B, units]``); td: the :class:`TDBatch` of the ``T``
    trained transitions (``q_target [B, T+1, A]``, or None when the trained pass gives it: bootstrap_from='online';
    the rest ``[B, T]``); privileged: ``[B, T+1, K]`` the kept true state per obs (greedy.true_tracking_state:
    the tracking error, then the relative velocity; K = 6 for a state_input network, 12 when its input is another
    point's (greedy.privileged_of), else NetworkConfig.aux_outputs; None when neither needs it); standoff: ``[B, T+1]``
    the stand-off signal per obs (greedy.standoff_signal; None unless the network reads it); expert_action:
    ``[B, T]`` the look-ahead's action at each trained transition's obs (None without the large-margin loss).
    """

    obs: jax.Array
    reset: jax.Array
    state: RecurrentState
    td: TDBatch
    privileged: jax.Array | None = None
    standoff: jax.Array | None = None
    expert_action: jax.Array | None = None


def average_policy(learner: LearnerState, chunk: jax.Array, start: int | None) -> LearnerState:
    """The running uniform mean of the target params at the ends of the chunks after ``start``
    (RunConfig.policy_average_from; None: ``learner`` unchanged); up to it, the target params themselves (weight 1).
    ``chunk``: [] int32 chunks completed, this one included."""
    if start is None:
        return learner
    weight = 1.0 / jnp.maximum(chunk - start, 1).astype(jnp.float32)
    averaged = optax.incremental_update(learner.target_params, learner.averaged_params, weight)
    return learner.replace(averaged_params=averaged)
