"""A scalability study on the swarm env: throughput per mover (goals per second) and collisions per 1000 goals
against the number of movers, at a fixed density (movers per tile), for the scripted planner (one-way lanes on
layouts of 32 tiles a side or more, ORCA steering and its provably collision-free safety filter) and, with
``--policy``, a trained shared policy (``magwarp train magwarp/Swarm-v0``: one network for every mover, on local
observations, so it runs zero-shot at any size).

Each size runs one world of a full square grid for ``--seconds`` of simulated time from a fresh reset (the same
worlds for both); the plot (PNG) and the printed table are what a scalability study reports.

    python examples/swarm_scaling.py                                    # 16 .. 1024 movers, 10 s each (CPU: minutes)
    python examples/swarm_scaling.py --movers 16 64 --seconds 2 --png /tmp/swarm.png
    python examples/swarm_scaling.py --device cuda:0 --movers 256 1024 4096 16384
    python examples/swarm_scaling.py --device cuda:0 --movers 64 256 1024 4096 --policy runs/swarm_ippo/policy.pt
"""

from __future__ import annotations

import argparse
import math
import time

from magwarp.layout import Layout
from magwarp.swarm import SwarmEnv, SwarmPlanner, run_policy


def study(movers: list[int], occupancy: float, seconds: float, device: str | None, policy: str | None = None,
          traffic: str = "auto") -> list[dict]:
    rows = []
    net = None
    if policy is not None:
        import torch

        from magwarp.training.policy import load_policy
    for m in movers:
        side = int(math.ceil(math.sqrt(m / occupancy)))
        env = SwarmEnv(1, num_movers=m, layout=Layout.grid(side, side), device=device, seed=0, check_inputs=False)
        steps = max(1, int(round(seconds / (env.num_cycles * 1e-3))))
        controllers = [("planner", SwarmPlanner(env, traffic=traffic))]
        if policy is not None:
            net = net or load_policy(policy, env.device)
            controllers.append(("policy", net))
        for name, ctrl in controllers:
            t = time.perf_counter()
            if name == "planner":
                res = run_policy(env, lambda obs: ctrl(), steps)
            else:
                with torch.no_grad():
                    res = run_policy(env, ctrl, steps)
            res["wall_s"] = time.perf_counter() - t
            res["tiles"] = side * side
            res["controller"] = name
            rows.append(res)
            print(f"{m:7d} movers on {side}x{side} tiles: {res['throughput_per_mover']:.4f} goals/s/mover, "
                  f"{res['collisions_per_1000_goals']:.1f} collisions per 1000 goals, {res['deadlocked']} deadlocked "
                  f"({name}, {res['wall_s']:.1f} s)", flush=True)
    return rows


def plot(rows: list[dict], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(9, 3.5))
    for i, name in enumerate(dict.fromkeys(r.get("controller", "planner") for r in rows)):
        sel = [r for r in rows if r.get("controller", "planner") == name]
        m = [r["movers"] for r in sel]
        label = {"planner": "scripted planner", "policy": "shared policy (zero-shot)"}.get(name, name)
        ax[0].plot(m, [r["throughput_per_mover"] for r in sel], "o-", color=f"C{i}", label=label)
        ax[1].plot(m, [r["collisions_per_1000_goals"] for r in sel], "o-", color=f"C{i}", label=label)
    ax[0].set(xscale="log", xlabel="movers per world", ylabel="goals / s / mover", title="throughput per mover")
    ax[1].set(xscale="log", xlabel="movers per world", ylabel="collisions / 1000 goals", title="safety")
    ax[0].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    print("wrote", path)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--movers", type=int, nargs="+", default=[16, 64, 256, 1024])
    p.add_argument("--occupancy", type=float, default=0.25, help="movers per tile")
    p.add_argument("--seconds", type=float, default=10.0, help="simulated seconds per size")
    p.add_argument("--device", default=None)
    p.add_argument("--png", default="swarm_scaling.png")
    p.add_argument("--policy", default=None, help="a trained policy.pt (or run folder) to compare with the planner")
    p.add_argument("--traffic", default="auto", choices=("auto", "lanes", "free"),
                   help="the planner's traffic rule (auto: one-way lanes on layouts of 32 tiles a side or more)")
    args = p.parse_args(argv)
    rows = study(args.movers, args.occupancy, args.seconds, args.device, args.policy, args.traffic)
    plot(rows, args.png)


if __name__ == "__main__":
    main()
