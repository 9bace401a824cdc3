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
    what: Annotated[Literal["env", "train", "network", "scaling"], tyro.conf.Positional],
    out: Path | None = None,
    quick: bool = False,
) -> None:
    """Throughput benchmarks; prints a table and writes JSON.

    Args:
        what: 'env' (env steps/s and frames/s vs envs and resolution, beside MuJoCo's mj_multiRay),
            'train' (trainer throughput per network), 'network' (inference and train-step speed),
            'scaling' (env steps/s and trained frames/s vs envs per device and devices, one worker process per
            device count: forced CPU devices, or the real ones where an accelerator is visible; also writes
            scaling.png beside the JSON).
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


def train_cmd(
    preset: Literal["quick", "paper", "smoke"] = "quick",
    network: Literal["ramavt", "drlavt", "origin", "se", "mha"] | None = None,
    obs: Literal["depth", "rgbd", "color"] | None = None,
    seeds: int = 1,
    seed: int = 0,
    out: Path = Path("runs/quick"),
    total_env_steps: int | None = None,
    augment: bool | None = None,
    eval_episodes: int | None = None,
    resume: bool = True,
    tensorboard: bool = False,
    progress: bool = True,
    devices: int = 0,
    coordinator_address: str | None = None,
    num_processes: int | None = None,
    process_id: int | None = None,
) -> None:
    """Train a tracker (recurrent DQN with burn-in), then evaluate it greedily on the train and held-out targets.

    Writes metrics.jsonl, checkpoints/ (re-running the same command resumes), training_curves.png, eval.json.

    Args:
        preset: 'quick' (minutes on 2 CPU cores: 32x32 depth, small RAMAVT), 'paper' (256x256, full RAMAVT,
            batch 64, lr 1e-4, gamma 0.99, 50,000-step replay), 'smoke' (seconds; plumbing only).
        network: network variant (default: the preset's).
        obs: observation mode (default: the preset's).
        seeds: number of independent seeds, trained together as ONE jitted program (vmap over seeds, each with
            its own envs and replay) into out/seed_<k>/ (each a complete run folder).
        seed: first seed.
        out: run directory.
        total_env_steps: override the preset's training length (env steps over all envs).
        augment: use image augmentation (default: the preset's).
        eval_episodes: episodes per target split in the final evaluation (default: the preset's; 0 = none).
        resume: continue from out/checkpoints when present.
        tensorboard: also log to out/tb with tensorboardX.
        progress: show a progress bar.
        devices: split the envs and replay over this many devices (0 = all visible; 1 = one device). More CPU
            devices for testing: XLA_FLAGS=--xla_force_host_platform_device_count=4.
        coordinator_address: multi-host run: host:port of process 0 (or JAX_COORDINATOR_ADDRESS).
        num_processes: multi-host run: number of processes (or JAX_NUM_PROCESSES).
        process_id: multi-host run: this process's index (or JAX_PROCESS_ID).
    """
    from ramavt_jax import distributed

    distributed.initialize(coordinator_address, num_processes, process_id)
    from ramavt_jax import train

    cfg = train.preset(preset)
    overrides = {}
    if network is not None:
        overrides["network"] = dataclasses.replace(cfg.network, variant=network)
    if obs is not None:
        overrides["env"] = dataclasses.replace(cfg.env, obs_mode=obs)
    if total_env_steps is not None:
        overrides["total_env_steps"] = total_env_steps
    if augment is not None:
        overrides["augment"] = augment
    if eval_episodes is not None:
        overrides["eval_episodes"] = eval_episodes
    if tensorboard:
        overrides["tensorboard"] = True
    cfg = dataclasses.replace(cfg, **overrides) if overrides else cfg
    if seeds < 1:
        raise ValueError(f"--seeds must be >= 1, got {seeds}")
    summary = train.run(cfg, out, seed=seed, resume=resume, progress=progress, num_seeds=seeds,
                        num_devices=devices or None)
    if not distributed.is_primary():
        return
    for one in summary.get("seeds", [summary]):
        print(json.dumps({"run": one["out_dir"], **{k: v for k, v in one.items() if not isinstance(v, dict)}},
                         default=str))
        if isinstance(one.get("eval"), dict):
            print(json.dumps(one["eval"], indent=1, default=str))
    mem = summary["memory"]
    print(f"memory per seed: state {mem['state_bytes_per_seed'] / 2**20:.1f} MiB (replay "
          f"{mem['replay_bytes_per_seed'] / 2**20:.1f} MiB); chunk working memory {mem['chunk_temp_bytes'] / 2**20:.1f} "
          f"MiB for {seeds} seed(s) on {summary['devices']} device(s), {summary['processes']} process(es)")


def main(argv: list[str] | None = None) -> None:
    commands = {
        "targets": targets_cmd,
        "render": render_cmd,
        "bench": bench_cmd,
    }
    commands["train"] = train_cmd
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
