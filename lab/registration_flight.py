"""Fly the ceiling on the centre that registration finds in the depth frames: an image-based tracker without
learning, to see what lab/centre_registration.py's estimate is worth in flight.

    python -m lab.registration_flight --targets val --episodes 5 --out lab/results/centre/flight.json

Arms, on the same episodes (those `ramavt eval --targets T --episodes N --seed S` flies in `--setting`, by default
without perturbation):

- `ceiling`: the true-state look-ahead (`mpc`), told the true state.
- `registration`: the same planner told the centre and its velocity from OnlineRegistration, fed each episode's
  newest depth frame (under Table II's blur, the observation's mean of the last frames), the chaser's own
  displacement since the start and its clock (the chaser's navigation: its true position, even under actuator
  noise, which its commands alone would not give).
  Everything else the planner reads (the chaser's own state, the target's attitude, which no reward reads) is
  as the ceiling's. Before the first registered pair the centre is the visible centroid, at rest.
- `visible`: the planner told the newest frame's visible centroid, at rest, for scale.

The estimator runs on the host (numpy, scipy), one episode at a time, so the flight is a Python loop over steps,
each env and planner step jitted across the episodes; the `ceiling` row of that loop is checked against
tables.evaluate_setting's (the compiled flight) on the same episodes, so the loop flies the recorded episodes.
"""

from __future__ import annotations

import argparse
import functools
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from lab.centre_registration import OnlineRegistration, Settings, frame_points
from ramavt_jax import baselines
from ramavt_jax import env as env_lib
from ramavt_jax.evaluation import episode_program, rollouts, tables

CAM_FROM_HILL = env_lib.HILL_FROM_CAM.T


def told(state: env_lib.EnvState, centre_cam: jax.Array, velocity_cam: jax.Array) -> env_lib.EnvState:
    """[N] states with the target's centre at ``centre_cam`` [N, 3] m from the chaser and moving at
    ``velocity_cam`` [N, 3] m/s (camera axes): what the planner reads."""
    hill = jnp.asarray(env_lib.HILL_FROM_CAM)
    return state.replace(target_pos=state.chaser_pos + centre_cam @ hill.T, target_vel=velocity_cam @ hill.T)


@functools.lru_cache(maxsize=4)
def _programs(tracking_env: env_lib.TrackingEnv):
    """(the planner, its act and the env's step, each jitted across episodes): one compile for every arm and target."""
    planner = baselines.make_policy("mpc", tracking_env.config.camera)
    act = jax.jit(jax.vmap(planner.act, in_axes=(0, 0, 0, 0, None)))
    return planner, act, jax.jit(jax.vmap(tracking_env.step_env, in_axes=(0, 0, 0, None)))


def fly(tracking_env, params, key, episodes: int, arm: str, settings: Settings, steps: int) -> np.ndarray:
    """Returns [N] of one arm on the ``episodes`` episodes of ``key`` (episode_program's draws)."""
    camera = tracking_env.config.camera
    planner, act, step = _programs(tracking_env)
    k_reset, k_policy, k_loop = episode_program.episode_keys(key)
    obs, state = jax.vmap(tracking_env.reset, in_axes=(0, None))(jax.random.split(k_reset, episodes), params)
    pstate = jax.vmap(planner.init)(jax.random.split(k_policy, episodes))
    trackers = [OnlineRegistration(camera, settings) for _ in range(episodes)]
    start = np.asarray(state.chaser_pos, np.float64)
    alive, total = np.ones(episodes, bool), np.zeros(episodes)
    for step_key in tqdm(jax.random.split(k_loop, steps), desc=arm, unit="step", mininterval=10, leave=False):
        k_act, k_env = jax.random.split(step_key)
        seen = state
        if arm != "ceiling":
            depth = np.asarray(obs[..., -1], np.float64) * camera.far  # [N, H, W] m
            scale = np.asarray(state.scale, np.float64)[:, None]  # frames show a target at 1 / k: m / k throughout
            moved = (np.asarray(state.chaser_pos, np.float64) - start) @ CAM_FROM_HILL.T / scale  # [N, 3] camera axes
            clock = np.asarray(state.sim_time, np.float64)  # the chaser's clock: steps last longer under a delay
            centre, velocity = np.zeros((episodes, 3)), np.zeros((episodes, 3))
            for e in np.nonzero(alive)[0]:
                if arm == "registration":
                    world, velocity[e] = trackers[e].update(depth[e], moved[e], clock[e])
                    centre[e] = world - moved[e]
                else:
                    centre[e] = frame_points(depth[e], trackers[e].rays, settings.jump)[2]
            centre = np.where(np.isnan(centre), np.asarray(params.desired_pos), centre)  # nothing seen yet
            seen = told(state, jnp.asarray(centre * scale, jnp.float32), jnp.asarray(velocity * scale, jnp.float32))
        action, pstate = act(jax.random.split(k_act, episodes), pstate, obs, seen, params)
        obs, state, reward, terminated, truncated, _ = step(jax.random.split(k_env, episodes), state, action, params)
        total += np.where(alive, np.asarray(reward), 0.0)
        alive &= ~np.asarray(terminated | truncated)
        if not alive.any():
            break
    return total


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--targets", default="val")
    ap.add_argument("--episodes", type=int, default=5, help="per target")
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--resolution", type=int, default=64)
    ap.add_argument("--arms", nargs="+", default=["ceiling", "registration", "visible"])
    ap.add_argument(
        "--depth-prior",
        type=float,
        nargs=2,
        default=(0.0, 0.0),
        metavar=("OFFSET", "GAIN"),
        help="Settings.depth_offset, depth_gain: the prior behind the visible surface (lab/centre_registration.py "
        "fits them on training episodes); 0 0: the visible centroid",
    )
    ap.add_argument("--setting", default="none", help="a Table II setting: " + ", ".join(rollouts.PERTURBATIONS))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    if set(args.arms) - {"ceiling", "registration", "visible"}:
        ap.error("--arms: ceiling, registration, visible")
    names = rollouts.resolve_targets(args.targets)
    settings = Settings(depth_offset=args.depth_prior[0], depth_gain=args.depth_prior[1])
    camera = env_lib.CameraConfig(resolution=args.resolution)
    tracking_env = tables.suite_env(env_lib.EnvConfig(camera=camera), names, rollouts.PERTURBATION_VALUES)
    perturbed = rollouts.perturbation_overrides(args.setting, rollouts.PERTURBATION_VALUES)
    params = tracking_env.eval_params(max_steps=args.steps, **perturbed)
    root = jax.random.PRNGKey(args.seed)
    returns = {arm: {} for arm in args.arms}
    for i, target in enumerate(tqdm(names, desc="targets", unit="target")):
        key = tables.episode_key(root, args.setting, target)
        for arm in args.arms:
            returns[arm][target] = fly(
                tracking_env, tracking_env.pinned(params, i), key, args.episodes, arm, settings, args.steps
            ).tolist()
    compiled = tables.evaluate_setting(
        tracking_env,
        baselines.make_policy("mpc", camera),
        {},
        args.episodes,
        args.steps,
        root,
        args.setting,
        rollouts.PERTURBATION_VALUES,
    )
    check = {t: s["return_mean"] for t, s in compiled["per_target"].items()}
    ceiling = (
        np.mean([np.mean(v) for v in returns.get("ceiling", {}).values()])
        if "ceiling" in returns
        else compiled["overall"]["return_mean"]
    )
    print(f"compiled ceiling per target: {check}")
    for arm, per in returns.items():
        aer = float(np.mean([x for v in per.values() for x in v]))
        print(
            f"{arm:14s} AER {aer:+7.1f} ({aer / ceiling:5.1%} of the ceiling)   "
            + " ".join(f"{t}:{np.mean(v):+.0f}" for t, v in per.items())
        )
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(
            json.dumps(
                {"command": vars(args) | {"out": str(args.out)}, "returns": returns, "compiled_ceiling": check},
                indent=1,
            )
        )


if __name__ == "__main__":
    main()
