"""Running policies for whole episodes and summarising them (episode length / reward tables)."""

from __future__ import annotations

import dataclasses
import functools
from typing import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from ramavt_jax import env as env_lib
from ramavt_jax.baselines import Policy


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
    terminated: jax.Array  # ended by losing the target (else truncated at max_steps)
    target_index: jax.Array


def run_episodes(
    tracking_env: env_lib.TrackingEnv,
    policy: Policy,
    params: env_lib.EnvParams,
    key: jax.Array,
    num_episodes: int,
    num_steps: int | None = None,
    record: bool = False,
) -> tuple[EpisodeStats, EpisodeRecord | None]:
    """Run `num_episodes` episodes in parallel (one per env, no auto-reset) for `num_steps` (default max_steps).

    Returns EpisodeStats [N] and, if `record`, the per-step EpisodeRecord [T, N]. Jit-compiled as one lax.scan.
    """
    steps = int(num_steps if num_steps is not None else np.asarray(params.max_steps))
    fn = _episode_runner(tracking_env, policy, steps, record)
    return fn(params, key, num_episodes)


@functools.lru_cache(maxsize=32)
def _episode_runner(tracking_env, policy, steps, record):
    def run(params, key, num_episodes):
        k_reset, k_policy, k_loop = jax.random.split(key, 3)
        obs, state = jax.vmap(tracking_env.reset, in_axes=(0, None))(jax.random.split(k_reset, num_episodes), params)
        pstate = jax.vmap(policy.init)(jax.random.split(k_policy, num_episodes))
        alive = jnp.ones(num_episodes, bool)
        zeros = jnp.zeros(num_episodes)

        def body(carry, step_key):
            obs, state, pstate, alive, length, ret, term = carry
            k_act, k_env = jax.random.split(step_key)
            act_keys = jax.random.split(k_act, num_episodes)
            action, pstate = jax.vmap(policy.act, in_axes=(0, 0, 0, 0, None))(act_keys, pstate, obs, state, params)
            env_keys = jax.random.split(k_env, num_episodes)
            obs, state, reward, terminated, truncated, info = jax.vmap(tracking_env.step_env, in_axes=(0, 0, 0, None))(
                env_keys, state, action, params
            )
            length = length + alive
            ret = ret + jnp.where(alive, reward, 0.0)
            term = term | (alive & terminated)
            out = None
            if record:
                out = EpisodeRecord(
                    reward=reward, action=action, terminated=terminated, truncated=truncated, alive=alive,
                    rel_pos=info["rel_pos"], chaser_pos=state.chaser_pos, target_pos=state.target_pos,
                    in_view=info["in_view"],
                )
            alive = alive & ~(terminated | truncated)
            return (obs, state, pstate, alive, length, ret, term), out

        init = (obs, state, pstate, alive, zeros.astype(jnp.int32), zeros, jnp.zeros(num_episodes, bool))
        (_, state, _, _, length, ret, term), rec = jax.lax.scan(body, init, jax.random.split(k_loop, steps))
        return EpisodeStats(length=length, episode_return=ret, terminated=term, target_index=state.target_index), rec

    return jax.jit(run, static_argnums=2)


@dataclasses.dataclass(frozen=True)
class Summary:
    """Table I columns for one set of episodes."""

    episodes: int
    length_mean: float
    length_min: float
    length_max: float
    return_mean: float
    return_min: float
    return_max: float
    lost_fraction: float

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


def summarise(stats: EpisodeStats) -> Summary:
    length = np.asarray(stats.length, dtype=np.float64)
    ret = np.asarray(stats.episode_return, dtype=np.float64)
    return Summary(
        episodes=int(length.size),
        length_mean=float(length.mean()),
        length_min=float(length.min()),
        length_max=float(length.max()),
        return_mean=float(ret.mean()),
        return_min=float(ret.min()),
        return_max=float(ret.max()),
        lost_fraction=float(np.asarray(stats.terminated).mean()),
    )


def evaluate_per_target(
    config: env_lib.EnvConfig,
    policy: Policy,
    key: jax.Array,
    episodes_per_target: int,
    params_overrides: dict | None = None,
    eval_settings: bool = True,
) -> dict[str, Summary]:
    """Summary per target of `config.targets`; one compiled program serves all targets (the target is pinned by
    `EnvParams.target_probs`, a traced value)."""
    tracking_env = env_lib.TrackingEnv(config)
    make = tracking_env.eval_params if eval_settings else tracking_env.default_params
    params = make(**(params_overrides or {}))
    results = {}
    for i, name in enumerate(config.targets):
        stats, _ = run_episodes(tracking_env, policy, tracking_env.pinned(params, i), jax.random.fold_in(key, i),
                                episodes_per_target)
        results[name] = summarise(stats)
    return results
