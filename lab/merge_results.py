"""One arm of more seeds from several `ramavt eval` results of the same arm on the same episodes (say seeds 0-4 and
5-9, trained as two programs): their checkpoint rows, renamed NAME/seed_<k>, in one results file that
`lab/arm_table.py OUT:NAME` reads.

    python lab/merge_results.py results/val/arms/ten-seeds/preset10.json preset10 \
        results/val/arms/patch-768k/results.json results/val/arms/quick-s5/results.json

A result that holds several arms' runs is read as RESULTS_JSON:ARM, its rows of that run folder only
(``results/val/sizes/clip1/results.json:clip_1152k``: the rows named ``clip_1152k/seed_<k>``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def only_arm(result: dict, arm: str) -> dict:
    """``result`` with only the checkpoint rows of run folder ``arm`` (rows named ``<arm>/seed_<k>``)."""
    rows = [r for r in result["rows"] if r.get("kind") == "checkpoint" and r["name"].rsplit("/", 1)[0] == arm]
    if not rows:
        raise SystemExit(f"the result has no checkpoint rows of {arm!r}")
    return dict(result, rows=rows)


def read(spec: str) -> dict:
    """One RESULTS_JSON or RESULTS_JSON:ARM argument."""
    path, sep, arm = spec.partition(".json:")
    result = json.loads(Path(path + ".json" if sep else path).read_text())
    return only_arm(result, arm) if sep else result


def merge(name: str, results: list[dict]) -> dict:
    """The first result with the checkpoint rows of all of them, each seed once, as arm ``name``."""
    first = results[0]["settings"]
    keys = ("seed", "episodes_per_target", "targets", "max_steps")
    rows, seeds = [], set()
    for result in results:
        mine = result["settings"]
        # evaluation fields recorded by both (results of earlier versions record fewer of them)
        shared = set(mine.get("eval_params", {})) & set(first.get("eval_params", {}))
        if any(mine.get(k) != first.get(k) for k in keys) or any(
            mine["eval_params"][k] != first["eval_params"][k] for k in shared
        ):
            raise SystemExit("the results flew different episodes or rules; merge only results of the same episodes")
        for row in result["rows"]:
            if row.get("kind") != "checkpoint" or row["info"].get("ensemble_of"):  # one seed per row
                continue
            seed = row["info"]["seed"]
            if seed in seeds:
                raise SystemExit(f"training seed {seed} is in more than one result")
            seeds.add(seed)
            info = dict(row["info"], run_dir=f"{name}/seed_{seed}")
            rows.append(dict(row, name=f"{name}/seed_{seed}", info=info))
    merged = {k: v for k, v in results[0].items() if k != "arms"}
    return dict(merged, rows=rows, merged_from=[r.get("command", "") for r in results])


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("name")
    parser.add_argument("results", nargs="+", help="RESULTS_JSON or RESULTS_JSON:ARM")
    args = parser.parse_args(argv)
    merged = merge(args.name, [read(spec) for spec in args.results])
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(merged))
    print(f"{args.out}: {len(merged['rows'])} runs as arm {args.name}")


if __name__ == "__main__":
    main()
