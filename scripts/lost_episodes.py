"""Why episodes end early: for each episode a policy loses, where the target started, how fast it drifts against the
command speed, how close it came to the camera and when it left the view. Lost episodes only; the others are counted.

    python scripts/lost_episodes.py mpc --targets examples/targets/cubesat-0.45m.xml --episodes 20 --seed 0

The episodes are those of `ramavt eval --targets ... --episodes N --seed S` with no perturbation (same keys, the
evaluation's reward rules, the stand-off speed rule unless --speed-standoff-power says otherwise), so a lost
episode here is one of that table's. Policies: 'depth' / 'proportional' / 'mpc' (baselines), 'pretrained' (the
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


def load(spec: str, resolution: int, names: tuple[str, ...]):
    """(policy, the env it flies on ``names``): a trained policy sees its own run's camera and inputs."""
    if spec in ("depth", "proportional", "mpc"):
        camera = env_lib.CameraConfig(resolution=resolution)
        return baselines.make_policy(spec, camera), env_lib.EnvConfig(camera=camera, targets=names)
    loaded = pretrained.load() if spec == "pretrained" else runs.load_policy(spec)
    return loaded.policy, dataclasses.replace(loaded.config.env, targets=names)


def describe(rec, stats, episode: int, dt: float, speed: float) -> str:
    """One line on a lost episode: start, drift speed, closest approach, first step out of view, length."""
    length = int(stats.length[episode])
    rel = np.asarray(rec.rel_pos)[:length, episode]  # [T, 3] camera frame
    drift = np.linalg.norm(np.diff(np.asarray(rec.target_pos)[:2, episode], axis=0)[0]) / dt
    closest = int(np.argmin(np.linalg.norm(rel, axis=1)))
    hidden = np.nonzero(~np.asarray(rec.in_view)[:length, episode])[0]
    left = f"step {int(hidden[0])}" if hidden.size else "never"
    return (f"  episode {episode:3d}: length {length:4d}, start {np.round(rel[0], 2)} m, target drift "
            f"{drift:.2f} m/s (commands {speed:.2f} m/s), closest {np.linalg.norm(rel[closest]):.2f} m at step "
            f"{closest}, first out of view: {left}")


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
    policy, env_config = load(args.policy, args.resolution, names)
    tracking_env = env_lib.TrackingEnv(env_config)
    task = {} if args.speed_standoff_power is None else {"speed_standoff_power": args.speed_standoff_power}
    params = tracking_env.eval_params(**task)
    root = jax.random.PRNGKey(args.seed)
    for index, name in enumerate(names):
        pinned = tracking_env.pinned(params, index)
        stats, rec = jax.device_get(rollouts.run_episodes(tracking_env, policy, pinned,
                                                          tables.episode_key(root, "none", name), args.episodes,
                                                          record=True))
        lost = np.nonzero(np.asarray(stats.terminated))[0]
        print(f"{name}: {lost.size} of {args.episodes} lost, AEL {float(np.mean(stats.length)):.1f}")
        state = tracking_env.initial_state(jax.random.PRNGKey(0), pinned)
        speed = float(env_lib.command_speed(state, pinned))
        for episode in lost:
            print(describe(rec, stats, int(episode), float(pinned.dt), speed))


if __name__ == "__main__":
    main()
