#!/usr/bin/env bash
# The last GPU session's work, in two calls on the device machine (each under the 10-minute limit):
#   export PYTHONPATH=/tmp/site:$PWD MAGWARP_COMMIT=<sha>
#   bash benchmarks/gpu_final.sh bench   # GPU tests, scaling (MagBotSim on the same machine's CPU), env throughput
#   bash benchmarks/gpu_final.sh push    # push env throughput: default solver and capped iterations
#   bash benchmarks/gpu_final.sh eval    # scripted baselines on every env and the shipped policies (magwarp/pretrained/)
set -u
OUT=${OUT:-/tmp/out}
mkdir -p "$OUT"
export WARP_CACHE_PATH=/tmp/warp_cache PYTHONUNBUFFERED=1
log() { echo "=== $* ($(date -u +%H:%M:%S))"; }
if [ "${1:-bench}" = "bench" ]; then
  log "GPU tests (kernels, CPU/GPU agreement)"
  timeout 150 python3 -m pytest -p no:cacheprovider tests/test_sim.py tests/test_kernels_collision.py \
    tests/test_kernels_dynamics.py tests/test_kernels_impedance.py tests/test_sim_pairs.py tests/test_sim_errors.py \
    > "$OUT/pytest_gpu.log" 2>&1; tail -3 "$OUT/pytest_gpu.log"
  log "scaling with MagBotSim on this machine's CPU"
  timeout 260 python3 benchmarks/scaling.py --device cuda:0 --steps 200 --ref-steps 30 --json "$OUT/scaling_gpu_vs_magbotsim.json" \
    --plot "$OUT/scaling_gpu.png" | tail -24
  log "env throughput"
  timeout 250 python3 benchmarks/env_throughput.py --device cuda:0 --no-magbotsim \
    --num-envs 16384,262144,1048576,2097152 --push-num-envs 1024,4096,16384,65536 --steps 30 \
    --json "$OUT/env_throughput_gpu.json" --plot "$OUT/env_throughput_gpu.png" | tail -22
elif [ "${1}" = "push" ]; then
  log "push env throughput (raw mujoco-warp from the env's own states), default solver and a 4-iteration cap"
  timeout 280 python3 benchmarks/env_throughput.py --device cuda:0 --no-magbotsim --envs magwarp/PushBox-v0,magwarp/PushT-v0 \
    --push-num-envs 1024,4096,16384,65536 --push-solvers auto,Newton:4 --steps 20 --json "$OUT/env_throughput_push_gpu.json" \
    | tail -18
else
  log "scripted baselines"
  bash benchmarks/eval_all.sh "$OUT/eval_gpu" cuda:0 100 2>&1 | grep -E "^\*|Success Rate|Collisions \(per"
  log "trained policies"
  for r in pushbox_sac:PushBox pusht_sac:PushT obstacles_sac:PushWithObstacles; do
    timeout 60 python3 -m magwarp eval "magwarp/${r##*:}-v0" --policy "pretrained:${r%%:*}" --episodes 200 --repeats 100 \
      --device cuda:0 --json "$OUT/eval_${r%%:*}_gpu.json" | grep -E "Success Rate"
  done
  # 10 s per world, the eval's default (83 steps of the policy's 120-cycle actions)
  timeout 60 python3 -m magwarp eval magwarp/TrajectoryPlanningB0-v0 --policy pretrained:b0_ppo --episodes 100 --repeats 100 \
    --device cuda:0 --json "$OUT/eval_b0_ppo_gpu.json" | grep -E "Success Rate|Collisions \(per"
fi
log "done"
