"""Training-curve figures over several runs: mean ± std bands across seeds (the paper's Figs. 3 and 7)."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Sequence

import numpy as np

CURVE_KEYS = (("episode_length", "episode length"), ("episode_return", "episode return"), ("loss", "TD loss"),
              ("q_mean", "mean Q"))
_SEED_SUFFIX = re.compile(r"[-_.]?(s|seed)\d+$", re.IGNORECASE)


def group_name(run_dir: str | Path) -> str:
    """Runs of one configuration with different seeds share a group: the folder name without a trailing
    seed suffix (runs/ramavt_s0, runs/ramavt-seed1 -> 'ramavt')."""
    path = Path(run_dir)
    name = path.name
    if re.fullmatch(r"seed_\d+", name):  # a folder of `ramavt train --seeds N`: the sweep folder names the group
        return path.resolve().parent.name
    return _SEED_SUFFIX.sub("", name) or name


def read_run(run_dir: str | Path) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """(env_steps [K], {metric: [K]}) from a run folder's metrics.jsonl (see train_log.read_metrics)."""
    from ramavt_jax.train_log import read_metrics

    path = Path(run_dir) / "metrics.jsonl"
    records = read_metrics(path)
    if not records:
        raise FileNotFoundError(f"no training metrics in {path}: is {run_dir} a folder written by `ramavt train`?")
    x = np.array([r["env_steps"] for r in records], float)
    return x, {k: np.array([r.get(k, np.nan) for r in records], float) for k, _ in CURVE_KEYS}


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


def plot_training_runs(run_dirs: Sequence[str | Path], out: str | Path, keys=CURVE_KEYS,
                       labels: dict[str, str] | None = None) -> Path:
    """One panel per metric; one line per group of runs (seeds) with a ±1 std band. Returns the PNG path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not run_dirs:
        raise ValueError("plot_training_runs: no run folders given")
    groups: dict[str, list] = {}
    for d in run_dirs:
        groups.setdefault(group_name(d), []).append(read_run(d))
    fig, axes = plt.subplots(1, len(keys), figsize=(4.2 * len(keys), 3.3), squeeze=False)
    for ax, (key, title) in zip(axes[0], keys):
        for name, runs in groups.items():
            x, mean, std = band([(rx, m[key]) for rx, m in runs])
            label = (labels or {}).get(name, name) + (f" ({len(runs)} seeds)" if len(runs) > 1 else "")
            (line,) = ax.plot(x, mean, lw=1.5, label=label)
            if len(runs) > 1:
                ax.fill_between(x, mean - std, mean + std, color=line.get_color(), alpha=0.25, lw=0)
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("env steps")
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=8)
    fig.tight_layout()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def run_label(run_dir: str | Path) -> str:
    """'<variant> <obs_mode>' from a run's config.json (the folder name if unreadable)."""
    try:
        cfg = json.loads((Path(run_dir) / "config.json").read_text())["config"]
        return f"{cfg['network']['variant']} {cfg['env']['obs_mode']}"
    except (OSError, KeyError, ValueError):
        return Path(run_dir).name
