"""Why the scripted swarm planner's throughput decays in a world that runs on (#18): per window of simulated time,
the goals reached, the movers' mean speed, the share of slow movers (under 0.05 m/s), the share in the planner's
deadlock escape and the mean distance to the goal; at the end, where the slow movers are (a coarse occupancy map of
every mover and of the slow ones, and a PNG of the final state).

    python benchmarks/swarm_jam.py --movers 256 --seconds 240 --json jam_256.json --png jam_256.png
    python benchmarks/swarm_jam.py --movers 1024 --seconds 240 --route x      # the lanes' x-first routes
    python benchmarks/swarm_jam.py --movers 1024 --seconds 400 --seed 1 --policy pretrained:swarm_residual_1024_gate_ep

One world of a full square grid at ``--occupancy`` movers per tile (as ``benchmarks/swarm_study.py``), the planner's
defaults (``traffic="auto"``: one-way lanes from 32 tiles a side); ``--route`` picks the lanes' route rule: ``outer``
(the default: of the two two-leg routes, the one whose corner lies farther from the middle) or ``x`` (along x first).
``--policy`` runs a trained swarm policy (a run folder, ``policy.pt`` or ``pretrained:NAME``) on the env it was
trained on, with the same size, layout and seed, instead of the planner (for a residual policy the escape share is
that of the planner under it).

At the end, besides the maps: how the slow movers stand against each other (``slow_pairs``): of the slow movers with
a slow neighbour within ``PAIR_RADIUS``, the share with one whose goal lies the opposite way (directions to the
goals at more than 120 degrees: a counterflow, two crowds pressing into each other) and the share with one heading
the same way (within 60 degrees: a queue).
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
PAIR_RADIUS = 0.4  # m: slow movers this close (centres) count as neighbours in ``slow_pairs``


def slow_pairs(xy, goals, slow, radius: float = PAIR_RADIUS) -> dict:
    """Of the slow movers (bool ``slow``) with a slow neighbour within ``radius``: how many, and the shares with an
    opposed one (cosine of the directions to the goals < -0.5) and with one heading the same way (> 0.5)."""
    import torch

    p, g = xy[slow].double(), goals[slow].double()
    u = g - p
    u = u / u.norm(dim=-1, keepdim=True).clamp_min(1e-9)
    near = torch.cdist(p, p) < radius
    near.fill_diagonal_(False)
    cos = u @ u.T
    paired = near.any(1)
    n = int(paired.sum())
    return {"slow": int(slow.sum()), "with_slow_neighbour": n,
            "opposed_share": float((near & (cos < -0.5)).any(1).sum()) / max(n, 1),
            "aligned_share": float((near & (cos > 0.5)).any(1).sum()) / max(n, 1)}


def occupancy_map(xy, side: float, cells: int = GRID) -> list[list[int]]:
    """Movers per cell of a ``cells`` x ``cells`` map of the square layout of ``side`` m (row 0: the top)."""
    import torch

    ij = (xy / side * cells).long().clamp(0, cells - 1)
    counts = torch.zeros(cells, cells, dtype=torch.int64)
    counts.index_put_((ij[:, 1], ij[:, 0]), torch.ones(len(ij), dtype=torch.int64), accumulate=True)
    return counts.flip(0).tolist()


def controller(movers: int, side_tiles: int, device: str, seed: int, policy: str | None):
    """The env and the action function: the planner on a :class:`SwarmEnv`, or ``policy`` on the env it was trained
    on; and the planner whose deadlock escape the windows count (a residual policy's base; None for other policies)."""
    from magwarp.layout import Layout
    from magwarp.swarm import SwarmEnv, SwarmPlanner

    if policy is None:
        env = SwarmEnv(1, num_movers=movers, layout=Layout.grid(side_tiles, side_tiles), device=device, seed=seed,
                       check_inputs=False)
        planner = SwarmPlanner(env)
        return env, lambda obs: planner(), planner
    import torch

    sys.path.insert(0, os.path.join(os.path.dirname(HERE), "examples"))
    from swarm_scaling import policy_env

    from magwarp.envs.residual import ResidualAction

    env, net = policy_env(policy, movers, side_tiles, device, seed)

    def act(obs):
        with torch.no_grad():
            return net(obs)

    return env, act, env.baseline if isinstance(env, ResidualAction) else None


def run(movers: int, occupancy: float, seconds: float, window: float, device: str, route: str, seed: int,
        policy: str | None = None) -> dict:
    import torch

    side_tiles = int(math.ceil(math.sqrt(movers / occupancy)))
    env, act, planner = controller(movers, side_tiles, device, seed, policy)
    if route == "x":
        if planner is None:
            raise ValueError(f"--route x sets the planner's routes, and policy {policy!r} runs on no planner")
        if planner.lanes is None:
            raise ValueError(f"--route x needs the planner's lanes (layouts of 32+ tiles a side), got {side_tiles}")
        planner.lanes.outer = False
    dt = env.num_cycles * float(env.sim.model.limits.dt)
    steps, per = int(round(seconds / dt)), max(1, int(round(window / dt)))
    obs, _ = env.reset()
    sums = torch.zeros(6, dtype=torch.float64, device=env.device)  # goals, speed, slow, escape, distance, steps
    windows = []
    t0 = time.perf_counter()
    for i in range(steps):
        obs, _, _, _, info = env.step(act(obs))
        speed = env.sim.vel[0, :, :2].norm(dim=-1)
        escape = (planner.stuck[0] >= planner.patience).float().mean() if planner is not None and planner.patience > 0 \
            else speed.new_zeros(())
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
    goals = env.goals[0].cpu()
    return {"movers": movers, "tiles": side_tiles ** 2, "route": route, "seed": seed, "policy": policy,
            "seconds": steps * dt,
            "window_s": per * dt, "goals": sum(w["goals"] for w in windows), "wall_s": time.perf_counter() - t0,
            "first_window_goals": windows[0]["goals"], "last_window_goals": windows[-1]["goals"],
            "slow_at_end": int(slow.sum()), "windows": windows, "movers_map": occupancy_map(xy, side),
            "slow_map": occupancy_map(xy[slow], side), "slow_pairs": slow_pairs(xy, goals, slow),
            "_final": (xy, vel, goals, side)}


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
           title=f"{(row['policy'] or 'planner').replace('pretrained:', '')}, {row['movers']} movers, "
                 f"route {row['route']}, after {row['seconds']:.0f} s")
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
    p.add_argument("--policy", default=None, help="a trained swarm policy (run folder, policy.pt or pretrained:NAME) "
                   "instead of the planner")
    p.add_argument("--device", default="cpu")
    p.add_argument("--json", default=None)
    p.add_argument("--png", default=None)
    args = p.parse_args(argv)
    if args.movers < 1 or not args.occupancy > 0 or not args.seconds > 0 or not args.window > 0:
        p.error("--movers, --occupancy, --seconds and --window must be positive, got "
                f"{args.movers}, {args.occupancy}, {args.seconds}, {args.window}")
    info, _ = start_run(args.device)
    row = run(args.movers, args.occupancy, args.seconds, args.window, args.device, args.route, args.seed, args.policy)
    if args.png:
        plot(row, args.png)
    del row["_final"]
    print("movers per cell (top row first):", *row["movers_map"], sep="\n  ")
    print("slow movers per cell:", *row["slow_map"], sep="\n  ")
    print("slow movers beside slow movers:", row["slow_pairs"])
    return finish([row], ["movers", "policy", "route", "seed", "seconds", "goals", "first_window_goals",
                          "last_window_goals", "slow_at_end", "wall_s"], info, args.json)


if __name__ == "__main__":
    sys.exit(main())
