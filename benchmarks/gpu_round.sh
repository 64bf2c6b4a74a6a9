#!/usr/bin/env bash
# The GPU work of one session (issues #16-#21), in a few calls on the device machine (see the device tool's
# METHOD.md). Each stage checks or times several sizes and writes JSON and logs under $OUT. Usage there, after the
# wheels are staged (python3 ../shared/tools/device_wheels.py magbotsim==1.3.0 magpylib==6.3.0 shapely==2.2.0):
#   export PYTHONPATH=/tmp/site:$PWD; bash benchmarks/gpu_round.sh STAGE
# Stages: tests (GPU/CPU agreement of the new kernels), queries (collision queries), magnetics, swarm, perf
# (scaling and B0 env throughput), magbots, distributed, sim2real (latency/sensor models' cost), randomization,
# swarm_render, graph (#23: the fused B0 step, ceiling), push_dt (#23: push envs), ttt_* (#20), planner (#18),
# train_dr and robustness (#24), compare (B0 env throughput of an older tree beside this one).
set -u
source "$(dirname "$0")/gpu_common.sh"
for stage in "$@"; do
  log "$stage"
  case "$stage" in
    tests)
      timeout 420 python3 -X faulthandler -m pytest -q -p no:cacheprovider -p no:warnings tests/test_sim.py \
        tests/test_sim_starts.py tests/test_kernels_dynamics.py tests/test_kernels_collision.py \
        tests/test_collision_queries.py tests/test_swarm_placement.py tests/test_swarm_observations.py \
        tests/test_magnetics_exact.py tests/test_magnetics_commutation.py tests/test_magnetics_fast.py \
        tests/test_magnetics_table.py \
        tests/test_reliability.py tests/test_sim_errors.py tests/test_sim2real_models.py \
        > "$OUT/pytest_gpu.log" 2>&1
      grep -E "FAIL|ERROR|Fatal|Segmentation|passed|failed" "$OUT/pytest_gpu.log" | tail -25 ;;
    queries)
      timeout 400 python3 benchmarks/collision_queries.py --devices cpu cuda:0 --max-poses-cpu 1e5 \
        --json "$OUT/collision_queries_gpu.json" 2>&1 | tail -40 ;;
    magnetics)
      timeout 500 python3 benchmarks/magnetics.py --json "$OUT/magnetics_gpu.json" 2>&1 | tail -45 ;;
    swarm)
      timeout 500 python3 benchmarks/swarm.py --device cuda:0 --json "$OUT/swarm_gpu.json" 2>&1 | tail -40 ;;
    perf)
      timeout 250 python3 benchmarks/scaling.py --device cuda:0 --no-magbotsim --steps 100 \
        --json "$OUT/scaling_gpu.json" 2>&1 | tail -25
      timeout 300 python3 benchmarks/env_throughput.py --device cuda:0 --no-magbotsim \
        --envs magwarp/TrajectoryPlanningB0-v0 --num-envs 4096,65536,1048576 --steps 50 \
        --json "$OUT/env_throughput_gpu.json" 2>&1 | tail -20 ;;
    magbots)
      timeout 500 python3 benchmarks/magbots.py --json "$OUT/magbots_gpu.json" 2>&1 | tail -30 ;;
    distributed)
      timeout 400 python3 benchmarks/distributed.py --seconds 20 --json "$OUT/distributed_gpu.json" 2>&1 | tail -30 ;;
    sim2real)
      timeout 400 python3 benchmarks/sim2real_models.py --device cuda:0 --num-envs 4096,65536,262144,1048576 \
        --json "$OUT/sim2real_models_gpu.json" 2>&1 | tail -25 ;;
    randomization)
      timeout 120 python3 -m pytest -q -p no:cacheprovider -p no:warnings tests/test_randomization.py -k no_host_sync \
        2>&1 | tail -3
      timeout 400 python3 benchmarks/randomization.py --device cuda:0 --num-envs 4096,16384,65536 \
        --json "$OUT/randomization_gpu.json" 2>&1 | tail -15 ;;
    swarm_render)
      timeout 300 python3 benchmarks/swarm_render.py --json "$OUT/swarm_render_gpu.json" 2>&1 | tail -20 ;;
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
      timeout 300 python3 -m pytest -q -p no:cacheprovider -p no:warnings tests/test_graph_step.py \
        tests/test_kernels_task.py tests/test_ceiling.py 2>&1 | tail -4
      timeout 200 python3 benchmarks/ceiling.py --device cuda:0 --num-envs 4096,65536,1048576,2097152 \
        --json "$OUT/ceiling_gpu.json" 2>&1 | tail -8
      timeout 400 python3 benchmarks/env_throughput.py --devices cuda:0 --envs magwarp/TrajectoryPlanningB0-v0 \
        --num-envs 4096,16384,65536,262144,1048576,2097152 --compare-eager --no-magbotsim --adapters-at 0 --steps 50 \
        --json "$OUT/env_throughput_b0_graph_gpu.json" 2>&1 | tail -25 ;;
    push_dt)
      # #23: the push envs' fused step and the 2 ms mode (shipped policies' success at 1 and 2 ms; env vs raw mjw)
      timeout 300 python3 -m pytest -q -p no:cacheprovider -p no:warnings tests/test_push_step.py 2>&1 | tail -4
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
    planner)
      # #18: the scripted planner (lanes, safety filter) at 256 / 1024 / 4096 movers (2000 steps each: goal share in 40 s)
      timeout 590 python3 benchmarks/swarm.py --device cuda:0 --planner-only --json "$OUT/swarm_planner_gpu.json" \
        2>&1 | tail -20 ;;
    train_dr)
      # #24: a B0 PPO policy trained with the sim2real randomisation, latency and sensor models (5 minutes)
      B0='"num_cycles":120,"collision_shape":"box","collision_size":[0.09,0.09],"mover_params":{"size":[0.0565,0.0565,0.006],"mass":0.63}'
      DR='"randomization":"sim2real","actuation":{"latency_range":[0,5]},"sensors":{"pos_bias_std":0.001,"vel_bias_std":0.01,"pos_noise_std":0.0005,"vel_noise_std":0.005,"dropout_prob":0.02}'
      timeout 590 python3 -m magwarp.training.ppo --env-id magwarp/TrajectoryPlanningB0-v0 --device cuda:0 \
        --minutes 5 --no-progress --out "$OUT/b0_ppo_dr" --env-kwargs "{$B0,\"max_episode_steps\":40,$DR}" \
        --eval-env-kwargs "{$B0,$DR}" 2>&1 | tail -15 ;;
    robustness)
      # #24: the shipped B0 policy and the randomisation-trained one, nominal and under randomisation
      timeout 590 python3 benchmarks/robustness.py --device cuda:0 --episodes 100 --repeats 100 \
        --policy pretrained:b0_ppo --policy "${DR_POLICY:-$OUT/b0_ppo_dr/policy.pt}" \
        --conditions nominal,terms,latency,sensors,randomised --json "$OUT/robustness_gpu.json" 2>&1 | tail -20 ;;
    *) echo "unknown stage $stage"; exit 2 ;;
  esac
done
log "done"
