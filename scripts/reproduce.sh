#!/usr/bin/env bash
# Training runs for the paper's Tables I and III, scaled to a 2-core CPU (one seed each; evaluate them with
# scripts/reproduce_eval.sh): the 'quick' preset (32x32, small
# networks, 384k env steps) for every agent / input / ablation, seed 0; plus one longer RAMAVT-depth run.
# Each run folder gets metrics.jsonl, checkpoints/, training_curves.png, eval.json; `time` lines go to stdout.
# Usage: bash scripts/reproduce.sh [runs/repro]   (re-running resumes finished/unfinished runs from checkpoints)
set -euo pipefail
OUT=${1:-runs/repro}
mkdir -p "$OUT"
train() {  # name, then ramavt-train flags
  local name=$1; shift
  local t0=$(date +%s)
  ramavt train --preset quick --seed 0 --out "$OUT/$name" --no-progress "$@" > "$OUT/$name.log" 2>&1
  echo "$name $(( $(date +%s) - t0 )) s" | tee -a "$OUT/wall_times.txt"
}
# Table I: both agents, three input modes (augmentation on, as in the paper's full agents)
train ramavt_depth --network.variant ramavt --env.obs-mode depth --learner.augment
# the target run: RAMAVT depth, 3x the quick budget, quick-preset recipe (no augmentation)
train ramavt_depth_long --network.variant ramavt --env.obs-mode depth --learner.no-augment --run.total-env-steps 1152000
train drlavt_depth --network.variant drlavt --env.obs-mode depth --learner.augment
train ramavt_rgbd  --network.variant ramavt --env.obs-mode rgbd  --learner.augment
train ramavt_color --network.variant ramavt --env.obs-mode color --learner.augment
train drlavt_rgbd  --network.variant drlavt --env.obs-mode rgbd  --learner.augment
train drlavt_color --network.variant drlavt --env.obs-mode color --learner.augment
# Table III: cumulative ablation on depth (RAMAVT + augment is ramavt_depth above)
train origin       --network.variant origin --env.obs-mode depth --learner.no-augment
train origin_aug   --network.variant origin --env.obs-mode depth --learner.augment
train se_aug       --network.variant se     --env.obs-mode depth --learner.augment
train mha_aug      --network.variant mha    --env.obs-mode depth --learner.augment
