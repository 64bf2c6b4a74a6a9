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

ENV OPTIONS: ``--env-kwargs JSON`` sets env options (e.g. ``'{"num_cycles": 160}'``). Without it, a policy file
written by ``magwarp train`` brings the options it is meant to be evaluated with (its ``eval_env_kwargs``, e.g. the
paper's 160 control cycles per step): they are applied and printed.
"""

from __future__ import annotations

import argparse
import json
import os

from magwarp.commands import UsageError, add_trust_option

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
                   help="env steps per world (trajectory planning: default 10 s, 250 steps of 40 cycles; pushing: the "
                        "episode length)")
    p.add_argument("--makespan-goals", type=int, default=5, help="goals per mover for the makespan (default 5)")
    p.add_argument("--max-worlds", type=int, default=None, help="worlds simulated at once (default 65536 GPU, 2048 CPU)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--env-kwargs", default=None, metavar="JSON",
                   help="env options (default: the policy file's eval_env_kwargs, if it has them)")
    add_trust_option(p)
    return p


def _env_kwargs(args) -> dict:
    """--env-kwargs, else the evaluation options stored in a TorchScript policy file by the training scripts."""
    from magwarp.training.common import parse_env_kwargs

    try:
        if args.env_kwargs is not None:
            return parse_env_kwargs(args.env_kwargs)
        if args.policy == "scripted" or not os.path.isfile(args.policy):
            return {}
        from magwarp.training.policy import policy_metadata

        try:
            stored = policy_metadata(args.policy).get("eval_env_kwargs")
        except Exception:  # noqa: BLE001 - not a TorchScript file (torch.save'd module): it carries no options
            return {}
        kwargs = parse_env_kwargs(stored)
    except ValueError as e:
        raise UsageError(str(e)) from None
    if kwargs:
        print(f"env options from {args.policy}: {stored}")
    return kwargs


def run(args) -> int:
    if args.json is not None:
        parent = os.path.dirname(os.path.abspath(args.json))
        if not os.path.isdir(parent):
            raise UsageError(f"--json: directory {parent!r} does not exist")
    if args.max_worlds is not None and args.max_worlds < 1:
        raise UsageError(f"--max-worlds must be >= 1, got {args.max_worlds}")
    import warp as wp

    from magwarp.evaluate import EvalError, evaluate, format_table

    env_kwargs = _env_kwargs(args)
    wp.config.quiet = True  # Warp < 1.19
    wp.config.log_level = getattr(wp, "LOG_WARNING", 30)  # no init banner or module-load lines around the table
    try:
        result = evaluate(args.env_id, args.policy, args.episodes, args.repeats, device=args.device, steps=args.steps,
                          makespan_goals=args.makespan_goals, max_worlds=args.max_worlds, seed=args.seed,
                          env_kwargs=env_kwargs, trusted=args.trust)
    except EvalError as e:
        raise UsageError(str(e)) from None
    print(format_table(result))
    if args.json is not None:
        with open(args.json, "w") as f:
            json.dump(result.to_dict(), f, indent=2, allow_nan=False)
        print(f"wrote {args.json}")
    return 0
