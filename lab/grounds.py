"""The grounds a generalist tracker is judged on, and one table of arms over all of them.

A ground is a set of targets, the Table II settings flown on them and the episodes per target. Validation grounds
choose; test grounds are flown once, at the end, for what is shipped.

    python -m lab.grounds baselines --grounds val val-sizes val-shapes          # mpc and the depth tracker, once
    python -m lab.grounds eval g32 runs/arms/g32/seed_{0..4} --grounds val val-sizes val-shapes
    python -m lab.grounds eval g32-ens runs/arms/g32/seed_{0..4} --ensemble   # the seeds flying as one ensemble
    python -m lab.grounds table quick g32 g64 --grounds val val-sizes val-shapes

Every policy of a ground flies the same episodes (evaluation seed 0): `ramavt eval` draws a setting's episodes from
the seed, the setting's name and the target only. Results go to ``runs/evals/<ground>/<name>/``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path
from typing import NamedTuple

import numpy as np

from lab import arm_records, arm_table
from ramavt_jax.evaluation import seeds, statistics

EVALS = Path("runs/evals")
USER_MODELS = "examples/targets/cubesat-0.3m.xml,examples/targets/cubesat-0.45m.xml,examples/targets/fragment-1.2m.xml,examples/targets/station-12m.xml,examples/targets/tug-4m.xml"  # noqa: E501


class Ground(NamedTuple):
    targets: str  # --targets of `ramavt eval`
    episodes: int  # per target
    tables: tuple[int, ...]  # (1,) clean only; (1, 2) also Table II's 'all three' setting (--settings all)


GROUNDS = {
    # validation: for choosing
    "val": Ground("val", 20, (1, 2)),
    "val-sizes": Ground("val-sizes", 20, (1,)),
    "val-shapes": Ground("val-shapes", 20, (1,)),
    # test: flown once per issue, at its end
    "test": Ground("test", 100, (1, 2)),
    "user": Ground(USER_MODELS, 20, (1,)),
    "test-shapes": Ground("test-shapes", 20, (1,)),
}
COMMON = ["--resolution", "32", "--speed-steps", "0", "--seed", "0"]


def _eval(ground: str, name: str, policy_args: list[str]) -> Path:
    g = GROUNDS[ground]
    out = EVALS / ground / name
    command = ["ramavt", "eval", *policy_args, "--targets", g.targets, "--episodes", str(g.episodes)]
    command += ["--tables", *map(str, g.tables), *(["--settings", "all"] if 2 in g.tables else [])]
    command += [*COMMON, "--out", str(out)]
    print("$", " ".join(command), flush=True)
    subprocess.run(command, check=True)
    return out / "results.json"


def evaluate(name: str, runs: list[str], grounds: list[str], pretrained: bool = False, ensemble: bool = False) -> None:
    """The arm ``name`` (its seeds' run folders, or the shipped agent) on each ground, no baselines. ``ensemble``:
    the runs also fly as one ensemble (`ramavt eval --ensemble`), and ``name`` is that ensemble in tables."""
    policy = ["--policy", "pretrained"] if pretrained else ["--policy", "checkpoint", "--run", *runs]
    policy += ["--ensemble"] if ensemble else []
    for ground in grounds:
        _eval(ground, name, [*policy, "--no-baselines"])


def baselines(grounds: list[str]) -> None:
    """The ceiling and the depth tracker on each ground (the same episodes as every arm)."""
    for ground in grounds:
        for policy in ("mpc", "depth"):
            _eval(ground, policy, ["--policy", policy])


def _settings(ground: str) -> list[str]:
    return ["none", "all"] if 2 in GROUNDS[ground].tables else ["none"]


def _baseline(ground: str, policy: str, setting: str) -> np.ndarray:
    """[targets] mean return of a baseline row."""
    result = json.loads((EVALS / ground / policy / "results.json").read_text())
    row = result["rows"][0]["settings"][setting]["per_target"]
    return np.array([row[t]["return_mean"] for t in result["settings"]["targets"]])


def cell(ground: str, name: str, setting: str) -> dict:
    """An arm on a ground in a setting: mean AER with its 95 % interval, of the ceiling, lost share, per-target
    means, and how many targets it is below the depth tracker on."""
    arm = arm_table.load_arm(f"{EVALS / ground / name / 'results.json'}:{_arm_key(ground, name)}", setting)
    ceiling = _baseline(ground, "mpc", setting)
    depth = _baseline(ground, "depth", setting)
    per_target = arm.scores.mean(axis=0)
    s = arm.summary
    ci = (s["return_ci_low"], s["return_ci_high"])
    if arm.scores.shape[0] == 1:  # one policy (the shipped agent, an ensemble): the interval over its episodes
        overall = _row(ground, name)["settings"][setting]["overall"]
        ci = (overall["return_ci_low"], overall["return_ci_high"])
    return {
        "aer": s["return_mean"],
        "ci": ci,
        "of_ceiling": s["return_mean"] / ceiling.mean(),
        "ael": s.get("length_mean_over_runs"),
        "lost": s["lost_fraction_over_runs"],
        "seeds": arm.scores.shape[0],
        "seed_means": arm.scores.mean(axis=1).tolist(),
        "below_depth": int((per_target < depth).sum()),
        "worst_of_ceiling": float((per_target / ceiling).min()),
    }


def _row(ground: str, name: str) -> dict:
    """The row of the arm a folder holds: its ensemble's where it was evaluated with --ensemble, else its first."""
    rows = json.loads((EVALS / ground / name / "results.json").read_text())["rows"]
    ensembles = [r for r in rows if "ensemble_of" in r.get("info", {})]
    return ensembles[-1] if ensembles else rows[0]


def _arm_key(ground: str, name: str) -> str:
    return seeds.arm_name(_row(ground, name)).removesuffix(" (seeds)")


# The specialist presets' recorded evaluations on the same validation episodes (lab/results/arms.csv.gz: the
# records' ceilings agree with this ground's to 0.1): ground -> setting -> (label, record, arm).
RECORDED = {
    "val": {
        "none": [("quick", "val/arms/ten-seeds/margin_10", "margin_10")],
        "all": [("quick", "val/table2/expert-margin", "expert_margin")],
    },
    "val-sizes": {"none": [("sizes", "val/sizes/ten-seeds/size_wider_retreat_10", "size_wider_retreat_10")]},
}
RECORDED["val"]["none"].append(("robust", "val/table2/ten-seeds/perturb_05_margin_10", "perturb_05_margin_10"))
RECORDED["val"]["all"].append(("robust", "val/table2/ten-seeds/perturb_05_margin_10", "perturb_05_margin_10"))


def recorded(record: str, arm: str, setting: str) -> tuple[float, float, float, int]:
    """(mean AER, 95 % CI low, high, seeds) of a recorded arm: its seeds' per-target AER, resampled within targets."""
    rows = arm_records.select(arm_records.load(), record=record, arm=arm, setting=setting)
    by_seed: dict[str, dict[str, float]] = {}
    for r in rows:
        if r["target"] != "all":
            by_seed.setdefault(r["seed"], {})[r["target"]] = float(r["aer"])
    targets = sorted(next(iter(by_seed.values())))
    scores = np.array([[s[t] for t in targets] for s in by_seed.values()])  # [seeds, targets]
    strata = np.broadcast_to(np.arange(scores.shape[1]), scores.shape)
    low, high = statistics.bootstrap_ci(scores, strata)
    return float(scores.mean()), low, high, scores.shape[0]


def table(names: list[str], grounds: list[str]) -> str:
    """One Markdown row per arm, one column per ground and setting: AER [95 % CI] (of ceiling), ↓n below the depth
    tracker on n targets."""
    columns = [(g, s) for g in grounds for s in _settings(g)]
    head = "| arm | " + " | ".join(f"{g} {'all three' if s == 'all' else ''}".strip() for g, s in columns) + " |"
    lines = [head, "|---" * (len(columns) + 1) + "|"]
    for name in ["mpc", "depth", *names]:
        cells = []
        for g, s in columns:
            if name in ("mpc", "depth"):
                cells.append(f"{_baseline(g, name, s).mean():+.1f}")
                continue
            c = cell(g, name, s)
            low, high = c["ci"]
            ci = f" [{low:.1f}, {high:.1f}]" if low is not None else ""
            below = f", below depth on {c['below_depth']}" if c["below_depth"] else ""
            cells.append(f"{c['aer']:+.1f}{ci} ({100 * c['of_ceiling']:.0f} %{below})")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    for label in ("quick", "robust", "sizes"):  # the specialists, where recorded
        cells = []
        for g, s in columns:
            entry = next((e for e in RECORDED.get(g, {}).get(s, []) if e[0] == label), None)
            if entry is None:
                cells.append("-")
                continue
            mean, low, high, n = recorded(*entry[1:], s)
            cells.append(
                f"{mean:+.1f} [{low:.1f}, {high:.1f}] ({100 * mean / _baseline(g, 'mpc', s).mean():.0f} %, {n})"
            )
        lines.append(f"| `{label}` (recorded) | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def seed_ranking(name: str, grounds: list[str]) -> list[tuple[int, float]]:
    """[(seed index, score)] from worst to best, the score a seed's fraction of the ceiling averaged over every
    ground and setting (each column counts once, whatever its number of targets)."""
    if any("ensemble_of" in _row(g, name).get("info", {}) for g in grounds):
        raise ValueError(f"{name} is one ensemble, not seeds to rank; rank the arm its runs came from")
    columns = [(g, s) for g in grounds for s in _settings(g)]
    fractions = np.array([np.array(cell(g, name, s)["seed_means"]) / _baseline(g, "mpc", s).mean() for g, s in columns])
    score = fractions.mean(axis=0)
    return sorted(enumerate(score.tolist()), key=lambda pair: pair[1])


def median_seed(name: str, grounds: list[str]) -> int:
    """The seed to ship: the median of `seed_ranking` (a rule that does not reward a lucky seed; an odd count)."""
    ranking = seed_ranking(name, grounds)
    if len(ranking) % 2 == 0:
        raise ValueError(f"{name} has {len(ranking)} seeds; the median seed needs an odd count")
    return ranking[len(ranking) // 2][0]


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", required=True)
    b = sub.add_parser("baselines", help="mpc and the depth tracker on each ground")
    e = sub.add_parser("eval", help="an arm's seeds (run folders) or the shipped agent ('pretrained') on each ground")
    e.add_argument("name")
    e.add_argument("runs", nargs="*")
    e.add_argument("--ensemble", action="store_true", help="the runs also fly as one ensemble, the arm of this name")
    t = sub.add_parser("table", help="one table of arms over the grounds")
    t.add_argument("names", nargs="+")
    m = sub.add_parser("median", help="an arm's seeds ranked on the grounds, and the median seed (the one to ship)")
    m.add_argument("name")
    for s in (b, e, t, m):
        s.add_argument("--grounds", nargs="+", choices=sorted(GROUNDS), default=["val", "val-sizes", "val-shapes"])
    a = p.parse_args(argv)
    if a.command == "baselines":
        baselines(a.grounds)
    elif a.command == "eval":
        if not a.runs and a.name != "pretrained":
            sys.exit("give the arm's run folders, or the name 'pretrained' for the shipped agent")
        if a.ensemble and len(a.runs) < 2:
            sys.exit("--ensemble flies two or more run folders as one (the shipped agent may be one already)")
        evaluate(a.name, a.runs, a.grounds, pretrained=not a.runs, ensemble=a.ensemble)
    elif a.command == "median":
        for seed, score in seed_ranking(a.name, a.grounds):
            print(f"seed index {seed}: {100 * score:.1f} % of the ceiling, averaged over the grounds")
        print(f"median: seed index {median_seed(a.name, a.grounds)}")
    else:
        print(table(a.names, a.grounds))


if __name__ == "__main__":
    main()
