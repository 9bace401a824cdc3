"""Baselines on one catalogue model resized to other bounding radii (the target spec ``NAME@Rm``): per size, the
stand-off scale k, the share of a depth image the target covers at the desired position, and each policy's AEL,
AER, lost share and tracking error (stand-off units). Every size flies the same episodes (each is the first target
of its own env).

    python lab/target_sizes.py --radii 0.3 2.4 12 --policies mpc depth --episodes 8
    python lab/target_sizes.py --radii 0.3 --env-params actuator_noise=0.3 delay_max=0.5
"""

from __future__ import annotations

import argparse

import jax
import numpy as np

from ramavt_jax import baselines, env, render
from ramavt_jax.evaluation import rollouts


def coverage(config: env.EnvConfig, overrides: dict) -> tuple[float, float, float]:
    """(bounding radius, k, mean share of target pixels over 32 attitudes) with the target at the desired point."""
    tracking_env = env.TrackingEnv(config)
    p = tracking_env.eval_params(**overrides, init_xy_std=0.0, init_z_min=5.0, init_z_max=5.0001)
    obs, state = jax.vmap(tracking_env.reset, in_axes=(0, None))(jax.random.split(jax.random.key(0), 32), p)
    return float(state.target.bound_radius[0]), float(state.scale[0]), float((np.asarray(obs[..., -1]) > 0).mean())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--target", default="Satellite-v1")
    ap.add_argument("--radii", type=float, nargs="+", default=[0.3, 2.4, 12.0], help="bounding radii in m")
    ap.add_argument("--policies", nargs="+", default=["mpc", "depth"])
    ap.add_argument("--episodes", type=int, default=8)
    ap.add_argument("--max-steps", type=int, default=1000)
    ap.add_argument("--resolution", type=int, default=32)
    ap.add_argument("--env-params", nargs="*", default=[], metavar="NAME=VALUE", help="EnvParams overrides")
    args = ap.parse_args()
    overrides = {k: float(v) for k, v in (a.split("=", 1) for a in args.env_params)}
    camera = render.CameraConfig(resolution=args.resolution)
    policies = {name: baselines.make_policy(name, camera) for name in args.policies}
    for spec in (f"{args.target}@{r:g}m" for r in args.radii):
        config = env.EnvConfig(camera=camera, targets=(spec,))
        radius, k, share = coverage(config, overrides)
        print(
            f"{spec}: bounding radius {radius:.3g} m, k {k:.3g}, {100 * share:.2f} % of the image "
            f"({share * args.resolution**2:.1f} px) at the desired point",
            flush=True,
        )
        for name, policy in policies.items():
            s = rollouts.evaluate_per_target(
                config, policy, jax.random.key(0), args.episodes, {"max_steps": args.max_steps, **overrides}
            )[spec]
            print(
                f"  {name:6s} AEL {s.length_mean:6.1f} (min {s.length_min:4.0f})  AER {s.return_mean:7.1f}  "
                f"lost {s.lost_fraction:.2f}  error {s.error_mean:.3f}",
                flush=True,
            )


if __name__ == "__main__":
    main()
