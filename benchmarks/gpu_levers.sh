#!/usr/bin/env bash
# Lever measurements for time to target on the device machine (one call each, < 10 minutes):
#   export PYTHONPATH=/tmp/site:$PWD; bash benchmarks/gpu_levers.sh RUN "NAME:SECONDS:OPTIONS" ...
# RUN: a PAPER_RUNS name. Each NAME trains RUN from scratch for SECONDS (process time) with OPTIONS (training module
# options, e.g. --profile, --cuda-graph on) and prints its log lines, profile and periodic evaluations. An option
# written @KEY=VALUE (VALUE in JSON) is merged into the training env's options only (e.g. @physics_dt=0.002: the
# evaluation env keeps the paper run's). WARM=1 compiles the run's env kernels first (time_to_target's warm step), so
# that no run's clock pays the cold compile.
set -u
OUT=${OUT:-/tmp/out}
mkdir -p "$OUT"
export WARP_CACHE_PATH=/tmp/warp_cache PYTHONUNBUFFERED=1
W=/tmp/lev
mkdir -p $W
RUN=$1; shift
read -r MOD ENV TK EK < <(python3 -c "
from magwarp.training.paper import PAPER_RUNS as R; r = R['$RUN']; print(r.module, r.env_id, r.train_json(), r.eval_json())")
echo "=== $RUN: $MOD $ENV ($(date -u +%H:%M:%S))"
if [ "${WARM:-0}" = 1 ]; then
  t0=$(date +%s)
  python3 -c "import sys; sys.path.insert(0, 'benchmarks'); import time_to_target as t
from magwarp.training.paper import PAPER_RUNS as R; print('warm', t.warm_kernels(t.Task('$RUN', 0, 0), 'cuda:0'))"
  echo "--- warm: $(( $(date +%s) - t0 )) s"
fi
for spec in "$@"; do
  name=${spec%%:*}; rest=${spec#*:}; secs=${rest%%:*}; opts=${rest#*:}
  tk=$(python3 -c "
import json, sys; d = json.loads(sys.argv[1])
for tok in sys.argv[2].split():
    if tok.startswith('@'):
        k, v = tok[1:].split('=', 1); d[k] = json.loads(v)
print(json.dumps(d, separators=(',', ':')))" "$TK" "$opts")
  opts=$(echo "$opts" | tr ' ' '\n' | grep -v '^@' | tr '\n' ' ')
  t0=$(date +%s)
  python3 -m $MOD --env-id $ENV --env-kwargs "$tk" --eval-env-kwargs "$EK" --device cuda:0 --out $W/$name \
    --stop-after $secs --no-progress --eval-steps 0 --checkpoint-every 1e9 --log-every 5 --eval-every 5 \
    --eval-envs 2048 $opts > $W/$name.log 2>&1
  echo "--- $name ($opts): exit $?, $(( $(date +%s) - t0 )) s"
  grep -E "^step|profile|time to target|Error|error" $W/$name.log | tail -14
  python3 -c "
import json; d = json.load(open('$W/$name/run.json'))
print('evals:', ' '.join(f\"{e['process_s']:.0f}s:{100*e['success_rate']:.1f}%/{e['collisions_per_1k_goals']:.1f}\" for e in d['evals']))
print('summary:', {k: v for k, v in d['summary'].items() if k != 'profile'})" 2>&1 | tail -3
  cp $W/$name/run.json "$OUT/$name.json" 2>/dev/null
done
