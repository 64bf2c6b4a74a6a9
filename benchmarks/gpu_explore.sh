#!/usr/bin/env bash
# Tuning runs on the device machine (one call): simulator kernel compile options and the push envs' MuJoCo solver.
#   export PYTHONPATH=/tmp/site:$PWD MAGWARP_COMMIT=<sha>; OUT=$OUT bash benchmarks/gpu_explore.sh
set -u
OUT=${OUT:-/tmp/out}
mkdir -p "$OUT"
export WARP_CACHE_PATH=/tmp/warp_cache PYTHONUNBUFFERED=1
log() { echo "=== $* ($(date -u +%H:%M:%S))"; }
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
for opts in "" "fast_math=1" "default_grid_stride=0" "fast_math=1,default_grid_stride=0"; do
  tag=${opts:-default}; tag=${tag//[=,]/_}
  log "scaling with MAGWARP_KERNEL_OPTIONS='$opts'"
  MAGWARP_KERNEL_OPTIONS="$opts" timeout 150 python3 benchmarks/scaling.py --device cuda:0 --no-magbotsim --steps 200 \
    --max-movers 1000 --skip-large --json "$OUT/scaling_$tag.json" | grep -E "^  magwarp"
done
log "push solver profile"
timeout 200 python3 benchmarks/profile_push.py --device cuda:0 --envs magwarp/PushBox-v0,magwarp/PushT-v0 --num-envs 65536 \
  --solvers Newton,CG --top 12 --json "$OUT/profile_push.json"
log "push throughput by solver"
timeout 300 python3 benchmarks/env_throughput.py --device cuda:0 --no-magbotsim --envs magwarp/PushBox-v0,magwarp/PushT-v0 \
  --push-num-envs 16384,65536,131072 --push-solvers Newton,CG --steps 20 --json "$OUT/env_throughput_solvers.json" | tail -16
log done
