"""One table of learning arms from several `ramavt eval` results on the same episodes: each arm's mean over its
seeds with the 95 % stratified bootstrap interval, the standard deviation over seeds, the fraction of the ceiling,
its mean per target, and P(arm > the arm before it) (rliable's probability of improvement).

    python scripts/arm_table.py results/val/target_params/results.json:quick5 runs/ev/a/results.json:patch2 \
        --ceiling results/val/mpc_h12/results.json

Each argument is RESULTS_JSON:ARM (the arm as the results name it, without " (seeds)"). The results must share the
evaluation seed, the episodes per target, the targets and the episode cap, so that every arm flew the same episodes.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from ramavt_jax.evaluation import seeds, statistics


def _episodes(result: dict) -> tuple:
    s = result["settings"]
    return s["seed"], s["episodes_per_target"], tuple(s["targets"]), s["max_steps"]


def _speed_rule(result: dict) -> tuple | None:
    """The stand-off speed rules the result flew, (speed_standoff_power, small_standoff_power); None: recorded
    before the rules existed."""
    task = result["settings"].get("eval_params", {})
    if "speed_standoff_power" not in task:
        return None
    return task["speed_standoff_power"], task.get("small_standoff_power", 0.0)


def load_arm(spec: str) -> tuple[str, dict, np.ndarray, tuple]:
    """(arm, its summary, scores [seeds, targets], the episodes' identity) of one RESULTS_JSON:ARM argument."""
    path, _, arm = spec.rpartition(":")
    result = json.loads(Path(path).read_text())
    summary = seeds.summarise_arms(result)["arms"]
    key = f"{arm} (seeds)" if f"{arm} (seeds)" in summary else arm
    if key not in summary:
        raise SystemExit(f"{path} has no arm {arm!r}; it has {sorted(summary)}")
    runs = seeds.arms(result)[key]
    targets = list(result["settings"]["targets"])
    scores = np.array([[r["per_target"][t]["return_mean"] for t in targets] for r in runs], np.float64)
    return arm, summary[key], scores, _episodes(result), _speed_rule(result)


def ceiling_aer(path: Path) -> float:
    result = json.loads(path.read_text())
    row = next(r for r in result["rows"] if r.get("info", {}).get("variant") == "mpc")
    return row["settings"]["none"]["overall"]["return_mean"], _episodes(result), _speed_rule(result)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("arms", nargs="+", help="RESULTS_JSON:ARM, in the order of the table")
    p.add_argument("--ceiling", type=Path, default=None, help="a results.json with the mpc row on the same episodes")
    a = p.parse_args(argv)
    loaded = [load_arm(spec) for spec in a.arms]
    ceiling, episodes, rule = ceiling_aer(a.ceiling) if a.ceiling else (None, loaded[0][3], loaded[0][4])
    if any(arm[3] != episodes for arm in loaded):
        raise SystemExit("the results did not fly the same episodes (seed, episodes per target, targets, cap differ)")
    rules = {r for r in [rule] + [arm[4] for arm in loaded] if r is not None}
    if len(rules) > 1 and any("@" in t or t.endswith(".xml") for t in episodes[2]):
        raise SystemExit(f"the results flew different stand-off speed rules ((speed_standoff_power, "
                         f"small_standoff_power): {sorted(rules)})")
    targets = episodes[2]
    print("| arm | seeds | AER | 95 % CI | std over seeds | of ceiling | lost | P(> row above) | "
          + " | ".join(targets) + " |")
    print("|---" * (8 + len(targets)) + "|")
    previous = None
    for arm, s, scores, _, _ in loaded:
        frac = f"{100 * s['return_mean'] / ceiling:.0f} %" if ceiling else "-"
        ci = f"[{s['return_ci_low']:.1f}, {s['return_ci_high']:.1f}]" if s["return_ci_low"] is not None else "-"
        p_up = f"{statistics.probability_of_improvement(scores, previous):.2f}" if previous is not None else "-"
        per = " | ".join(f"{v:+.0f}" for v in scores.mean(axis=0))
        print(f"| {arm} | {scores.shape[0]} | {s['return_mean']:+.1f} | {ci} | {s['return_sample_std_over_runs']:.1f} "
              f"| {frac} | {100 * s['lost_fraction_over_runs']:.1f} % | {p_up} | {per} |")
        previous = scores


if __name__ == "__main__":
    main()
