"""The magnetic drive in the simulator: the wrench on every mover comes from its coil currents.

    sim = Simulator(layout, num_movers, num_worlds, force_model="magnetic")   # or MagneticModel(params, table)
    drive = sim.magnetic_drive                      # the wrench-table model of the default design (cached on disk)
    sim.step(40)                                    # currents, copper loss and energy follow every cycle

(by hand: ``Simulator(..., force_model=magnetic_force, force_aux_dim=AUX_DIM)``, then ``MagneticDrive(sim)``).

Every cycle (inside the step kernels, or a pre-cycle hook: see below; no host sync): the wrench the ideal model
would apply at the cycle's starting state (:func:`~magwarp.kernels.impedance.default_force`: gravity compensation,
the x/y drive of the command, the impedance hold) is the wanted wrench; the wrench-table model (:mod:`~magwarp.magnetics.table`)
gives each mover's Gamma(q); the commutation gives the least-loss currents within the limits; the realised wrench
Gamma i acts on the mover and goes into ``force_aux[w, m, 0:6]`` (float32; the hook's :func:`magnetic_force`
returns it to the integrator). When
no coil saturates, the realised wrench is the wanted one (to float32 rounding) and the motion matches the ideal
model; when coils saturate, the wrench falls short (the mover accelerates less, or sinks) as on the real system.

``force_aux[w, m, 6]`` is the copper loss (W) and ``[7]`` the commutation flags
(:mod:`~magwarp.magnetics.commutation`); :attr:`MagneticDrive.energy` accumulates the loss over time (J);
:attr:`MagneticDrive.currents` and :attr:`MagneticDrive.coil_ids` are the active coils' currents (A) and ids.

Two ways to run it:

* ``in_step=True``: inside the simulator's step kernels, as their
  :class:`~magwarp.kernels.step.Actuator` (:meth:`~magwarp.sim.Simulator.set_actuator`): every cycle of every mover,
  the force model (:func:`~magwarp.kernels.impedance.default_force`) gives the wanted wrench and the one-thread cycle
  (:mod:`~magwarp.magnetics.thread_cycle`, float64 arithmetic by default, float32 columns) the realised one, in the
  same thread. The step stays the fused one-launch kernel (B0's worlds of 3 movers: one thread per world runs all 40
  cycles), captured in the env's graph. ``force_aux`` and the energy follow every cycle; the per-slot currents and coil ids
  are written in a step's last cycle (a world that halts early on a collision keeps those of its last full step).
* ``in_step=False`` (the default): a pre-cycle hook (float64, one block of threads per mover, below).

The hook stays the default until the in-step drive has run on a GPU inside the trajectory env's graph: its first H100
run (2026-11-25) failed to capture B0's step graph with it (torch graphs destroyed during the capture; the eager
fallback then found the env's generator still registered with the failed graph). On the CPU both give the same
motion (``tests/test_magnetics_drive.py``).

The hook is one launch per cycle (:func:`drive_cycle_kernel`: the wanted wrench, the look-up, the commutation and
the store, one block of threads per mover, :mod:`~magwarp.magnetics.cycle`), captured in the step graph; it still
forces the simulator's per-cycle launch path (as any cycle hook does): each cycle is this launch, the step kernel's
and the collision check's. The trajectory env keeps its fused step (one CUDA graph per env step) with the drive:
the hook is marked ``fused_step_safe``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import warp as wp

from magwarp.kernels.collision import model_row
from magwarp.kernels.dynamics import planar_acceleration
from magwarp.kernels.impedance import default_force
from magwarp.kernels.step import Actuator
from magwarp.magnetics.commutation import Commutation, CommutationOptions
from magwarp.magnetics.cycle import CycleOutputs, CycleParams, cycle_buffers, cycle_mover
from magwarp.magnetics.exact import vec6d
from magwarp.magnetics.fast_cycle import FastCycle, resolve_cycle
from magwarp.magnetics.table import TableModel, WrenchTableSpec
from magwarp.magnetics.thread_cycle import PRECISIONS, ThreadOutputs, make_thread_cycle, thread_outputs
from magwarp.magnetics.geometry import MagneticParams, MagneticsError
from magwarp.types import Body, Impedance, Limits, Pose, Wrench, make_pose

#: Width of ``force_aux`` the drive needs: the realised wrench (6), the copper loss, the commutation flags.
AUX_DIM = 8


@wp.func
def magnetic_force(
    p: Pose,
    body: Body,
    drive: wp.vec3,
    target_pos: wp.vec3,
    target_quat: wp.quat,
    imp: Impedance,
    lim: Limits,
    aux: wp.array(dtype=float),
) -> Wrench:
    """The wrench the coils deliver this cycle (written into ``aux`` by :class:`MagneticDrive` before it)."""
    w = Wrench()
    w.force = wp.vec3(aux[0], aux[1], aux[2])
    w.torque = wp.vec3(aux[3], aux[4], aux[5])
    return w


@wp.func
def wanted_wrench(
    w: int,
    m: int,
    lim: Limits,
    imp: Impedance,
    body: wp.array2d(dtype=Body),
    cmd: wp.array2d(dtype=wp.vec2),
    target_pos: wp.array2d(dtype=wp.vec3),
    target_quat: wp.array2d(dtype=wp.quat),
    force_aux: wp.array3d(dtype=float),
    pos: wp.array2d(dtype=wp.vec3),
    quat: wp.array2d(dtype=wp.quat),
    vel: wp.array2d(dtype=wp.vec3),
    omega: wp.array2d(dtype=wp.vec3),
    acc: wp.array2d(dtype=wp.vec2),
):
    """The ideal model's wrench on mover (w, m) at the cycle's start (what the step kernel would apply), and its pose
    in float64 (the quaternion normalised)."""
    p = make_pose(pos[w, m], quat[w, m], vel[w, m], omega[w, m])
    b = body[model_row(body.shape[0], w), m]
    a = planar_acceleration(p.vel, acc[w, m], cmd[w, m], lim)
    wr = default_force(p, b, wp.vec3(a[0] * b.mass, a[1] * b.mass, 0.0), target_pos[w, m], target_quat[w, m], imp,
                       lim, force_aux[w, m])
    pos_d = wp.vec3d(wp.float64(p.pos[0]), wp.float64(p.pos[1]), wp.float64(p.pos[2]))
    q = wp.quatd(wp.float64(p.quat[0]), wp.float64(p.quat[1]), wp.float64(p.quat[2]), wp.float64(p.quat[3]))
    wanted = vec6d(wp.float64(wr.force[0]), wp.float64(wr.force[1]), wp.float64(wr.force[2]),
                   wp.float64(wr.torque[0]), wp.float64(wr.torque[1]), wp.float64(wr.torque[2]))
    return pos_d, wp.normalize(q), wanted


@wp.kernel
def drive_wanted_kernel(
    # Model:
    lim: Limits,
    imp: Impedance,
    body: wp.array2d(dtype=Body),
    # State in:
    cmd: wp.array2d(dtype=wp.vec2),
    target_pos: wp.array2d(dtype=wp.vec3),
    target_quat: wp.array2d(dtype=wp.quat),
    force_aux: wp.array3d(dtype=float),
    pos: wp.array2d(dtype=wp.vec3),
    quat: wp.array2d(dtype=wp.quat),
    vel: wp.array2d(dtype=wp.vec3),
    omega: wp.array2d(dtype=wp.vec3),
    acc: wp.array2d(dtype=wp.vec2),
    # State out:
    pos_d: wp.array(dtype=wp.vec3d),
    quat_d: wp.array(dtype=wp.quatd),
    wanted: wp.array(dtype=vec6d),
):
    """The fast cycle's first launch (``cycle="fast"``): every mover's wanted wrench and float64 pose (flat index
    ``w * movers + m``), as :func:`drive_cycle_kernel` computes them."""
    w, m = wp.tid()
    i = w * pos.shape[1] + m
    p, q, want = wanted_wrench(w, m, lim, imp, body, cmd, target_pos, target_quat, force_aux, pos, quat, vel, omega,
                               acc)
    pos_d[i] = p
    quat_d[i] = q
    wanted[i] = want


@wp.func
def store_wrench(w: int, m: int, dt: float, delivered: vec6d, loss: wp.float64, flags: int,
                 force_aux: wp.array3d(dtype=float), energy: wp.array2d(dtype=wp.float64)):
    """The realised wrench, loss and flags into ``force_aux[w, m]``; the loss integrated into the energy."""
    for k in range(6):
        force_aux[w, m, k] = float(delivered[k])
    force_aux[w, m, 6] = float(loss)
    force_aux[w, m, 7] = float(flags)
    energy[w, m] = energy[w, m] + loss * wp.float64(dt)


@wp.kernel
def drive_cycle_kernel(
    # Model:
    lim: Limits,
    imp: Impedance,
    body: wp.array2d(dtype=Body),
    c: CycleParams,
    dt: float,
    # State in:
    cmd: wp.array2d(dtype=wp.vec2),
    target_pos: wp.array2d(dtype=wp.vec3),
    target_quat: wp.array2d(dtype=wp.quat),
    pos: wp.array2d(dtype=wp.vec3),
    quat: wp.array2d(dtype=wp.quat),
    vel: wp.array2d(dtype=wp.vec3),
    omega: wp.array2d(dtype=wp.vec3),
    acc: wp.array2d(dtype=wp.vec2),
    # State out:
    o: CycleOutputs,
    force_aux: wp.array3d(dtype=float),
    energy: wp.array2d(dtype=wp.float64),
):
    """The drive's whole cycle, one block of threads per mover (flat index ``w * movers + m``): the wanted wrench,
    the look-up and the commutation (:func:`~magwarp.magnetics.cycle.cycle_mover`), the realised wrench, loss and
    flags into ``force_aux`` and the energy."""
    i, lane = wp.tid()
    w = i / pos.shape[1]
    m = i % pos.shape[1]
    # Every thread of the block reads force_aux here, before the block's first sum; only thread 0 writes it, after.
    pos_d, quat_d, wanted = wanted_wrench(w, m, lim, imp, body, cmd, target_pos, target_quat, force_aux, pos, quat,
                                          vel, omega, acc)
    out, p, flag = cycle_mover(i, lane, c, pos_d, quat_d, wanted, o)
    if lane == 0:
        store_wrench(w, m, dt, out, p, flag, force_aux, energy)


@wp.kernel
def store_wrench_kernel(
    # Model:
    dt: float,
    # State in:
    delivered: wp.array(dtype=vec6d),
    loss: wp.array(dtype=wp.float64),
    flags: wp.array(dtype=wp.int32),
    # State out:
    force_aux: wp.array3d(dtype=float),
    energy: wp.array2d(dtype=wp.float64),
):
    """The realised wrench, loss and flags into ``force_aux``; the loss integrated into the energy."""
    w, m = wp.tid()
    i = w * force_aux.shape[1] + m
    store_wrench(w, m, dt, delivered[i], loss[i], flags[i], force_aux, energy)


def launch_store(sim, dt: float, res, energy: wp.array) -> None:
    """:func:`store_wrench_kernel` over ``sim``'s movers: the commutation result ``res``'s realised wrench, loss and
    flags into ``force_aux``, the loss into ``energy``."""
    wp.launch(store_wrench_kernel, dim=(sim.num_worlds, sim.num_movers), device=sim.device,
              inputs=[dt, res.delivered, res.loss, res.flags], outputs=[sim.state.force_aux, energy])


@wp.struct
class DriveParams:
    """The in-step drive's parameters (the step kernels' actuator argument): the cycle's model and outputs, the
    energy (J) per mover, the cycle time and the movers per world."""

    c: CycleParams
    o: ThreadOutputs
    energy: wp.array2d(dtype=wp.float64)
    dt: float
    movers: int


@functools.cache
def drive_actuator(slots: int, precision: str = "float64") -> Actuator:
    """The in-step magnetic drive (a :class:`~magwarp.kernels.step.Actuator` over :class:`DriveParams`) for a window
    of ``slots`` slots: the one-thread cycle of the wanted wrench at the cycle's starting pose; the realised wrench,
    loss and flags into ``force_aux``, the loss into the energy."""
    mover_cycle = make_thread_cycle(slots, precision)[0]
    real = PRECISIONS[precision]
    vec6r = wp.types.vector(length=6, dtype=real)

    @wp.func
    def actuate(a: DriveParams, w: int, m: int, last: int, p: Pose, wanted: Wrench, aux: wp.array(dtype=float)):
        q = p.quat
        yaw = wp.atan2(2.0 * (q[3] * q[2] + q[0] * q[1]), 1.0 - 2.0 * (q[1] * q[1] + q[2] * q[2]))
        want = vec6r(real(wanted.force[0]), real(wanted.force[1]), real(wanted.force[2]), real(wanted.torque[0]),
                     real(wanted.torque[1]), real(wanted.torque[2]))
        d, loss, flag = mover_cycle(a.c, w * a.movers + m, p.pos[0], p.pos[1], p.pos[2], yaw, want, a.o, last)
        for k in range(6):
            aux[k] = d[k]
        aux[6] = loss
        aux[7] = float(flag)
        a.energy[w, m] = a.energy[w, m] + wp.float64(loss) * wp.float64(a.dt)
        out = Wrench()
        out.force = wp.vec3(d[0], d[1], d[2])
        out.torque = wp.vec3(d[3], d[4], d[5])
        return out

    return Actuator(actuate, DriveParams)


class MagneticDrive:
    """Attach the magnetic drive to ``sim`` (built with ``force_aux_dim >= AUX_DIM``): a
    :class:`~magwarp.magnetics.table.TableModel` of ``params`` on the simulator's layout and device, and the
    commutation, run every cycle: inside the step kernels (``in_step=True``, in ``precision``; the simulator's force
    model becomes the wanted wrench's, :func:`~magwarp.kernels.impedance.default_force`) or as a pre-cycle hook
    (``in_step=False``, float64; the simulator built with ``force_model=magnetic_force``). The hook's ``cycle``:
    ``"fast"`` (:class:`~magwarp.magnetics.fast_cycle.FastCycle`: the wanted wrenches, then a few lanes per mover,
    then the store; the default on a GPU, where it is 2.3-2.8x faster) or ``"block"`` (one launch, a block of threads
    per mover; the default on a CPU, where both take the same time); the same currents to rounding."""

    def __init__(self, sim, params: MagneticParams | None = None, spec: WrenchTableSpec | None = None,
                 options: CommutationOptions | None = None, use_cache: bool = True, in_step: bool = False,
                 precision: str = "float64", cycle: str | None = None):
        aux = sim.state.force_aux
        if aux.shape[2] < AUX_DIM:
            raise MagneticsError(f"the simulator's force_aux has {aux.shape[2]} columns; the magnetic drive needs "
                                 f"force_aux_dim >= {AUX_DIM} (and force_model=magnetic_force)")
        if precision not in PRECISIONS:
            raise MagneticsError(f"MagneticDrive precision must be one of {sorted(PRECISIONS)}, got {precision!r}")
        self.sim = sim
        dev = sim.device
        self.model = TableModel(sim.layout, params, spec, device=dev, use_cache=use_cache)
        self.commutation = Commutation(self.model.coilset, options, device=dev)
        w_, m_ = sim.num_worlds, sim.num_movers
        n = w_ * m_
        self._energy = wp.zeros((w_, m_), dtype=wp.float64, device=dev)
        self._dt = float(sim.model.limits.dt)
        self._ids, self._count, self._gamma, self._res, self._cycle, self._outputs = cycle_buffers(
            self.model, self.commutation, n)
        self.in_step, self.precision = bool(in_step), precision
        self.cycle = resolve_cycle(cycle, dev)
        if not self.in_step:
            if self.cycle == "fast":
                self._fast = FastCycle(self.model, self.commutation).reserve(n)
                self._pos = wp.zeros(n, dtype=wp.vec3d, device=dev)
                self._quat = wp.zeros(n, dtype=wp.quatd, device=dev)
                self._wanted = wp.zeros(n, dtype=vec6d, device=dev)
            sim.add_cycle_hook(self._before_cycle, before=True)
            return
        p = DriveParams()
        p.c, p.o = self._cycle, thread_outputs(self._res, self._count, self._ids)
        p.energy, p.dt, p.movers = self._energy, self._dt, m_
        sim.set_actuator(drive_actuator(self.model.max_active, precision), p)

    def _before_cycle(self, sim) -> None:
        m, s = sim.model, sim.state
        if self.cycle == "fast":
            wp.launch(drive_wanted_kernel, dim=(sim.num_worlds, sim.num_movers), device=sim.device,
                      inputs=[m.limits, m.impedance, m.body, s.cmd, s.target_pos, s.target_quat, s.force_aux, s.pos,
                              s.quat, s.vel, s.omega, s.acc],
                      outputs=[self._pos, self._quat, self._wanted])
            self._fast.run(self._pos, self._quat, self._wanted, self._res, self._count, self._ids)
            launch_store(sim, self._dt, self._res, self._energy)
            return
        wp.launch_tiled(drive_cycle_kernel, dim=[sim.num_worlds * sim.num_movers], block_dim=self.commutation.block_dim,
                        device=sim.device,
                        inputs=[m.limits, m.impedance, m.body, self._cycle, self._dt, s.cmd, s.target_pos,
                                s.target_quat, s.pos, s.quat, s.vel, s.omega, s.acc],
                        outputs=[self._outputs, s.force_aux, self._energy])

    # Device launches only (one, or the fast cycle's five), no host work: the trajectory env's fused step (and its CUDA
    # graph) may run it
    # (magwarp.envs.trajectory_fused.fused_step_blocker).
    _before_cycle.fused_step_safe = True

    def _view(self, arr, shape):
        return self.sim._t(arr.reshape(shape))

    @property
    def currents(self):
        """[W, M, slots] currents (A) of the active coils (torch view)."""
        return self._view(self._res.currents, (self.sim.num_worlds, self.sim.num_movers, self.model.max_active))

    @property
    def coil_ids(self):
        """[W, M, slots] ids of the active coils, -1 for empty slots (torch view)."""
        return self._view(self._ids, (self.sim.num_worlds, self.sim.num_movers, self.model.max_active))

    @property
    def loss(self):
        """[W, M] copper loss (W) of the last cycle (torch view)."""
        return self.sim.force_aux[..., 6]

    @property
    def flags(self):
        """[W, M] commutation flags of the last cycle (float32 torch view of the integer bits)."""
        return self.sim.force_aux[..., 7]

    @property
    def energy(self):
        """[W, M] copper energy (J) since the drive was attached (torch view; zero it to restart)."""
        return self.sim._t(self._energy)


@dataclass(frozen=True)
class MagneticModel:
    """The magnetic force model as a simulator option: ``Simulator(..., force_model=MagneticModel(...))`` or
    ``force_model="magnetic"`` (the defaults). ``params``: the design (:class:`MagneticParams`); ``table``: the
    wrench table's grid (:class:`~magwarp.magnetics.table.WrenchTableSpec`); ``options``: the commutation's;
    ``in_step``, ``precision``, ``cycle``: where, in what arithmetic and in which launch shape the cycle runs
    (:class:`MagneticDrive`)."""

    params: MagneticParams | None = None
    table: WrenchTableSpec | None = None
    options: CommutationOptions | None = None
    use_cache: bool = True
    in_step: bool = False
    precision: str = "float64"
    cycle: str | None = None

    def attach(self, sim) -> MagneticDrive:
        return MagneticDrive(sim, self.params, self.table, self.options, self.use_cache, self.in_step,
                             self.precision, self.cycle)


#: Force models by name (``Simulator(force_model=NAME)``); None: the ideal model.
FORCE_MODELS = {"ideal": None, "magnetic": MagneticModel}


def resolve_force_model(force_model, force_aux_dim: int):
    """``(force function or None, force_aux_dim, attach or None)`` for a simulator's ``force_model`` argument: a
    name of :data:`FORCE_MODELS`, a :class:`MagneticModel`, or a ``@wp.func`` (returned as given). ``attach(sim)``
    runs once the simulator is built (the magnetic drive's hook)."""
    if isinstance(force_model, str):
        if force_model not in FORCE_MODELS:
            raise ValueError(f"unknown force_model {force_model!r}; known: {sorted(FORCE_MODELS)} (or a @wp.func "
                             f"or a MagneticModel)")
        factory = FORCE_MODELS[force_model]
        force_model = factory() if factory is not None else None
    if isinstance(force_model, MagneticModel):
        return magnetic_force, max(int(force_aux_dim), AUX_DIM), force_model.attach
    return force_model, force_aux_dim, None
