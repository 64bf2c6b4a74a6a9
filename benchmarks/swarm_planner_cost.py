"""The scripted swarm planner's cost per call with its Warp kernels against its torch forms (#18), in one run.

:class:`~magwarp.swarm.SwarmPlanner` builds its half-planes and runs ORCA's linear program
(:func:`magwarp.kernels.orca.build_lines`, :func:`~magwarp.kernels.orca.solve_lines`) and the safety filter
(:meth:`magwarp.swarm.safety.SafetyFilter.choose`) as Warp kernels, a thread per mover, by default;
``kernels=False`` runs their torch forms (the kernels' references). Per swarm size, from the same env state (after
``--warm`` planner steps): ms per planner call and the two stages' share of it, both ways (the lines and the linear
program: two launches, or the torch lines and their solve; the safety filter); then the residual env's
step (``magwarp/SwarmResidual-v0``: the planner and the env's shield inside every step, what residual training and
``swarm_study.py`` run) both ways. CPU: the wall clock, torch on one thread; CUDA: synchronised wall clock.

    python benchmarks/swarm_planner_cost.py --device cpu --movers 64 256 --worlds 16 --json out.json
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from common import finish, start_run, sync_device  # noqa: E402


@contextlib.contextmanager
def timed(obj, name: str, totals: collections.Counter, device: str):
    """``obj.name`` wrapped so that its synchronised wall time adds up in ``totals[name]``; restored after."""
    fn = getattr(obj, name)

    def wrapper(*args, **kwargs):
        sync_device(device)
        t = time.perf_counter()
        out = fn(*args, **kwargs)
        sync_device(device)
        totals[name] += time.perf_counter() - t
        return out

    setattr(obj, name, wrapper)
    try:
        yield
    finally:
        setattr(obj, name, fn)


def planner_rows(movers: int, worlds: int, device: str, warm: int, calls: int) -> list[dict]:
    import magwarp.swarm.planner as planner_mod
    from magwarp.swarm import SwarmEnv, SwarmPlanner
    from swarm import _layout

    env = SwarmEnv(worlds, num_movers=movers, layout=_layout(movers), device=device, seed=0, check_inputs=False)
    env.reset(seed=0)
    warm_planner = SwarmPlanner(env)
    for _ in range(warm):
        env.step(warm_planner())
    rows = []
    for kernels in (True, False):
        planner = SwarmPlanner(env, kernels=kernels)
        planner()  # loads the kernels
        totals: collections.Counter = collections.Counter()
        choose = "choose" if kernels else "choose_torch"
        with contextlib.ExitStack() as stack:
            # the lines and the program: two launches with the kernels, the torch ops and their solve without
            if kernels:
                stack.enter_context(timed(planner, "_greedy_kernels", totals, device))
            else:
                for obj, name in ((planner, "_neighbour_lines"), (planner, "_wall_lines"),
                                  (planner_mod, "solve_lines_torch")):
                    stack.enter_context(timed(obj, name, totals, device))
            stack.enter_context(timed(planner.safety, choose, totals, device))
            sync_device(device)
            t = time.perf_counter()
            for _ in range(calls):
                planner()
            sync_device(device)
            ms = 1e3 * (time.perf_counter() - t) / calls
        lines = sum(v for name, v in totals.items() if name != choose)
        rows.append({"what": "planner call", "movers": movers, "worlds": worlds, "kernels": kernels, "ms": ms,
                     "lines_lp_ms": 1e3 * lines / calls, "filter_ms": 1e3 * totals[choose] / calls,
                     "traffic": planner.traffic})
    return rows


def residual_rows(movers: int, worlds: int, device: str, warm: int, steps: int) -> list[dict]:
    import torch

    from magwarp.swarm.residual import SwarmResidualEnv
    from swarm import _layout

    rows = []
    for kernels in (True, False):
        env = SwarmResidualEnv(worlds, num_movers=movers, layout=_layout(movers), device=device, seed=0,
                               check_inputs=False, planner={"kernels": kernels})
        if env.shield_filter is not None:
            env.shield_filter.kernel = kernels
        env.reset(seed=0)
        zero = torch.zeros(env.num_envs, env.num_movers, 2, device=env.device)
        for _ in range(warm):
            env.step(zero)
        sync_device(device)
        t = time.perf_counter()
        for _ in range(steps):
            env.step(zero)
        sync_device(device)
        ms = 1e3 * (time.perf_counter() - t) / steps
        rows.append({"what": "residual env step", "movers": movers, "worlds": worlds, "kernels": kernels, "ms": ms,
                     "agent_steps_per_s": worlds * movers / (ms * 1e-3)})
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default="cpu")
    p.add_argument("--movers", type=int, nargs="+", default=[64, 256])
    p.add_argument("--worlds", type=int, default=16)
    p.add_argument("--warm", type=int, default=10, help="planner steps before timing (the traffic settles)")
    p.add_argument("--calls", type=int, default=5, help="timed planner calls or residual env steps")
    p.add_argument("--no-residual", action="store_true", help="time the planner calls only")
    p.add_argument("--json")
    args = p.parse_args(argv)
    info, _ = start_run(args.device)
    rows = []
    for m in args.movers:
        rows += planner_rows(m, args.worlds, args.device, args.warm, args.calls)
        if not args.no_residual:
            rows += residual_rows(m, args.worlds, args.device, args.warm, args.calls)
    by = {(r["what"], r["movers"], r["kernels"]): r for r in rows}
    for r in rows:
        if r["kernels"]:
            r["speedup"] = by[(r["what"], r["movers"], False)]["ms"] / r["ms"]
    return finish(rows, ["what", "movers", "worlds", "kernels", "ms", "lines_lp_ms", "filter_ms", "speedup",
                         "agent_steps_per_s"], info, args.json)


if __name__ == "__main__":
    sys.exit(main())
