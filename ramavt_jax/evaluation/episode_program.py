"""The compiled program that flies a batch of episodes side by side, and what it returns: per-step records
(`EpisodeRecord`, [T, N]) and per-episode results (`EpisodeStats`, `TrackingSums`, [N]).

`episode_runner` is the jitted program of one (env, policy, horizon): a lax.scan over the whole horizon when every
step is recorded, else a lax.while_loop that stops once every episode has ended. `compiled_runner` compiles it ahead
of time for one batch (cached), so that `episodes_that_fit` can read its memory before anything is allocated.
:func:`ramavt_jax.evaluation.rollouts.run_episodes` runs it, in batches when the episodes do not fit side by side.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from flax import struct

from ramavt_jax.training import memory as memplan

__all__ = [
    "EpisodeRecord",
    "EpisodeStats",
    "TrackingSums",
    "compiled_runner",
    "episodes_that_fit",
    "episode_keys",
    "episode_runner",
]


@struct.dataclass
class EpisodeRecord:
    """Per-step arrays of one batch of episodes run side by side, [T, N] (or [T, N, 3])."""

    reward: jax.Array
    action: jax.Array
    terminated: jax.Array
    truncated: jax.Array
    alive: jax.Array  # the step belongs to the episode (False after it ended)
    rel_pos: jax.Array  # [T, N, 3] target centre in the camera frame after the step
    chaser_pos: jax.Array  # [T, N, 3] Hill frame
    target_pos: jax.Array  # [T, N, 3] Hill frame
    in_view: jax.Array


@struct.dataclass
class EpisodeStats:
    """One entry per episode, [N]."""

    length: jax.Array
    episode_return: jax.Array
    terminated: jax.Array  # ended by losing the target
    target_index: jax.Array
    truncated: jax.Array | None = None  # ended by reaching max_steps (None: unknown, taken as ~terminated)
    tracking: TrackingSums | None = None  # per-episode sums of the tracking error (None: not recorded)


@struct.dataclass
class TrackingSums:
    """Per-episode sums over the episode's steps, [N]. Distances are in stand-off units: metres for every catalogue
    target, metres / k for a target held at the scaled stand-off k (env.standoff_scale)."""

    error: jax.Array  # sum of |target centre - desired point| / k
    within_quarter: jax.Array  # steps with that distance <= 0.25
    within_half: jax.Array  # steps with that distance <= 0.5

    @staticmethod
    def zeros(n: int) -> TrackingSums:
        return TrackingSums(jnp.zeros(n), jnp.zeros(n, jnp.int32), jnp.zeros(n, jnp.int32))

    def add(self, tracking_error: jax.Array, scale: jax.Array, alive: jax.Array) -> TrackingSums:
        """Add one step: tracking_error [N, 3] (m, camera frame), scale [N], alive [N] bool (ended: nothing)."""
        distance = jnp.linalg.norm(tracking_error, axis=-1) / scale
        return TrackingSums(
            error=self.error + jnp.where(alive, distance, 0.0),
            within_quarter=self.within_quarter + (alive & (distance <= 0.25)),
            within_half=self.within_half + (alive & (distance <= 0.5)),
        )


_COMPILED_RUNS: dict = {}  # (runner, episodes, total, argument types) -> the compiled runner


def compiled_runner(fn, params, key, num_episodes: int, total: int | None = None, policy_params=None):
    """``fn`` (an :func:`episode_runner`) compiled for ``num_episodes`` of ``total`` episodes (default: all) and the
    types of ``params``, ``key`` and ``policy_params``; called as ``compiled(params, key, policy_params, offset)``
    for the episodes from ``offset`` on. Compiled ahead of time so its memory is known before anything is allocated
    (:func:`episodes_that_fit`); cached, so repeated calls (targets, settings, checkpoints) do not trace again."""
    total = num_episodes if total is None else total
    args = (params, key, policy_params)
    types = (jax.tree.structure(args), tuple(jax.typeof(x) for x in jax.tree.leaves(args)))
    cache_key = (fn, num_episodes, total, types)
    if cache_key not in _COMPILED_RUNS:
        if len(_COMPILED_RUNS) >= 64:
            _COMPILED_RUNS.pop(next(iter(_COMPILED_RUNS)))
        _COMPILED_RUNS[cache_key] = fn.lower(*args, num_episodes, total, 0).compile()
    return _COMPILED_RUNS[cache_key]


def episodes_that_fit(compiled, num_episodes: int) -> int:
    """How many of ``num_episodes`` episodes can run side by side: all of them when ``compiled`` (their runner)
    fits in the memory available (or either is unknown), else as many as fit at the same bytes per episode.
    Raises MemoryPlanError when not even one fits."""
    try:
        stats = compiled.memory_analysis()
        need = int(stats.temp_size_in_bytes + stats.output_size_in_bytes + stats.argument_size_in_bytes)
    except Exception:  # noqa: BLE001 (not every backend reports it)
        return num_episodes
    avail = memplan.available_bytes()
    if avail is None or need <= memplan.FRACTION * avail:
        return num_episodes
    batch = int(memplan.FRACTION * avail * num_episodes // need)
    if batch < 1:
        memplan.check_fits(need // num_episodes, "one evaluation episode", "lower the camera resolution")
    return max(batch, 1)


def episode_keys(key: jax.Array) -> jax.Array:
    """[3] keys of a set of episodes: resets, policy inits, steps (each split per episode)."""
    return jax.random.split(key, 3)


@functools.lru_cache(maxsize=32)
def episode_runner(tracking_env, policy, steps, record):
    """Jitted runner. With `record` the whole horizon is one lax.scan; without, a lax.while_loop that stops as soon
    as every episode has ended (random agents lose the target within ~200 steps). Both draw the same per-step keys,
    so the same key gives the same episodes either way. Without ``policy_params`` (None) ``policy`` is a Policy,
    with them a function of them that returns one (rollouts.run_episodes)."""

    def run(params, key, policy_params, num_episodes, total, offset):
        pol = policy if policy_params is None else policy(policy_params)

        def split(k):  # episodes offset .. offset + num_episodes of the keys of all `total` episodes
            return jax.lax.dynamic_slice_in_dim(jax.random.split(k, total), offset, num_episodes)

        k_reset, k_policy, k_loop = episode_keys(key)
        obs, state = jax.vmap(tracking_env.reset, in_axes=(0, None))(split(k_reset), params)
        pstate = jax.vmap(pol.init)(split(k_policy))
        alive = jnp.ones(num_episodes, bool)
        zeros = jnp.zeros(num_episodes)
        step_keys = jax.random.split(k_loop, steps)

        def body(carry, step_key):
            obs, state, pstate, alive, length, ret, term, trunc, track = carry
            k_act, k_env = jax.random.split(step_key)
            act_keys = split(k_act)
            action, pstate = jax.vmap(pol.act, in_axes=(0, 0, 0, 0, None))(act_keys, pstate, obs, state, params)
            env_keys = split(k_env)
            obs, state, reward, terminated, truncated, info = jax.vmap(tracking_env.step_env, in_axes=(0, 0, 0, None))(
                env_keys, state, action, params
            )
            length = length + alive
            ret = ret + jnp.where(alive, reward, 0.0)
            term = term | (alive & terminated)
            trunc = trunc | (alive & truncated)
            track = track.add(info["tracking_error"], state.scale, alive)
            out = None
            if record:
                out = EpisodeRecord(
                    reward=reward,
                    action=action,
                    terminated=terminated,
                    truncated=truncated,
                    alive=alive,
                    rel_pos=info["rel_pos"],
                    chaser_pos=state.chaser_pos,
                    target_pos=state.target_pos,
                    in_view=info["in_view"],
                )
            alive = alive & ~(terminated | truncated)
            return (obs, state, pstate, alive, length, ret, term, trunc, track), out

        none = jnp.zeros(num_episodes, bool)
        init = (obs, state, pstate, alive, zeros.astype(jnp.int32), zeros, none, none, TrackingSums.zeros(num_episodes))
        if record:
            carry, rec = jax.lax.scan(body, init, step_keys)
        else:

            def cond(c):
                t, carry = c
                return (t < steps) & carry[3].any()

            def loop(c):
                t, carry = c
                return t + 1, body(carry, step_keys[t])[0]

            _, carry = jax.lax.while_loop(cond, loop, (jnp.zeros((), jnp.int32), init))
            rec = None
        _, state, _, _, length, ret, term, trunc, track = carry
        stats = EpisodeStats(
            length=length,
            episode_return=ret,
            terminated=term,
            target_index=state.target_index,
            truncated=trunc,
            tracking=track,
        )
        return stats, rec

    return jax.jit(run, static_argnums=(3, 4))
