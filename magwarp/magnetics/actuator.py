"""Coil currents as the simulator's input: the low-level actuator of :mod:`magwarp.envs.levitation`.

    sim = Simulator(layout, 1, worlds, dt=2.5e-4, hold_mask=(0,) * 6, force_model=magnetic_force,
                    force_aux_dim=AUX_DIM)
    act = CoilActuator(sim)                 # the wrench-table model of the default design
    act.currents.copy_(i)                   # [W, M, slots] A, the slots of act.coil_ids (the window of each mover)
    sim.step(4)                             # every cycle: Gamma(q) at the cycle's start, w = Gamma i, copper loss

Before every cycle (a pre-cycle hook in the step graph, no host sync) the wrench-table model gives each mover's
window of coils and their columns at the cycle's starting pose, and the realised wrench is ``Gamma i`` with the
commanded currents held at the coils' limits (an amplifier saturates: a command beyond the limit gives the limit;
:attr:`CoilActuator.saturated` says where). Slots without a coil (beyond the footprint, a hole) carry no current.
The wrench goes into ``force_aux[..., 0:6]`` (what :func:`~magwarp.magnetics.drive.magnetic_force` returns to the
integrator; gravity is the integrator's), the copper loss (W) into ``[..., 6]``; :attr:`energy` integrates it.

``mode="wrench"``: the input is a wanted wrench per mover (:attr:`wanted`, ``[W, M, 6]``, force N and torque N m
about the mover's centre, world frame) that the commutation (:mod:`~magwarp.magnetics.commutation`) turns into
currents every cycle: ``cycle="block"`` one launch per cycle (look-up, commutation and store,
:func:`wrench_cycle_kernel`; the default on a CPU) or ``cycle="fast"`` (the default on a GPU: the float64 poses and
wrenches, :class:`~magwarp.magnetics.fast_cycle.FastCycle`, the store; 2.3-2.8x faster on an H100).
:meth:`commutate` runs the same commutation once, outside the step, at the current state.
"""

from __future__ import annotations

import torch
import warp as wp

from magwarp.magnetics.commutation import Commutation, CommutationOptions, vec6f
from magwarp.magnetics.cycle import CycleOutputs, CycleParams, cycle_buffers, cycle_mover
from magwarp.magnetics.drive import AUX_DIM, launch_store, store_wrench
from magwarp.magnetics.exact import vec6d
from magwarp.magnetics.fast_cycle import FastCycle, resolve_cycle
from magwarp.magnetics.geometry import MagneticParams, MagneticsError
from magwarp.magnetics.table import TableModel, WrenchTableSpec

__all__ = ["CoilActuator"]


@wp.kernel
def pose64_kernel(
    # State in:
    pos: wp.array2d(dtype=wp.vec3),
    quat: wp.array2d(dtype=wp.quat),
    # State out:
    pos_d: wp.array(dtype=wp.vec3d),
    quat_d: wp.array(dtype=wp.quatd),
    count: wp.array(dtype=wp.int32),
):
    """The simulator's poses as the flat float64 arrays of the wrench model; the coil counts zeroed."""
    w, m = wp.tid()
    i = w * pos.shape[1] + m
    p = pos[w, m]
    q = quat[w, m]
    pos_d[i] = wp.vec3d(wp.float64(p[0]), wp.float64(p[1]), wp.float64(p[2]))
    quat_d[i] = wp.normalize(wp.quatd(wp.float64(q[0]), wp.float64(q[1]), wp.float64(q[2]), wp.float64(q[3])))
    count[i] = 0


@wp.kernel
def wanted64_kernel(
    # State in:
    wanted: wp.array(dtype=vec6f),
    # State out:
    wanted_d: wp.array(dtype=vec6d),
):
    i = wp.tid()
    w = wanted[i]
    wanted_d[i] = vec6d(wp.float64(w[0]), wp.float64(w[1]), wp.float64(w[2]), wp.float64(w[3]), wp.float64(w[4]),
                        wp.float64(w[5]))


@wp.kernel
def apply_currents_kernel(
    # Model:
    resistance: wp.array(dtype=wp.float64),
    limit: wp.array(dtype=wp.float64),
    # State in:
    gamma: wp.array2d(dtype=vec6f),
    coil_ids: wp.array2d(dtype=wp.int32),
    command: wp.array2d(dtype=float),
    # State out:
    currents: wp.array2d(dtype=wp.float64),
    saturated: wp.array2d(dtype=wp.int32),
    delivered: wp.array(dtype=vec6d),
    loss: wp.array(dtype=wp.float64),
):
    """Per mover: the commanded currents held at the limits (zero in slots without a coil), w = Gamma i, and the
    copper loss sum R i^2."""
    m = wp.tid()
    w = vec6d()
    p = wp.float64(0.0)
    for j in range(gamma.shape[1]):
        k = coil_ids[m, j]
        i = wp.float64(0.0)
        sat = int(0)
        if k >= 0:
            i = wp.float64(command[m, j])
            if wp.abs(i) > limit[k]:
                i = wp.sign(i) * limit[k]
                sat = 1
            g = gamma[m, j]
            w = w + vec6d(wp.float64(g[0]), wp.float64(g[1]), wp.float64(g[2]), wp.float64(g[3]), wp.float64(g[4]),
                          wp.float64(g[5])) * i
            p = p + resistance[k] * i * i
        currents[m, j] = i
        saturated[m, j] = sat
    delivered[m] = w
    loss[m] = p


@wp.kernel
def wrench_cycle_kernel(
    # Model:
    c: CycleParams,
    dt: float,
    # State in:
    pos: wp.array2d(dtype=wp.vec3),
    quat: wp.array2d(dtype=wp.quat),
    wanted: wp.array(dtype=vec6f),
    # State out:
    o: CycleOutputs,
    force_aux: wp.array3d(dtype=float),
    energy: wp.array2d(dtype=wp.float64),
):
    """``mode="wrench"``, one launch per cycle, one block of threads per mover (flat index ``w * movers + m``): the
    look-up and the commutation of the wanted wrench (:func:`~magwarp.magnetics.cycle.cycle_mover`), then the
    realised wrench, loss and flags into ``force_aux`` and the energy."""
    i, lane = wp.tid()
    w = i / pos.shape[1]
    m = i % pos.shape[1]
    p = pos[w, m]
    q = quat[w, m]
    pos_d = wp.vec3d(wp.float64(p[0]), wp.float64(p[1]), wp.float64(p[2]))
    quat_d = wp.normalize(wp.quatd(wp.float64(q[0]), wp.float64(q[1]), wp.float64(q[2]), wp.float64(q[3])))
    wf = wanted[i]
    want = vec6d(wp.float64(wf[0]), wp.float64(wf[1]), wp.float64(wf[2]), wp.float64(wf[3]), wp.float64(wf[4]),
                 wp.float64(wf[5]))
    out, loss_w, flag = cycle_mover(i, lane, c, pos_d, quat_d, want, o)
    if lane == 0:
        store_wrench(w, m, dt, out, loss_w, flag, force_aux, energy)


class CoilActuator:
    """Drive ``sim`` (built with ``force_model=magnetic_force``, ``force_aux_dim >= AUX_DIM``) by coil currents
    (``mode="currents"``) or by wanted wrenches through the commutation (``mode="wrench"``); see the module
    docstring."""

    def __init__(self, sim, params: MagneticParams | None = None, table: WrenchTableSpec | None = None,
                 mode: str = "currents", options: CommutationOptions | None = None, use_cache: bool = True,
                 cycle: str | None = None):
        if mode not in ("currents", "wrench"):
            raise MagneticsError(f"CoilActuator mode must be 'currents' or 'wrench', got {mode!r}")
        aux = sim.state.force_aux
        if aux.shape[2] < AUX_DIM:
            raise MagneticsError(f"the simulator's force_aux has {aux.shape[2]} columns; the coil actuator needs "
                                 f"force_aux_dim >= {AUX_DIM} (and force_model=magnetic_force)")
        self.sim, self.mode = sim, mode
        dev = sim.device
        self.model = TableModel(sim.layout, params, table, device=dev, use_cache=use_cache)
        self.commutation = Commutation(self.model.coilset, options, device=dev)
        w_, m_ = sim.num_worlds, sim.num_movers
        n, slots = w_ * m_, self.model.max_active
        self.slots = slots
        self._pos = wp.zeros(n, dtype=wp.vec3d, device=dev)
        self._quat = wp.zeros(n, dtype=wp.quatd, device=dev)
        self._command = wp.zeros((n, slots), dtype=float, device=dev)
        self._wanted = wp.zeros(n, dtype=vec6f, device=dev)
        self._wanted_d = wp.zeros(n, dtype=vec6d, device=dev)
        self._energy = wp.zeros((w_, m_), dtype=wp.float64, device=dev)
        self._dt = float(sim.model.limits.dt)
        self._ids, self._count, self._gamma, self._res, self._cycle, self._outputs = cycle_buffers(
            self.model, self.commutation, n)
        self.cycle = resolve_cycle(cycle, dev)
        self._fast = FastCycle(self.model, self.commutation).reserve(n) if self.cycle == "fast" else None
        sim.add_cycle_hook(self._before_cycle, before=True)

    def _pose64(self) -> None:
        """The poses into the flat float64 arrays of the wrench model; the coil counts zeroed."""
        s = self.sim.state
        wp.launch(pose64_kernel, dim=(self.sim.num_worlds, self.sim.num_movers), device=self.sim.device,
                  inputs=[s.pos, s.quat], outputs=[self._pos, self._quat, self._count])

    def _wanted64(self) -> None:
        wp.launch(wanted64_kernel, dim=self._wanted.shape[0], device=self.sim.device, inputs=[self._wanted],
                  outputs=[self._wanted_d])

    def _columns(self) -> None:
        self._pose64()
        self.model.columns(self._pos, self._quat, self._ids, self._gamma, self._count, zero_count=False)

    def _solve_wanted(self) -> None:
        self._wanted64()
        self.commutation.solve(self._gamma, self._ids, self._count, self._wanted_d, self._res)

    def _before_cycle(self, sim) -> None:
        if self.mode == "wrench" and self._fast is None:  # one launch: look-up, commutation, store
            wp.launch_tiled(wrench_cycle_kernel, dim=[self._wanted.shape[0]], block_dim=self.commutation.block_dim,
                            device=sim.device, inputs=[self._cycle, self._dt, sim.state.pos, sim.state.quat,
                                                       self._wanted],
                            outputs=[self._outputs, sim.state.force_aux, self._energy])
            return
        if self.mode == "wrench":  # poses and wrenches in float64, the fast cycle
            self._pose64()
            self._wanted64()
            self._fast.run(self._pos, self._quat, self._wanted_d, self._res, self._count, self._ids, self._gamma)
        else:
            self._columns()
            wp.launch(apply_currents_kernel, dim=self._command.shape[0], device=sim.device,
                      inputs=[self.commutation.resistance, self.commutation.limit, self._gamma, self._ids,
                              self._command],
                      outputs=[self._res.currents, self._res.saturated, self._res.delivered, self._res.loss])
        launch_store(sim, self._dt, self._res, self._energy)

    def refresh(self) -> None:
        """Find the windows and columns at the current poses now (e.g. after a reset), so that :attr:`coil_ids`
        names the coils of the next cycle's slots."""
        with self.sim._on_stream():
            self._columns()

    def commutate(self, wrench: torch.Tensor) -> torch.Tensor:
        """Least-loss currents ``[W, M, slots]`` (A, within the limits) for wanted wrenches ``[W, M, 6]`` at the
        movers' current poses (the slots of :attr:`coil_ids` there); runs on the device, no host sync."""
        shape = (self.sim.num_worlds, self.sim.num_movers, 6)
        if tuple(wrench.shape) != shape:
            raise MagneticsError(f"commutate: wrench must have shape {shape}, got {tuple(wrench.shape)}")
        with self.sim._on_stream():
            self.wanted.copy_(wrench)
            self._columns()
            self._solve_wanted()
        return self._view(self._res.currents, (*shape[:2], self.slots)).clone()

    def _view(self, arr, shape):
        return self.sim._t(arr.reshape(shape))

    @property
    def currents(self) -> torch.Tensor:
        """[W, M, slots] commanded currents (A; write into it: ``mode="currents"``)."""
        return self._view(self._command, (self.sim.num_worlds, self.sim.num_movers, self.slots))

    @property
    def wanted(self) -> torch.Tensor:
        """[W, M, 6] wanted wrench (write into it: ``mode="wrench"``)."""
        return self._view(self._wanted, (self.sim.num_worlds, self.sim.num_movers)).view(
            self.sim.num_worlds, self.sim.num_movers, 6)

    @property
    def applied_currents(self) -> torch.Tensor:
        """[W, M, slots] the currents of the last cycle (A, after the limits)."""
        return self._view(self._res.currents, (self.sim.num_worlds, self.sim.num_movers, self.slots))

    @property
    def saturated(self) -> torch.Tensor:
        """[W, M, slots] int: the slot's current was held at its limit in the last cycle."""
        return self._view(self._res.saturated, (self.sim.num_worlds, self.sim.num_movers, self.slots))

    @property
    def coil_ids(self) -> torch.Tensor:
        """[W, M, slots] coil ids of the window at the last cycle's start (-1: no coil)."""
        return self._view(self._ids, (self.sim.num_worlds, self.sim.num_movers, self.slots))

    @property
    def wrench(self) -> torch.Tensor:
        """[W, M, 6] realised wrench of the last cycle (float32 view of ``force_aux``)."""
        return self.sim.force_aux[..., :6]

    @property
    def loss(self) -> torch.Tensor:
        """[W, M] copper loss (W) of the last cycle."""
        return self.sim.force_aux[..., 6]

    @property
    def energy(self) -> torch.Tensor:
        """[W, M] copper energy (J) since the actuator was attached (zero it to restart)."""
        return self.sim._t(self._energy)
