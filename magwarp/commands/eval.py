"""``magwarp eval``: batched benchmark evaluation of a policy, printed as the paper's table.

    magwarp eval PushBox --policy scripted --episodes 200 --repeats 100
    magwarp eval TrajectoryPlanningB0 --policy scripted --episodes 100 --repeats 10 --steps 250 --json b0.json
    magwarp eval PushBox --policy my_agent.pt --episodes 200 --repeats 10 --device cuda:0
    magwarp eval PushBox --policy mypkg.policies:MyPolicy --episodes 50 --repeats 4
    magwarp eval PushBox --policy pretrained:pushbox_sac --episodes 200 --repeats 100
    magwarp eval Swarm --policy scripted --episodes 4 --repeats 5 --steps 250 --env-kwargs '{"num_movers": 64}'

POLICY: ``scripted`` (the built-in baseline), ``pretrained:NAME`` (a policy shipped with magwarp: b0_ppo,
pushbox_sac, pusht_sac, obstacles_sac), a TorchScript or ``torch.save``d module file (it receives the
observation dict flattened in sorted key order: achieved_goal, desired_goal, observation), or ``module:callable``
(a class is instantiated with the env; a function is called as ``fn(obs) -> actions``). All episodes of a repeat
run in parallel worlds; for trajectory planning every "episode" is one world's long-horizon run of --steps steps.

SWARMS (magwarp/Swarm-v0, magwarp/SwarmMaterialFlow-v0; ``scripted`` is the ORCA planner): a swarm world never
ends by default (goals stream, collided movers respawn), so what is evaluated is a window of --steps env steps per
world (default 250: 10 s) from a fresh reset; an "episode" is one world of ``num_movers`` movers (--env-kwargs,
SwarmConfig fields, e.g. '{"num_movers": 1024, "layout": [[1, ...], ...]}'). Rows: throughput (goals, and jobs for
material flow, per second per world and per mover), collided movers per 1000 goals, movers deadlocked at the
window's end (slow and away from their goal for 25 steps), and the makespan (the slowest mover's --makespan-goals-th goal).
A policy file or callable gets the [worlds, movers, D] observation and returns [worlds, movers, 2] accelerations.
With --device cpu, torch uses one intra-op thread (small tensors: more threads only make timings unstable).

LEVITATION (magwarp/Levitation-v0 and its Hover, Wrench, Liftoff, Track, Move, Payload, Pendulum variants;
``scripted`` is the PD baseline through the commutation): success (within the env's ``success_tol`` at the episode's
end), failures, the tracking error (mean position error over the episode's steps), the final errors and the copper
energy per episode and per success (J; for the Move variant: energy per move at that arrival accuracy).

SEVERAL GPUS: ``--nproc-per-node N`` runs N processes through torchrun (one per GPU, ``cuda:LOCAL_RANK``; CPU
processes with ``--device cpu``): the repeats are shared out in batches of at most ceil(repeats / N), and rank 0
prints the one table (the same as one process with ``--max-worlds`` = episodes x ceil(repeats / N)).

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
    p.add_argument("--policy", default="scripted",
                   help="scripted | pretrained:NAME | PATH (TorchScript / torch.save) | module:callable")
    p.add_argument("--episodes", type=int, default=100, help="episodes (goals) per repeat, run in parallel (default 100)")
    p.add_argument("--repeats", type=int, default=10, help="repeats; the table shows mean ± std over them (default 10)")
    p.add_argument("--device", default=None, help="cpu or cuda:N (default: the best available)")
    p.add_argument("--json", default=None, metavar="PATH", help="also write the results (per-repeat values) as JSON")
    p.add_argument("--steps", type=int, default=None,
                   help="env steps per world (trajectory planning and swarms: default 10 s, 250 steps of 40 cycles; "
                        "pushing: the episode length)")
    p.add_argument("--makespan-goals", type=int, default=5, help="goals per mover for the makespan (default 5)")
    p.add_argument("--max-worlds", type=int, default=None, help="worlds simulated at once (default 65536 GPU, 2048 CPU)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--env-kwargs", default=None, metavar="JSON",
                   help="env options (default: the policy file's eval_env_kwargs, if it has them)")
    p.add_argument("--nproc-per-node", type=int, default=None, metavar="N",
                   help="share the repeats out over N processes (one per GPU) through torchrun; one table")
    p.add_argument("--dist-timeout", type=float, default=300.0,
                   help="seconds a torchrun rank waits for the others before the job fails")
    add_trust_option(p)
    return p


def _launch(args) -> int:
    """``--nproc-per-node N``: this command again, in N torchrun processes."""
    from magwarp.commands import CommandError
    from magwarp.training import distributed

    if args.nproc_per_node < 1:
        raise UsageError(f"--nproc-per-node must be >= 1, got {args.nproc_per_node}")
    argv = ["eval", args.env_id]
    for flag, value in (("--policy", args.policy), ("--episodes", args.episodes), ("--repeats", args.repeats),
                        ("--device", args.device), ("--json", args.json), ("--steps", args.steps),
                        ("--makespan-goals", args.makespan_goals), ("--max-worlds", args.max_worlds),
                        ("--seed", args.seed), ("--env-kwargs", args.env_kwargs),
                        ("--dist-timeout", args.dist_timeout)):
        if value is not None:
            argv += [flag, str(value)]
    rc = distributed.launch(args.nproc_per_node, "magwarp", argv)
    if rc != 0:
        raise CommandError(f"torchrun exited with code {rc} (a rank failed: its error is above)")
    return 0


def _env_kwargs(args) -> dict:
    """--env-kwargs, else the evaluation options stored in a TorchScript policy file by the training scripts."""
    from magwarp.training.common import parse_env_kwargs

    try:
        if args.env_kwargs is not None:
            return parse_env_kwargs(args.env_kwargs)
        from magwarp.training.pretrained import resolve_policy

        path = resolve_policy(args.policy)
        if path == "scripted" or not os.path.isfile(path):
            return {}
        from magwarp.training.policy import policy_metadata

        try:
            meta = policy_metadata(path)
            # the evaluation's options, else those it was trained with (a run given --env-kwargs only)
            stored = meta.get("eval_env_kwargs") or meta.get("env_kwargs")
        except Exception:  # noqa: BLE001 - not a TorchScript file (torch.save'd module): it carries no options
            return {}
        kwargs = parse_env_kwargs(stored)
    except ValueError as e:
        raise UsageError(str(e)) from None
    if kwargs:
        print(f"env options from {args.policy}: {stored}")
    return kwargs


def _quiet(fn, *args):
    """``fn(*args)`` without its prints (the other ranks of a torchrun job: rank 0 prints)."""
    import contextlib
    import io

    with contextlib.redirect_stdout(io.StringIO()):
        return fn(*args)


def run(args) -> int:
    if args.json is not None:
        parent = os.path.dirname(os.path.abspath(args.json))
        if not os.path.isdir(parent):
            raise UsageError(f"--json: directory {parent!r} does not exist")
    if args.max_worlds is not None and args.max_worlds < 1:
        raise UsageError(f"--max-worlds must be >= 1, got {args.max_worlds}")
    if args.nproc_per_node is not None:
        return _launch(args)
    import warp as wp

    from magwarp.evaluate import EvalError, evaluate, format_table
    from magwarp.training import distributed as dist

    wp.config.quiet = True  # Warp < 1.19
    wp.config.log_level = getattr(wp, "LOG_WARNING", 30)  # no init banner or module-load lines around the table
    device = dist.setup(args.device, args.dist_timeout)  # under torchrun: this rank's device and process group
    main_rank = dist.is_main()
    try:
        env_kwargs = _env_kwargs(args) if main_rank else _quiet(_env_kwargs, args)
        result = evaluate(args.env_id, args.policy, args.episodes, args.repeats, device=device, steps=args.steps,
                          makespan_goals=args.makespan_goals, max_worlds=args.max_worlds, seed=args.seed,
                          env_kwargs=env_kwargs, trusted=args.trust)
    except EvalError as e:
        raise UsageError(str(e)) from None
    finally:
        dist.shutdown(wait=False)
    if not main_rank:
        dist.leave(0)
        return 0
    print(format_table(result))
    if args.json is not None:
        with open(args.json, "w") as f:
            json.dump(result.to_dict(), f, indent=2, allow_nan=False)
        print(f"wrote {args.json}")
    dist.leave(0)  # a torchrun rank: done, exit without the runtime's teardown (see magwarp.training.distributed)
    return 0
