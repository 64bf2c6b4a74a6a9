"""The swarm scalability study (#18) as a benchmark: the scripted planner and a trained shared policy on the same
worlds at each size (``examples/swarm_scaling.py``'s ``study``: one world of a full square grid at ``--occupancy``
movers per tile, ``--seconds`` of simulated time from a fresh reset, the policy on the env it was trained on), with
goals per second per mover, collisions per 1000 goals, deadlocked movers and the share of first goals reached, into
JSON with the run's provenance and a PNG.

    python benchmarks/swarm_study.py --device cuda:0 --movers 256 1024 4096 --seconds 40 \\
        --policy /tmp/runs/swarm_residual/policy.pt --json out.json --png out.png
    python benchmarks/swarm_study.py --device cpu --movers 16 64 --seconds 2                  # smoke: planner only
"""

from __future__ import annotations

import argparse
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(os.path.dirname(HERE), "examples"))

from common import finish, start_run  # noqa: E402
from swarm_scaling import plot, study  # noqa: E402

COLUMNS = ("controller", "movers", "tiles", "throughput_per_mover", "throughput", "goals", "collisions_per_1000_goals",
           "deadlocked", "wall_s")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--movers", type=int, nargs="+", default=[256, 1024])
    p.add_argument("--occupancy", type=float, default=0.25, help="movers per tile")
    p.add_argument("--seconds", type=float, default=40.0, help="simulated seconds per size")
    p.add_argument("--device", default="cpu")
    p.add_argument("--policy", default=None,
                   help="a trained policy.pt (or run folder, or pretrained:NAME) beside the planner")
    p.add_argument("--traffic", default="auto", choices=("auto", "lanes", "free"))
    p.add_argument("--window", type=float, default=0.0,
                   help="also the goals of each window of this many simulated seconds (goals_per_window)")
    p.add_argument("--env-kwargs", default=None,
                   help="JSON options of the policy's env over those stored with it, e.g. '{\"gate_speed\": 0.3}'")
    p.add_argument("--seed", type=int, default=0, help="the worlds' seed (the same for the planner and the policy)")
    p.add_argument("--no-planner", action="store_true", help="the policy's rows alone (needs --policy)")
    p.add_argument("--json", default=None)
    p.add_argument("--png", default=None)
    args = p.parse_args(argv)
    info, _ = start_run(args.device)
    if not args.window >= 0:
        p.error(f"--window must be >= 0 seconds, got {args.window}")
    from magwarp.training.common import parse_env_kwargs

    env_kwargs = parse_env_kwargs(args.env_kwargs)
    if (env_kwargs or args.no_planner) and args.policy is None:
        p.error("--env-kwargs and --no-planner concern a policy: give --policy too")
    rows = study(args.movers, args.occupancy, args.seconds, args.device, args.policy, args.traffic, args.window,
                 env_kwargs, args.seed, planner=not args.no_planner)
    for r in rows:
        r["seconds"], r["occupancy"], r["policy"], r["seed"] = args.seconds, args.occupancy, args.policy, args.seed
        if env_kwargs:
            r["env_kwargs"] = env_kwargs
    if args.png:
        plot(rows, args.png)
    return finish(rows, [c for c in COLUMNS if c in rows[0]] + [k for k in rows[0] if k not in COLUMNS
                                                               and k not in ("seconds", "occupancy", "policy", "seed",
                                                                             "goals_per_window", "env_kwargs")],
                  info, args.json)


if __name__ == "__main__":
    sys.exit(main())
