#!/usr/bin/env bash
# Lever measurements for time to target on the device machine (one call each, < 10 minutes):
#   export PYTHONPATH=/tmp/site:$PWD; bash benchmarks/gpu_levers.sh RUN "NAME:SECONDS:OPTIONS" ...
# RUN: a PAPER_RUNS name. Each NAME trains RUN from scratch for SECONDS (process time) with OPTIONS (training module
# options, e.g. --profile, --cuda-graph on, --overlap off) and prints its log lines, profile, periodic evaluations and
# summary (env-steps/s, updates, start-up milestones in seconds since the process started). An option written
# @KEY=VALUE (VALUE in JSON) is merged into the training env's options only (e.g. @physics_dt=0.002: the evaluation
# env keeps the paper run's). The run's kernels are compiled into the cache first (WARM=0 skips it), so that no run's
# budget pays for a cold compile. E.g. SAC + HER on Push-Box with and without the env step overlapping the updates,
# and with the periodic evaluation on a stream of its own too, 90 s each (about 7.5 minutes with a cold kernel cache,
# 5 with a warm one):
#   bash benchmarks/gpu_levers.sh pushbox_sac "off:90:--overlap off --eval-every 15 --eval-envs 256" \
#     "on:90:--overlap on --eval-every 15 --eval-envs 256" \
#     "async:90:--overlap on --async-eval on --eval-every 15 --eval-envs 256"
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
if [ "${WARM:-1}" = 1 ]; then
  python3 -c "
import sys, types; sys.path.insert(0, 'benchmarks')
from time_to_target import warm_kernels
print(f'kernels compiled / loaded in {warm_kernels(types.SimpleNamespace(run=\"$RUN\"), \"cuda:0\"):.1f} s')"
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
  rc=$?
  echo "--- $name ($opts): exit $rc, $(( $(date +%s) - t0 )) s"
  [ $rc = 0 ] || grep -v "^Module" $W/$name.log | tail -25
  grep -E "^step|profile|time to target|Error|error" $W/$name.log | tail -14
  python3 -c "
import json; d = json.load(open('$W/$name/run.json'))
print('evals:', ' '.join(f\"{e['process_s']:.0f}s:{100*e['success_rate']:.1f}%/{e['collisions_per_1k_goals']:.1f}\" for e in d['evals']))
print('evaluation seconds:', round(sum(e.get('eval_s', 0.0) for e in d['evals']), 1))
print('summary:', {k: v for k, v in d['summary'].items() if k != 'profile'})" 2>&1 | tail -4
  cp $W/$name/run.json "$OUT/$name.json" 2>/dev/null
done
