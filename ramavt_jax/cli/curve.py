"""`ramavt curve`: held-out return of every checkpoint of training runs against training wall time."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Literal

from ramavt_jax import baselines as baselines_lib
from ramavt_jax.cli.checks import MAX_EPISODES, MAX_STEPS, UsageError, keeps_policy_params, output_folder, positive
from ramavt_jax.evaluation import curve as curve_lib
from ramavt_jax.evaluation import rollouts
from ramavt_jax.figures import curve as curve_fig
from ramavt_jax.training import files, run_folder
from ramavt_jax.training.checkpoint import has_checkpoint

OTHER_WRITER = "wait for that command to finish, stop it, or write into another --out"
JSON_FILE, PNG_FILE = "curve.json", "curve.png"


def _check_runs(run: tuple[Path, ...], policy_params: str | None = None) -> None:
    """Every --run is a run folder with checkpoints (and the parameter set asked for; one-line UsageError otherwise),
    before anything compiles."""
    if not run:
        raise UsageError("--run needs at least one run folder written by `ramavt train`")
    for run_dir in run:
        if not (Path(run_dir) / run_folder.CONFIG_FILE).is_file():
            raise UsageError(
                f"--run {run_dir}: {run_folder.CONFIG_FILE} not found; --run must name a folder written "
                f"by `ramavt train` (config.json, checkpoints/)"
            )
        if not has_checkpoint(Path(run_dir) / run_folder.CHECKPOINTS):
            raise UsageError(
                f"--run {run_dir} has no checkpoints; train it with --run.checkpoint-every-chunks 1 "
                f"--run.keep-checkpoints K to keep one per chunk"
            )
        keeps_policy_params(run_dir, policy_params)


def curve_cmd(
    run: tuple[Path, ...] = (),
    targets: str = "val",
    episodes: int = 10,
    max_steps: int = 1000,
    seed: int = 0,
    policy_params: Literal["online", "target", "averaged"] | None = None,
    baselines: bool = True,
    resolution: int = 64,
    horizon: int = baselines_lib.MPC_HORIZON,
    out: Path = Path("curve"),
    progress: bool = True,
    chunks: tuple[int, ...] = (),
) -> dict:
    """Evaluate every checkpoint of training runs greedily on the same episodes and plot the return (AER) against
    training wall time, beside the depth tracker and the mpc ceiling; writes curve.json and curve.png to --out.

    Args:
        run: training run folders (written by `ramavt train`; e.g. the seed_<k> folders of a sweep), one line each.
            Keep every chunk's parameters with `--run.checkpoint-every-chunks 1 --run.keep-checkpoints K`.
        targets: a split ('val', 'val-sizes', 'val-shapes', 'test', ...), or comma-separated catalogue names
            / MJCF files (each optionally resized: Satellite-v2@0.3m).
        episodes: episodes per target; the episodes of `ramavt eval` with the same --targets, --episodes, --seed and
            --max-steps (no perturbation), so its AER of a checkpoint is the curve's.
        max_steps: episode length cap.
        seed: evaluation seed.
        policy_params: the runs' parameter set, 'online', 'target' or 'averaged'; default: each run's own
            `run.policy_params`.
        baselines: also fly the depth tracker and the mpc ceiling once on the same episodes (horizontal lines; the
            table marks the first checkpoint above the depth tracker).
        resolution: camera resolution of the depth tracker (as `ramavt eval --resolution`).
        horizon: look-ahead steps of the mpc ceiling (as `ramavt eval --horizon`).
        out: output folder (curve.json, curve.png).
        progress: a progress bar over each run's checkpoints.
        chunks: only the checkpoints of these chunks (e.g. `--chunks 6 7 8 9 10`); default: every checkpoint.
    """
    for name, value, most in (
        ("--episodes", episodes, MAX_EPISODES),
        ("--max-steps", max_steps, MAX_STEPS),
        ("--resolution", resolution, None),
        ("--horizon", horizon, None),
    ):
        positive(name, value, maximum=most)
    _check_runs(run, policy_params)
    names = rollouts.resolve_targets(targets)
    output_folder(out)
    ep = curve_lib.CurveEpisodes(names, episodes, max_steps, seed)
    with run_folder.RunLock(Path(out), OTHER_WRITER):  # a second command writing into --out is refused
        result = curve_lib.learning_curves(
            run,
            ep,
            policy_params,
            tuple(curve_lib.BASELINES) if baselines else (),
            resolution,
            horizon,
            progress=progress,
            chunks=chunks,
        )
        js = files.replace_atomic(Path(out) / JSON_FILE, lambda tmp: tmp.write_text(files.dumps(result, indent=1)))
        png = files.replace_atomic(Path(out) / PNG_FILE, lambda tmp: curve_fig.plot_curve(result, tmp))
    print(curve_table(result))
    print(f"wrote {js} and {png} ({result['wall_s']:.0f} s)")
    return result


def _num(x, digits: int = 1) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x:.{digits}f}"


def _ci(p: dict) -> str:
    low, high = p["aer_ci_low"], p["aer_ci_high"]
    return "-" if low is None or not math.isfinite(low) else f"[{low:.1f}, {high:.1f}]"


def curve_table(result: dict) -> str:
    """The printed summary: the baselines, then per run one row per checkpoint (step, env steps, wall s, AER [CI],
    AER minus the depth tracker's) and the first checkpoint above the depth tracker."""
    lines = [f"{b['label']}: AER {_num(b['aer'])} {_ci(b)}" for b in result["baselines"].values()]
    depth = result["baselines"].get(curve_lib.DEPTH, {}).get("aer")
    for run in result["runs"]:
        lines += [
            "",
            f"{run['name']} (training seed {run['seed']}, {run['policy_params']} params)",
            f"{'step':>5} {'env steps':>10} {'wall s':>8}  {'AER':>8} {'95 % CI':<20} {'vs depth':>8}",
        ]
        for p in run["points"]:
            vs = "-" if depth is None else f"{p['aer'] - depth:+.1f}"
            lines.append(
                f"{p['step']:>5} {p['env_steps'] or '-':>10} {_num(p['wall_s']):>8}  {p['aer']:>8.1f} "
                f"{_ci(p):<20} {vs:>8}"
            )
        if depth is not None:
            cross = run["above_depth"]
            lines.append(
                "never above the depth tracker"
                if cross is None
                else f"first above the depth tracker: step {cross['step']} ({cross['env_steps']} env steps, "
                f"{_num(cross['wall_s'], 0)} s)"
            )
    return "\n".join(lines)
