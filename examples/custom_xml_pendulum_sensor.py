"""User XML hooks: every mover carries a sprung inverted pendulum (a metronome), a sensor reads its tip, plus a ball.

Shows :func:`magwarp.mjcf.generate_mjcf` hooks (``mover_bodies``, ``worldbody``, ``sensor``, ``defaults``) and
stepping the result with the batched mujoco-warp backend, which keeps controlling the movers (hover + x/y commands)
while MuJoCo simulates whatever the user added.

Run: python examples/custom_xml_pendulum_sensor.py [--device cpu]
"""

import argparse

import numpy as np
import torch

from magwarp.layout import Layout
from magwarp.mjcf import XmlHooks, generate_mjcf
from magwarp.physics import ControlParams, MjwBackend

PENDULUM = (
    '<body name="pendulum_{k}" pos="0 0 0.006">'
    '<joint name="swing_{k}" type="hinge" axis="0 1 0" stiffness="0.05" damping="0.0005"/>'
    '<geom class="user" type="capsule" fromto="0 0 0 0 0 0.08" size="0.005" mass="0.02"/>'
    '<site name="tip_{k}" pos="0 0 0.08"/></body>'
)


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--device", default="cpu")
    p.add_argument("--num-worlds", type=int, default=8)
    args = p.parse_args()
    num_movers = 2
    hooks = XmlHooks(
        defaults='<default class="user"><geom rgba="0.1 0.6 0.9 1" contype="0" conaffinity="0"/></default>',
        mover_bodies=[PENDULUM.format(k=k) for k in range(num_movers)],
        worldbody='<body name="ball" pos="0.6 0.36 0.03"><freejoint/><geom type="sphere" size="0.03" mass="0.05"/></body>',
        sensor="".join(f'<framepos name="tip_pos_{k}" objtype="site" objname="tip_{k}"/>' for k in range(num_movers)),
    )
    xml = generate_mjcf(Layout.grid(4, 3), num_movers, hooks=hooks)
    # the pendulum's weight rests on the mover: a stiffer z hold keeps the hover sag small (m g / k_z = 0.2 mm)
    backend = MjwBackend(xml, args.num_worlds, control=ControlParams(k_lin=(1.0, 1.0, 1000.0), num_cycles=40),
                         device=args.device)
    # the pendulum joints sit between the movers' free joints: address them by qpos address, not strided views
    qpos = backend.qpos_t
    backend.init_qpos_t[:, backend.mover_qadr[0] + 7] = 0.6  # tilt mover 0's pendulum
    backend.reset()
    accel = torch.zeros(args.num_worlds, num_movers, 2, device=backend.torch_device)
    accel[:, 1, 0] = torch.linspace(-3, 3, args.num_worlds)  # mover 1: a different x acceleration per world
    for step in range(10):
        backend.step(accel if step < 5 else -accel)
        tips = backend.data.sensordata.numpy()[:, :6].reshape(args.num_worlds, num_movers, 3)
        swing = qpos[:, backend.mover_qadr[0] + 7]
        print(f"step {step}: pendulum 0 angle (world 0) {float(swing[0]):+.3f} rad, mover 1 x per world "
              f"{np.round(qpos[:, backend.mover_qadr[1]].numpy(), 3)}, tip 1 z (world 0) {tips[0, 1, 2]:.4f} m")


if __name__ == "__main__":
    main()
