"""What training logged over a run's last chunks, per seed: the mean of each chosen metrics.jsonl field over chunks
FROM-last (the chunks the quick preset's policy averages by default), one row per run folder, then each field's
range over the folders.

    python lab/training_tail.py runs/quick_margin/seed_{0..4} --from-chunk 37
    python lab/training_tail.py runs/rgbd_margin/seed_* --fields episode_return expert_agreement aux_loss

Training returns come from the training draw of starts with exploration on: they compare between arms, not with
`ramavt eval` on the validation or test episodes.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from ramavt_jax.training.run_folder import METRICS_FILE, read_metrics

DEFAULT_FIELDS = ("episode_return", "expert_agreement")


def tail_means(records: list[dict], fields: tuple[str, ...], from_chunk: int) -> dict[str, float]:
    """The mean of each field over the records of chunk >= from_chunk that hold a finite value of it (NaN if none)."""
    out = {}
    for field in fields:
        values = [
            r[field]
            for r in records
            if r.get("chunk", 0) >= from_chunk and isinstance(r.get(field), (int, float)) and math.isfinite(r[field])
        ]
        out[field] = sum(values) / len(values) if values else math.nan
    return out


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path, help="run folders (each with a metrics.jsonl)")
    parser.add_argument("--from-chunk", type=int, default=37, help="first chunk averaged (default 37)")
    parser.add_argument("--fields", nargs="+", default=list(DEFAULT_FIELDS), help="metrics.jsonl fields")
    args = parser.parse_args(argv)
    fields = tuple(args.fields)
    rows = {}
    for run in args.runs:
        records = read_metrics(run / METRICS_FILE, log=lambda *_: None)
        if not records:
            raise SystemExit(f"{run}: no {METRICS_FILE} records")
        rows[str(run)] = tail_means(records, fields, args.from_chunk)
    print(f"| run (chunks >= {args.from_chunk}) | " + " | ".join(fields) + " |")
    print("|---|" + "---|" * len(fields))
    for name, means in rows.items():
        print(f"| {name} | " + " | ".join(f"{means[f]:.3f}" for f in fields) + " |")
    for f in fields:
        finite = [m[f] for m in rows.values() if math.isfinite(m[f])]
        if finite:
            print(f"{f}: {min(finite):.3f} to {max(finite):.3f} over {len(finite)} run(s)")
    return rows


if __name__ == "__main__":
    main()
