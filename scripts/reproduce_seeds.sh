#!/usr/bin/env bash
# Two more seeds of the Table-I RAMAVT-depth agent (seed 0 is in scripts/reproduce.sh), trained together as ONE
# vmapped program: runs/repro/ramavt_depth_seeds/seed_1, seed_2.
set -euo pipefail
OUT=${1:-runs/repro}
t0=$(date +%s)
ramavt train --preset quick --network.variant ramavt --env.obs-mode depth --learner.augment --seeds 2 --seed 1 \
  --out "$OUT/ramavt_depth_seeds" --no-progress > "$OUT/ramavt_depth_seeds.log" 2>&1
echo "ramavt_depth_seeds (2 seeds, one program) $(( $(date +%s) - t0 )) s" | tee -a "$OUT/wall_times.txt"
