"""Reference policies: random, two true-state controllers and a classical depth-image tracker (PBVS-style).

- 'mpc': receding-horizon search over the 11 commands on the env's own noise-free model (`TrackingEnv.transition`
  + `score`); the ceiling of the tables: every other policy measured so far scores below it on the same episodes
  (a measured reference, not a proven optimum).
- 'proportional': feed-forward of the true target velocity + proportional correction, quantised (cheap, but far
  below the ceiling: it is not an upper bound).
- 'depth': classical depth-image tracker; 'random'.

Every policy is a `Policy` of pure per-env functions (batch them with vmap):
  init(key) -> policy_state
  act(key, policy_state, obs [H, W, C], env_state, params) -> (action [] int32, policy_state)
`env_state` is only read by the true-state controllers; image-based policies ignore it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from ramavt_jax import env as env_lib

ActFn = Callable[[jax.Array, Any, jax.Array, env_lib.EnvState, env_lib.EnvParams], tuple[jax.Array, Any]]


@dataclasses.dataclass(frozen=True)
class Policy:
    name: str
    init: Callable[[jax.Array], Any]
    act: ActFn


def quantise_velocity(desired_cam: jax.Array, speed: jax.Array) -> jax.Array:
    """The action whose velocity command is nearest to `desired_cam` [3] (camera frame, m/s). Returns [] int32."""
    commands = env_lib.ACTIONS * speed
    return jnp.argmin(jnp.sum((commands - desired_cam) ** 2, axis=-1)).astype(jnp.int32)


# ----------------------------------------------------------------------------------------- random
def random_policy(num_actions: int = env_lib.NUM_ACTIONS) -> Policy:
    def act(key, pstate, obs, env_state, params):
        return jax.random.randint(key, (), 0, num_actions), pstate

    return Policy("random", lambda key: jnp.zeros(()), act)


# ----------------------------------------------------------------------------------------- proportional
def proportional_policy(gain: float = 1.0) -> Policy:
    """Feed-forward of the true target velocity plus proportional correction of the true position error:
    v_chaser = v_target + gain * (p - r*), quantised to the 11 commands."""

    def act(key, pstate, obs, env_state: env_lib.EnvState, params: env_lib.EnvParams):
        position = env_lib.relative_position(env_state)
        target_vel_cam = env_lib.HILL_FROM_CAM.T @ env_state.target_vel
        desired = target_vel_cam + gain * (position - env_lib.desired_position(env_state, params))
        return quantise_velocity(desired, env_lib.command_speed(env_state, params)), pstate

    return Policy("proportional", lambda key: jnp.zeros(()), act)


# ----------------------------------------------------------------------------------------- mpc (the ceiling)
# Default look-ahead steps (see mpc_policy): every pair of the next two commands, the second held for 10 more steps
# scoring the view only. Longer or shorter horizons (2 to 24) track alike (the sweep: lab/experiments.md); the tail is
# there for targets that leave the view.
MPC_HORIZON = 12


def candidate_sequences(branch: int, num_actions: int = env_lib.NUM_ACTIONS) -> jax.Array:
    """Every sequence of `branch` actions, [num_actions ** branch, branch] int32 (first action slowest)."""
    grids = jnp.meshgrid(*[jnp.arange(num_actions)] * branch, indexing="ij")
    return jnp.stack([g.reshape(-1) for g in grids], axis=-1).astype(jnp.int32)


def mpc_policy(config: env_lib.EnvConfig, horizon: int = MPC_HORIZON, branch: int = 2, tail: str = "view") -> Policy:
    """Receding-horizon control on the true state: every sequence of `branch` actions (11 ** branch) is simulated
    with the env's own `transition` + `score` from the current state, then `horizon - branch` tail steps; the first
    action of the sequence with the highest model return is taken. Tails:

    - 'view': the last action held, scoring only whether the target is in view (+1 / -5). A 2-step search cannot
      see the reward's -5 -> +1 cliff when an out-of-view target is more than 2 steps from the view, and a held
      command's distance term would mislead (held for 1 s it overshoots), but its view term shows which first
      moves bring the target back soonest; when the target stays in view every plan's tail scores the same.
    - 'hold': the last action held, full reward. 'proportional': the proportional controller on the model's
      state, full reward (a rollout of a base policy).

    The model is noise-free (actuator noise and time delay off in its params, so one step lasts exactly dt): the
    real env still applies its perturbations when it steps. It never renders. `config` supplies the motion model
    and the camera (the reward's in-view test); the attitude, which no reward reads, gets one RK4 substep."""
    if not 1 <= branch <= horizon:
        raise ValueError(f"mpc needs 1 <= branch <= horizon, got branch {branch}, horizon {horizon}")
    if tail not in ("view", "hold", "proportional"):
        raise ValueError(f"mpc tail must be 'view', 'hold' or 'proportional', got {tail!r}")
    model = env_lib.TrackingEnv(dataclasses.replace(config, attitude_substeps=1))
    base = proportional_policy()
    sequences = candidate_sequences(branch)  # [S, branch]
    hold = jnp.broadcast_to(sequences[:, -1:], (sequences.shape[0], horizon - branch))
    plans = jnp.concatenate([sequences, hold], axis=1)  # [S, horizon]; tail 'proportional' ignores the held part
    in_tail = jnp.arange(horizon) >= branch
    follow_base = in_tail & (tail == "proportional")
    view_only = in_tail & (tail == "view")

    def plan_return(keys, state, params, plan):
        """Model return [] of one plan [horizon]; `keys` [horizon] (inert: the model has no noise)."""

        def step(s, xs):
            k, a, use_base, only_view = xs
            a = jnp.where(use_base, base.act(k, None, None, s, params)[0], a)
            s, reward, _, _, info = model.score(model.transition(k, s, a, params), params)
            return s, jnp.where(only_view, jnp.where(info["in_view"], 1.0, -5.0), reward)

        return jax.lax.scan(step, state, (keys, plan, follow_base, view_only))[1].sum()

    def act(key, pstate, obs, env_state: env_lib.EnvState, params: env_lib.EnvParams):
        model_params = params.replace(
            actuator_noise=jnp.zeros_like(params.actuator_noise), delay_max=jnp.zeros_like(params.delay_max)
        )
        keys = jax.random.split(key, horizon)  # every plan sees the same keys: common random numbers
        returns = jax.vmap(plan_return, in_axes=(None, None, None, 0))(keys, env_state, model_params, plans)
        return plans[jnp.argmax(returns), 0], pstate

    return Policy("mpc", lambda key: jnp.zeros(()), act)


# ----------------------------------------------------------------------------------------- depth tracker
@struct.dataclass
class DepthTrackerState:
    last_position: jax.Array  # [3] last position estimate (camera frame, m)
    target_vel: jax.Array  # [3] filtered estimate of the target's velocity (m/s)
    last_command: jax.Array  # [3] chaser velocity commanded at the previous step (m/s)
    has_estimate: jax.Array  # [] bool


def estimate_position(depth: jax.Array, camera) -> tuple[jax.Array, jax.Array]:
    """Target position [3] from a depth observation [H, W] (z / far, 0 = background) and whether any pixel hit.

    Centroid of the target pixels back-projected at their mean depth; the centre of mass lies deeper than the
    visible surface, which the tracker does not know (a classical tracker's bias)."""
    hit = depth > 0
    count = hit.sum()
    res = depth.shape[0]
    c = (res - 1) / 2.0
    f = camera.focal()
    v, u = jnp.meshgrid(jnp.arange(res), jnp.arange(res), indexing="ij")
    safe = jnp.maximum(count, 1)
    z = (depth * camera.far * hit).sum() / safe
    u_mean = (u * hit).sum() / safe
    v_mean = (v * hit).sum() / safe
    return jnp.array([(u_mean - c) / f * z, (v_mean - c) / f * z, z]), count > 0


def depth_tracker_policy(camera, kp: float = 1.0, velocity_smoothing: float = 0.3, dt: float = 0.1) -> Policy:
    """PBVS-style tracker using only the depth image: estimate the target centre from the depth pixels, estimate
    its velocity by finite differences (adding back the chaser's own commanded motion) and command
    v = v_target_est + kp * (p_est - r*), quantised. Without a detection it repeats its last command."""

    def init(key):
        zero = jnp.zeros(3)
        return DepthTrackerState(zero, zero, zero, jnp.zeros((), bool))

    def act(key, pstate: DepthTrackerState, obs, env_state, params: env_lib.EnvParams):
        depth = obs[..., -1]  # depth is the last channel in 'depth' and 'rgbd' modes
        position, seen = estimate_position(depth, camera)
        position = position * env_state.scale  # depths of a target at a scaled stand-off are divided by k
        # Relative displacement = target displacement - chaser displacement (trapezoid of its last command).
        rel_vel = (position - pstate.last_position) / params.dt
        target_vel_raw = rel_vel + pstate.last_command
        blend = jnp.where(pstate.has_estimate, velocity_smoothing, 0.0)
        target_vel = jnp.where(
            seen & pstate.has_estimate, blend * pstate.target_vel + (1 - blend) * target_vel_raw, pstate.target_vel
        )
        desired = target_vel + kp * (position - env_lib.desired_position(env_state, params))
        speed = env_lib.command_speed(env_state, params)  # the env's speed rule, as a tracker knows its actuator
        action = quantise_velocity(desired, speed)
        action = jnp.where(seen, action, quantise_velocity(pstate.last_command, speed))
        command = jnp.asarray(env_lib.ACTIONS)[action] * speed
        new_state = DepthTrackerState(
            last_position=jnp.where(seen, position, pstate.last_position),
            target_vel=target_vel,
            last_command=command,
            has_estimate=pstate.has_estimate | seen,
        )
        return action, new_state

    return Policy("depth_tracker", init, act)


def make_policy(name: str, camera, dynamics: str = "cw", horizon: int = MPC_HORIZON) -> Policy:
    """'random' | 'proportional' | 'mpc' (the ceiling; `horizon` steps) | 'depth' (the classical depth-image tracker).
    `dynamics` is the env's motion model, which the mpc's model must share."""
    if name == "oracle":
        raise ValueError(
            "baseline 'oracle' was renamed 'proportional' (it is no upper bound); the measured ceiling is 'mpc'"
        )
    table = {
        "random": random_policy,
        "proportional": proportional_policy,
        "mpc": lambda: mpc_policy(env_lib.EnvConfig(camera=camera, dynamics=dynamics), horizon, min(2, horizon)),
        "depth": lambda: depth_tracker_policy(camera),
        "depth_tracker": lambda: depth_tracker_policy(camera),
    }
    if name not in table:
        raise ValueError(f"unknown baseline policy {name!r}; choose one of {sorted(table)}")
    return table[name]()
