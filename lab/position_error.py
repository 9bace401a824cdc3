"""Where a policy's distance penalty comes from: the target centre's camera-frame position error, split into its
mean (bias) and its spread (std) per axis, per target of a split, after the first 100 steps (the approach), and the
share of those steps on which the policy commands no motion (action 0; a policy that dithers about the desired point
seldom holds still). Metres divided by the target's stand-off scale k (plain metres for the catalogue's sizes, k = 1).

    python lab/position_error.py mpc depth runs/quick_now/seed_0 --targets val --episodes 8

Policies: 'depth' / 'proportional' / 'mpc' (baselines), 'pretrained' (the shipped agent) or a training run folder.
Every policy runs the same episodes (fixed key) with the evaluation's reward rules.
"""

from __future__ import annotations

import argparse

import jax
import numpy as np

from ramavt_jax import baselines
from ramavt_jax import env as env_lib
from ramavt_jax import targets as targets_lib
from ramavt_jax.evaluation import pretrained, rollouts, runs


def load(spec: str, resolution: int):
    if spec in ("depth", "proportional", "mpc"):
        return baselines.make_policy(spec, env_lib.CameraConfig(resolution=resolution))
    return pretrained.load().policy if spec == "pretrained" else runs.load_policy(spec).policy


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("policies", nargs="+")
    ap.add_argument("--episodes", type=int, default=8, help="episodes per target")
    ap.add_argument("--resolution", type=int, default=32)
    ap.add_argument("--skip", type=int, default=100, help="steps of each episode left out (the approach)")
    ap.add_argument("--targets", default="val", help="a split of targets_lib.split: val (default), test, ...")
    args = ap.parse_args()
    policies = {spec: load(spec, args.resolution) for spec in args.policies}
    print(
        f"{'target':13s} {'policy':24s} {'AEL':>6s} {'AER':>7s}  bias x/y/z (m)       std x/y/z (m)      "
        "mean |e|  still"
    )
    names = targets_lib.split(args.targets)
    tracking_env = env_lib.TrackingEnv(
        env_lib.EnvConfig(camera=env_lib.CameraConfig(resolution=args.resolution), targets=names)
    )  # one env: each policy compiles once
    for index, name in enumerate(names):
        params = tracking_env.pinned(tracking_env.eval_params(), index)
        k = float(tracking_env.initial_state(jax.random.PRNGKey(0), params).scale)  # stand-off scale: 1 unless resized
        for spec, policy in policies.items():
            stats, rec = rollouts.run_episodes(
                tracking_env, policy, params, jax.random.PRNGKey(5), args.episodes, record=True
            )
            alive = np.asarray(rec.alive)[args.skip :]
            err = (np.asarray(rec.rel_pos) / k - np.asarray(params.desired_pos))[args.skip :][alive]  # [steps, 3]
            bias, std = np.round(err.mean(0), 2), np.round(err.std(0), 2)
            still = float((np.asarray(rec.action)[args.skip :][alive] == 0).mean())
            print(
                f"{name:13s} {spec[-24:]:24s} {float(stats.length.mean()):6.1f} "
                f"{float(stats.episode_return.mean()):7.1f}  {str(bias):20s} {str(std):18s} "
                f"{np.linalg.norm(err, axis=1).mean():.2f}  {still:5.1%}"
            )


if __name__ == "__main__":
    main()
