"""Results over training seeds: the rows of one ``ramavt train --seeds N`` sweep (folders ``<sweep>/seed_<k>``)
summarised as one arm, and every arm compared with every other one, as a reviewer would ask for them.

An arm's scores are a matrix [runs, targets] of per-target mean returns (AER), one row per training seed, as in
`rliable`; a baseline or the shipped agent is an arm of one run. Per arm: the mean over seeds with a 95 %
stratified bootstrap interval (seeds resampled within each target), the interquartile mean (IQM) with its interval,
the fraction of the ceiling, and the probability that it improves on each other arm (rliable's, per target).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ramavt_jax.evaluation import statistics
from ramavt_jax.training import run_folder

_SEED_FIELDS = ("return_mean", "length_mean", "error_mean", "lost_fraction", "within_half_fraction")


def arm_name(row: dict) -> str:
    """The arm a row belongs to: its sweep folder's name for a seed folder of a sweep, else the row's own name."""
    run_dir = row.get("info", {}).get("run_dir")
    if row.get("kind") == "checkpoint" and run_dir and run_folder.is_seed_dir(run_dir):
        return f"{Path(run_dir).parent.name} (seeds)"
    return row["name"]


def arms(result: dict, setting: str = "none") -> dict[str, list[dict]]:
    """{arm: [that setting's result of each of its rows]} in the order the rows ran."""
    out: dict[str, list[dict]] = {}
    for row in result["rows"]:
        if setting in row["settings"]:
            out.setdefault(arm_name(row), []).append(row["settings"][setting])
    return out


def _scores(runs: list[dict], targets: list[str], field: str = "return_mean") -> np.ndarray:
    """[runs, targets] of one per-target field."""
    return np.array([[r["per_target"][t][field] for t in targets] for r in runs], np.float64)


def summarise_arms(result: dict, setting: str = "none") -> dict:
    """{'arms': {arm: {...}}, 'probability_of_improvement': {'x>y': p}} for one setting (see the module doc)."""
    targets = result["settings"]["targets"]
    grouped = arms(result, setting)
    scores = {name: _scores(runs, targets) for name, runs in grouped.items()}
    ceiling = next(
        (
            r["settings"][setting]["overall"]["return_mean"]
            for r in result["rows"]
            if r.get("info", {}).get("variant") == "mpc" and setting in r["settings"]
        ),
        None,
    )
    compared = statistics.compare_arms(scores)  # IQM with its interval, P(x > y) for every ordered pair
    out = {"arms": {}, "probability_of_improvement": compared["probability_of_improvement"]}
    for name, runs in grouped.items():
        s, iqm = scores[name], compared["iqm"][name]
        strata = np.broadcast_to(np.arange(s.shape[1]), s.shape)
        low, high = statistics.bootstrap_ci(s, strata) if s.shape[0] > 1 else (None, None)
        several = s.shape[0] > 1
        per_run = {f: [r["overall"][f] for r in runs] for f in _SEED_FIELDS}
        mean = float(s.mean())
        out["arms"][name] = {
            "runs": int(s.shape[0]),
            "return_mean": mean,
            "return_ci_low": low,
            "return_ci_high": high,
            "return_iqm": iqm["iqm"],
            "iqm_ci_low": iqm["ci_low"] if several else None,
            "iqm_ci_high": iqm["ci_high"] if several else None,
            "return_sample_std_over_runs": statistics.sample_std(per_run["return_mean"]),
            "ceiling_fraction": mean / ceiling if ceiling and ceiling > 0 else None,
            **{f"{f}_over_runs": float(np.mean(v)) for f, v in per_run.items() if f != "return_mean"},
            "per_run_return_mean": per_run["return_mean"],
            "per_target_return_mean": dict(zip(targets, s.mean(axis=0).tolist())),
        }
    return out


def _cell(value, digits: int = 1, scale: float = 1.0) -> str:
    return "-" if value is None or not np.isfinite(value) else f"{scale * value:.{digits}f}"


def arms_md(result: dict, setting: str = "none") -> str:
    """A Markdown table: one line per arm (mean over its runs with the interval, IQM, fraction of the ceiling,
    lost %, error), then P(arm > each other arm) for the arms of several runs."""
    summary = summarise_arms(result, setting)
    lines = [
        "| Arm | Runs | AER mean | 95 % CI (runs within targets) | std over runs | IQM | IQM 95 % CI | "
        "of ceiling % | lost % | error (m) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, a in summary["arms"].items():
        ci = "-" if a["return_ci_low"] is None else f"[{a['return_ci_low']:.1f}, {a['return_ci_high']:.1f}]"
        iqm_ci = "-" if a["iqm_ci_low"] is None else f"[{a['iqm_ci_low']:.1f}, {a['iqm_ci_high']:.1f}]"
        lines.append(
            f"| {name} | {a['runs']} | {a['return_mean']:.1f} | {ci} | "
            f"{_cell(a['return_sample_std_over_runs'])} | {a['return_iqm']:.1f} | {iqm_ci} | "
            f"{_cell(a['ceiling_fraction'], 0, 100)} | {_cell(a['lost_fraction_over_runs'], 1, 100)} | "
            f"{_cell(a['error_mean_over_runs'], 2)} |"
        )
    multi = [n for n, a in summary["arms"].items() if a["runs"] > 1]
    pis = [
        f"P({x} > {y}) = {p:.2f}"
        for k, p in summary["probability_of_improvement"].items()
        for x, y in [k.split(">", 1)]
        if x in multi
    ]
    if pis:
        lines += ["", "Probability of improvement (rliable; per target, averaged over targets): " + "; ".join(pis)]
    return "\n".join(lines)
