"""The lab's results as one tidy table: one row per record, policy, setting and target.

Every `ramavt eval` result file (``results.json``, or a merged one) the lab wrote becomes rows of
``lab/results/arms.csv.gz``:

    record     the result's folder or file, relative to the results root (``val/arms/avg-12``)
    policy     the evaluated row (``avg12/seed_0``, ``mpc``, ``depth``)
    arm        the policy's name without its seed (``avg12``); seed: its seed (empty for baselines)
    split      the ground the targets come from (``val``, ``test``, ``train``, ``user``, ``sizes``)
    setting    the perturbation setting (``none``, ``all``, ...); target: a target's name, or ``all``
    episodes, ael, aer, error, within_quarter, within_half, lost
    commit     the commit that last wrote the record (git), so every figure can be traced to its code

    python -m lab.arm_records --root results --out lab/results/arms.csv.gz   # rebuild from result files
    python -m lab.arm_records --show val/arms/avg-12                          # print one record's rows

Reading: :func:`load` gives the rows as dicts; :func:`seed_means` a record's per-seed means, as RESULTS.md quotes
them (each arm's mean AER over its seeds is the mean of these).
"""

from __future__ import annotations

import argparse
import csv
import gzip
import json
import re
import subprocess
from pathlib import Path

TABLE = Path(__file__).resolve().parent / "results" / "arms.csv.gz"
COLUMNS = ("record", "policy", "arm", "seed", "split", "setting", "target", "episodes", "ael", "aer", "error",
           "within_quarter", "within_half", "lost", "commit")  # fmt: skip
_METRICS = {"ael": "length_mean", "aer": "return_mean", "error": "error_mean", "within_quarter":
            "within_quarter_fraction", "within_half": "within_half_fraction", "lost": "lost_fraction"}  # fmt: skip


def _split(record: str, targets: list[str]) -> str:
    """The ground of a record: from its targets' names where they say it (``-val``, ``@``, ``.xml``), else its path."""
    if any(t.endswith(".xml") for t in targets):
        return "user"
    if any("@" in t for t in targets):
        return "sizes"
    if targets and all("-val" in t for t in targets):
        return "val"
    top = record.split("/")[0]
    return {"user_targets": "user"}.get(top, top.split("_")[0])


def _commit(path: Path) -> str:
    out = subprocess.run(["git", "log", "-1", "--format=%h", "--", str(path)], capture_output=True, text=True)
    return out.stdout.strip()


def _rows_of(path: Path, root: Path) -> list[dict]:
    data = json.loads(path.read_text())
    record = str(path.relative_to(root).with_suffix(""))
    record = record.removesuffix("/results")
    targets = data.get("settings", {}).get("targets", [])
    split, commit, rows = _split(record, targets), _commit(path), []
    for row in data.get("rows", []):
        name = row["name"]
        arm, _, seed = name.partition("/seed_")
        for setting, result in row.get("settings", {}).items():
            per_target = {"all": result["overall"], **result.get("per_target", {})}
            for target, stats in per_target.items():
                values = {k: stats.get(v) for k, v in _METRICS.items()}
                rows.append({"record": record, "policy": name, "arm": arm, "seed": seed, "split": split,
                             "setting": setting, "target": target, "episodes": str(stats.get("episodes")),
                             **{k: "" if v is None else f"{v:.6g}" for k, v in values.items()}, "commit": commit})  # fmt: skip
    return rows


def build(root: Path) -> list[dict]:
    """Rows of every evaluation result file under ``root`` (files holding ``rows``; curves and fits are skipped)."""
    rows = []
    for path in sorted(root.rglob("*.json")):
        text = path.read_text()
        if '"rows"' in text and '"settings"' in text:
            rows += _rows_of(path, root)
    return rows


def write(rows: list[dict], out: Path) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    with gzip.open(out, "wt", newline="") as f:
        writer = csv.DictWriter(f, COLUMNS)
        writer.writeheader()
        writer.writerows(rows)


def load(path: Path = TABLE) -> list[dict]:
    """The table's rows as dicts of strings (numbers as written: 6 significant digits)."""
    with gzip.open(path, "rt", newline="") as f:
        return list(csv.DictReader(f))


def select(rows: list[dict], **where: str) -> list[dict]:
    """The rows whose columns equal ``where``'s values (a value may be a regular expression: ``policy='.*/seed_'``)."""
    return [r for r in rows if all(re.fullmatch(v, r[k]) for k, v in where.items())]


def seed_means(rows: list[dict], record: str, arm: str, setting: str = "none", metric: str = "aer") -> list[float]:
    """One arm's figure over all its targets, per seed (seed order), in one record."""
    picked = select(rows, record=re.escape(record), arm=re.escape(arm), setting=setting, target="all")
    picked = [r for r in picked if r["seed"] != ""]
    return [float(r[metric]) for r in sorted(picked, key=lambda r: int(r["seed"]))]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, help="rebuild the table from the result files under this folder")
    parser.add_argument("--out", type=Path, default=TABLE)
    parser.add_argument("--show", help="print the rows of one record (target 'all')")
    args = parser.parse_args(argv)
    if args.root:
        rows = build(args.root)
        write(rows, args.out)
        print(f"{len(rows)} rows from {len({r['record'] for r in rows})} records -> {args.out}")
    if args.show:
        for r in select(load(args.out), record=re.escape(args.show), target="all"):
            print(f"{r['policy']:32s} {r['setting']:8s} AEL {r['ael']:>8s} AER {r['aer']:>9s} error {r['error']}")


if __name__ == "__main__":
    main()
