"""Robustness of trained B0 policies to the sim2real gap: success and collisions per 1000 goals evaluated on the
nominal env and under domain randomisation with action latency and sensor noise, in one table.

    python benchmarks/robustness.py --device cuda:0 --repeats 100 --json robustness_gpu.json
    python benchmarks/robustness.py --device cuda:0 --policy pretrained:b0_ppo --policy runs/b0_ppo_dr/policy.pt

Each policy is evaluated with the options it records (its ``eval_env_kwargs``, as ``magwarp eval`` does), with the
randomisation, latency and sensor options stripped (``nominal``), then with :data:`RANDOMIZED` added (``randomised``:
the planar ``"sim2real"`` preset of :data:`magwarp.envs.randomization.PRESETS`, a latency drawn in 0..5 cycles and
sensor bias and noise, per world at every reset). ``loss`` is the success rate's drop from nominal to randomised
(points). ``--conditions nominal,terms,latency,sensors,randomised`` also evaluates each part alone (``dropout``: 2 %
dropped readings alone, a stress test outside the randomised condition). The issue's goal: a policy trained with
randomisation loses at most 1 point; the shipped one loses more.
``--smoke`` runs a tiny CPU evaluation (2 episodes, 1 repeat, 5 steps) to check the script.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from common import finish, start_run  # noqa: E402

from magwarp.training.paper import SIM2REAL  # noqa: E402

ENV_ID = "magwarp/TrajectoryPlanningB0-v0"
#: The randomised condition: the planar "sim2real" preset (its ranges and where they come from:
#: :data:`magwarp.envs.randomization.PRESETS`), an action latency of 0..5 control cycles and sensor bias and noise,
#: as the randomisation-trained runs of :mod:`magwarp.training.paper` (``b0_ppo_dr``, ``b0_ppo_dr_ft``) see it
#: (:data:`magwarp.training.paper.SIM2REAL`, which says where each figure comes from).
RANDOMIZED = SIM2REAL
DROPOUT = {"sensors": {"dropout_prob": 0.02}}
SIM2REAL_KEYS = ("randomization", "actuation", "sensors", "std_noise")
#: evaluation conditions (``--conditions``): the options added to the policy's nominal ones
CONDITIONS = {"nominal": {}, "terms": {"randomization": RANDOMIZED["randomization"]},
              "latency": {"actuation": RANDOMIZED["actuation"]}, "sensors": {"sensors": RANDOMIZED["sensors"]},
              "randomised": RANDOMIZED, "dropout": DROPOUT}


def stored_eval_kwargs(policy: str) -> dict:
    """The env options a policy file records for evaluation (``eval_env_kwargs``), without the sim2real ones."""
    from magwarp.training.common import parse_env_kwargs
    from magwarp.training.policy import policy_metadata
    from magwarp.training.pretrained import resolve_policy

    path = resolve_policy(policy)
    try:
        stored = policy_metadata(path).get("eval_env_kwargs")
    except Exception:  # noqa: BLE001 - not a TorchScript file: it records no options
        stored = None
    kwargs = parse_env_kwargs(stored) if isinstance(stored, str) else dict(stored or {})
    return {k: v for k, v in kwargs.items() if k not in SIM2REAL_KEYS}


def row_value(result, key: str) -> tuple[float, float]:
    row = next(r for r in result.rows if r.key == key)
    return row.mean, row.std


def main(argv=None) -> int:
    from magwarp.evaluate import evaluate

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default=None, help="cpu or cuda:N (default: cuda:0 when present, else cpu)")
    p.add_argument("--policy", action="append", default=None,
                   help="policy to evaluate (repeatable; default: pretrained:b0_ppo)")
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--repeats", type=int, default=100)
    p.add_argument("--steps", type=int, default=None, help="env steps per world (default: 10 s)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--conditions", default="nominal,randomised",
                   help=f"comma-separated, from {', '.join(CONDITIONS)} (terms, latency, sensors: one part of "
                   "randomised alone)")
    p.add_argument("--smoke", action="store_true", help="tiny CPU run that only checks the script")
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    conditions = args.conditions.split(",")
    bad = [c for c in conditions if c not in CONDITIONS]
    if bad or conditions[0] != "nominal":
        p.error(f"--conditions must start with nominal and name only {', '.join(CONDITIONS)}, got {args.conditions!r}")
    if args.smoke:
        args.device, args.episodes, args.repeats, args.steps = "cpu", 2, 1, 5
    info, devices = start_run(args.device)
    device = devices[-1]  # the GPU when there is one
    policies = args.policy or ["pretrained:b0_ppo"]
    rows: list[dict] = []
    for policy in policies:
        nominal = stored_eval_kwargs(policy)
        success = {}
        for condition in conditions:
            kwargs = {**nominal, **CONDITIONS[condition]}
            res = evaluate(ENV_ID, policy, args.episodes, args.repeats, device=device, steps=args.steps,
                           seed=args.seed, env_kwargs=kwargs, progress=False)
            s, s_std = row_value(res, "success_rate")
            c, c_std = row_value(res, "collisions_per_1k")
            success[condition] = s
            rows.append({"policy": policy, "eval": condition, "success_pct": s, "success_std": s_std,
                         "collisions_per_1k": c, "collisions_std": c_std, "loss_pts": s - success["nominal"],
                         "device": device, "episodes": args.episodes, "repeats": args.repeats,
                         "env_kwargs": json.dumps(kwargs, default=str)})
            print(f"  {policy} {condition}: success {s:.2f} +- {s_std:.2f} %, {c:.2f} collisions per 1000 goals",
                  flush=True)
    columns = ["policy", "eval", ("success_pct", "success %"), ("success_std", "±"),
               ("collisions_per_1k", "collisions / 1000 goals"), ("collisions_std", "±"),
               ("loss_pts", "success change (points)")]
    return finish(rows, columns, info, args.json)


if __name__ == "__main__":
    raise SystemExit(main())
