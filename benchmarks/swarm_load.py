"""The fused swarm env step (#18) under different action loads: how much of a step is the load's own work (the
respawns and new goals it causes), at many worlds of 64-256 movers.

``benchmarks/swarm.py --fused-sweep`` times the step under ``seek_goals`` (every mover straight at its goal, no
avoidance): a collision-heavy load, where about 18% of the movers wait to respawn at any time and every step's
placement rounds retry them. Here the same env is timed under

* ``seek``: that load;
* ``planner``: the scripted planner's actions (:class:`~magwarp.swarm.SwarmPlanner`: lanes, ORCA and its safety
  filter; no collisions at 25% occupancy), the load a trained policy approaches; its own time is not counted;
* ``still``: zero actions (no collision, no goal: the step with no placement work, a floor).

Each load runs ``--warm`` steps first (the planner's traffic settles, the respawn queue fills), then ``--steps``
steps. The step's time is the device time between CUDA events recorded around ``env.step`` alone (the graph
replay; on the CPU the wall clock), so the policy's time is never in it. Per load: ms per step, agent-steps/s, and
per step the respawns asked (``info["respawn_pending"]`` and new collisions), goals reached and collisions, and the
ratio to the memory-bandwidth floor (``swarm.py``'s: the bytes an agent-step cannot avoid at the device's copy
bandwidth, measured in the same run).

    python benchmarks/swarm_load.py --device cuda:0 --movers 64 256 --worlds 16384 --json out.json
    python benchmarks/swarm_load.py --device cpu --movers 64 --worlds 64 --steps 5       # smoke
"""

from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from common import finish, start_run  # noqa: E402

LOADS = ("seek", "planner", "still")


def _actions(env, load: str, planner):
    import torch

    from swarm import seek_goals

    if load == "seek":
        return seek_goals(env)
    if load == "planner":
        return planner()
    return torch.zeros((env.num_envs, env.num_movers, 2), device=env.device)


def bench(movers: int, worlds: int, device: str, load: str, warm: int, steps: int, profile_steps: int = 0) -> dict:
    import torch

    from magwarp.swarm import SwarmEnv, SwarmPlanner
    from magwarp.swarm.fused import exchange, guard_in_step, launch_block, worlds_per_block
    from swarm import _layout, floor_bytes

    env = SwarmEnv(worlds, num_movers=movers, layout=_layout(movers), device=device, seed=0, check_inputs=False)
    planner = SwarmPlanner(env) if load == "planner" else None
    cuda = device.startswith("cuda")
    for _ in range(warm):
        env.step(_actions(env, load, planner))
    counts = {"pending": 0.0, "collided": 0.0, "goals": 0.0}
    elapsed = 0.0
    goals_before = int(env.collected_goals.sum())
    for _ in range(steps):
        action = _actions(env, load, planner)
        if cuda:
            start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
            start.record()
            _, _, _, _, info = env.step(action)
            end.record()
            end.synchronize()
            elapsed += start.elapsed_time(end) / 1e3
        else:
            t = time.perf_counter()
            _, _, _, _, info = env.step(action)
            elapsed += time.perf_counter() - t
        counts["pending"] += float(info["respawn_pending"].float().sum())
        counts["collided"] += float(info["collided"].float().sum())
    counts["goals"] = float(int(env.collected_goals.sum()) - goals_before)
    ms = elapsed / steps * 1e3
    agents = movers * worlds
    row = {"device": device, "movers": movers, "worlds": worlds, "agents": agents, "load": load, "warm": warm,
           "steps": steps, "env_ms": ms, "agent_steps_per_s": agents / (ms * 1e-3), "step_path": env.step_path,
           "exchange": exchange() if cuda else "-", "worlds_per_block": worlds_per_block(movers) if cuda else "-",
           "max_registers": launch_block(movers)[2] if cuda else "-",
           "guard": "fused" if guard_in_step() else "separate",
           "place_blocks": env.placer.blocks}
    row.update({f"{k}_per_step": v / steps for k, v in counts.items()})
    row["pending_share"] = row["pending_per_step"] / agents
    row["floor_bytes_per_agent_step"] = floor_bytes(env)
    if cuda and profile_steps:
        row["kernels"] = kernel_times(env, load, planner, profile_steps)
        for name, us, n in row["kernels"]:
            print(f"    {us:9.1f} us/step  {n:5.2f} launches  {name}", flush=True)
    return row


def kernel_times(env, load: str, planner, steps: int, top: int = 8) -> list[list]:
    """The device kernels of ``steps`` env steps under ``load`` (torch's profiler around ``env.step`` alone: each
    step's action is computed and finished first, so the planner's kernels stay out): ``[name, us per step, launches
    per step]`` for the ``top`` kernels by time, and the rest summed as ``"other"``."""
    import re

    import torch
    from torch.profiler import ProfilerActivity, profile

    cuda = torch.autograd.DeviceType.CUDA
    totals: dict[str, list[float]] = {}
    for _ in range(steps):
        action = _actions(env, load, planner)
        torch.cuda.synchronize()
        with profile(activities=[ProfilerActivity.CUDA]) as prof:
            env.step(action)
            torch.cuda.synchronize()
        for e in prof.profiler.kineto_results.events():
            if e.device_type() != cuda:
                continue
            name = re.sub(r"_[0-9a-f]{7,}", "", e.name())[:80]  # Warp's module hashes out
            t = totals.setdefault(name, [0.0, 0])
            t[0] += e.duration_ns() / 1e3 / steps
            t[1] += 1 / steps
    ranked = sorted(([k, round(v[0], 2), round(v[1], 2)] for k, v in totals.items()), key=lambda r: -r[1])
    rest = ranked[top:]
    return ranked[:top] + ([["other", round(sum(r[1] for r in rest), 2), round(sum(r[2] for r in rest), 2)]]
                           if rest else [])


def add_floor(rows: list[dict], bandwidth: float) -> None:
    """Each row's ratio to the memory-bandwidth floor (``swarm.floor_bytes``: the simulator state read and written
    once, the action read, the observation written per agent-step, at ``bandwidth`` bytes/s)."""
    for row in rows:
        row["bandwidth_gb_s"] = bandwidth / 1e9
        row["floor_agent_steps_per_s"] = bandwidth / row["floor_bytes_per_agent_step"]
        row["of_floor"] = row["agent_steps_per_s"] / row["floor_agent_steps_per_s"]


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default="cpu")
    p.add_argument("--movers", type=int, nargs="+", default=[64])
    p.add_argument("--worlds", type=int, default=16384)
    p.add_argument("--loads", nargs="+", default=list(LOADS), choices=LOADS)
    p.add_argument("--warm", type=int, default=30, help="steps before the timed ones")
    p.add_argument("--steps", type=int, default=30)
    p.add_argument("--kernels", type=int, default=0, metavar="STEPS", help="CUDA: after the timing, the device "
                   "kernels of STEPS more steps by time (torch's profiler), in the JSON row and printed")
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    info, _ = start_run(args.device)
    rows = []
    for movers in args.movers:
        for load in args.loads:
            row = bench(movers, args.worlds, args.device, load, args.warm, args.steps, args.kernels)
            rows.append(row)
            print(f"  {args.device} {args.worlds} x {movers}, {load}: {row['env_ms']:.3f} ms/step "
                  f"({row['agent_steps_per_s']:.3g} agent-steps/s, {row['step_path']}); per step "
                  f"{row['pending_per_step']:.0f} waiting to respawn ({100 * row['pending_share']:.1f}%), "
                  f"{row['collided_per_step']:.0f} collided, {row['goals_per_step']:.0f} goals", flush=True)
    from swarm import copy_bandwidth

    add_floor(rows, copy_bandwidth(args.device))
    finish(rows, [("load", "load"), ("movers", "movers"), ("worlds", "worlds"), ("env_ms", "ms/step"),
                  ("agent_steps_per_s", "agent-steps/s"), ("of_floor", "of the floor"),
                  ("pending_share", "share waiting"),
                  ("collided_per_step", "collided/step"), ("goals_per_step", "goals/step")], info, args.json)


if __name__ == "__main__":
    main()
