#!/usr/bin/env bash
# The GPU work of one session (issues #16-#21), in a few calls on the device machine (see the device tool's
# METHOD.md). Each stage checks or times several sizes and writes JSON and logs under $OUT. Usage there, after the
# wheels are staged (python3 ../shared/tools/device_wheels.py magbotsim==1.3.0 magpylib==6.3.0 shapely==2.2.0):
#   export PYTHONPATH=/tmp/site:$PWD; bash benchmarks/gpu_round.sh STAGE
# Stages: tests (GPU/CPU agreement of the new kernels), queries (collision queries), magnetics, swarm, perf
# (scaling and B0 env throughput), magbots, distributed, sim2real (latency/sensor models' cost), randomization,
# swarm_render, graph (#23: the fused B0 step, ceiling), push_dt (#23: push envs), ttt_* (#20), planner (#18),
# suite (paper.py training runs side by side: RUNS=b0_ppo_dr,b0_ppo_dr_ft,...), robustness (#24), lev_eval (#17),
# small_world_kernels and small_world (#24: the one-thread-per-mover fused step), rand_rows, rand_profile and
# tests24 (#24: the randomisation's cost by part, its reset firing, its CUDA tests), rand_gaps, fire_cost and
# branches (#24), magnetics_variants and magnetics_fast (#17), swarm_fused, swarm_obs, swarm_place and tests18
# and place_scan (#18), compare (B0 env throughput of an older tree beside this one), configs (the env configs'
# CUDA tests), swarm_load (#18: the step by action load), b0_check (B0 with and without randomisation), ncu (#18,
# #24: Nsight Compute on the swarm step and B0's physics kernel; ncu18, ncu17: the swarm step, the fast magnetic
# cycle), exchange and exchange_swarm (#18: the
# swarm step's per-cycle exchange: tests, timing), caps (#18, #24: register caps),
# swarm_vs_ref (#18: the swarm step against an older tree), mag_vs_ref (#17: the fast magnetic cycle against an
# older tree), mag_rest (#17: its active-set launch by block size), swarm_pack (#18: several worlds per block),
# swarm_sift (#18: the observation's sift), swarm_abc (#18: an older tree, the sift off / on / on with packing),
# swarm_pack_cap (#18: several worlds per block under a register cap), capture_gc (graph captures beside dropped
# torch graphs), swarm_kernels (#18: the env step's kernels by time), swarm_cap_check (#18: the register cap rule at
# sizes not yet measured), swarm_small_check (#18: the NaN guard in the fused step, the placement's capped
# launches), planner_cost (#18: the planner's kernels against their torch forms). ncu18 with NCU_OBS=1 also profiles
# the observation kernel.
set -u
source "$(dirname "$0")/gpu_common.sh"
# swarm_load at 16,384 worlds with the environment variable VAR set to each of VALUES in turn, the whole set ROUNDS
# times (default 2); JSON "$OUT/swarm_NAME_VALUE_rROUND_gpu.json". Arguments: VAR NAME "VALUES" "MOVERS" "LOADS" LIMIT.
swarm_load_by() {
  local var=$1 name=$2 values=$3 movers=$4 loads=$5 limit=$6 round v
  for round in $(seq ${ROUNDS:-2}); do
    for v in $values; do
      env "$var=$v" timeout "$limit" python3 benchmarks/swarm_load.py --device cuda:0 --movers $movers \
        --worlds 16384 --loads $loads --json "$OUT/swarm_${name}_${v}_r${round}_gpu.json" 2>&1 | grep -v "^Module" \
        | tail -8
    done
  done
}
for stage in "$@"; do
  log "$stage"
  case "$stage" in
    tests)
      timeout 420 python3 -X faulthandler -m pytest -p no:cacheprovider -p no:warnings tests/test_sim.py \
        tests/test_sim_starts.py tests/test_kernels_dynamics.py tests/test_kernels_collision.py \
        tests/test_collision_queries.py tests/test_swarm_placement.py tests/test_swarm_observations.py \
        tests/test_magnetics_exact.py tests/test_magnetics_commutation.py tests/test_magnetics_fast.py \
        tests/test_magnetics_table.py \
        tests/test_reliability.py tests/test_sim_errors.py tests/test_sim2real_models.py \
        > "$OUT/pytest_gpu.log" 2>&1
      grep -E "FAIL|ERROR|Fatal|Segmentation|passed|failed" "$OUT/pytest_gpu.log" | tail -25 ;;
    tests24)
      # #24: the randomisation, sensor and latency draws on CUDA (graph step == torch step bit for bit, no host sync)
      timeout 400 python3 -X faulthandler -m pytest -p no:cacheprovider -p no:warnings tests/test_graph_step.py \
        tests/test_sensor_draws.py tests/test_sim2real_models.py tests/test_planar_randomization.py \
        > "$OUT/pytest24_gpu.log" 2>&1
      grep -E "FAIL|ERROR|Fatal|Segmentation|passed|failed" "$OUT/pytest24_gpu.log" | tail -25 ;;
    tests18)
      # #18: the swarm env's step as one CUDA graph against the same launches eagerly (bit for bit), the fused step
      timeout 300 python3 -X faulthandler -m pytest -p no:cacheprovider -p no:warnings tests/test_swarm_graph.py \
        tests/test_swarm_fused.py tests/test_swarm_task_kernels.py tests/test_swarm_placement.py \
        > "$OUT/pytest18_gpu.log" 2>&1
      grep -E "FAIL|ERROR|Error|Fatal|Segmentation|passed|failed" "$OUT/pytest18_gpu.log" | tail -25 ;;
    queries)
      timeout 400 python3 benchmarks/collision_queries.py --devices cpu cuda:0 --max-poses-cpu 1e5 \
        --json "$OUT/collision_queries_gpu.json" 2>&1 | tail -40 ;;
    magnetics)
      timeout 500 python3 benchmarks/magnetics.py --json "$OUT/magnetics_gpu.json" 2>&1 | tail -45 ;;
    magnetics_speed)
      # #17: the control cycle at 1e3/1e5/1e6 movers and the B0 magnetic/ideal ratio only (no accuracy, magpylib or
      # current-limit sweep: those rows are in magnetics_table_gpu.json)
      timeout 400 python3 benchmarks/magnetics.py --device cuda:0 --accuracy-poses 0 --magpylib-movers 0 --limits '' \
        --json "$OUT/magnetics_cycle_gpu.json" 2>&1 | grep -v "^Module" | tail -30 ;;
    magnetics_variants)
      # #17: the one-thread control cycle (float32/float64), the in-step drive and smaller tables beside the block
      # kernel, 1e3-1e6 movers and B0 at 4096/65536 envs
      timeout 590 python3 benchmarks/magnetics.py --device cuda:0 --accuracy-poses 8 --magpylib-movers 0 --limits '' \
        --fast-sizes '' --exact-sizes '' --table-variants default,yaw24_gap25_55 --per-cycle \
        --drive-variants ${DRIVES:-hook} --env-steps 10 --json "$OUT/magnetics_cycle_gpu.json" 2>&1 | grep -v "^Module" | tail -40 ;;
    magnetics_fast)
      # #17: the block cycle beside the fast cycle (magwarp/magnetics/fast_cycle.py: 8 lanes per mover, the fast path,
      # then the active-set steps of the movers it left) and its variants at 1e3/1e5/1e6 movers, with their current
      # differences; then the fast cycle's GPU tests (about 6 minutes on a cold machine: the first H100 call, 2026-12-06,
      # compiled for 39 s and was cut at 130 s before its first row)
      timeout 420 python3 benchmarks/magnetics.py --device cuda:0 --fast-cycle-only \
        --fast-cycle-sizes 1000,100000,1000000 --json "$OUT/magnetics_fast_cycle_gpu.json" 2>&1 | grep -v "^Module" \
        | tail -16
      timeout 150 python3 -m pytest -p no:cacheprovider -p no:warnings tests/test_magnetics_fast_cycle.py 2>&1 \
        | tail -4 ;;
    magnetics_sweep)
      # #17: the shipped B0 policy driven magnetically (the in-step drive) as the current limit falls; not timed
      timeout 590 python3 benchmarks/magnetics.py --device cuda:0 --sizes '' --fast-sizes '' --exact-sizes '' \
        --sim-worlds '' --env-envs '' --accuracy-poses 0 --magpylib-movers 0 --limits 7,5,3,2 \
        --json "$OUT/magnetics_sweep_gpu.json" 2>&1 | grep -v "^Module" | tail -20 ;;
    swarm)
      timeout 500 python3 benchmarks/swarm.py --device cuda:0 --json "$OUT/swarm_gpu.json" 2>&1 | tail -40 ;;
    perf)
      timeout 250 python3 benchmarks/scaling.py --device cuda:0 --no-magbotsim --steps 100 \
        --json "$OUT/scaling_gpu.json" 2>&1 | tail -25
      timeout 300 python3 benchmarks/env_throughput.py --device cuda:0 --no-magbotsim \
        --envs magwarp/TrajectoryPlanningB0-v0 --num-envs 4096,65536,1048576 --steps 50 \
        --json "$OUT/env_throughput_gpu.json" 2>&1 | tail -20 ;;
    magbots)
      # cuda:0 only (the CPU rows: benchmarks/results/magbots_cpu.json), MagBotSim's references on the CPU beside them
      timeout 560 python3 benchmarks/magbots.py --device cuda:0 --envs pose,pickplace,gripper,coop --action-modes pose \
        --num-envs 4096,16384,65536 --steps 10 --magbotsim-steps 30 --json "$OUT/magbots_gpu.json" 2>&1 \
        | grep -v "^Module" | tail -30 ;;
    distributed)
      timeout 400 python3 benchmarks/distributed.py --seconds 20 --json "$OUT/distributed_gpu.json" 2>&1 | tail -30 ;;
    sim2real)
      timeout 400 python3 benchmarks/sim2real_models.py --device cuda:0 --num-envs 4096,65536,262144,1048576 \
        --json "$OUT/sim2real_models_gpu.json" 2>&1 | tail -25 ;;
    randomization)
      timeout 120 python3 -m pytest -p no:cacheprovider -p no:warnings tests/test_randomization.py -k no_host_sync \
        2>&1 | tail -3
      timeout 400 python3 benchmarks/randomization.py --device cuda:0 --num-envs 4096,16384,65536 \
        --json "$OUT/randomization_gpu.json" 2>&1 | tail -15 ;;
    swarm_render)
      timeout 300 python3 benchmarks/swarm_render.py --json "$OUT/swarm_render_gpu.json" 2>&1 | tail -20 ;;
    configs)
      # the env config dataclasses on CUDA (trajectory, levitation, swarm graph key): the graph step tests too
      timeout 420 python3 -X faulthandler -m pytest -p no:cacheprovider -p no:warnings tests/test_graph_step.py \
        tests/test_trajectory_config.py tests/test_levitation_config.py tests/test_swarm_graph.py \
        ${EXTRA_TESTS:-} > "$OUT/pytest_configs_gpu.log" 2>&1
      grep -E "FAIL|ERROR|Error|Fatal|Segmentation|passed|failed" "$OUT/pytest_configs_gpu.log" | tail -25 ;;
    swarm_load)
      # #18: the fused swarm step under the seek (collision-heavy), planner and still loads, 16,384 worlds
      for movers in ${LOAD_MOVERS:-64 256}; do
        timeout 300 python3 benchmarks/swarm_load.py --device cuda:0 --movers $movers --worlds 16384 \
          --json "$OUT/swarm_load_${movers}_gpu.json" 2>&1 | grep -v "^Module" | tail -8
      done ;;
    exchange)
      # #18: the swarm step's per-cycle exchange, Warp tiles against native barriers: the CUDA tests (bit for bit
      # against the tiles and the per-cycle path); exchange_swarm: the swarm step (tile: about four block barriers a
      # cycle, native: one __syncthreads_or; MAGWARP_SWARM_EXCHANGE) at 16,384 worlds under the seek and still loads,
      # alternated twice. (B0's movers kernel with two native barriers a cycle instead of four, 595ca77, was 2.8%
      # slower: removed.)
      timeout 400 python3 -X faulthandler -m pytest -p no:cacheprovider -p no:warnings tests/test_swarm_fused.py \
        tests/test_step_blocks.py tests/test_swarm_graph.py tests/test_graph_step.py > "$OUT/pytest_exchange_gpu.log" 2>&1
      grep -E "FAIL|ERROR|Error|Fatal|Segmentation|passed|failed" "$OUT/pytest_exchange_gpu.log" | tail -25 ;;
    exchange_swarm)
      swarm_load_by MAGWARP_SWARM_EXCHANGE exchange "tile native" "${LOAD_MOVERS:-64 100 256}" "${LOADS:-seek still}" \
        300 ;;
    caps)
      # #18, #24: register caps per thread (occupancy against spills) of the swarm step kernel with the native exchange
      # (MAGWARP_SWARM_MAX_REGISTERS, 16,384 worlds, seek and still) and of B0's movers kernel
      # (MAGWARP_SMALL_WORLD_MAXREG, the env step at 65,536 envs, no / full randomisation)
      for cap in ${SWARM_CAPS:-128 112 96 80}; do
        MAGWARP_SWARM_EXCHANGE=native MAGWARP_SWARM_MAX_REGISTERS=$cap timeout 200 python3 benchmarks/swarm_load.py \
          --device cuda:0 --movers ${LOAD_MOVERS:-64 100 256} --worlds 16384 --loads seek still \
          --json "$OUT/swarm_cap${cap}_gpu.json" 2>&1 | grep -v "^Module" | tail -7
      done
      for cap in ${B0_CAPS:-168 144 128}; do
        MAGWARP_SMALL_WORLD_MAXREG=$cap timeout 200 python3 benchmarks/rand_gaps.py --device cuda:0 --num-envs 65536 \
          --steps 200 --settings off,full --json "$OUT/rand_gaps_cap${cap}_gpu.json" 2>&1 | grep -v "^Module" | tail -3
      done ;;
    swarm_vs_ref)
      # #18: the swarm step of this tree against an older one (REF, e.g. `git archive e05f5fc magwarp benchmarks | tar
      # -x -C .devrun/old`) in the same run: the CUDA tests of this tree's fused step (bit for bit against the
      # per-cycle path, both exchanges), then both trees' swarm_load at 16,384 worlds, alternated twice
      timeout 300 python3 -X faulthandler -m pytest -p no:cacheprovider -p no:warnings tests/test_swarm_fused.py \
        tests/test_swarm_graph.py > "$OUT/pytest_swarm_vs_ref_gpu.log" 2>&1
      grep -E "FAIL|ERROR|Error|Fatal|Segmentation|passed|failed" "$OUT/pytest_swarm_vs_ref_gpu.log" | tail -25
      for round in $(seq ${ROUNDS:-2}); do
        for tree in "${REF:-.devrun/old}" .; do
          name=$([ "$tree" = . ] && echo new || echo ref)
          (cd "$tree" && PYTHONPATH=/tmp/site:$PWD timeout 200 python3 benchmarks/swarm_load.py --device cuda:0 \
            --movers ${LOAD_MOVERS:-64 100 256} --worlds 16384 --loads ${LOADS:-seek planner} \
            --json "$OUT/swarm_${name}_r${round}_gpu.json" 2>&1 | grep -v "^Module" | tail -7)
        done
      done ;;
    mag_vs_ref)
      # #17: the fast magnetic cycle of this tree (its variants) and of an older one (REF) in the same run, at 1e5 and
      # 1e6 movers (the wrench table is built once, on the first run, into the machine's cache)
      for tree in . "${REF:-.devrun/old}"; do
        name=$([ "$tree" = . ] && echo new || echo ref)
        (cd "$tree" && PYTHONPATH=/tmp/site:$PWD timeout 300 python3 benchmarks/magnetics.py --device cuda:0 \
          --fast-cycle-only --fast-cycle-sizes ${MAG_SIZES:-100000,1000000} \
          --json "$OUT/magnetics_fast_${name}_gpu.json" 2>&1 | grep -v "^Module" | tail -8)
      done ;;
    mag_rest)
      # #17: the fast magnetic cycle's active-set launch by threads per block (a block retires when its slowest mover
      # is done) at 1M movers
      timeout 280 python3 benchmarks/magnetics.py --device cuda:0 --fast-cycle-only --fast-cycle-sizes 1000000 \
        --fast-variants fast_rb64,fast_rb32,fast_rb16 --json "$OUT/magnetics_rest_block_gpu.json" 2>&1 \
        | grep -v "^Module" | grep -E "fast cycle|^  \|" ;;
    swarm_sift)
      # #18: the observation's sift (only the candidates within the radius merged into the slots): the CUDA tests of
      # the observations (bit for bit against the grid), the kernel alone by variant (swarm_obs.py), then the env step
      # with the sift off and on (MAGWARP_OBS_SIFT), alternated twice
      timeout 240 python3 -X faulthandler -m pytest -p no:cacheprovider -p no:warnings \
        tests/test_swarm_observations.py -k cuda > "$OUT/pytest_swarm_sift_gpu.log" 2>&1
      grep -E "FAIL|ERROR|Error|Fatal|Segmentation|passed|failed" "$OUT/pytest_swarm_sift_gpu.log" | tail -25
      timeout 200 python3 benchmarks/swarm_obs.py --device cuda:0 --movers ${OBS_MOVERS:-100 256} \
        --json "$OUT/swarm_obs_sift_gpu.json" 2>&1 | grep -v "^Module" | grep -E " full |no_rays|Error" | tail -24
      swarm_load_by MAGWARP_OBS_SIFT sift "0 1" "${LOAD_MOVERS:-100 256}" "${LOADS:-planner}" 200 ;;
    swarm_abc)
      # #18: the env step of an older tree (REF) beside this one with the observation's sift off, on, and on with
      # several worlds per block (MAGWARP_SWARM_WORLDS=auto), at 16,384 worlds, the four alternated ROUNDS times
      for round in $(seq ${ROUNDS:-2}); do
        for cfg in ref nosift sift siftpack; do
          tree=.; [ $cfg = ref ] && tree=${REF:-.devrun/old}
          sift=$([ $cfg = nosift ] && echo 0 || echo 1); pack=$([ $cfg = siftpack ] && echo auto || echo 1)
          (cd "$tree" && MAGWARP_OBS_SIFT=$sift MAGWARP_SWARM_WORLDS=$pack PYTHONPATH=/tmp/site:$PWD timeout 200 \
            python3 benchmarks/swarm_load.py --device cuda:0 --movers ${LOAD_MOVERS:-100 256} --worlds 16384 \
            --loads ${LOADS:-planner} --json "$OUT/swarm_${cfg}_r${round}_gpu.json" 2>&1 | grep -v "^Module" \
            | tail -${TAIL:-4} | sed "s/^/$cfg r$round /")
        done
      done ;;
    swarm_pack_cap)
      # #18: several worlds per block with a register cap (2 worlds of 100 movers in 224 threads: 2 blocks per SM at
      # 128 registers, 3 at 96): worlds per block 1 or auto, cap 128 (the default) or 96, at 16,384 worlds of 100
      # movers under the planner, the four alternated ROUNDS times
      for round in $(seq ${ROUNDS:-2}); do
        for cfg in 1:128 auto:128 auto:96 1:96; do
          MAGWARP_SWARM_WORLDS=${cfg%:*} MAGWARP_SWARM_MAX_REGISTERS=${cfg#*:} timeout 200 python3 \
            benchmarks/swarm_load.py --device cuda:0 --movers ${LOAD_MOVERS:-100} --worlds 16384 \
            --loads ${LOADS:-planner} --json "$OUT/swarm_pack${cfg%:*}_cap${cfg#*:}_r${round}_gpu.json" 2>&1 \
            | grep -v "^Module" | tail -${TAIL:-2} | sed "s/^/$cfg r$round /"
        done
      done ;;
    capture_gc)
      # graph captures with dropped torch CUDA graphs in reference cycles: the tests (gc_paused on), then the same
      # with gc_paused switched off (it must fail: the test can fail), then the two test files whose order showed it
      timeout 200 python3 -X faulthandler -m pytest -p no:cacheprovider -p no:warnings tests/test_capture_gc.py \
        > "$OUT/pytest_capture_gc_gpu.log" 2>&1
      grep -E "FAIL|ERROR|Error|Fatal|Segmentation|passed|failed" "$OUT/pytest_capture_gc_gpu.log" | tail -8
      for what in simulator torch_graph; do
        WHAT=$what timeout 120 python3 - <<'PY' 2>&1 | grep -v "^Module" | tail -3
import contextlib, os, sys
sys.path.insert(0, "tests")
import magwarp.envs.step_graph as sg, magwarp.sim as sim
sim.gc_paused = sg.gc_paused = lambda cuda=True: contextlib.nullcontext()
import test_capture_gc as t
what = os.environ["WHAT"]
try:
    t.test_captures_survive_dropped_cuda_graphs(what)
    print(f"gc_paused off, {what}: passed (the test did not catch it)")
except BaseException as e:
    print(f"gc_paused off, {what}: failed as it should: {type(e).__name__}: {str(e)[:200]}")
PY
      done
      timeout 300 python3 -X faulthandler -m pytest -p no:cacheprovider -p no:warnings \
        tests/test_swarm_observations.py tests/test_swarm_fused.py -k cuda > "$OUT/pytest_order_gpu.log" 2>&1
      grep -E "FAIL|ERROR|Error|Fatal|Segmentation|passed|failed" "$OUT/pytest_order_gpu.log" | tail -8 ;;
    swarm_kernels)
      # #18: the env step's device kernels by time (torch's profiler over 10 steps) at 16,384 worlds, per load
      timeout 300 python3 benchmarks/swarm_load.py --device cuda:0 --movers ${LOAD_MOVERS:-64 100 256} --worlds 16384 \
        --loads ${LOADS:-planner seek} --kernels 10 --json "$OUT/swarm_kernels_gpu.json" 2>&1 | grep -v "^Module" \
        | tail -80 ;;
    swarm_cap_check)
      # #18: the register cap rule (96 where it fits more one-world blocks per SM) at sizes not yet measured (200
      # movers: 224 threads, 3 blocks against 2), against 128, planner and seek; then the 100-mover step's kernels
      # under the planner (profiled around env.step alone) and the swarm CUDA tests at the default caps
      ROUNDS=${ROUNDS:-1} swarm_load_by MAGWARP_SWARM_MAX_REGISTERS capE "96 128" "${LOAD_MOVERS:-200}" \
        "${LOADS:-planner seek}" 250
      timeout 200 python3 benchmarks/swarm_load.py --device cuda:0 --movers 100 --worlds 16384 --loads planner \
        --kernels 10 --json "$OUT/swarm_kernels_planner_gpu.json" 2>&1 | grep -v "^Module" | tail -14
      timeout 300 python3 -X faulthandler -m pytest -p no:cacheprovider -p no:warnings tests/test_swarm_fused.py \
        tests/test_swarm_graph.py tests/test_capture_gc.py -k "cuda or graph or capture" \
        > "$OUT/pytest_swarm_caps_gpu.log" 2>&1
      grep -E "FAIL|ERROR|Error|Fatal|Segmentation|passed|failed" "$OUT/pytest_swarm_caps_gpu.log" | tail -8 ;;
    swarm_small_check)
      # #18: the step's small launches: the NaN guard's record written by the fused step (MAGWARP_SWARM_GUARD=fused,
      # the default, against separate) and the placement's launches capped at 4 or 8 blocks per SM through their
      # grid-stride twins (MAGWARP_PLACE_BLOCKS; 0, the default: the lean kernels uncapped), first the CUDA tests (bit
      # for bit against the per-cycle path and the uncapped launches), then swarm_load with each setting, alternated
      # twice in one call (one card: 2026-12-08's two H100s differed by more than the levers)
      timeout 300 python3 -X faulthandler -m pytest -p no:cacheprovider -p no:warnings tests/test_swarm_fused.py \
        tests/test_swarm_graph.py tests/test_swarm_placement.py -k "cuda or graph or guard" \
        > "$OUT/pytest_swarm_small_gpu.log" 2>&1
      grep -E "FAIL|ERROR|Error|Fatal|Segmentation|passed|failed" "$OUT/pytest_swarm_small_gpu.log" | tail -8
      ROUNDS=2 swarm_load_by MAGWARP_PLACE_BLOCKS blocks "0 8 4" "${LOAD_MOVERS:-100}" "planner seek" 300
      ROUNDS=2 swarm_load_by MAGWARP_SWARM_GUARD guard "fused separate" "${LOAD_MOVERS:-100}" "planner seek" 200 ;;
    planner_cost)
      # #18: the scripted planner's linear program and safety filter as Warp kernels against their torch forms: the
      # CUDA tests (kernel against torch on random lines and crowds), then ms per planner call and per residual env
      # step both ways (benchmarks/swarm_planner_cost.py)
      timeout 200 python3 -X faulthandler -m pytest -p no:cacheprovider -p no:warnings tests/test_swarm_planner.py \
        tests/test_swarm_safety.py -k "kernel" > "$OUT/pytest_planner_kernels_gpu.log" 2>&1
      grep -E "FAIL|ERROR|Error|Fatal|Segmentation|passed|failed" "$OUT/pytest_planner_kernels_gpu.log" | tail -8
      timeout 400 python3 benchmarks/swarm_planner_cost.py --device cuda:0 --movers 64 256 1024 --worlds 256 \
        --json "$OUT/swarm_planner_cost_gpu.json" 2>&1 | grep -v "^Module" | tail -10 ;;
    swarm_pack)
      # #18: several worlds per block of the swarm step (MAGWARP_SWARM_WORLDS=auto: 2 worlds of 100 movers in 7 warps,
      # 2 of 16 or 48 in 1 or 3 warps) against one world per block: the CUDA tests (bit for bit against the per-cycle
      # path), then swarm_load at 16,384 worlds, alternated twice
      timeout 300 python3 -X faulthandler -m pytest -p no:cacheprovider -p no:warnings tests/test_swarm_fused.py \
        -k cuda > "$OUT/pytest_swarm_pack_gpu.log" 2>&1
      grep -E "FAIL|ERROR|Error|Fatal|Segmentation|passed|failed" "$OUT/pytest_swarm_pack_gpu.log" | tail -25
      swarm_load_by MAGWARP_SWARM_WORLDS pack "1 auto" "${LOAD_MOVERS:-16 48 100}" "${LOADS:-seek planner}" 200 ;;
    b0_check)
      # B0's env step with and without full randomisation at 65,536 envs (no regression from the config refactor)
      timeout 300 python3 benchmarks/rand_gaps.py --device cuda:0 --num-envs 65536 --steps 200 --settings off,full \
        --json "$OUT/rand_gaps_check_gpu.json" 2>&1 | grep -v "^Module" | tail -8 ;;
    compare)
      # B0 env throughput of an older tree (REF, e.g. `git archive ae8dbf4 magwarp benchmarks | tar -x -C .devrun/old`)
      # beside this one, in the same run
      for tree in "${REF:-.devrun/old}" .; do
        echo "--- tree $tree"
        (cd "$tree" && PYTHONPATH=/tmp/site:$PWD timeout 200 python3 benchmarks/env_throughput.py --device cuda:0 \
          --no-magbotsim --envs magwarp/TrajectoryPlanningB0-v0 --num-envs 4096,65536,1048576 --steps 50 \
          --json "$OUT/env_throughput_$(basename "$(realpath "$tree")").json" 2>&1 | tail -8)
      done ;;
    graph)
      # #23: the fused B0 step (one CUDA graph) against the torch step, its physics and the bare-kernel ceiling
      timeout 300 python3 -m pytest -p no:cacheprovider -p no:warnings tests/test_graph_step.py \
        tests/test_kernels_task.py tests/test_ceiling.py 2>&1 | tail -4
      timeout 200 python3 benchmarks/ceiling.py --device cuda:0 --num-envs 4096,65536,1048576,2097152 \
        --json "$OUT/ceiling_gpu.json" 2>&1 | tail -8
      timeout 400 python3 benchmarks/env_throughput.py --devices cuda:0 --envs magwarp/TrajectoryPlanningB0-v0 \
        --num-envs 4096,16384,65536,262144,1048576,2097152 --compare-eager --no-magbotsim --adapters-at 0 --steps 50 \
        --json "$OUT/env_throughput_b0_graph_gpu.json" 2>&1 | tail -25 ;;
    push_dt)
      # #23: the push envs' fused step and the 2 ms mode (shipped policies' success at 1 and 2 ms; env vs raw mjw)
      timeout 300 python3 -m pytest -p no:cacheprovider -p no:warnings tests/test_push_step.py 2>&1 | tail -4
      timeout 550 python3 benchmarks/push_physics_dt.py --device cuda:0 --num-envs 4096,65536 \
        --json "$OUT/push_physics_dt_gpu.json" 2>&1 | tail -30 ;;
    ttt_b0|ttt_pushbox)
      # #20: time to target, one task, 3 seeds, confirmed by magwarp eval's 100 repeats (each under the 600 s limit)
      timeout 590 python3 benchmarks/time_to_target.py --tasks "${stage#ttt_}" --json "$OUT/$stage.json" 2>&1 | tail -20 ;;
    ttt_pusht_a|ttt_pusht_b|ttt_obstacles_a|ttt_obstacles_b)
      # #20: the 180 s tasks, seeds 0,1 (a) and 2 (b) in separate calls
      task=${stage#ttt_}; task=${task%_*}; seeds=0,1; [ "${stage##*_}" = b ] && seeds=2
      timeout 590 python3 benchmarks/time_to_target.py --tasks "$task" --seeds "$seeds" --json "$OUT/$stage.json" \
        2>&1 | tail -20 ;;
    suite)
      # Training runs of magwarp/training/paper.py side by side on the one GPU (RUNS=a,b,...; MINUTES, default 5),
      # with TESTS (pytest files) running meanwhile, into /tmp/runs (kept while the machine stays warm: suite_eval and
      # robustness read it). The device returns at most 8 files: the run folders (checkpoints left out) and logs come
      # back as one $OUT/suite.tgz
      mkdir -p /tmp/runs
      python3 -m magwarp.training.suite --runs "$RUNS" --minutes "${MINUTES:-5}" \
        --stop-after "$(python3 -c "print(int(${MINUTES:-5} * 60 + 80))")" --work /tmp/runs > /tmp/runs/suite.log 2>&1 &
      train_pid=$!
      if [ -n "${TESTS:-}" ]; then
        timeout 400 python3 -X faulthandler -m pytest -p no:cacheprovider -p no:warnings $TESTS \
          > /tmp/runs/pytest_gpu.log 2>&1
        grep -E "FAIL|ERROR|Fatal|passed|failed" /tmp/runs/pytest_gpu.log | tail -12
      fi
      wait $train_pid; tail -14 /tmp/runs/suite.log
      tar czf "$OUT/suite.tgz" -C /tmp --exclude=checkpoint.pt runs ;;
    swarm_study)
      # #18: the planner and each trained swarm policy of RUNS (from the suite stage's /tmp/runs) on the same worlds
      # at 256 / 1024 / 4096 movers (SECONDS_SIM of simulated time each, default 40): goals/s per mover, collisions;
      # one swarm_study_<run>_gpu.json / .png per run
      for run in ${RUNS//,/ }; do
        timeout $((580 / $(echo ${RUNS//,/ } | wc -w))) python3 benchmarks/swarm_study.py --device cuda:0 \
          --movers ${STUDY_MOVERS:-256 1024 4096} --seconds ${SECONDS_SIM:-40} --policy "/tmp/runs/$run/policy.pt" \
          --json "$OUT/swarm_study_${run}_gpu.json" --png "$OUT/swarm_study_${run}_gpu.png" 2>&1 \
          | grep --line-buffered -v "^Module"  # (no tail: a run cut by its timeout still shows its rows)
      done ;;
    suite_eval)
      # magwarp eval of each run of RUNS left in /tmp/runs by the suite stage, and of the task's scripted baseline
      # (200 episodes x 10 repeats, the run's eval options), all side by side; JSON into the run folders and the tarball
      for name in ${RUNS//,/ }; do
        read -r env kw < <(python3 -c "import json; from magwarp.training.paper import PAPER_RUNS as R; \
r = R['$name']; print(r.env_id, json.dumps(r.eval_kwargs, separators=(',', ':')))")
        for pol in "/tmp/runs/$name/policy.pt" scripted; do
          timeout 300 python3 -m magwarp eval "$env" --policy "$pol" --env-kwargs "$kw" --episodes 200 \
            --repeats 10 --device cuda:0 --json "/tmp/runs/$name/eval_$(basename "$pol" .pt).json" \
            > "/tmp/runs/$name/eval_$(basename "$pol" .pt).log" 2>&1 &
        done
        # a residual env's run also writes its policy for the base env (policy_<base>.pt, e.g. CoopPush-v0's): on the
        # env its metadata names, with the options it stores
        for pol in /tmp/runs/"$name"/policy_*.pt; do
          [ -f "$pol" ] || continue
          penv=$(python3 -c "from magwarp.training.policy import policy_metadata as m; print(m('$pol')['env_id'])")
          stem="/tmp/runs/$name/eval_$(basename "$pol" .pt)"
          timeout 300 python3 -m magwarp eval "$penv" --policy "$pol" --episodes 200 --repeats 10 --device cuda:0 \
            --json "$stem.json" > "$stem.log" 2>&1 &
        done
      done
      wait
      for f in /tmp/runs/*/eval_*.log; do echo "--- $f"; grep -E "Success|Coll|Energy|Error|error" "$f" | head -5; done
      tar czf "$OUT/suite.tgz" -C /tmp --exclude=checkpoint.pt runs ;;
    night_eval)
      # Not timed, so side by side: suite_eval of RUNS, the robustness table (REPEATS, default 10), the levitation
      # policy against its PD (when lev_residual was trained) and the swarm planner at 256/1024/4096 movers
      bash "$0" suite_eval > "$OUT/suite_eval.log" 2>&1 &
      REPEATS=${REPEATS:-10} bash "$0" robustness > "$OUT/robustness.log" 2>&1 &
      bash "$0" lev_eval > "$OUT/levitation_policy.log" 2>&1 &
      timeout 560 python3 benchmarks/swarm.py --device cuda:0 --planner-only --json "$OUT/swarm_planner_gpu.json" \
        > "$OUT/planner.log" 2>&1 &
      wait
      for f in suite_eval robustness levitation_policy planner; do
        [ -f "$OUT/$f.log" ] && { echo "--- $f"; tail -25 "$OUT/$f.log"; }
      done ;;
    lev_eval)
      # #17: each levitation residual run left in /tmp/runs by the suite stage (lev_residual, lev_residual_soft, ...)
      # against the shipped PD and its frequency sweep on the same 4096 worlds, one run after the other (the policy's
      # env options come from its policy.pt); JSON levitation_policy_gpu.json (lev_residual) or
      # levitation_policy_<run>_gpu.json
      for pol in /tmp/runs/lev_residual*/policy.pt; do
        [ -f "$pol" ] || continue
        name=$(basename "$(dirname "$pol")"); tag=${name#lev_residual}
        echo "--- $name"
        timeout 280 python3 benchmarks/levitation_policy.py --policy "$pol" --device cuda:0 --envs 4096 \
          --json "$OUT/levitation_policy${tag:+_${name}}_gpu.json" 2>&1 | grep -v "^Module" | tail -20
      done ;;
    planner)
      # #18: the scripted planner (lanes, safety filter) at 256 / 1024 / 4096 movers (2000 steps each: goal share in 40 s)
      timeout 590 python3 benchmarks/swarm.py --device cuda:0 --planner-only --json "$OUT/swarm_planner_gpu.json" \
        2>&1 | tail -20 ;;
    swarm_obs)
      # #18: the observation kernel alone at 16,384 worlds x 64 and x 100 movers, by variant (chain/merge into the
      # slots, tile walk/closed-form rays, grid) and by part (full, no rays, no neighbours, own
      # state only), each also as a replayed CUDA graph (graph_ms: device time without the host's per-call work)
      timeout 300 python3 benchmarks/swarm_obs.py --device cuda:0 --json "$OUT/swarm_obs_gpu.json" 2>&1 \
        | grep -v "^Module" | tail -70 ;;
    swarm_place)
      # #18: the placement alone at 16384 x 64 and x 100 by launch shape of its rounds (Placer.lanes), with a
      # bit-for-bit check of the spots against the default shape (match)
      timeout 200 python3 benchmarks/swarm_place.py --device cuda:0 --json "$OUT/swarm_place_gpu.json" 2>&1 \
        | grep -v "^Module" | tail -30 ;;
    swarm_fused)
      # #18: the fused swarm env step at many worlds (FUSED_MOVERS, default 100; FUSED_WORLDS, default 1024-16384
      # worlds), split by phase; the observation and the respawn placement alone by search; the motion uncapped
      timeout 560 python3 benchmarks/swarm.py --device cuda:0 --fused-sweep --fused-movers ${FUSED_MOVERS:-100} \
        --fused-worlds ${FUSED_WORLDS:-1024 4096 8192 16384} --json "$OUT/swarm_fused_gpu_${FUSED_MOVERS:-100}.json" \
        2>&1 | grep -v "^Module" | tail -40 ;;
    place_scan)
      # #18: the placement's scan shapes (Placer.scan: serial, chunked), the lane shape and the grid alone at
      # 16,384 worlds x 64-256 movers (bit for bit against serial), then the fused swarm step at
      # 64 movers with each scan shape (MAGWARP_PLACE_SCAN)
      timeout 300 python3 benchmarks/swarm_place.py --device cuda:0 --lanes 8 --movers 64 100 160 256 \
        --json "$OUT/swarm_place_scan_gpu.json" 2>&1 | grep -v "^Module" | tail -40
      for shape in serial chunked; do
        MAGWARP_PLACE_SCAN=$shape timeout 300 python3 benchmarks/swarm.py --device cuda:0 --fused-sweep \
          --fused-movers 64 --fused-worlds 16384 --json "$OUT/swarm_fused_scan_${shape}_64_gpu.json" 2>&1 \
          | grep -v "^Module" | tail -6
      done ;;
    followup)
      # The placement's lane shape (#18: Placer.lanes) and the observation's variants against the defaults, bit for
      # bit; then the swarm step at 64, 100 and 256 movers per world with the defaults of the day (about 4 minutes)
      bash "$0" swarm_place swarm_obs
      for movers in 64 100 256; do
        FUSED_MOVERS=$movers FUSED_WORLDS=16384 bash "$0" swarm_fused
      done ;;
    ncu|ncu18|ncu17)
      # Nsight Compute (benchmarks/ncu_target.py drives one env or cycle; only its profiled steps count): stall
      # reasons, occupancy, pipe utilisation, instruction mix. ncu: #18's fused swarm step kernel (16,384 worlds of 64
      # / 100 / 256 movers) and #24's B0 physics kernel and reset firing at 65,536 envs (no randomisation / full);
      # ncu18: the swarm step only; ncu17: the fast magnetic cycle's two launches at 1M movers
      NCU=$(command -v ncu || ls /opt/nvidia/nsight-compute/*/ncu 2>/dev/null | head -1)
      SECTIONS="--section SpeedOfLight --section Occupancy --section LaunchStats --section WarpStateStats \
        --section SchedulerStats --section ComputeWorkloadAnalysis --section InstructionStats \
        --section MemoryWorkloadAnalysis --section SourceCounters \
        --metrics regex:smsp__average_warps_issue_stalled_.*_per_issue_active\.ratio"  # every stall reason's cycles
      run_ncu() {  # name, kernel regex, launches, driver args
        local name=$1 regex=$2 count=$3; shift 3
        timeout 300 "$NCU" --profile-from-start off --clock-control none --kernel-name "regex:$regex" \
          --launch-count $count $SECTIONS python3 benchmarks/ncu_target.py "$@" > "$OUT/ncu_$name.txt" 2>&1
        echo "$name rc=$? $(grep -cE 'Section:' "$OUT/ncu_$name.txt") sections"
        grep -E "Duration|Registers Per|Achieved Occupancy|Theoretical Occupancy|Warp Cycles Per Issued|Issued Ipc|\
Stall|Executed Instructions  |FP64|Block Limit Reg" "$OUT/ncu_$name.txt" | head -$((20 * count))
      }
      if [ "$stage" != ncu17 ]; then
        for movers in ${NCU_MOVERS:-64 100 256}; do
          run_ncu swarm_$movers swarm_step 1 swarm --movers $movers --worlds 16384 --load ${NCU_LOAD:-seek}
          if [ -n "${NCU_OBS:-}" ]; then  # the observation kernel of the same step
            run_ncu swarm_obs_$movers observe 1 swarm --movers $movers --worlds 16384 --load ${NCU_LOAD:-seek}
          fi
        done
      fi
      if [ "$stage" = ncu ]; then
        for setting in off full; do
          run_ncu b0_$setting fused_movers 1 b0 --envs 65536 --setting $setting
        done
        run_ncu b0_fire fire_terms 1 b0 --envs 65536 --setting full
      fi
      if [ "$stage" = ncu17 ]; then
        run_ncu mag_fast 'first_kernel|rest_kernel' 2 magnetics --movers ${NCU_MAG_MOVERS:-1000000}
      fi ;;
    rand_gaps)
      # #24: B0's randomisation cost by setting at 16,384 and 65,536 envs: env step, graph replay alone, kernel time and
      # the gaps between kernels (full_nofire: full with the reset firing left out of the step)
      timeout 400 python3 benchmarks/rand_gaps.py --device cuda:0 --num-envs 65536,16384 --steps 200 \
        --json "$OUT/rand_gaps_gpu.json" 2>&1 | grep -v "^Module" | tail -16 ;;
    branches)
      # #24: the fused B0 step's two graph branches (MAGWARP_STEP_BRANCHES: the torch draws beside the physics, the
      # reset firing beside the reset and observation kernels) off and on, twice each, at 65,536 envs, off / full
      # randomisation; then the CUDA tests of the branched step (graph == torch step bit for bit)
      timeout 200 python3 -X faulthandler -m pytest -p no:cacheprovider -p no:warnings tests/test_side_branch.py \
        tests/test_graph_step.py > "$OUT/pytest_branches_gpu.log" 2>&1
      grep -E "FAIL|ERROR|Fatal|Segmentation|passed|failed" "$OUT/pytest_branches_gpu.log" | tail -12
      for round in 1 2; do
        for b in off on; do
          MAGWARP_STEP_BRANCHES=$b timeout 200 python3 benchmarks/rand_gaps.py --device cuda:0 --num-envs 65536 \
            --steps 200 --settings off,full --json "$OUT/rand_gaps_branches_${b}_${round}_gpu.json" 2>&1 \
            | grep -v "^Module" | tail -4
        done
      done ;;
    fire_cost)
      # #24: the B0 reset firing alone (one graph of 20 firings) at 65,536 and 16,384 envs, masks of 0-100 % of the
      # worlds: each candidate way of firing (checked bit for bit against today's on the device first: same_bits) and
      # the diagnostic kernels that split its time
      timeout 200 python3 benchmarks/fire_cost.py --device cuda:0 --json "$OUT/fire_cost_gpu.json" 2>&1 \
        | grep -v "^Module" | tail -30 ;;
    rand_profile)
      # #24: B0's randomisation cost at 4096/16384/65536 envs with each setting's per-kernel CUDA time at 65,536
      timeout 400 python3 benchmarks/randomization.py --device cuda:0 --num-envs 4096,16384,65536 \
        --env magwarp/TrajectoryPlanningB0-v0 --kernel-times 65536 --json "$OUT/randomization_fused_gpu.json" \
        2>&1 | grep -v "^Module" | tail -16 ;;
    register_rows)
      # #24: B0's randomisation cost with each register-row variant of the general fused kernel (one JSON each)
      for rows in all f32 sizes none; do
        timeout 180 python3 benchmarks/randomization.py --device cuda:0 --num-envs 16384,65536 \
          --env magwarp/TrajectoryPlanningB0-v0 --register-rows $rows --json "$OUT/randomization_rows_$rows.json" \
          2>&1 | grep -E "^magwarp" | tail -6
      done ;;
    rand_rows)
      # #24: B0's randomisation cost at 65,536 envs split into its parts (terms, + latency, + sensors, full) for each
      # register-row variant of the general fused kernel (ROWS, default "f32 none"; one JSON each)
      for rows in ${ROWS:-f32 none}; do
        timeout 170 python3 benchmarks/randomization.py --device cuda:0 --num-envs 65536 \
          --env magwarp/TrajectoryPlanningB0-v0 --register-rows $rows --settings terms,latency,sensors,full \
          --json "$OUT/randomization_parts_${rows}_gpu.json" 2>&1 | grep -E "^  cuda.*num_envs" | tail -6
      done ;;
    small_world_kernels)
      # #24: the fused small-world step's two launch shapes: B0 physics per step (nominal, per-world rows, + latency)
      # and bitwise agreement, registers vs movers for each block size (BLOCKS), register cap (MAXREGS, 0: none) and
      # place of the general variant's body rows (ROWS); each setting compiles up to three kernels: split larger sweeps
      # over calls (the kernel cache stays while the machine is warm), e.g. MAXREGS=0 in a second call
      timeout 590 python3 benchmarks/small_world_kernels.py --device cuda:0 --num-envs 16384,65536 \
        --blocks "${BLOCKS:-96}" --maxregs "${MAXREGS:-168}" --rows "${ROWS:-shared,registers}" \
        --json "$OUT/small_world_kernels${TAG:+_$TAG}_gpu.json" \
        2>&1 | grep -E "^  cuda|^cuda" | tail -40 ;;
    small_world)
      # #24: B0's randomisation cost with each launch shape of the fused small-world step (KERNELS, default
      # "registers movers"; the movers shape with SMALL_BLOCK threads a block, default 96, and a cap of SMALL_MAXREG
      # registers, default 168, 0: none)
      for k in ${KERNELS:-registers movers}; do
        timeout 290 python3 benchmarks/randomization.py --device cuda:0 --num-envs 16384,65536 \
          --env magwarp/TrajectoryPlanningB0-v0 --settings terms,latency,full --kernel-times 65536 \
          --small-world-kernel $k --small-world-block "${SMALL_BLOCK:-96}" \
          --small-world-maxreg "${SMALL_MAXREG:-168}" \
          --json "$OUT/randomization_small_world_${k}_gpu.json" 2>&1 | grep -E "^  cuda" | tail -12
      done ;;
    robustness)
      # #24: the shipped B0 policy, the shipped randomisation-trained one (pretrained:b0_ppo_sim2real) and any
      # randomisation-trained runs in /tmp/runs (paper.py runs b0_ppo_dr and b0_ppo_dr_ft, trained by the suite
      # stage: RUNS=b0_ppo_dr,b0_ppo_dr_ft), nominal and under each condition
      POL=(--policy pretrained:b0_ppo --policy pretrained:b0_ppo_sim2real)
      for r in b0_ppo_dr b0_ppo_dr_ft; do
        [ -f "/tmp/runs/$r/policy.pt" ] && POL+=(--policy "/tmp/runs/$r/policy.pt")
      done
      timeout 590 python3 benchmarks/robustness.py --device cuda:0 --episodes 100 --repeats "${REPEATS:-100}" \
        "${POL[@]}" --conditions nominal,terms,latency,sensors,randomised,dropout --json "$OUT/robustness_gpu.json" \
        2>&1 | tail -20 ;;
    *) echo "unknown stage $stage"; exit 2 ;;
  esac
done
log "done"
