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
from ramavt_jax.losses import LossBatch
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
    loss_sum: jax.Array  # the summed loss terms per update, summed
    q_sum: jax.Array  # mean taken Q per update, summed
    grad_norm_sum: jax.Array
    updates: jax.Array  # gradient steps done this iteration
    epsilon: jax.Array  # exploration rate at the iteration's last step, averaged over envs
    env_steps: jax.Array  # at the end of the iteration
    term_sums: dict  # {metric: sum per update} of the loss terms' metrics (e.g. td_loss, aux_loss), summed


@struct.dataclass
class EpisodeStats:
    """Episodes that ended in one acting step, or (summed) in a rollout: all ``[]``."""

    episodes: jax.Array
    length_sum: jax.Array
    return_sum: jax.Array  # unscaled env reward


@struct.dataclass
class LearnStats:
    """One gradient step (``update``), or the sums over an iteration's steps (``learn``): all ``[]``."""

    loss: jax.Array  # the loss terms' sum
    q_mean: jax.Array  # mean taken Q over the trained transitions
    grad_norm: jax.Array
    updates: jax.Array  # int32 gradient steps
    terms: dict  # {metric: []} the loss terms' metrics (losses.LossTerm), e.g. td_loss, aux_loss, margin_loss


@struct.dataclass
class PreparedBatch:
    """Everything the loss of ``B`` sampled windows needs that takes no gradient (``T = train_len``): the online
    pass's inputs after burn-in, obs ``[B, T+1, H, W, C]`` (augmented), reset ``[B, T+1]`` bool and state (the online
    net's ``RecurrentState`` after burn-in: h, c ``[layers, B, units]``), and the loss terms' batch without the
    online pass's outputs (``losses.LossBatch`` with q None; q_target None when the trained pass gives it:
    bootstrap_from='online')."""

    obs: jax.Array
    reset: jax.Array
    state: RecurrentState
    loss_batch: LossBatch


def average_policy(learner: LearnerState, chunk: jax.Array, start: int | None) -> LearnerState:
    """The running uniform mean of the target params at the ends of the chunks after ``start``
    (RunConfig.policy_average_from; None: ``learner`` unchanged); up to it, the target params themselves (weight 1).
    ``chunk``: [] int32 chunks completed, this one included."""
    if start is None:
        return learner
    weight = 1.0 / jnp.maximum(chunk - start, 1).astype(jnp.float32)
    averaged = optax.incremental_update(learner.target_params, learner.averaged_params, weight)
    return learner.replace(averaged_params=averaged)
