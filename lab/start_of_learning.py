"""The start of learning, arm against arm: the mean validation AER over an arm's seeds after each chunk (the band
spans its seeds), from the `curve.json` files that `ramavt curve` wrote for each arm on the same episodes, with the
depth tracker's AER; and a Markdown table of each seed's first chunk above the depth tracker.

    python lab/start_of_learning.py preset=results/val/curve_seeds/curve.json \
        polyak-002=results/val/curve_polyak_002/curve.json --out results/val/start_of_learning.png
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from ramavt_jax.evaluation import curve
from ramavt_jax.figures import pyplot, save_figure


def arm_points(result: dict) -> tuple[list[int], np.ndarray]:
    """(chunks [K], AER [seeds, K]) over the chunks every run of one `curve.json` has."""
    per_run = [{p["step"]: p["aer"] for p in run["points"]} for run in result["runs"]]
    chunks = sorted(set.intersection(*(set(r) for r in per_run)))
    return chunks, np.array([[r[c] for c in chunks] for r in per_run])


def first_above(result: dict, threshold: float) -> list[int | None]:
    """Per run of one `curve.json`, the first chunk whose AER is above ``threshold`` (None: none of them)."""
    return [(curve.first_above(run["points"], threshold) or {}).get("step") for run in result["runs"]]


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("arms", nargs="+", metavar="NAME=CURVE_JSON")
    parser.add_argument("--out", type=Path, required=True, help="the figure (PNG)")
    args = parser.parse_args(argv)
    arms = {}
    for item in args.arms:
        name, sep, path = item.partition("=")
        if not sep or not Path(path).is_file():
            raise SystemExit(f"{item!r}: expected NAME=CURVE_JSON naming a file written by `ramavt curve`")
        arms[name] = json.loads(Path(path).read_text())
    episodes = {json.dumps(r["episodes"], sort_keys=True) for r in arms.values()}
    if len(episodes) > 1:
        raise SystemExit("the curves were flown on different episodes; compare arms on the same ones")
    depth = next(iter(arms.values()))["baselines"]["depth"]["aer"]
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.0, 4.2))
    print(f"| arm | seeds | first chunk above the depth tracker (+{depth:.1f}), per seed | mean AER per chunk |")
    print("|---|---|---|---|")
    for i, (name, result) in enumerate(arms.items()):
        chunks, aer = arm_points(result)
        style = ("-", "-.", ":")[i // 10 % 3]  # the colour cycle has 10 colours; past it, another line style
        (line,) = ax.plot(chunks, aer.mean(0), marker=".", lw=1.5, ls=style, label=f"{name} ({len(aer)} seeds)")
        ax.fill_between(chunks, aer.min(0), aer.max(0), color=line.get_color(), alpha=0.15, lw=0)
        crossings = ", ".join("-" if c is None else str(c) for c in first_above(result, depth))
        means = ", ".join(f"{c}: {m:+.1f}" for c, m in zip(chunks, aer.mean(0)))
        print(f"| {name} | {len(aer)} | {crossings} | {means} |")
    ax.axhline(depth, color="tab:gray", ls="--", lw=1, label="depth tracker")
    ax.set_xlabel("chunk (32k env steps each)")
    ax.set_ylabel("validation AER (mean over seeds; band: min-max)")
    ax.legend(fontsize=8, loc="lower right")
    ax.grid(alpha=0.3)
    print(f"wrote {save_figure(fig, args.out)}")


if __name__ == "__main__":
    main()
