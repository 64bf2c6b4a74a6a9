"""Why the scripted swarm planner's throughput decays in a world that runs on (#18): per window of simulated time,
the goals reached, the movers' mean speed, the share of slow movers (under 0.05 m/s), the share in the planner's
deadlock escape and the mean distance to the goal; at the end, where the slow movers are (a coarse occupancy map of
every mover and of the slow ones, and a PNG of the final state).

    python benchmarks/swarm_jam.py --movers 256 --seconds 240 --json jam_256.json --png jam_256.png
    python benchmarks/swarm_jam.py --movers 1024 --seconds 240 --route x      # the lanes' x-first routes

One world of a full square grid at ``--occupancy`` movers per tile (as ``benchmarks/swarm_study.py``), the planner's
defaults (``traffic="auto"``: one-way lanes from 32 tiles a side); ``--route`` picks the lanes' route rule: ``outer``
(the default: of the two two-leg routes, the one whose corner lies farther from the middle) or ``x`` (along x first).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from common import finish, start_run  # noqa: E402

SLOW = 0.05  # m/s: a mover slower than this counts as slow (the swarm metrics' stuck speed)
GRID = 8  # cells per side of the occupancy maps


def occupancy_map(xy, side: float, cells: int = GRID) -> list[list[int]]:
    """Movers per cell of a ``cells`` x ``cells`` map of the square layout of ``side`` m (row 0: the top)."""
    import torch

    ij = (xy / side * cells).long().clamp(0, cells - 1)
    counts = torch.zeros(cells, cells, dtype=torch.int64)
    counts.index_put_((ij[:, 1], ij[:, 0]), torch.ones(len(ij), dtype=torch.int64), accumulate=True)
    return counts.flip(0).tolist()


def run(movers: int, occupancy: float, seconds: float, window: float, device: str, route: str, seed: int) -> dict:
    import torch

    from magwarp.layout import Layout
    from magwarp.swarm import SwarmEnv, SwarmPlanner

    side_tiles = int(math.ceil(math.sqrt(movers / occupancy)))
    env = SwarmEnv(1, num_movers=movers, layout=Layout.grid(side_tiles, side_tiles), device=device, seed=seed,
                   check_inputs=False)
    planner = SwarmPlanner(env)
    if route == "x":
        if planner.lanes is None:
            raise ValueError(f"--route x needs the planner's lanes (layouts of 32+ tiles a side), got {side_tiles}")
        planner.lanes.outer = False
    dt = env.num_cycles * float(env.sim.model.limits.dt)
    steps, per = int(round(seconds / dt)), max(1, int(round(window / dt)))
    env.reset()
    sums = torch.zeros(6, dtype=torch.float64, device=env.device)  # goals, speed, slow, escape, distance, steps
    windows = []
    t0 = time.perf_counter()
    for i in range(steps):
        _, _, _, _, info = env.step(planner())
        speed = env.sim.vel[0, :, :2].norm(dim=-1)
        escape = (planner.stuck[0] >= planner.patience).float().mean() if planner.patience > 0 else speed.new_zeros(())
        dist = (env.goals[0] - env.sim.pos[0, :, :2]).norm(dim=-1).mean()
        sums += torch.stack([info["goal_reached"].sum().double(), speed.mean().double(),
                             (speed < SLOW).float().mean().double(), escape.double(), dist.double(),
                             torch.ones((), dtype=torch.float64, device=env.device)])
        if (i + 1) % per == 0 or i + 1 == steps:
            s = sums.tolist()
            n = s[5]
            windows.append({"end_s": round((i + 1) * dt, 3), "goals": int(s[0]), "mean_speed": s[1] / n,
                            "slow_share": s[2] / n, "escape_share": s[3] / n, "goal_distance": s[4] / n})
            w = windows[-1]
            print(f"  {w['end_s']:7.1f} s: {w['goals']:5d} goals, mean speed {w['mean_speed']:.3f} m/s, slow "
                  f"{w['slow_share']:.3f}, in escape {w['escape_share']:.3f}, to goal {w['goal_distance']:.2f} m",
                  flush=True)
            sums.zero_()
    xy = env.sim.pos[0, :, :2].cpu()
    vel = env.sim.vel[0, :, :2].cpu()
    slow = vel.norm(dim=-1) < SLOW
    side = side_tiles * float(env.layout.tile.size)
    return {"movers": movers, "tiles": side_tiles ** 2, "route": route, "seed": seed, "seconds": steps * dt,
            "window_s": per * dt, "goals": sum(w["goals"] for w in windows), "wall_s": time.perf_counter() - t0,
            "first_window_goals": windows[0]["goals"], "last_window_goals": windows[-1]["goals"],
            "slow_at_end": int(slow.sum()), "windows": windows, "movers_map": occupancy_map(xy, side),
            "slow_map": occupancy_map(xy[slow], side), "_final": (xy, vel, env.goals[0].cpu(), side)}


def plot(row: dict, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    xy, vel, goals, side = row["_final"]
    slow = vel.norm(dim=-1) < SLOW
    fig, ax = plt.subplots(figsize=(7, 7))
    ax.quiver(xy[:, 0], xy[:, 1], vel[:, 0], vel[:, 1], color="0.3", scale=12, width=0.002)
    ax.scatter(xy[~slow, 0], xy[~slow, 1], s=8, c="C0", label="moving")
    ax.scatter(xy[slow, 0], xy[slow, 1], s=8, c="C3", label=f"slower than {SLOW} m/s")
    ax.set(xlim=(0, side), ylim=(0, side), aspect="equal", xlabel="x (m)", ylabel="y (m)",
           title=f"planner, {row['movers']} movers, route {row['route']}, after {row['seconds']:.0f} s")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--movers", type=int, default=256)
    p.add_argument("--occupancy", type=float, default=0.25, help="movers per tile")
    p.add_argument("--seconds", type=float, default=240.0, help="simulated seconds")
    p.add_argument("--window", type=float, default=20.0, help="simulated seconds per printed window")
    p.add_argument("--route", default="outer", choices=("outer", "x"))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device", default="cpu")
    p.add_argument("--json", default=None)
    p.add_argument("--png", default=None)
    args = p.parse_args(argv)
    if args.movers < 1 or not args.occupancy > 0 or not args.seconds > 0 or not args.window > 0:
        p.error("--movers, --occupancy, --seconds and --window must be positive, got "
                f"{args.movers}, {args.occupancy}, {args.seconds}, {args.window}")
    info, _ = start_run(args.device)
    row = run(args.movers, args.occupancy, args.seconds, args.window, args.device, args.route, args.seed)
    if args.png:
        plot(row, args.png)
    del row["_final"]
    print("movers per cell (top row first):", *row["movers_map"], sep="\n  ")
    print("slow movers per cell:", *row["slow_map"], sep="\n  ")
    return finish([row], ["movers", "route", "seed", "seconds", "goals", "first_window_goals", "last_window_goals",
                          "slow_at_end", "wall_s"], info, args.json)


if __name__ == "__main__":
    sys.exit(main())
