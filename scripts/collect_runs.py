"""Markdown table of reproduction run folders: training wall time and the end-of-training greedy evaluation
(eval.json: 32 episodes per split, reported-table settings) next to the random agent.

    python scripts/collect_runs.py runs/repro
"""

import json
import sys
from pathlib import Path

def main(root: str = "runs/repro") -> None:
    root = Path(root)
    walls = {}
    wt = root / "wall_times.txt"
    if wt.exists():
        for line in wt.read_text().splitlines():
            name, _, rest = line.partition(" ")
            walls[name] = rest
    print("| run | network | input | augment | env steps | train wall | greedy AEL train / held-out | "
          "greedy AER train / held-out | random AEL held-out |")
    print("|---|---|---|---|---|---|---|---|---|")
    for ev in sorted(root.glob("**/eval.json")):
        run = ev.parent
        cfg = json.loads((run / "config.json").read_text())["config"]
        e = json.loads(ev.read_text())
        name = str(run.relative_to(root))
        wall = walls.get(name.split("/")[0], "")
        g = {s: e[s]["greedy"] for s in ("train", "test")}
        print(f"| {name} | {cfg['network']['variant']} | {cfg['env']['obs_mode']} | {cfg['learner']['augment']} "
              f"| {cfg['run']['total_env_steps']:,} | {wall} "
              f"| {g['train']['length_mean']:.1f} / {g['test']['length_mean']:.1f} "
              f"| {g['train']['return_mean']:.1f} / {g['test']['return_mean']:.1f} | "
              f"{e['test']['random']['length_mean']:.1f} |")


if __name__ == "__main__":
    main(*sys.argv[1:])
