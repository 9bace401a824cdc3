"""Held-out return against training wall time (``ramavt curve``): one line per run with its 95 % bootstrap band,
the depth tracker and the mpc ceiling as horizontal lines."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np

from ramavt_jax.figures import pyplot, save_figure

BASELINE_STYLE = {"depth": ("tab:gray", "--"), "mpc": ("black", ":")}


def curve_arrays(run: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(minutes [K], AER [K], CI low [K], CI high [K]) of one run's points (``curve.run_curve``) that have a wall time;
    a missing interval (one episode) is drawn as the AER itself."""
    points = [p for p in run["points"] if p.get("wall_s") is not None]
    minutes = np.array([p["wall_s"] / 60 for p in points], float)
    aer = np.array([p["aer"] for p in points], float)
    low = np.array([np.nan if p["aer_ci_low"] is None else p["aer_ci_low"] for p in points], float)
    high = np.array([np.nan if p["aer_ci_high"] is None else p["aer_ci_high"] for p in points], float)
    return minutes, aer, np.where(np.isfinite(low), low, aer), np.where(np.isfinite(high), high, aer)


def plot_curve(result: dict, out: str | Path, title: str = "") -> Path:
    """AER (with the 95 % CI band) against minutes of training, one line per run of ``result``
    (``curve.learning_curves``); each baseline is a horizontal line. The first checkpoint above the depth tracker is
    circled. Returns the PNG path."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.0, 4.2))
    for run in result["runs"]:
        x, aer, low, high = curve_arrays(run)
        (line,) = ax.plot(x, aer, lw=1.5, marker="." if len(x) < 60 else None, label=run["name"])
        ax.fill_between(x, low, high, color=line.get_color(), alpha=0.2, lw=0)
        cross = run.get("above_depth")
        if cross and cross.get("wall_s") is not None:
            ax.plot(cross["wall_s"] / 60, cross["aer"], "o", mfc="none", ms=9, color=line.get_color())
    for name, base in result.get("baselines", {}).items():
        color, style = BASELINE_STYLE.get(name, ("tab:brown", "-."))
        ax.axhline(base["aer"], color=color, ls=style, lw=1.2, label=f"{base['label']} ({base['aer']:.1f})")
    ep = result["episodes"]
    ax.set_xlabel("training wall time (min; compile included, checkpoint writing not)")
    ax.set_ylabel(f"AER ({ep['episodes_per_target']} episodes x {len(ep['targets'])} targets)")
    title = title or f"greedy return on {', '.join(ep['targets'])} (evaluation seed {ep['seed']})"
    ax.set_title(textwrap.fill(title, 90), fontsize=9)
    right = max([curve_arrays(r)[0].max(initial=0.0) for r in result["runs"]] + [0.0]) * 1.04 or 1.0
    ax.set_xlim(0, right)  # the clock starts when training starts: the compile is the gap before the first point
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return save_figure(fig, out)
