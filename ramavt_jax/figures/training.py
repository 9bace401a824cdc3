"""Training-curve figures: one run's curves (``training_curves.png`` of a run folder) and several runs with mean ±
std bands across seeds (the paper's Figs. 3 and 7); one plotter serves both."""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ramavt_jax.figures import pyplot, save_figure
from ramavt_jax.training import run_folder as folders

CURVE_KEYS = (
    ("episode_length", "episode length"),
    ("episode_return", "episode return"),
    ("loss", "loss (TD + weighted aux)"),
    ("q_mean", "mean Q"),
)
RUN_CURVE_KEYS = CURVE_KEYS + (("epsilon", "epsilon"),)  # one run's own training_curves.png
_SEED_SUFFIX = re.compile(r"[-_.]?(s|seed)\d+$", re.IGNORECASE)


def group_name(run_dir: str | Path) -> str:
    """Runs of one configuration with different seeds share a group: the folder name without a trailing
    seed suffix (runs/ramavt_s0, runs/ramavt-seed1 -> 'ramavt')."""
    path = Path(run_dir)
    name = path.name
    if folders.is_seed_dir(path):  # a folder of `ramavt train --seeds N`: the sweep folder names the group
        return path.resolve().parent.name
    return _SEED_SUFFIX.sub("", name) or name


def read_run(run_dir: str | Path, keys=RUN_CURVE_KEYS) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """(env_steps [K], {metric: [K]}) from a run folder's metrics.jsonl (missing values are NaN)."""
    path = Path(run_dir) / folders.METRICS_FILE
    records = folders.read_metrics(path)
    if not records:
        raise FileNotFoundError(f"no training metrics in {path}: is {run_dir} a folder written by `ramavt train`?")
    x = np.array([r["env_steps"] for r in records], float)
    return x, {k: np.array([r.get(k, np.nan) for r in records], float) for k, _ in keys}


def band(curves: Sequence[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean and std across runs on a common x grid: the x of the run with the most points, cut to the span every
    run covers, each run linearly interpolated (NaNs, e.g. chunks without finished episodes, are skipped).
    Returns (x, mean, std); std is 0 for a single run."""
    lo = max(float(np.min(x)) for x, _ in curves)
    hi = min(float(np.max(x)) for x, _ in curves)
    grid = max((x for x, _ in curves), key=len)
    grid = grid[(grid >= lo) & (grid <= hi)]
    ys = []
    for x, y in curves:
        ok = np.isfinite(y)
        ys.append(np.interp(grid, x[ok], y[ok]) if ok.sum() >= 1 else np.full(grid.shape, np.nan))
    ys = np.stack(ys)
    with np.errstate(all="ignore"):
        return grid, np.nanmean(ys, 0), np.nanstd(ys, 0)


def plot_training_runs(
    run_dirs: Sequence[str | Path],
    out: str | Path,
    keys=CURVE_KEYS,
    labels: dict[str, str] | None = None,
    title: str = "",
) -> Path:
    """One panel per metric; one line per group of runs (seeds) with a ±1 std band. Returns the PNG path."""
    plt = pyplot()
    if not run_dirs:
        raise ValueError("plot_training_runs: no run folders given")
    groups: dict[str, list] = {}
    for d in run_dirs:
        groups.setdefault(group_name(d), []).append(read_run(d, keys))
    fig, axes = plt.subplots(1, len(keys), figsize=(4.2 * len(keys), 3.3), squeeze=False)
    for ax, (key, panel_title) in zip(axes[0], keys):
        for name, runs in groups.items():
            x, mean, std = band([(rx, m[key]) for rx, m in runs])
            label = (labels or {}).get(name, name) + (f" ({len(runs)} seeds)" if len(runs) > 1 else "")
            (line,) = ax.plot(x, mean, lw=1.5, label=label, marker="." if len(x) < 50 else None)
            if len(runs) > 1:
                ax.fill_between(x, mean - std, mean + std, color=line.get_color(), alpha=0.25, lw=0)
        ax.set_title(panel_title, fontsize=10)
        ax.set_xlabel("env steps")
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return save_figure(fig, out)


def run_label(run_dir: str | Path) -> str:
    """'<variant> <obs_mode>' from a run's config.json (the folder name if unreadable)."""
    try:
        cfg = json.loads((Path(run_dir) / "config.json").read_text())["config"]
        return f"{cfg['network']['variant']} {cfg['env']['obs_mode']}"
    except (OSError, KeyError, ValueError):
        return Path(run_dir).name


def plot_run(run_dir: str | Path, title: str = "") -> Path:
    """A run folder's own ``training_curves.png`` (episode length and return, loss, mean Q, epsilon)."""
    return plot_training_runs([run_dir], Path(run_dir) / folders.CURVES_FILE, keys=RUN_CURVE_KEYS, title=title)
