"""``magwarp eval``: batched benchmark evaluation of a policy, printed as the paper's table.

    magwarp eval PushBox --policy scripted --episodes 200 --repeats 100
    magwarp eval TrajectoryPlanningB0 --policy scripted --episodes 100 --repeats 10 --steps 250 --json b0.json
    magwarp eval PushBox --policy my_agent.pt --episodes 200 --repeats 10 --device cuda:0
    magwarp eval PushBox --policy mypkg.policies:MyPolicy --episodes 50 --repeats 4

POLICY: ``scripted`` (the built-in baseline), a TorchScript or ``torch.save``d module file (it receives the
observation dict flattened in sorted key order: achieved_goal, desired_goal, observation), or ``module:callable``
(a class is instantiated with the env; a function is called as ``fn(obs) -> actions``). All episodes of a repeat
run in parallel worlds; for trajectory planning every "episode" is one world's long-horizon run of --steps steps.
With --device cpu, torch uses one intra-op thread (small tensors: more threads only make timings unstable).
"""

from __future__ import annotations

import argparse
import json
import os

from magwarp.commands import UsageError

HELP = "evaluate a policy on an env: success rate, collisions, makespan, ..."


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser("eval", help=HELP, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("env_id", metavar="ENV_ID", help="e.g. magwarp/PushBox-v0, PushBox, TrajectoryPlanningB0")
    p.add_argument("--policy", default="scripted", help="scripted | PATH (TorchScript / torch.save) | module:callable")
    p.add_argument("--episodes", type=int, default=100, help="episodes (goals) per repeat, run in parallel (default 100)")
    p.add_argument("--repeats", type=int, default=10, help="repeats; the table shows mean ± std over them (default 10)")
    p.add_argument("--device", default=None, help="cpu or cuda:N (default: the best available)")
    p.add_argument("--json", default=None, metavar="PATH", help="also write the results (per-repeat values) as JSON")
    p.add_argument("--steps", type=int, default=None,
                   help="env steps per world (trajectory planning: default 250 = 10 s; pushing: the episode length)")
    p.add_argument("--makespan-goals", type=int, default=5, help="goals per mover for the makespan (default 5)")
    p.add_argument("--max-worlds", type=int, default=None, help="worlds simulated at once (default 65536 GPU, 2048 CPU)")
    p.add_argument("--seed", type=int, default=0)
    return p


def run(args) -> int:
    if args.json is not None:
        parent = os.path.dirname(os.path.abspath(args.json))
        if not os.path.isdir(parent):
            raise UsageError(f"--json: directory {parent!r} does not exist")
    if args.max_worlds is not None and args.max_worlds < 1:
        raise UsageError(f"--max-worlds must be >= 1, got {args.max_worlds}")
    import warp as wp

    from magwarp.evaluate import EvalError, evaluate, format_table

    wp.config.quiet = True  # Warp < 1.19
    wp.config.log_level = getattr(wp, "LOG_WARNING", 30)  # no init banner or module-load lines around the table
    try:
        result = evaluate(args.env_id, args.policy, args.episodes, args.repeats, device=args.device, steps=args.steps,
                          makespan_goals=args.makespan_goals, max_worlds=args.max_worlds, seed=args.seed)
    except EvalError as e:
        raise UsageError(str(e)) from None
    print(format_table(result))
    if args.json is not None:
        with open(args.json, "w") as f:
            json.dump(result.to_dict(), f, indent=2, allow_nan=False)
        print(f"wrote {args.json}")
    return 0
