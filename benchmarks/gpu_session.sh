#!/usr/bin/env bash
# One GPU session's work, in one call on the device machine (see the device tool's METHOD.md): checks first, then
# every GPU benchmark, each writing JSON under $OUT. Usage there (after the wheels are staged):
#   export PYTHONPATH=/tmp/site:$PWD MAGWARP_COMMIT=<sha>; bash benchmarks/gpu_session.sh [perf|quick]
set -u
source "$(dirname "$0")/gpu_common.sh"
if [ "${1:-}" = "perf" ]; then
  python3 benchmarks/scaling.py --device cuda:0 --no-magbotsim --steps 200 --json "$OUT/scaling_gpu.json"
  python3 benchmarks/env_throughput.py --device cuda:0 --no-magbotsim --envs magwarp/TrajectoryPlanningB0-v0 \
    --num-envs 1024,16384,262144,1048576,2097152 --steps 50 --json "$OUT/env_throughput_gpu.json"
  exit 0
fi
log "GPU tests (CPU/GPU agreement, env on cuda)"
timeout 300 python3 -X faulthandler -m pytest -v -p no:cacheprovider tests/test_sim.py tests/test_kernels_collision.py \
  tests/test_kernels_dynamics.py tests/test_kernels_impedance.py tests/test_sim_errors.py tests/test_sim_pairs.py \
  tests/test_env_trajectory.py tests/test_physics.py tests/test_push_envs.py tests/test_render.py > "$OUT/pytest_gpu.log" 2>&1
grep -E "PASS|FAIL|ERROR|Fatal|Segmentation|passed|failed" "$OUT/pytest_gpu.log" | grep -v PASSED | tail -25
if [ "${1:-}" = "quick" ]; then
  python3 benchmarks/scaling.py --device cuda:0 --no-magbotsim --steps 50 --max-movers 1000 --json "$OUT/scaling_gpu.json"
  exit 0
fi
log "scaling"
timeout 400 python3 benchmarks/scaling.py --device cuda:0 --no-magbotsim --steps 200 --json "$OUT/scaling_gpu.json"
log "env throughput"
timeout 500 python3 benchmarks/env_throughput.py --device cuda:0 --no-magbotsim --num-envs 1024,16384,262144,1048576,2097152 \
  --push-num-envs 1024,4096,16384,65536 --steps 50 --json "$OUT/env_throughput_gpu.json"
log "demo"
timeout 200 python3 -m magwarp demo --device cuda:0 --num-envs 65536 --out-dir "$OUT/demo"
log "done"
