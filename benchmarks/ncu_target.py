"""A driver for Nsight Compute (``ncu``): builds one env, warms it up (compiles, graph capture, traffic), then runs a
few steps between ``cudaProfilerStart`` and ``cudaProfilerStop``, so that ``ncu --profile-from-start off`` profiles
only the kernels of those steps (#18: the fused swarm step; #24: B0's physics kernel with and without
randomisation; #17: the fast magnetic control cycle).

    ncu --profile-from-start off --clock-control none --kernel-name regex:step_kernel --launch-count 1 \\
        python benchmarks/ncu_target.py swarm --movers 64 --worlds 16384 --load seek
    ncu ... python benchmarks/ncu_target.py b0 --setting full --envs 65536
    ncu ... --kernel-name regex:first_kernel\|rest_kernel --launch-count 2 python benchmarks/ncu_target.py magnetics

``benchmarks/gpu_round.sh ncu`` runs the profiles this project reads (the stall reasons, occupancy, the pipes'
utilisation and the top stall sites); on the CPU the driver runs the same steps with no profiler (a smoke test).
"""

from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))


def _profiler(on: bool, device: str) -> None:
    if not device.startswith("cuda"):
        return
    import torch

    torch.cuda.synchronize()
    (torch.cuda.cudart().cudaProfilerStart if on else torch.cuda.cudart().cudaProfilerStop)()


def swarm(args) -> None:
    from magwarp.swarm import SwarmEnv, SwarmPlanner
    from swarm import _layout
    from swarm_load import _actions

    env = SwarmEnv(args.worlds, num_movers=args.movers, layout=_layout(args.movers), device=args.device, seed=0,
                   check_inputs=False)
    planner = SwarmPlanner(env) if args.load == "planner" else None
    for _ in range(args.warm):
        env.step(_actions(env, args.load, planner))
    actions = [_actions(env, args.load, planner) for _ in range(args.steps)]
    _profiler(True, args.device)
    for a in actions:
        env.step(a)
    _profiler(False, args.device)
    print(f"swarm {args.worlds} x {args.movers} ({args.load}): {args.steps} profiled steps")


def b0(args) -> None:
    import torch

    import magwarp  # noqa: F401 - registers the envs
    from randomization import ENVS, PARTS

    import gymnasium as gym

    env_id = "magwarp/TrajectoryPlanningB0-v0"
    settings = {**ENVS[env_id], **PARTS[env_id]}
    if args.setting not in settings:
        raise SystemExit(f"unknown setting {args.setting!r}; known: {sorted(settings)}")
    env = gym.make_vec(env_id, num_envs=args.envs, device=args.device, check_inputs=False,
                       **settings[args.setting]).unwrapped
    env._last_obs, _ = env.reset(seed=0)
    gen = torch.Generator(device=env.device).manual_seed(0)
    bank = torch.rand((8, args.envs, *env.single_action_space.shape), generator=gen, device=env.device) * 2 - 1
    for i in range(args.warm):
        env.step(bank[i % 8])
    _profiler(True, args.device)
    for i in range(args.steps):
        env.step(bank[i % 8])
    _profiler(False, args.device)
    print(f"B0 {args.envs} envs ({args.setting}): {args.steps} profiled steps")


def magnetics(args) -> None:
    """The fast magnetic control cycle (#17) of ``--movers`` movers at the benchmark's random poses and wrenches
    (``benchmarks/magnetics.py``'s speed rows): its two launches (the fast path, then the active-set steps)."""
    import numpy as np
    import warp as wp

    from magnetics import random_poses, wanted_wrench  # the benchmark's own draws
    from magwarp.layout import Layout
    from magwarp.magnetics.commutation import Commutation, CommutationResult
    from magwarp.magnetics.exact import vec6d
    from magwarp.magnetics.fast_cycle import FastCycle
    from magwarp.magnetics.geometry import MagneticParams
    from magwarp.magnetics.table import TableModel

    params = MagneticParams()
    table = TableModel(Layout.grid(args.tiles, args.tiles), params, device=args.device)
    cyc = FastCycle(table, Commutation(table.coilset, device=args.device))
    rng = np.random.default_rng(0)
    pos, quat = table.as_arrays(random_poses(rng, args.movers, args.tiles, float(params.magnets.bounds[0, 2])))
    wanted = wp.array(wanted_wrench(rng, args.movers), dtype=vec6d, device=args.device)
    out = CommutationResult.zeros(args.movers, table.max_active, args.device)
    for _ in range(args.warm):
        cyc.run(pos, quat, wanted, out)
    _profiler(True, args.device)
    for _ in range(args.steps):
        cyc.run(pos, quat, wanted, out)
    _profiler(False, args.device)
    print(f"fast magnetic cycle, {args.movers} movers: {args.steps} profiled cycles ({cyc.rest_movers} movers to the "
          f"active-set steps)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="what", required=True)
    s = sub.add_parser("swarm")
    s.add_argument("--movers", type=int, default=64)
    s.add_argument("--worlds", type=int, default=16384)
    s.add_argument("--load", choices=("seek", "planner", "still"), default="seek")
    b = sub.add_parser("b0")
    b.add_argument("--envs", type=int, default=65536)
    b.add_argument("--setting", default="off")
    g = sub.add_parser("magnetics")
    g.add_argument("--movers", type=int, default=1_000_000)
    g.add_argument("--tiles", type=int, default=8)
    for p in (s, b, g):
        p.add_argument("--device", default="cuda:0")
        p.add_argument("--warm", type=int, default=10)
        p.add_argument("--steps", type=int, default=2)
    args = parser.parse_args()
    {"swarm": swarm, "b0": b0, "magnetics": magnetics}[args.what](args)


if __name__ == "__main__":
    main()
