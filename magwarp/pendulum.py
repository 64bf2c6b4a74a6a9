"""A swinging payload on every mover of a simulator: a point mass on a rigid rod hung from a pivot on the mover,
integrated with the mover's rigid-body motion every control cycle (equations: :mod:`magwarp.kernels.pendulum`).

    sim = Simulator(layout, 1, worlds, hold_mask=(0,) * 6, force_model=magnetic_pendulum_force,
                    force_aux_dim=PENDULUM_AUX_DIM)
    actuator = CoilActuator(sim)            # writes the coils' wrench into force_aux[..., 0:6] before every cycle
    swing = SwingingPayload(sim, mass=0.2, length=0.08, pivot=(0, 0, 0.1))   # attach after the actuator
    swing.reset(mask, angle, azimuth)       # the rod's start direction, at rest relative to the pivot

Before every cycle (a pre-cycle hook, after the actuator's, inside the step graph) the rod's tension and its wrench
on the mover go into ``force_aux[..., 8:14]``, which :func:`magnetic_pendulum_force` adds to the coils' wrench; after
every cycle the bob is put back on the rod at the mover's new pose. The mover's own centre of mass stays at its centre
(no rigid payload on the same mover). ``mass`` and ``length`` are per world (:attr:`mass`, :attr:`length`: write
into them between steps).
"""

from __future__ import annotations

import math

import torch
import warp as wp

from magwarp.kernels.pendulum import pendulum_constrain_kernel, pendulum_reaction_kernel
from magwarp.magnetics.drive import AUX_DIM
from magwarp.types import Body, Impedance, Limits, Pose, Wrench

__all__ = ["PENDULUM_AUX_DIM", "SwingingPayload", "magnetic_pendulum_force", "rotate"]

#: force_aux columns of a simulator with coils and a swinging payload: the coils' (:data:`AUX_DIM`), then the rod's
#: wrench on the mover (6)
PENDULUM_AUX_DIM = AUX_DIM + 6


@wp.func
def magnetic_pendulum_force(
    p: Pose,
    body: Body,
    drive: wp.vec3,
    target_pos: wp.vec3,
    target_quat: wp.quat,
    imp: Impedance,
    lim: Limits,
    aux: wp.array(dtype=float),
) -> Wrench:
    """The coils' wrench (``aux[0:6]``) plus the rod's (``aux[8:14]``)."""
    w = Wrench()
    w.force = wp.vec3(aux[0] + aux[8], aux[1] + aux[9], aux[2] + aux[10])
    w.torque = wp.vec3(aux[3] + aux[11], aux[4] + aux[12], aux[5] + aux[13])
    return w


def _positive(name: str, value, zero_ok: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = float("nan")
    if not math.isfinite(v) or v < 0 or (v == 0 and not zero_ok) or v > 1e3:
        raise ValueError(f"{name} must be a finite number in {'[' if zero_ok else '('}0, 1e3], got {value!r}")
    return v


class SwingingPayload:
    """Attach a swinging payload to ``sim`` (see the module docstring): ``mass`` (kg, may be 0: no payload),
    ``length`` (m) of the rod, ``pivot`` (m, body frame from the mover centre)."""

    def __init__(self, sim, mass: float = 0.2, length: float = 0.08, pivot=(0.0, 0.0, 0.1)):
        aux = sim.state.force_aux
        if aux.shape[2] < PENDULUM_AUX_DIM:
            raise ValueError(f"the simulator's force_aux has {aux.shape[2]} columns; a swinging payload needs "
                             f"force_aux_dim >= {PENDULUM_AUX_DIM} (and force_model=magnetic_pendulum_force)")
        mass, length = _positive("mass", mass, zero_ok=True), _positive("length", length)
        try:
            piv = tuple(float(v) for v in pivot)
        except (TypeError, ValueError):
            piv = ()
        if len(piv) != 3 or not all(math.isfinite(v) and abs(v) <= 10.0 for v in piv):
            raise ValueError(f"pivot must be three finite numbers (m, body frame, |x| <= 10), got {pivot!r}")
        self.sim, self.pivot = sim, piv
        dev, W, M = sim.device, sim.num_worlds, sim.num_movers
        self._mass = wp.full(W, mass, dtype=float, device=dev)
        self._length = wp.full(W, length, dtype=float, device=dev)
        self._rod = wp.zeros((W, M), dtype=wp.vec3, device=dev)
        self._rate = wp.zeros((W, M), dtype=wp.vec3, device=dev)
        self._bob_pos = wp.zeros((W, M), dtype=wp.vec3, device=dev)
        self._bob_vel = wp.zeros((W, M), dtype=wp.vec3, device=dev)
        self._tension = wp.zeros((W, M), dtype=float, device=dev)
        self.rod[..., 2] = -length  # hanging straight down
        sim.add_cycle_hook(self._before_cycle, before=True)
        sim.add_cycle_hook(self._after_cycle)

    def _before_cycle(self, sim) -> None:
        s = sim.state
        wp.launch(pendulum_reaction_kernel, dim=(sim.num_worlds, sim.num_movers), device=sim.device,
                  inputs=[sim.model.limits, sim.model.body, wp.vec3(*self.pivot), self._mass, self._length, AUX_DIM,
                          s.pos, s.quat, s.vel, s.omega, self._rod, self._rate],
                  outputs=[s.force_aux, self._bob_pos, self._bob_vel, self._tension])

    def _after_cycle(self, sim) -> None:
        s = sim.state
        wp.launch(pendulum_constrain_kernel, dim=(sim.num_worlds, sim.num_movers), device=sim.device,
                  inputs=[wp.vec3(*self.pivot), self._length, s.pos, s.quat, s.vel, s.omega, self._bob_pos,
                          self._bob_vel], outputs=[self._rod, self._rate])

    def reset(self, mask: torch.Tensor, angle: torch.Tensor, azimuth: torch.Tensor) -> None:
        """Worlds of ``mask`` ([W] bool): the rod at ``angle`` (rad, from hanging straight down) towards the world
        direction ``azimuth`` (rad, from +x), at rest relative to the pivot ([W] tensors each, on the device)."""
        length = self.length
        d = torch.stack([torch.sin(angle) * torch.cos(azimuth), torch.sin(angle) * torch.sin(azimuth),
                         -torch.cos(angle)], -1) * length[:, None]
        keep = mask[:, None, None]
        self.rod.copy_(torch.where(keep, d[:, None], self.rod))
        self.rod_rate.copy_(torch.where(keep, torch.zeros_like(self.rod_rate), self.rod_rate))

    def swing(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Swing angles ``[W, M, 2]`` (rad: the rod's angle from the vertical in the world's x-z and y-z planes,
        ``atan2(d_x, -d_z)``, ``atan2(d_y, -d_z)``) and their rates ``[W, M, 2]`` (rad/s)."""
        d, dd = self.rod, self.rod_rate
        down = -d[..., 2:3]
        hor = d[..., :2]
        angles = torch.atan2(hor, down)
        rates = (dd[..., :2] * down + hor * dd[..., 2:3]) / (hor * hor + down * down)
        return angles, rates

    @property
    def mass(self) -> torch.Tensor:
        """[W] bob mass (kg; writable)."""
        return self.sim._t(self._mass)

    @property
    def length(self) -> torch.Tensor:
        """[W] rod length (m; writable: :meth:`reset` the worlds after changing it)."""
        return self.sim._t(self._length)

    @property
    def rod(self) -> torch.Tensor:
        """[W, M, 3] the rod, pivot to bob (m, world frame)."""
        return self.sim._t(self._rod)

    @property
    def rod_rate(self) -> torch.Tensor:
        """[W, M, 3] the bob's velocity relative to the pivot (m/s, world frame)."""
        return self.sim._t(self._rate)

    @property
    def tension(self) -> torch.Tensor:
        """[W, M] the rod's tension in the last cycle (N; negative: the rod pushes)."""
        return self.sim._t(self._tension)

    def bob_position(self) -> torch.Tensor:
        """[W, M, 3] the bob's position (m, world)."""
        return self.sim.pos + self.pivot_offset() + self.rod

    def pivot_offset(self) -> torch.Tensor:
        """[W, M, 3] the pivot from the mover centre (m, world frame)."""
        q = self.sim.quat
        return rotate(q, torch.tensor(self.pivot, dtype=q.dtype, device=q.device).expand(q.shape[:-1] + (3,)))


def rotate(q: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """``v`` ``[..., 3]`` rotated by the quaternions ``q`` ``[..., 4]`` (x, y, z, w)."""
    u, w = q[..., :3], q[..., 3:4]
    t = 2 * torch.cross(u, v, dim=-1)
    return v + w * t + torch.cross(u, t, dim=-1)
