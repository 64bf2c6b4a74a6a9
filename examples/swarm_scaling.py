"""A scalability study on the swarm env: throughput per mover (goals per second) and collisions per 1000 goals
against the number of movers, at a fixed density (movers per tile), for the scripted ORCA planner.

Each size runs one world of a full square grid for ``--seconds`` of simulated time from a fresh reset; the plot
(PNG) and the printed table are what a scalability study reports. A trained shared policy can be compared on the
same worlds by passing it to :func:`magwarp.swarm.run_policy` in place of the planner.

    python examples/swarm_scaling.py                                    # 16 .. 1024 movers, 10 s each (CPU: minutes)
    python examples/swarm_scaling.py --movers 16 64 --seconds 2 --png /tmp/swarm.png
    python examples/swarm_scaling.py --device cuda:0 --movers 256 1024 4096 16384
"""

from __future__ import annotations

import argparse
import math
import time

from magwarp.layout import Layout
from magwarp.swarm import SwarmEnv, SwarmPlanner, run_policy


def study(movers: list[int], occupancy: float, seconds: float, device: str | None) -> list[dict]:
    rows = []
    for m in movers:
        side = int(math.ceil(math.sqrt(m / occupancy)))
        env = SwarmEnv(1, num_movers=m, layout=Layout.grid(side, side), device=device, seed=0, check_inputs=False)
        planner = SwarmPlanner(env)
        steps = max(1, int(round(seconds / (env.num_cycles * 1e-3))))
        t = time.perf_counter()
        res = run_policy(env, lambda obs: planner(), steps)
        res["wall_s"] = time.perf_counter() - t
        res["tiles"] = side * side
        rows.append(res)
        print(f"{m:7d} movers on {side}x{side} tiles: {res['throughput_per_mover']:.4f} goals/s/mover, "
              f"{res['collisions_per_1000_goals']:.1f} collisions per 1000 goals, {res['deadlocked']} deadlocked "
              f"({res['wall_s']:.1f} s)", flush=True)
    return rows


def plot(rows: list[dict], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(9, 3.5))
    m = [r["movers"] for r in rows]
    ax[0].plot(m, [r["throughput_per_mover"] for r in rows], "o-", label="ORCA planner")
    ax[0].set(xscale="log", xlabel="movers per world", ylabel="goals / s / mover", title="throughput per mover")
    ax[1].plot(m, [r["collisions_per_1000_goals"] for r in rows], "o-", color="C3")
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
    args = p.parse_args(argv)
    rows = study(args.movers, args.occupancy, args.seconds, args.device)
    plot(rows, args.png)


if __name__ == "__main__":
    main()
