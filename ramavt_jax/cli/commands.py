"""`ramavt targets`, `ramavt render` and `ramavt bench`."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Literal

import jax

from ramavt_jax import baselines, env, render, targets
from ramavt_jax.cli.checks import UsageError, output_file, positive
from ramavt_jax.evaluation import pretrained
from ramavt_jax.evaluation.rollouts import resolve_targets
from ramavt_jax.figures import episode
from ramavt_jax.targets import specs
from ramavt_jax.training import files

BENCHMARKS = ("env", "train", "gpu", "network", "render", "scaling", "mjx_ray")


def catalogue_table(names: Sequence[str] | None = None) -> list[dict]:
    """One row per target (default: the catalogue) for ``ramavt targets``: name, class, split, num_geoms,
    bound_radius (m), mass (kg). A user's MJCF path gets class and split ``"custom"``."""
    rows = []
    for target in targets.ALL_TARGETS if names is None else names:
        _, info = targets.load_numpy(target)
        key = specs.sized_name(target)
        split_name = next((n for n in targets.SPLITS if n != "all" and key in targets.split(n)), "custom")
        rows.append(
            {
                "name": info.name,
                "class": targets.CATALOGUE.get(
                    specs.sized_spec(key)[0], "custom" if split_name == "custom" else "generated"
                ),
                "split": split_name,
                "num_geoms": info.num_geoms,
                "bound_radius": info.bound_radius,
                "mass": info.mass,
            }
        )
    return rows


def targets_cmd(
    split: Literal["all", "train", "val", "test", "val-sizes", "val-shapes", "test-shapes"] = "all",
) -> None:
    """List the target catalogue: name, class, split, geoms, bounding radius and mass."""
    rows = catalogue_table(targets.split(split))
    print(f"{'name':<20} {'class':<10} {'split':<11} {'geoms':>5} {'radius_m':>9} {'mass_kg':>10}")
    for r in rows:
        print(
            f"{r['name']:<20} {r['class']:<10} {r['split']:<11} {r['num_geoms']:>5} {r['bound_radius']:>9.2f} "
            f"{r['mass']:>10.1f}"
        )


def render_cmd(
    target: str = "Satellite-v1",
    policy: Literal["proportional", "mpc", "random", "depth", "pretrained"] = "proportional",
    steps: int = 200,
    out: Path = Path("episode.gif"),
    agent: str = "ramavt_depth",
    resolution: int = 64,
    obs: Literal["depth", "color", "rgbd"] = "depth",
    dynamics: Literal["cw", "kinematic"] = "cw",
    seed: int = 0,
    size: int = 256,
    every: int = 1,
) -> None:
    """Fly one episode with a baseline policy and write what the camera sees, beside the trajectory, as GIF/MP4.

    Args:
        target: catalogue name or path to an MJCF file (resized with a suffix: Satellite-v2@0.3m).
        policy: baseline that flies the chaser, or 'pretrained': the agent shipped with the package (--agent); it
            sees with its own camera resolution and observation mode.
        steps: number of steps to record.
        out: output file (.gif or .mp4).
        resolution: camera resolution in pixels (square).
        obs: observation channels shown in the middle panel.
        dynamics: target motion model.
        seed: random seed of the episode.
        size: panel size in pixels.
        every: keep every n-th frame.
        agent: the shipped agent flown by --policy pretrained.
    """
    for name, value in (("--steps", steps), ("--resolution", resolution), ("--size", size), ("--every", every)):
        positive(name, value)
    output_file(out, (".gif", ".mp4"))
    resolve_targets(target)
    config = env.EnvConfig(
        camera=render.CameraConfig(resolution=resolution), obs_mode=obs, targets=(target,), dynamics=dynamics
    )
    if policy == "pretrained":
        if agent not in pretrained.available():
            raise UsageError(
                f"--agent {agent!r} is not shipped; available: {', '.join(pretrained.available()) or 'none'}"
            )
        loaded = pretrained.load(agent)
        config = dataclasses.replace(config, camera=loaded.config.env.camera, obs_mode=loaded.config.env.obs_mode)
        pol = loaded.policy
    else:
        pol = baselines.make_policy(policy, config.camera, dynamics)
    tracking_env = env.TrackingEnv(config)
    t = time.time()
    print(f"flying {steps} steps of {policy} on {target} (compiling the episode first) ...", flush=True)
    frames = episode.record_episode(tracking_env, pol, tracking_env.eval_params(), jax.random.key(seed), steps)
    length = int(frames.alive.sum())
    print(f"recorded in {time.time() - t:.0f} s; writing {out} ...", flush=True)
    path = files.replace_atomic(out, lambda tmp: episode.episode_video(frames, tmp, size=size, every=every))
    print(
        f"{pol.name} on {target}: {length} steps tracked, return {float(frames.reward[:length].sum()):.1f}; wrote {path}"
    )


def bench_main(argv: list[str]) -> None:
    """`ramavt bench WHAT [ARGS ...]`: run ``benchmarks/bench_WHAT.py ARGS`` of the source checkout."""
    usage = (
        f"usage: ramavt bench {{{','.join(BENCHMARKS)}}} [ARGS ...]\n\nThroughput benchmarks of a source "
        f"checkout; ARGS go to benchmarks/bench_WHAT.py (see `ramavt bench WHAT --help`). Each prints a table "
        f"and writes JSON (default benchmarks/results_WHAT.json).\n  env: env steps/s and frames/s vs envs "
        f"and resolution\n  train: trainer throughput per network\n  gpu: the accelerator check in one command "
        f"(env steps/s up to 64k envs, the quick and paper presets' chunks)\n  network: inference and train-step "
        f"speed\n  render: renderer frames/s\n  scaling: env steps/s and trained frames/s vs envs per device "
        f"and devices (one worker process per device count)\n  mjx_ray: MuJoCo MJX ray casting for comparison"
    )
    if not argv or argv[0] in ("-h", "--help"):
        print(usage)
        raise SystemExit(0)
    what, rest = argv[0], argv[1:]
    if what not in BENCHMARKS:
        raise UsageError(f"unknown benchmark {what!r}; choose one of {', '.join(BENCHMARKS)}")
    script = Path(__file__).resolve().parents[2] / "benchmarks" / f"bench_{what}.py"
    if not script.is_file():
        raise UsageError(f"{script} not found: benchmarks run from a source checkout of ramavt_jax")
    code = subprocess.call([sys.executable, str(script), *rest], cwd=script.parent.parent)
    if code:
        raise SystemExit(code)
