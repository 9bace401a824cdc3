"""`ramavt` command line: targets | render | bench | train | eval.

Each subcommand is a typed function; tyro builds the parser from its signature (`ramavt <cmd> --help`).
"""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path
from typing import Literal

import tyro
from typing_extensions import Annotated


def targets_cmd(split: Literal["all", "train", "test"] = "all") -> None:
    """List the target catalogue: name, class, split, geoms, bounding radius and mass."""
    from ramavt_jax import targets

    names = targets.split(split)
    print(f"{'name':<14} {'class':<10} {'split':<6} {'geoms':>5} {'radius_m':>9} {'mass_kg':>10}  types")
    for name in names:
        _, info = targets.load_numpy(name)
        which = "test" if name in targets.TEST_TARGETS else "train"
        kinds = ",".join(sorted(set(info.geom_types)))
        print(f"{name:<14} {targets.CATALOGUE[name]:<10} {which:<6} {info.num_geoms:>5} {info.bound_radius:>9.2f} "
              f"{info.mass:>10.1f}  {kinds}")


def render_cmd(
    target: str = "Satellite-v1",
    policy: Literal["oracle", "random", "depth"] = "oracle",
    steps: int = 200,
    out: Path = Path("episode.gif"),
    resolution: int = 64,
    obs: Literal["depth", "color", "rgbd"] = "depth",
    dynamics: Literal["cw", "kinematic"] = "cw",
    seed: int = 0,
    size: int = 256,
    every: int = 1,
) -> None:
    """Fly one episode with a baseline policy and write what the camera sees, beside the trajectory, as GIF/MP4.

    Args:
        target: catalogue name or path to an MJCF file.
        policy: baseline that flies the chaser.
        steps: number of steps to record.
        out: output file (.gif or .mp4).
        resolution: camera resolution in pixels (square).
        obs: observation channels shown in the middle panel.
        dynamics: target motion model.
        seed: random seed of the episode.
        size: panel size in pixels.
        every: keep every n-th frame.
    """
    import jax

    from ramavt_jax import baselines, env, render, viz

    config = env.EnvConfig(camera=render.CameraConfig(resolution=resolution), obs_mode=obs, targets=(target,),
                           dynamics=dynamics)
    tracking_env = env.TrackingEnv(config)
    params = tracking_env.eval_params()
    pol = baselines.make_policy(policy, config.camera)
    frames = viz.record_episode(tracking_env, pol, params, jax.random.key(seed), steps)
    length = int(frames.alive.sum())
    path = viz.episode_video(frames, out, size=size, every=every)
    print(f"{policy} on {target}: {length} steps tracked, return {float(frames.reward[:length].sum()):.1f}; wrote {path}")


def bench_cmd(
    what: Annotated[Literal["env", "train", "network"], tyro.conf.Positional],
    out: Path | None = None,
    quick: bool = False,
) -> None:
    """Throughput benchmarks; prints a table and writes JSON.

    Args:
        what: 'env' (env steps/s and frames/s vs envs and resolution, beside MuJoCo's mj_multiRay),
            'train' (trainer throughput per network), 'network' (inference and train-step speed).
        out: JSON output path (default benchmarks/results_<what>.json).
        quick: fewer sizes and repeats (a smoke run).
    """
    import importlib.util

    bench_dir = Path(__file__).resolve().parent.parent / "benchmarks"
    module_file = bench_dir / f"bench_{what}.py"
    if not module_file.is_file():
        raise SystemExit(f"{module_file} not found: benchmarks run from a source checkout of ramavt_jax")
    spec = importlib.util.spec_from_file_location(f"bench_{what}", module_file)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.run(out=out or bench_dir / f"results_{what}.json", quick=quick)


def main(argv: list[str] | None = None) -> None:
    commands = {
        "targets": targets_cmd,
        "render": render_cmd,
        "bench": bench_cmd,
    }
    try:
        from ramavt_jax import train  # noqa: F401

        commands["train"] = train.train_cmd
    except (ImportError, AttributeError):
        pass
    try:
        from ramavt_jax import evaluate

        if hasattr(evaluate, "eval_cmd"):
            commands["eval"] = evaluate.eval_cmd
    except ImportError:
        pass
    try:
        from ramavt_jax import viz

        commands["plot"] = viz.plot_cmd
    except ImportError:
        pass
    tyro.extras.subcommand_cli_from_dict(commands, prog="ramavt", args=argv)


if __name__ == "__main__":
    main(sys.argv[1:])
