"""A custom force model swapped into the simulator without forking its kernels.

The wrench on every mover comes from one ``@wp.func`` (default: gravity compensation + the x/y drive + the
impedance hold of z, roll, pitch and yaw). Here a toy "magnetic field" model adds, on top of the default:

* a planar force from two coil currents per mover, ``F = K_COIL * (i_x, i_y)``, read from the free per-mover input
  row ``sim.force_aux[w, m, :]`` (``force_aux_dim=2``): think of the currents a real planar motor drives;
* a viscous drag ``-C_DRAG * v`` on x/y (eddy currents).

With no x/y command, a mover under constant currents accelerates toward the terminal speed
``K_COIL * |i| / C_DRAG`` with time constant ``mass / C_DRAG``. The script prints the simulated speed next to that
closed form. ``tests/test_sim_force_model.py`` checks the model against a numpy integration.

    python examples/custom_force_model.py [--cycles 600] [--device cpu]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch
import warp as wp

from magwarp.kernels.impedance import default_force
from magwarp.layout import Layout
from magwarp.sim import Simulator
from magwarp.types import Body, Impedance, Limits, Pose, Wrench

K_COIL = wp.constant(2.0)  # N per A
C_DRAG = wp.constant(4.0)  # N s / m


@wp.func
def coil_force(
    p: Pose,
    body: Body,
    drive: wp.vec3,
    target_pos: wp.vec3,
    target_quat: wp.quat,
    imp: Impedance,
    lim: Limits,
    aux: wp.array(dtype=float),
) -> Wrench:
    """The default model (gravity compensation, x/y drive, impedance hold), plus a coil force and x/y drag."""
    w = default_force(p, body, drive, target_pos, target_quat, imp, lim, aux)
    coil = wp.vec3(K_COIL * aux[0], K_COIL * aux[1], 0.0)
    drag = wp.vec3(-C_DRAG * p.vel[0], -C_DRAG * p.vel[1], 0.0)
    w.force = w.force + coil + drag
    return w


def make_sim(num_worlds=2, device=None) -> Simulator:
    """Two movers per world on a 6 x 2 layout, driven by the coil model."""
    return Simulator(Layout.grid(6, 2), num_movers=2, num_worlds=num_worlds, start_xy=[[0.12, 0.12], [0.12, 0.36]],
                     force_model=coil_force, force_aux_dim=2, device=device, stop_on_collision=False)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=600, help="control cycles to run (1 ms each)")
    parser.add_argument("--device", default=None)
    args = parser.parse_args(argv)

    sim = make_sim(device=args.device)
    # World 0: mover 0 gets 0.5 A along x, mover 1 gets 1 A; world 1: no current (it must not move).
    currents = torch.zeros(2, 2, 2, device=sim.torch_device)
    currents[0, 0, 0] = 0.5
    currents[0, 1, 0] = 1.0
    sim.force_aux.copy_(currents)
    mass = sim.mover.mass
    tau = mass / float(C_DRAG)
    print(f"coil model: K = {float(K_COIL)} N/A, drag C = {float(C_DRAG)} N s/m, time constant m/C = {tau:.3f} s")
    print(" time (s)   mover 0 speed (sim / closed form)   mover 1 speed (sim / closed form)")
    done = 0
    while done < args.cycles:
        n = min(100, args.cycles - done)
        sim.step(n)
        done += n
        t = done * 1e-3
        row = []
        for m, i in ((0, 0.5), (1, 1.0)):
            v_sim = float(sim.vel[0, m, 0])
            v_exact = float(K_COIL) * i / float(C_DRAG) * (1.0 - np.exp(-t / tau))
            row.append(f"{v_sim:8.4f} / {v_exact:8.4f} m/s")
        print(f"{t:8.3f}   " + "             ".join(row))
    still = torch.linalg.norm(sim.vel[1, :, :2], dim=-1).max()
    print(f"world 1 (no current) max speed: {float(still):.2e} m/s; x travelled in world 0: "
          f"{(sim.pos[0, :, 0] - sim.start_pos[0, :, 0]).cpu().numpy().round(4)} m")


if __name__ == "__main__":
    main()
