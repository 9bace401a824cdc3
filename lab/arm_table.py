"""One table of learning arms from several `ramavt eval` results on the same episodes: each arm's mean over its
seeds with the 95 % stratified bootstrap interval, the standard deviation over seeds, the fraction of the ceiling,
its mean per target, and P(arm > the arm before it) (rliable's probability of improvement).

    python lab/arm_table.py results/val/target_params/results.json:quick5 runs/ev/a/results.json:patch2 \
        --ceiling results/val/mpc_h12/results.json

Each argument is RESULTS_JSON:ARM (the arm as the results name it, without " (seeds)"). The results must share the
evaluation seed, the episodes per target, the targets and the episode cap, so that every arm flew the same episodes,
and the evaluation fields they record (the stand-off speed rules, say).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ramavt_jax.evaluation import seeds, statistics


class Arm(NamedTuple):
    name: str
    summary: dict  # seeds.summarise_arms' entry of the arm
    scores: np.ndarray  # [seeds, targets] AER
    episodes: tuple  # (seed, episodes per target, targets, cap): which episodes it flew
    task: dict  # the evaluation fields it flew (_task)


# What a result recorded before these evaluation fields existed flew: 1 m/s at every size.
RULES_BEFORE_RECORDED = {"speed_standoff_power": 0.0, "small_standoff_power": 0.0}


def _task(result: dict) -> dict:
    """The evaluation fields a result flew. The stand-off speed rules only count where a target may be resized
    (a size suffix or an MJCF file): at a catalogue target's k = 1 they change nothing."""
    task = {**RULES_BEFORE_RECORDED, **result["settings"].get("eval_params", {})}
    if not any("@" in t or t.endswith(".xml") for t in result["settings"]["targets"]):
        task = {k: v for k, v in task.items() if k not in RULES_BEFORE_RECORDED}
    return task


def _episodes(result: dict) -> tuple:
    s = result["settings"]
    return s["seed"], s["episodes_per_target"], tuple(s["targets"]), s["max_steps"]


def load_arm(spec: str, setting: str = "none") -> Arm:
    """One RESULTS_JSON:ARM argument (ARM may hold a colon itself: 'pretrained:ramavt_depth'), in one Table II
    setting ('none': no perturbation)."""
    path, sep, arm = spec.partition(".json:")
    path += ".json" if sep else ""
    if not Path(path).is_file():
        raise SystemExit(f"{path}: no such results file (written by `ramavt eval --out DIR` as DIR/results.json)")
    result = json.loads(Path(path).read_text())
    settings = result["settings"].get("perturbation_settings", ["none"])
    if setting not in settings:
        raise SystemExit(f"{path} has no setting {setting!r}; it has {settings}")
    summary = seeds.summarise_arms(result, setting)["arms"]
    key = f"{arm} (seeds)" if f"{arm} (seeds)" in summary else arm
    if key not in summary:
        raise SystemExit(f"{path} has no arm {arm!r}; it has {sorted(summary)}")
    runs = seeds.arms(result, setting)[key]
    targets = list(result["settings"]["targets"])
    scores = np.array([[r["per_target"][t]["return_mean"] for t in targets] for r in runs], np.float64)
    return Arm(arm, summary[key], scores, _episodes(result), _task(result))


def ceiling_aer(path: Path, setting: str = "none") -> tuple[float, tuple, dict]:
    """(the mpc row's AER in ``setting``, the episodes it flew, the evaluation fields it flew) of a results.json."""
    result = json.loads(path.read_text())
    row = next(r for r in result["rows"] if r.get("info", {}).get("variant") == "mpc")
    if setting not in row["settings"]:
        raise SystemExit(f"{path}'s ceiling has no setting {setting!r}; it has {sorted(row['settings'])}")
    return row["settings"][setting]["overall"]["return_mean"], _episodes(result), _task(result)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("arms", nargs="+", help="RESULTS_JSON:ARM, in the order of the table")
    p.add_argument("--ceiling", type=Path, default=None, help="a results.json with the mpc row on the same episodes")
    p.add_argument(
        "--setting",
        default="none",
        help="the Table II setting tabulated: none (default), "
        "actuator_noise, time_delay, blur or all (results of `ramavt eval --tables 2`)",
    )
    a = p.parse_args(argv)
    loaded = [load_arm(spec, a.setting) for spec in a.arms]
    ceiling, episodes, task = (
        ceiling_aer(a.ceiling, a.setting) if a.ceiling else (None, loaded[0].episodes, loaded[0].task)
    )
    if any(arm.episodes != episodes for arm in loaded):
        raise SystemExit("the results did not fly the same episodes (seed, episodes per target, targets, cap differ)")
    for arm in loaded:  # a field both record must agree (a speed rule, say); older results record fewer
        differ = {k: (task[k], arm.task[k]) for k in task.keys() & arm.task.keys() if task[k] != arm.task[k]}
        if differ:
            raise SystemExit(f"{arm.name} flew other evaluation fields than the first result: {differ}")
    targets = episodes[2]
    print(
        "| arm | seeds | AER | 95 % CI | std over seeds | of ceiling | lost | P(> row above) | "
        + " | ".join(targets)
        + " |"
    )
    print("|---" * (8 + len(targets)) + "|")
    previous = None
    for arm in loaded:
        s, scores = arm.summary, arm.scores
        frac = f"{100 * s['return_mean'] / ceiling:.0f} %" if ceiling else "-"
        ci = f"[{s['return_ci_low']:.1f}, {s['return_ci_high']:.1f}]" if s["return_ci_low"] is not None else "-"
        p_up = f"{statistics.probability_of_improvement(scores, previous):.2f}" if previous is not None else "-"
        per = " | ".join(f"{v:+.0f}" for v in scores.mean(axis=0))
        print(
            f"| {arm.name} | {scores.shape[0]} | {s['return_mean']:+.1f} | {ci} "
            f"| {s['return_sample_std_over_runs']:.1f} "
            f"| {frac} | {100 * s['lost_fraction_over_runs']:.1f} % | {p_up} | {per} |"
        )
        previous = scores


if __name__ == "__main__":
    main()
