#!/usr/bin/env bash
# The last GPU session's work: evaluation tables (scripted baselines and the trained policies in policies/) and the
# scaling benchmark with MagBotSim measured on the same machine's CPU. Usage on the device machine:
#   export PYTHONPATH=/tmp/site:$PWD MAGWARP_COMMIT=<sha>; bash benchmarks/gpu_final.sh
set -u
OUT=${OUT:-/tmp/out}
mkdir -p "$OUT"
export WARP_CACHE_PATH=/tmp/warp_cache PYTHONUNBUFFERED=1
log() { echo "=== $* ($(date -u +%H:%M:%S))"; }
log "render tests on the GPU"
timeout 120 python3 -m pytest -q -p no:cacheprovider tests/test_render.py 2>&1 | tail -2
log "eval: Push-Box scripted, 100 repeats x 200 episodes"
timeout 200 python3 -m magwarp eval magwarp/PushBox-v0 --policy scripted --episodes 200 --repeats 100 --device cuda:0 \
  --json "$OUT/eval_pushbox_scripted_gpu.json"
log "eval: Push-Box trained SAC+HER, 100 repeats x 200 episodes"
timeout 200 python3 -m magwarp eval magwarp/PushBox-v0 --policy policies/pushbox_sac.pt --episodes 200 --repeats 100 \
  --device cuda:0 --json "$OUT/eval_pushbox_sac_gpu.json"
log "eval: B0 trained PPO"
timeout 200 python3 -m magwarp eval magwarp/TrajectoryPlanningB0-v0 --policy policies/b0_ppo.pt --episodes 100 --repeats 100 \
  --steps 250 --device cuda:0 --json "$OUT/eval_b0_ppo_gpu.json"
log "eval: B0 scripted"
timeout 200 python3 -m magwarp eval magwarp/TrajectoryPlanningB0-v0 --policy scripted --episodes 100 --repeats 100 \
  --steps 250 --device cuda:0 --json "$OUT/eval_b0_scripted_gpu.json"
log "scaling with MagBotSim on this machine's CPU"
timeout 280 python3 benchmarks/scaling.py --device cuda:0 --steps 200 --ref-steps 50 --json "$OUT/scaling_gpu_vs_magbotsim.json"
log "done"
