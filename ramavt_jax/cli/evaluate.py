"""`ramavt eval`: the paper's tables for trained run folders and baselines, and `ramavt plot`: figures."""

from __future__ import annotations

import dataclasses
import shlex
import sys
import time
from pathlib import Path
from typing import Literal

import jax

from ramavt_jax import baselines as baselines_lib
from ramavt_jax import env as env_lib
from ramavt_jax import greedy, render
from ramavt_jax.cli.checks import (
    MAX_EPISODES,
    MAX_STEPS,
    UsageError,
    finite,
    keeps_policy_params,
    output_folder,
    positive,
)
from ramavt_jax.env_config import RANGES, check_settings
from ramavt_jax.evaluation import pretrained, report, rollouts
from ramavt_jax.evaluation import tables as tables_lib
from ramavt_jax.evaluation.runs import LoadedRun, ensemble_params, load_policy, row_name
from ramavt_jax.figures import episode, training
from ramavt_jax.training import run_folder

OTHER_WRITER = "wait for that command to finish, stop it, or write into another --out"
LABELS = {
    "mpc": "mpc ceiling (true state)",
    "proportional": "proportional (true state)",
    "depth": "depth tracker",
    "random": "random",
}


def _run_entries(
    runs: tuple[Path, ...], policy_params: str | None = None, search: str = "learned"
) -> tuple[list[tables_lib.Entry], list[LoadedRun]]:
    entries, loaded = [], []
    for run_dir in runs:
        lr = load_policy(run_dir, policy_params=policy_params, search=search)
        loaded.append(lr)
        cfg = lr.config
        info = {
            "run_dir": str(run_dir),
            "variant": cfg.network.variant,
            "augment": bool(cfg.learner.augment),
            "seed": lr.seed,
            "step": lr.step,
            "env_steps": lr.meta.get("env_steps"),
            "policy_params": cfg.run.policy_params,
            "blind_search": search,
        }
        entries.append(
            tables_lib.Entry(
                row_name(run_dir),
                "checkpoint",
                lr.policy,
                cfg.env,
                rollouts.run_env_overrides(cfg.env_params),
                cfg.env.obs_mode,
                info,
            )
        )
    return entries, loaded


def _ensemble_entry(loaded: list[LoadedRun], search: str) -> tables_lib.Entry:
    """One row for the runs ``loaded`` flying as an ensemble (greedy.greedy_policy(members=)); their network, env
    and env settings must agree (a one-line UsageError names the first run that differs)."""
    first = loaded[0].config
    try:
        params = ensemble_params(loaded)
    except ValueError as e:
        raise UsageError(f"--ensemble: {e}") from None
    policy = greedy.greedy_policy(
        first.network,
        params,
        tuple(first.env.obs_shape),
        "ensemble",
        search,
        members=len(loaded),
    )
    sweeps = sorted(
        {
            (path.parent if run_folder.is_seed_dir(path) else path).name
            for path in (Path(lr.run_dir).resolve() for lr in loaded)
        }
    )
    info = {
        "ensemble_of": [lr.run_dir for lr in loaded],
        "variant": first.network.variant,
        "policy_params": first.run.policy_params,
        "blind_search": search,
    }
    return tables_lib.Entry(
        f"ensemble of {len(loaded)}: {', '.join(sweeps)}",
        "checkpoint",
        policy,
        first.env,
        rollouts.run_env_overrides(first.env_params),
        first.env.obs_mode,
        info,
    )


def _pretrained_entry(name: str, search: str = "learned") -> tables_lib.Entry:
    agent = pretrained.load(name, search=search)
    cfg = agent.config
    info = {
        "variant": cfg.network.variant,
        "augment": bool(cfg.learner.augment),
        "pretrained": name,
        **agent.info,
        "policy_params": cfg.run.policy_params,
        "blind_search": search,
    }
    return tables_lib.Entry(
        f"pretrained:{name}",
        "checkpoint",
        agent.policy,
        cfg.env,
        rollouts.run_env_overrides(cfg.env_params),
        cfg.env.obs_mode,
        info,
    )


def _baseline_entries(
    names: list[str],
    obs: tuple[str, ...],
    resolution: int,
    dynamics: str,
    targets: tuple[str, ...],
    horizon: int = baselines_lib.MPC_HORIZON,
) -> list[tables_lib.Entry]:
    camera = render.CameraConfig(resolution=resolution)
    entries = []
    for name in names:
        # one object per baseline: one compile for all its runs
        pol = baselines_lib.make_policy(name, camera, dynamics, horizon)
        modes = [m for m in obs if m != "color"] if name == "depth" else list(obs[:1])
        for mode in modes:
            config = env_lib.EnvConfig(camera=camera, obs_mode=mode, targets=targets, dynamics=dynamics)
            label = mode if name == "depth" else f"any ({mode})"
            info = {"variant": name, **({"horizon": horizon} if name == "mpc" else {})}
            entries.append(tables_lib.Entry(LABELS[name], "baseline", pol, config, {}, label, info))
    return entries


def _check_eval_args(
    policy, agent, run, targets, episodes, max_steps, tables, blur_frames, out, policy_params=None
) -> tuple[str, ...]:
    """Every argument of `ramavt eval` checked before anything compiles; returns the resolved target names."""
    positive("--episodes", episodes, maximum=MAX_EPISODES)
    positive("--max-steps", max_steps, maximum=MAX_STEPS)
    positive("--blur-frames", blur_frames, maximum=int(RANGES["blur_frames"][1]))
    if any(t not in (1, 2, 3) for t in tables):
        raise UsageError(f"--tables must be among 1 2 3, got {' '.join(map(str, tables))}")
    if policy == "pretrained" and agent not in pretrained.available():
        raise UsageError(f"--agent {agent!r} is not shipped; available: {', '.join(pretrained.available()) or 'none'}")
    if policy == "checkpoint" and not run:
        raise UsageError("--policy checkpoint needs at least one --run folder (or pick a baseline policy)")
    for run_dir in run:
        if not (Path(run_dir) / run_folder.CONFIG_FILE).is_file():
            raise UsageError(
                f"--run {run_dir}: {run_folder.CONFIG_FILE} not found; --run must name a folder written by "
                f"`ramavt train` (config.json, checkpoints/)"
            )
        keeps_policy_params(run_dir, policy_params)
    names = rollouts.resolve_targets(targets)
    output_folder(out)
    return names


def eval_cmd(
    policy: Literal["checkpoint", "pretrained", "mpc", "proportional", "depth", "random"] = "checkpoint",
    run: tuple[Path, ...] = (),
    policy_params: Literal["online", "target", "averaged"] | None = None,
    blind_search: Literal["learned", "retreat"] = "learned",
    ensemble: bool = False,
    agent: str = pretrained.DEFAULT_AGENT,
    baselines: bool = True,
    targets: str = "test",
    episodes: int = 100,
    max_steps: int = 1000,
    tables: tuple[int, ...] = (1, 2, 3),
    settings: tuple[Literal["actuator_noise", "time_delay", "blur", "all"], ...] = (),
    obs: tuple[Literal["depth", "rgbd", "color"], ...] = ("depth",),
    resolution: int = 64,
    dynamics: Literal["cw", "kinematic"] = "cw",
    actuator_noise: float = 0.3,
    delay_max: float = 0.5,
    blur_frames: int = 3,
    speed_steps: int = 200,
    seed: int = 0,
    horizon: int = baselines_lib.MPC_HORIZON,
    speed_standoff_power: float | None = None,
    small_standoff_power: float | None = None,
    out: Path = Path("eval"),
    figures: bool = False,
) -> dict:
    """Evaluate policies greedily and write the paper's tables (Markdown + JSON) to --out.

    Args:
        policy: 'checkpoint' (trained runs given by --run), 'pretrained' (an agent shipped with the package, see
            --agent; --run folders may be added) or a baseline: 'mpc' (the ceiling: receding-horizon search over
            the 11 commands on the env's own noise-free model of the true state; the fraction-of-ceiling column
            divides by its AER), 'proportional' (a proportional controller on the true state, quantised; not an
            upper bound), 'depth' (classical depth-image tracker) or 'random'.
        run: training run folders (written by `ramavt train`); each is one row of Tables I-III.
        policy_params: the runs' parameter set: 'online', 'target' (the Polyak-averaged target net's) or 'averaged'
            (the target net's averaged over the chunks after `run.policy_average_from`); default: each run's own
            `run.policy_params`.
        blind_search: what the --run policies and a pretrained agent command until a frame first shows the target:
            'learned' (their own greedy action) or 'retreat' (back along the camera axis; greedy.greedy_policy).
        ensemble: one more row: the --run policies flying together, each with its own memory, greedy on their
            mean output, Q or a policy head's logits (runs of one network, env and parameter-set config, e.g. the
            seeds of a sweep; greedy.greedy_policy(members=)).
        agent: the shipped agent evaluated by --policy pretrained.
        baselines: with --policy checkpoint, also evaluate mpc, proportional, depth tracker and random in every table (a
            baseline given as --policy is evaluated alone).
        targets: 'test' (held-out split), 'val' (validation split), 'val-sizes' (validation models resized to
            0.3-12 m), 'val-shapes' / 'test-shapes' (24 generated shapes each, 0.3-12 m), 'train', 'all', or
            comma-separated catalogue names / MJCF files, each (and each split but val-sizes) optionally resized to a
            bounding radius with '@<radius>m' (Satellite-v2@0.3m; val@0.3m: every validation model at 0.3 m).
        episodes: episodes per target (run side by side; the paper's protocol: 100).
        max_steps: episode length cap (the paper: 1000).
        tables: which tables to produce (2 runs the five perturbation settings, 5x the episodes).
        settings: with Table II, fly only these perturbation settings besides 'none' (e.g. `--settings all`: clean
            and all three perturbations, 2x the episodes); default: all of them.
        obs: input modes of the baselines (the depth tracker skips 'color'; the others run once).
        resolution: camera resolution of the baselines (trained runs use their own).
        dynamics: target motion model of the baselines (trained runs use their own).
        actuator_noise: Table II actuator noise (command x (1 + a N(0, 1))).
        delay_max: Table II time delay: each step lasts dt + U(0, delay_max) s.
        blur_frames: Table II image blur: observation = mean of the last n frames.
        speed_steps: single-env steps timed for the speed column (0 = skip).
        seed: evaluation seed (the same episodes for every policy; a setting's episodes depend only on the seed,
            the setting's name and the target).
        horizon: look-ahead steps of the mpc ceiling: every pair of the next two commands, the second then held
            for horizon - 2 steps scoring only whether the target stays in view (2: the pairs alone).
        speed_standoff_power: the command speed of every policy is speed * max(1, k) ** power, k the stand-off
            scale of a target larger than the catalogue's (EnvParams.speed_standoff_power; k = 1 for every
            catalogue target, so only large resized and user targets see it); default: EnvParams' default.
        small_standoff_power: a small target's (k < 1) command speed and drift times k ** power (1: its dynamics are
            the catalogue's in stand-off units; EnvParams.small_standoff_power); default: EnvParams' default (0).
        out: output folder (tables.md, results.json, figures/).
        figures: also plot one episode per policy (tracking error, 3-D trajectory, frame strip), attention maps and
            training curves of the runs.
    """
    t0 = time.time()
    positive("--horizon", horizon)
    task = {"speed_standoff_power": speed_standoff_power, "small_standoff_power": small_standoff_power}
    task = {name: value for name, value in task.items() if value is not None}
    for name, value in task.items():
        if not 0.0 <= value <= 1.0:
            raise UsageError(f"--{name.replace('_', '-')} must be in [0, 1], got {value}")
    finite("--actuator-noise", actuator_noise)
    finite("--delay-max", delay_max)
    for flag, value in (("--actuator-noise", actuator_noise), ("--delay-max", delay_max)):
        try:  # the range of the EnvParams setting (env_config.RANGES)
            check_settings({flag[2:].replace("-", "_"): value}, owner="EnvParams.")
        except ValueError as e:
            raise UsageError(f"{flag}: {e}") from None
    positive("--speed-steps", speed_steps, minimum=0, maximum=MAX_EPISODES)
    names = _check_eval_args(policy, agent, run, targets, episodes, max_steps, tables, blur_frames, out, policy_params)
    if settings and 2 not in tables:
        raise UsageError(f"--settings {' '.join(settings)} picks Table II settings: add 2 to --tables")
    if ensemble and len(run) < 2:
        raise UsageError(f"--ensemble needs at least two --run folders, got {len(run)}")
    with run_folder.RunLock(Path(out), OTHER_WRITER):  # a second command writing into --out is refused
        entries, loaded = _run_entries(run, policy_params, blind_search)
        if ensemble:
            entries.append(_ensemble_entry(loaded, blind_search))
        if policy == "pretrained":
            entries.insert(0, _pretrained_entry(agent, blind_search))
        trained = policy in ("checkpoint", "pretrained")
        wanted = [] if trained else [policy]
        if baselines and trained:
            wanted += [p for p in ("mpc", "proportional", "depth", "random") if p not in wanted]
        entries += _baseline_entries(wanted, obs, resolution, dynamics, names, horizon)
        if task:  # evaluation fields: the same task for every row
            entries = [dataclasses.replace(e, env_overrides={**e.env_overrides, **task}) for e in entries]
        flown = tables_lib.settings_for(tuple(tables), tuple(settings))
        print(
            f"evaluating {len(entries)} policies x {len(flown)} setting(s) x {len(names)} targets x {episodes} "
            f"episodes (each policy compiles first) ...",
            flush=True,
        )
        values = {"actuator_noise": actuator_noise, "delay_max": delay_max, "blur_frames": blur_frames}
        result = tables_lib.run_suite(
            entries, names, episodes, max_steps, seed, tuple(tables), values, speed_steps, only_settings=tuple(settings)
        )
        if figures:
            print("plotting one episode per policy ...", flush=True)
            result["figures"] = episode.eval_figures(
                entries, loaded, names[0], Path(out) / "figures", seed=seed, steps=max_steps
            )
        result["wall_s"] = time.time() - t0
        command = "ramavt " + " ".join(shlex.quote(a) for a in sys.argv[1:]) if sys.argv[1:2] == ["eval"] else ""
        md, js = report.write(result, out, command)
    print(f"wrote {md} and {js} ({result['wall_s']:.0f} s)")
    return result


def plot_cmd(
    runs: tuple[Path, ...] = (),
    run: Path | None = None,
    policy: Literal["mpc", "proportional", "depth", "random"] = "proportional",
    target: str = "Satellite-v2",
    steps: int = 1000,
    resolution: int = 64,
    obs: Literal["depth", "color", "rgbd"] = "depth",
    seed: int = 0,
    frames: int = 8,
    out: Path = Path("figures"),
) -> dict:
    """Paper figures as PNGs: training curves (mean ± std over seeds), and for one episode the tracking error x/y/z,
    3-D trajectories, a strip of observed frames and (for a trained run) attention maps.

    Args:
        runs: training run folders for the curves; folders differing only by a seed suffix (_s0, -seed1) form one
            band.
        run: a trained run folder whose greedy policy flies the episode (attention maps included); else --policy.
        policy: baseline flying the episode when no --run is given.
        target: catalogue name or MJCF file of the episode's target (resized with a suffix: Satellite-v2@0.3m).
        steps: episode length cap.
        resolution: camera resolution for a baseline (a trained run uses its own).
        obs: observation mode for a baseline (a trained run uses its own).
        seed: episode seed.
        frames: frames in the strip.
        out: output folder.
    """
    positive("--steps", steps)
    positive("--frames", frames)
    names = rollouts.resolve_targets(target)
    output_folder(out)
    with run_folder.RunLock(Path(out), OTHER_WRITER):  # a second command writing into --out is refused
        return _plot(runs, run, policy, names, steps, resolution, obs, seed, frames, Path(out))


def _plot(runs, run, policy, names, steps, resolution, obs, seed, frames, out: Path) -> dict:
    out_paths = {}
    if runs:
        labels = {training.group_name(r): training.run_label(r) for r in runs}
        if len(set(labels.values())) < len(labels):  # two groups would share a legend entry: name them by folder
            labels = {g: f"{g} ({lab})" for g, lab in labels.items()}
        out_paths["training_curves"] = str(
            training.plot_training_runs(runs, out / "training_curves.png", labels=labels)
        )
    if run is not None:
        lr = load_policy(run)
        config = dataclasses.replace(lr.config.env, targets=names[:1])
        overrides = rollouts.run_env_overrides(lr.config.env_params)
        pol, network, prefix = lr.policy, (lr.config.network, lr.params), episode.slug(Path(run).name)
    else:
        config = env_lib.EnvConfig(camera=render.CameraConfig(resolution=resolution), obs_mode=obs, targets=names[:1])
        pol = baselines_lib.make_policy(policy, config.camera, config.dynamics)
        overrides, network, prefix = {}, None, policy
    tracking_env = env_lib.TrackingEnv(config)
    params = tracking_env.eval_params(**overrides, max_steps=steps)
    print(f"recording one episode of {pol.name} on {names[0]} ...", flush=True)
    out_paths.update(
        episode.episode_figures(
            tracking_env, pol, params, jax.random.PRNGKey(seed), steps, out, prefix, strip=frames, network=network
        )
    )
    for k, v in out_paths.items():
        print(f"{k}: {v}")
    return out_paths
