"""Baselines on copies of one catalogue model at other sizes: per size, the bounding radius, the stand-off scale k,
the share of a depth image the target covers at the desired position, and each policy's AEL, AER, lost share and
tracking error (stand-off units). Every size flies the same episodes (each is the first target of its own env).

    python scripts/target_sizes.py --factors 0.125 1 5 --policies mpc depth --episodes 8
    python scripts/target_sizes.py --factors 0.125 --env-params actuator_noise=0.3 delay_max=0.5

Satellite-v1 (bounding radius 2.4 m) times 0.125 is a 0.3 m target, times 5 a 12 m one.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import numpy as np

from ramavt_jax import baselines, env, render
from ramavt_jax.evaluation import rollouts
from resized_targets import write_resized  # beside this script


def coverage(config: env.EnvConfig, overrides: dict) -> tuple[float, float, float]:
    """(bounding radius, k, mean share of target pixels over 32 attitudes) with the target at the desired point."""
    tracking_env = env.TrackingEnv(config)
    p = tracking_env.eval_params(**overrides, init_xy_std=0.0, init_z_min=5.0, init_z_max=5.0001)
    obs, state = jax.vmap(tracking_env.reset, in_axes=(0, None))(jax.random.split(jax.random.key(0), 32), p)
    return float(state.target.bound_radius[0]), float(state.scale[0]), float((np.asarray(obs[..., -1]) > 0).mean())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--target", default="Satellite-v1")
    ap.add_argument("--factors", type=float, nargs="+", default=[0.125, 1.0, 5.0])
    ap.add_argument("--policies", nargs="+", default=["mpc", "depth"])
    ap.add_argument("--episodes", type=int, default=8)
    ap.add_argument("--max-steps", type=int, default=1000)
    ap.add_argument("--resolution", type=int, default=32)
    ap.add_argument("--env-params", nargs="*", default=[], metavar="NAME=VALUE", help="EnvParams overrides")
    ap.add_argument("--out", type=Path, default=Path("runs/target_sizes"))
    args = ap.parse_args()
    overrides = {k: float(v) for k, v in (a.split("=", 1) for a in args.env_params)}
    camera = render.CameraConfig(resolution=args.resolution)
    policies = {name: baselines.make_policy(name, camera) for name in args.policies}
    for factor, path in zip(args.factors, write_resized(args.out, args.factors, names=(args.target,))):
        config = env.EnvConfig(camera=camera, targets=(str(path),))
        radius, k, share = coverage(config, overrides)
        print(f"{path.stem}: bounding radius {radius:.3g} m, k {k:.3g}, {100 * share:.2f} % of the image "
              f"({share * args.resolution ** 2:.1f} px) at the desired point", flush=True)
        for name, policy in policies.items():
            s = rollouts.evaluate_per_target(config, policy, jax.random.key(0), args.episodes,
                                             {"max_steps": args.max_steps, **overrides})[str(path)]
            print(f"  {name:6s} AEL {s.length_mean:6.1f} (min {s.length_min:4.0f})  AER {s.return_mean:7.1f}  "
                  f"lost {s.lost_fraction:.2f}  error {s.error_mean:.3f}", flush=True)


if __name__ == "__main__":
    main()
