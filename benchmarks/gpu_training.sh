#!/usr/bin/env bash
# The paper's training runs on the device machine, across calls of at most 10 minutes each:
#   export PYTHONPATH=/tmp/site:$PWD MAGWARP_COMMIT=<sha>
#   bash benchmarks/gpu_training.sh check                  # CUDA training tests + where a step's time goes
#   bash benchmarks/gpu_training.sh start RUNS MINUTES [STOP_AFTER_S]  # the suite, detached (outlives this call)
#   bash benchmarks/gpu_training.sh wait SECONDS           # until the suite ends (or SECONDS pass): progress lines
#   bash benchmarks/gpu_training.sh eval RUNS              # magwarp eval (100 repeats) of each run, packed into $OUT
# RUNS: comma separated names of magwarp.training.paper.PAPER_RUNS. The suite writes /tmp/runs/<run>/ and its log.
set -u
OUT=${OUT:-/tmp/out}
mkdir -p "$OUT"
export WARP_CACHE_PATH=/tmp/warp_cache PYTHONUNBUFFERED=1
WORK=/tmp/runs
log() { echo "=== $* ($(date -u +%H:%M:%S))"; }
case "${1:-check}" in
check)
  log "CUDA training tests"
  timeout 240 python3 -m pytest -p no:cacheprovider tests/test_training.py 2>&1 | tail -4
  log "training profile"
  timeout 300 python3 benchmarks/training_profile.py --device cuda:0 --json "$OUT/training_profile_gpu.json" 2>&1 \
    | grep -E "^\||^#"
  ;;
start)
  mkdir -p $WORK
  cap=()
  [ -n "${4:-}" ] && cap=(--stop-after "$4")
  setsid nohup python3 -m magwarp.training.suite --runs "$2" --minutes "$3" "${cap[@]}" --work $WORK \
    > $WORK/suite.log 2>&1 < /dev/null &
  sleep 75
  log "started $2 for $3 minutes"; cat $WORK/suite.log; tail -n 3 $WORK/*.log
  ;;
wait)
  end=$((SECONDS + $2))
  while [ $SECONDS -lt $end ] && ! grep -q "^| run |" $WORK/suite.log 2>/dev/null; do sleep 10; done
  log "progress"
  for f in $WORK/*/progress.csv; do echo "$f: $(head -1 "$f")"; echo "    $(tail -1 "$f")"; done
  grep -A8 "^| run |" $WORK/suite.log || true
  ;;
eval)
  for run in ${2//,/ }; do
    env_id=$(python3 -c "from magwarp.training.paper import PAPER_RUNS as R; print(R['$run'].env_id)")
    episodes=200
    case $env_id in *Trajectory*) episodes=100 ;; esac
    log "eval $run ($env_id)"
    timeout 150 python3 -m magwarp eval "$env_id" --policy $WORK/$run/policy.pt --episodes $episodes --repeats 100 \
      --device cuda:0 --json "$WORK/$run/eval_gpu.json" | grep -E "env options|Success Rate|Collisions|wall"
    tar czf "$OUT/$run.tgz" -C $WORK "$run" "$run.log"
  done
  cp $WORK/suite.log "$OUT/" 2>/dev/null
  ;;
esac
log "done"
