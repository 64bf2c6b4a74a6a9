"""The simulator driven from a plain Python loop: a basic environment without an RL API.

Movers on an L-shaped layout follow a simple P controller (with a repulsive term between movers) toward target tile
centres; when a mover arrives it gets a new target. Every step (40 control cycles = 40 ms) the loop prints the
arrivals and the collisions of each world: which movers collided with which (mover-mover) and which left the tiles
(wall). A world that collides stops for the rest of its step (``stop_on_collision``) and is then reset to its start
poses, without touching the other worlds.

    python examples/basic_loop.py                    # 3 worlds x 3 movers, 100 steps (4 s), CPU or first GPU
    python examples/basic_loop.py --steps 5 --worlds 2 --device cpu
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from magwarp.layout import Layout, MoverSpec
from magwarp.sim import Simulator
from magwarp.types import COLLIDE_MOVER, COLLIDE_WALL

# An L: a 4 x 2 tile bar along x plus a 2 x 2 block on top of its left end (x index = first axis).
L_SHAPE = np.array([
    [1, 1, 1, 1],
    [1, 1, 1, 1],
    [1, 1, 0, 0],
    [1, 1, 0, 0],
])


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=100, help="env steps of 40 cycles each")
    parser.add_argument("--worlds", type=int, default=3)
    parser.add_argument("--movers", type=int, default=3)
    parser.add_argument("--device", default=None, help='"cpu", "cuda:0", or the best available')
    parser.add_argument("--kp", type=float, default=3.0, help="position gain (1/s): desired speed per metre to go")
    parser.add_argument("--kv", type=float, default=40.0, help="velocity gain (1/s): acceleration per m/s of error")
    parser.add_argument("--v-cruise", type=float, default=1.0, help="top speed asked for (m/s)")
    parser.add_argument("--avoid-dist", type=float, default=0.25, help="movers closer than this push apart (m)")
    parser.add_argument("--avoid-gain", type=float, default=10.0, help="repulsive speed per metre of overlap (1/s)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    layout = Layout(L_SHAPE)
    # Start poses: tile centres spread over the layout (every third tile), the same in every world.
    starts = layout.tile_centers()[:: 3][: args.movers]
    # Box collision shapes: the real 155 mm square footprint (the default circle of radius 0.11 m is more cautious).
    mover = MoverSpec(collision_shape="box")
    sim = Simulator(layout, num_worlds=args.worlds, start_xy=starts, mover=mover, device=args.device)
    sim_a_max = sim.model.limits.a_max
    gen = torch.Generator().manual_seed(args.seed)
    centres = torch.as_tensor(layout.tile_centers(), dtype=torch.float32, device=sim.torch_device)
    print(f"{args.worlds} worlds x {args.movers} movers on a {layout.num_tiles}-tile L-shaped layout, "
          f"device {sim.device}")

    def new_targets():
        """A different tile centre for each mover of each world."""
        idx = torch.stack([torch.randperm(len(centres), generator=gen)[: args.movers] for _ in range(args.worlds)])
        return centres[idx.to(sim.torch_device)]

    targets = new_targets()
    arrivals = collisions = 0
    for step in range(args.steps):
        # The simulator clips the commands to the mover's acceleration and speed limits.
        for sub in range(40 // 10):  # update the command every 10 cycles within the step
            xy, vel = sim.pos[..., :2], sim.vel[..., :2]
            # P control of the velocity toward the target, with a speed that still allows braking in time.
            err = targets - xy
            dist = torch.linalg.norm(err, dim=-1, keepdim=True)
            speed = torch.minimum(args.kp * dist, torch.sqrt(2.0 * 0.5 * sim_a_max * dist)).clamp_max(args.v_cruise)
            v_des = err / dist.clamp_min(1e-6) * speed
            # A simple repulsive field keeps the movers apart (most of the time: collisions still happen).
            d = xy[:, :, None, :] - xy[:, None, :, :]  # [W, M, M, 2], from each other mover to this one
            gap = torch.linalg.norm(d, dim=-1, keepdim=True).clamp_min(1e-6)
            v_des = v_des + args.avoid_gain * ((args.avoid_dist - gap).clamp_min(0.0) * d / gap).sum(dim=2)
            cmd = args.kv * (v_des - vel)
            sim.step(10, cmd=cmd)
            # (each sim.step clears the step accumulators, so read collisions after every call)
            hit = sim.halted.bool()
            if hit.any():
                break
        dist = torch.linalg.norm(targets - sim.pos[..., :2], dim=-1)
        arrived = (dist < 0.01) & (torch.linalg.norm(sim.vel[..., :2], dim=-1) < 0.05)
        if arrived.any():
            arrivals += int(arrived.sum())
            targets = torch.where(arrived[..., None], new_targets(), targets)
            for w, m in arrived.nonzero().tolist():
                print(f"step {step:3d} world {w}: mover {m} reached its target")
        hit = sim.halted.bool()
        if hit.any():
            flags, partner = sim.flags.cpu(), sim.partner.cpu()
            for w in hit.nonzero().flatten().tolist():
                collisions += 1
                movers = [f"mover {m} hit mover {int(partner[w, m])}" for m in range(args.movers)
                          if flags[w, m] & COLLIDE_MOVER and m < partner[w, m]]
                walls = [f"mover {m} left the tiles" for m in range(args.movers) if flags[w, m] & COLLIDE_WALL]
                print(f"step {step:3d} world {w}: collision in cycle {10 * sub + int(sim.cycles[w])} of 40: "
                      + ", ".join(movers + walls) + " -> reset")
            sim.reset(hit)  # only the colliding worlds start over
            targets = torch.where(hit[:, None, None], new_targets(), targets)
    print(f"done: {args.steps} steps, {arrivals} targets reached, {collisions} collisions")


if __name__ == "__main__":
    main()
