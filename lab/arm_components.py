"""Components of lab arms that the package keeps no config field for, plugged into the trainer through its extension
points (``train.Components``: loss terms, a network factory, a labeller; docs/extending.md). lab/learning_arms.py's
COMPONENTS registry names the arms that use them; lab/experiments.md records what they scored."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ramavt_jax import env as env_lib
from ramavt_jax.losses import PRIORITY_KEY, LossBatch, LossTerm, TDConfig, masked_mean, sequence_td_targets, td_term

__all__ = ["advantage_learning_term", "command_cost_term"]


def advantage_learning_term(config: TDConfig, alpha: float) -> LossTerm:
    """The TD term with advantage learning's targets (Bellemare et al. 2016, "Increasing the action gap"): the target
    of a taken action lowered by ``alpha * (max_a q_target(s, a) - q_target(s, a_taken))`` at obs t, which widens the
    gaps between the best action's value and the others'. Squared TD error, as losses.td_term; its metrics too."""

    def td_loss(batch: LossBatch) -> tuple[jax.Array, dict]:
        taken = batch.action[..., None].astype(jnp.int32)  # [B, T, 1]
        target = sequence_td_targets(batch.q, batch.q_target, batch.reward, batch.terminated, batch.truncated, config)
        q_tm1 = batch.q_target[:, :-1]  # [B, T, A] at obs t
        gap = q_tm1.max(-1) - jnp.take_along_axis(q_tm1, taken, -1)[..., 0]  # [B, T]
        target = jax.lax.stop_gradient(target - alpha * gap)
        td_error = target - jnp.take_along_axis(batch.q[:, :-1], taken, -1)[..., 0]
        loss = masked_mean(0.5 * jnp.square(td_error), batch.mask, batch.weight)
        return loss, {"td_loss": loss, PRIORITY_KEY: td_error}

    return td_loss


def command_cost_term(config: TDConfig, cost: float, reward_scale: float) -> LossTerm:
    """The TD term on shaped rewards: each transition's reward less ``cost`` (in the env's reward units, scaled as the
    rewards are by ``reward_scale``) times its command's size in units of the full speed (0 holding still, 1 along an
    axis, sqrt 2 diagonally). Training only: the env's reward, and so evaluation, is unchanged."""
    sizes = jnp.linalg.norm(jnp.asarray(env_lib.ACTIONS, jnp.float32), axis=-1)  # [A]
    td = td_term(config)

    def shaped(batch: LossBatch) -> tuple[jax.Array, dict]:
        return td(batch.replace(reward=batch.reward - reward_scale * cost * sizes[batch.action]))

    return shaped
