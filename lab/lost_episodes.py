"""Why episodes end early: for each episode a policy loses, where the target started, how fast it drifts against the
command speed, how close it came to the camera, when it first left the view and from when it stayed out. Lost
episodes only; the others are counted. Steps are counted from 1 (step L is an episode's last, L its length).

    python lab/lost_episodes.py mpc --targets examples/targets/cubesat-0.45m.xml --episodes 20 --seed 0

The episodes are those of `ramavt eval --targets ... --episodes N --seed S --resolution 32` with no perturbation
(same keys, the evaluation's task and a trained run's own env settings; --resolution is this script's, 32 by
default, and matters to image-based baselines only), so a lost episode here is one of that table's. Policies: 'depth' / 'proportional' / 'mpc' (baselines), 'pretrained' (the
shipped agent) or a training run folder. Distances are in metres (not stand-off units).
"""

from __future__ import annotations

import argparse
import dataclasses

import jax
import numpy as np

from ramavt_jax import baselines
from ramavt_jax import env as env_lib
from ramavt_jax.evaluation import pretrained, rollouts, runs, tables


def load(spec: str, resolution: int, names: tuple[str, ...], search: str = "learned"):
    """(policy, the env it flies on ``names``, EnvParams overrides): a trained policy sees its own run's camera,
    inputs and env settings (those evaluation keeps: rollouts.run_env_overrides), as `ramavt eval` flies it, and
    commands ``search`` until the target is first in view (greedy.greedy_policy)."""
    if spec in ("depth", "proportional", "mpc"):
        camera = env_lib.CameraConfig(resolution=resolution)
        return baselines.make_policy(spec, camera), env_lib.EnvConfig(camera=camera, targets=names), {}
    loaded = pretrained.load(search=search) if spec == "pretrained" else runs.load_policy(spec, search=search)
    return (
        loaded.policy,
        dataclasses.replace(loaded.config.env, targets=names),
        rollouts.run_env_overrides(loaded.config.env_params),
    )


def describe(rec, stats, episode: int, dt: float, speed: float) -> str:
    """One line on a lost episode of a record [T, N] (episode_program.EpisodeRecord; row t is after step t + 1): its
    length, start (after step 1), drift speed, closest approach, first step out of view and the step from which it
    stayed out (steps from 1)."""
    length = int(stats.length[episode])
    rel = np.asarray(rec.rel_pos)[:length, episode]  # [L, 3] camera frame
    drift = np.linalg.norm(np.diff(np.asarray(rec.target_pos)[:2, episode], axis=0)[0]) / dt
    closest = int(np.argmin(np.linalg.norm(rel, axis=1)))
    seen = np.asarray(rec.in_view)[:length, episode]
    hidden = np.nonzero(~seen)[0]
    if hidden.size:
        shown = np.nonzero(seen)[0]
        stayed = (int(shown[-1]) + 2) if shown.size else 1
        left = (
            f"step {int(hidden[0]) + 1}, out for good from step {stayed}"
            if not seen[-1]
            else f"step {int(hidden[0]) + 1}, in view at the end"
        )
    else:
        left = "never"
    return (
        f"  episode {episode:3d}: length {length:4d}, start {np.round(rel[0], 2)} m, target drift "
        f"{drift:.2f} m/s (commands {speed:.2f} m/s), closest {np.linalg.norm(rel[closest]):.2f} m at step "
        f"{closest + 1}, first out of view: {left}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("policy")
    ap.add_argument("--targets", default="val", help="a split or comma-separated catalogue names / MJCF files")
    ap.add_argument("--episodes", type=int, default=20, help="episodes per target")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--resolution", type=int, default=32, help="a baseline's camera (a trained policy uses its own)")
    ap.add_argument("--speed-standoff-power", type=float, default=None)
    args = ap.parse_args()
    if args.episodes < 1:
        ap.error(f"--episodes must be >= 1, got {args.episodes}")
    names = rollouts.resolve_targets(args.targets)
    policy, env_config, run_overrides = load(args.policy, args.resolution, names)
    tracking_env = env_lib.TrackingEnv(env_config)
    task = {} if args.speed_standoff_power is None else {"speed_standoff_power": args.speed_standoff_power}
    params = tracking_env.eval_params(**run_overrides, **task)
    root = jax.random.PRNGKey(args.seed)
    for index, name in enumerate(names):
        pinned = tracking_env.pinned(params, index)
        stats, rec = jax.device_get(
            rollouts.run_episodes(
                tracking_env, policy, pinned, tables.episode_key(root, "none", name), args.episodes, record=True
            )
        )
        lost = np.nonzero(np.asarray(stats.terminated))[0]
        print(f"{name}: {lost.size} of {args.episodes} lost, AEL {float(np.mean(stats.length)):.1f}")
        state = tracking_env.initial_state(jax.random.PRNGKey(0), pinned)
        speed = float(env_lib.command_speed(state, pinned))
        for episode in lost:
            print(describe(rec, stats, int(episode), float(pinned.dt), speed))


if __name__ == "__main__":
    main()
