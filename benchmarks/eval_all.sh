#!/usr/bin/env bash
# The scripted baselines on every env, in the paper's format (magwarp eval). Writes one JSON per env under $1.
#   bash benchmarks/eval_all.sh OUT_DIR DEVICE REPEATS
# e.g. bash benchmarks/eval_all.sh benchmarks/results/eval_cpu cpu 5
set -u
out=${1:?output folder}; device=${2:-cpu}; repeats=${3:-5}
mkdir -p "$out"
for env in TrajectoryPlanningB0 TrajectoryPlanningB1 TrajectoryPlanningB2 TrajectoryPlanningB3 TrajectoryPlanningB4 \
           TrajectoryPlanningB5 TrajectoryPlanningB6 TrajectoryPlanningB7 TrajectoryPlanningB8 TrajectoryPlanningB9; do
  python -m magwarp eval "magwarp/$env-v0" --policy scripted --episodes 64 --repeats "$repeats" --steps 250 \
    --device "$device" --json "$out/$env.json" | tail -n +1
done
for env in PushBox PushT PushL PushX PushWithObstacles; do
  python -m magwarp eval "magwarp/$env-v0" --policy scripted --episodes 200 --repeats "$repeats" --device "$device" \
    --json "$out/$env.json"
done
