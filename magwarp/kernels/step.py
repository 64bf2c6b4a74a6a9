"""Step kernels: one control cycle of one mover (command limits, force model, integration, wall check), composed
into the launch shapes the simulator uses.

* :func:`make_advance_kernel` returns ``advance_movers`` — one thread per mover for one cycle (binning it into the
  grid on the way); the simulator launches it once per cycle, followed by the narrow phase. Used for large worlds and
  whenever per-cycle hooks (metrics) must run between cycles — and ``fused_worlds`` — one thread per world runs every
  cycle of the step, movers and pair checks included, reading the state from memory.
* :func:`make_register_kernel` — the same fused step with the whole world held in registers, specialised for a mover
  count: the fast shape for many small worlds (the RL regime).

Action latency (per-world delays, :meth:`magwarp.sim.Simulator.set_latency`) is compiled in only when asked for
(``latency=True``): without it the kernels take placeholder arguments they never read.

All are built from a user-swappable force model (see :mod:`magwarp.kernels.impedance`), so a custom wrench law
needs no fork of the kernels: pass another ``@wp.func`` with the same signature.

An :class:`Actuator` (optional) turns the force model's wrench into the one that acts, inside the same kernels: every
cycle of every mover, ``func(params, w, m, last, pose, wanted, aux) -> Wrench`` with the actuator's own parameters
(``params``, a ``wp.struct`` of type ``params_type``, one kernel argument), ``last`` 1 in a step's last cycle (0 before
it; 1 on the per-cycle path); e.g. the magnetic drive's commutation (:mod:`magwarp.magnetics.drive`): the force model
gives the wanted wrench, the coils' currents the realised one. Without one the kernels take a placeholder
(:class:`NoActuator`).
"""

# (no "from __future__ import annotations": the kernels annotate an argument with the actuator's parameter type)

import functools
from dataclasses import dataclass

import warp as wp

from magwarp.kernels.collision import (collision_flags, hits_wall_cs, model_row, movers_collide_cs, push_to_cell,
                                       shape_heading, world_collision)
from magwarp.kernels.dynamics import integrate_body, integrate_planar64, planar_acceleration64, sync_planar64
from magwarp.kernels.impedance import default_force
from magwarp.kernels.options import MODULE_OPTIONS
from magwarp.kernels.params import body_f32, body_f64, row_body
from magwarp.types import Body, Collision, Grid, Impedance, Limits, Planar64, Pose, make_pose

# Forward simulation only: skipping adjoint code halves the (cold) compile time.
wp.set_module_options({"enable_backward": False, **MODULE_OPTIONS})


@wp.struct
class NoActuator:
    """The step kernels' actuator argument when there is no actuator (never read)."""

    unused: int


@dataclass(frozen=True)
class Actuator:
    """What turns the force model's (wanted) wrench into the acting one, inside the step kernels: ``func`` (a
    ``@wp.func``, see the module docstring) and the ``wp.struct`` type of its parameters."""

    func: object
    params_type: object


@wp.func
def delayed_command(
    cmd: wp.array2d(dtype=wp.vec2), prev_cmd: wp.array2d(dtype=wp.vec2), delay: wp.array(dtype=wp.int32), w: int,
    m: int, c: int,
):
    """Action latency: the command acting in cycle ``c`` of a step, the previous step's command during the world's
    first ``delay[w]`` cycles, then the new one."""
    if c < delay[w]:
        return prev_cmd[w, m]
    return cmd[w, m]


@wp.func
def body_impedance(imp: Impedance, b: Body) -> Impedance:
    """The impedance the force model sees for one mover: the mover's (per-world) gains with the shared hold mask."""
    out = Impedance()
    out.k_lin = b.k_lin
    out.k_rot = b.k_rot
    out.mask_lin = imp.mask_lin
    out.mask_rot = imp.mask_rot
    return out


@wp.func
def gravity_torque(com: wp.vec3, q: wp.quat) -> bool:
    """Whether gravity has a torque about the mover centre: a centre of mass off it, unless it lies on the vertical
    axis of a level mover (``q`` a pure yaw: ``cross(R com, (0, 0, -M g))`` is then exactly zero, so skipping it gives
    the same bits; a payload on top of a level mover, the sim2real preset's, costs nothing per cycle)."""
    if com[0] != 0.0 or com[1] != 0.0:
        return True
    return com[2] != 0.0 and (q[0] != 0.0 or q[1] != 0.0)


@functools.cache
def make_advance_kernel(force_fn=default_force, latency: bool = False, nominal: bool = False,
                        actuator: Actuator | None = None):
    """The per-cycle kernel, the fused per-world kernel and the one-mover cycle function, for ``force_fn`` (and
    ``actuator``, see the module docstring; the kernels' ``act`` argument is its parameters, else a
    :class:`NoActuator`).

    ``latency`` compiles in the action latency (:meth:`magwarp.sim.Simulator.set_latency`): the kernels then read the
    previous command ``prev_cmd`` during the first ``delay[w]`` cycles of a step, and the fused kernel copies the
    command into ``prev_cmd`` at the end of the step. Without it these arguments are placeholders, never read.

    ``nominal`` compiles the body rows as the simulator builds them (drive gain 1, centre of mass at the mover centre,
    the shared impedance gains and x/y limits): the same results bit for bit, without the per-world mass, payload,
    gain and limit reads (about 20% of a B0 step's physics on the CPU). The simulator uses it until a body row can differ
    (:meth:`~magwarp.sim.Simulator.make_per_world`, :attr:`~magwarp.sim.Simulator.mover_params`)."""
    act_type = actuator.params_type if actuator is not None else NoActuator
    act_fn = actuator.func if actuator is not None else None

    @wp.func
    def advance_pose(
        p: Pose, xy: Planar64, cmd: wp.vec2, b: Body, target_pos: wp.vec3, target_quat: wp.quat,
        aux: wp.array(dtype=float), lim: Limits, imp: Impedance, act: act_type, w: int, m: int, last: int,
    ):
        """One cycle of one mover: limited x/y drive, force model, semi-implicit Euler. Returns the new pose, the
        x/y drive acceleration and the new float64 x/y state.

        The acceleration is carried as state (jerk commands integrate from it, as MuJoCo's integrator actuator,
        ``act``, does in MagBotSim), not re-derived from the velocity change; the x/y law runs in float64
        (:func:`~magwarp.kernels.dynamics.planar_acceleration64`), the other axes in float32. ``xy`` is the float64
        x/y state, synced with the float32 fields where it was read from memory (:func:`sync_planar64`).

        Mass: the controller asks for ``m_ctrl a`` (its own, nominal mass), so the mover accelerates by
        ``a * b.drive_gain`` (``m_ctrl / m``; 1 nominal); the carried acceleration state stays the commanded one. A
        centre of mass off the mover centre (``b.com``, a payload) adds gravity's torque about the centre, where the
        levitation compensates the weight ``m g``."""
        if wp.static(nominal):  # the limits of the body rows as built: the shared ones
            a64 = planar_acceleration64(wp.vec2d(xy[2], xy[3]), wp.vec2d(xy[4], xy[5]), cmd, lim)
        else:
            a64 = planar_acceleration64(wp.vec2d(xy[2], xy[3]), wp.vec2d(xy[4], xy[5]), cmd, lim, b)
        a = wp.vec2(wp.float32(a64[0]), wp.float32(a64[1]))
        a_eff = a64
        if wp.static(not nominal):
            a_eff = a64 * b.drive_gain
        drive = wp.vec3(wp.float32(a_eff[0]) * b.mass, wp.float32(a_eff[1]) * b.mass, 0.0)
        if wp.static(nominal):
            wrench = force_fn(p, b, drive, target_pos, target_quat, imp, lim, aux)
        else:
            wrench = force_fn(p, b, drive, target_pos, target_quat, body_impedance(imp, b), lim, aux)
        if wp.static(actuator is not None):  # the force model's wrench is the wanted one; this one acts
            wrench = act_fn(act, w, m, last, p, wrench, aux)
        if wp.static(not nominal):
            if gravity_torque(b.com, p.quat):
                weight = wp.vec3(0.0, 0.0, -b.mass * lim.gravity)
                wrench.torque = wrench.torque + wp.cross(wp.quat_rotate(p.quat, b.com), weight)
        n = integrate_body(p, wrench, b, lim)
        extra = wp.vec2(wrench.force[0] - drive[0], wrench.force[1] - drive[1]) * b.inv_mass
        n, xy_new = integrate_planar64(n, xy, a_eff, extra, lim)
        xy_new[4] = a64[0]
        xy_new[5] = a64[1]
        return n, a, xy_new

    @wp.func
    def advance_mover(
        w: int,
        m: int,
        lim: Limits,
        imp: Impedance,
        col: Collision,
        tiles: wp.array2d(dtype=wp.int32),
        body: wp.array2d(dtype=Body),
        radius: wp.array2d(dtype=float),
        half_size: wp.array2d(dtype=wp.vec2),
        cmd: wp.array2d(dtype=wp.vec2),
        prev_cmd: wp.array2d(dtype=wp.vec2),
        delay: wp.array(dtype=wp.int32),
        c: int,
        last: int,
        act: act_type,
        target_pos: wp.array2d(dtype=wp.vec3),
        target_quat: wp.array2d(dtype=wp.quat),
        force_aux: wp.array3d(dtype=float),
        pos: wp.array2d(dtype=wp.vec3),
        quat: wp.array2d(dtype=wp.quat),
        vel: wp.array2d(dtype=wp.vec3),
        omega: wp.array2d(dtype=wp.vec3),
        acc: wp.array2d(dtype=wp.vec2),
        planar: wp.array2d(dtype=Planar64),
        wall: wp.array2d(dtype=wp.int32),
    ):
        p = make_pose(pos[w, m], quat[w, m], vel[w, m], omega[w, m])
        xy0 = sync_planar64(planar[w, m], p.pos, p.vel, acc[w, m])
        u = cmd[w, m]
        if wp.static(latency):
            u = delayed_command(cmd, prev_cmd, delay, w, m, c)
        n, a, xy = advance_pose(p, xy0, u, body[model_row(body.shape[0], w), m], target_pos[w, m], target_quat[w, m],
                                force_aux[w, m], lim, imp, act, w, m, last)
        pos[w, m] = n.pos
        quat[w, m] = n.quat
        vel[w, m] = n.vel
        omega[w, m] = n.omega
        acc[w, m] = a
        planar[w, m] = xy
        hit = int(0)
        if hits_wall_cs(tiles, col, wp.vec2(n.pos[0], n.pos[1]), shape_heading(col, n.quat),
                        radius[model_row(radius.shape[0], w), m], half_size[model_row(half_size.shape[0], w), m]):
            hit = 1
        wall[w, m] = hit

    @wp.kernel(module="unique", enable_backward=False, module_options=MODULE_OPTIONS)
    def advance_movers(
        # Model:
        lim: Limits,
        imp: Impedance,
        col_shared: Collision,
        tiles: wp.array2d(dtype=wp.int32),
        body: wp.array2d(dtype=Body),
        radius: wp.array2d(dtype=float),
        half_size: wp.array2d(dtype=wp.vec2),
        margins: wp.array(dtype=wp.vec2),
        act: act_type,  # the actuator's parameters (a NoActuator without one)
        # State in:
        cmd: wp.array2d(dtype=wp.vec2),
        prev_cmd: wp.array2d(dtype=wp.vec2),  # latency only: the previous step's command
        delay: wp.array(dtype=wp.int32),  # latency only: per-world delay (cycles)
        cycle: int,  # latency only: this cycle's index in the step
        target_pos: wp.array2d(dtype=wp.vec3),
        target_quat: wp.array2d(dtype=wp.quat),
        force_aux: wp.array3d(dtype=float),
        halted: wp.array(dtype=wp.int32),
        # State out:
        pos: wp.array2d(dtype=wp.vec3),
        quat: wp.array2d(dtype=wp.quat),
        vel: wp.array2d(dtype=wp.vec3),
        omega: wp.array2d(dtype=wp.vec3),
        acc: wp.array2d(dtype=wp.vec2),
        planar: wp.array2d(dtype=Planar64),
        wall: wp.array2d(dtype=wp.int32),
        cycles: wp.array(dtype=wp.int32),
        # Broad phase, folded in to save launches (bin_cells = 0: brute-force worlds, which clear the counters here):
        grid: Grid,
        bin_cells: int,
        head: wp.array(dtype=wp.int32),
        next_in_cell: wp.array2d(dtype=wp.int32),
        world_pairs: wp.array(dtype=wp.int32),
        world_walls: wp.array(dtype=wp.int32),
    ):
        w, m = wp.tid()
        col = world_collision(col_shared, margins, w)
        if bin_cells == 0 and m == 0:
            world_pairs[w] = 0
            world_walls[w] = 0
        if col.stop_on_collision == 0 or halted[w] == 0:
            advance_mover(w, m, lim, imp, col, tiles, body, radius, half_size, cmd, prev_cmd, delay, cycle, 1, act,
                          target_pos, target_quat, force_aux, pos, quat, vel, omega, acc, planar, wall)
            if m == 0:
                cycles[w] = cycles[w] + 1
        if bin_cells == 1:  # halted worlds are binned too: the collision check still runs on them
            push_to_cell(w, m, grid, pos, head, next_in_cell)

    @wp.kernel(module="unique", enable_backward=False, module_options=MODULE_OPTIONS)
    def fused_worlds(
        num_cycles: int,
        # Model:
        lim: Limits,
        imp: Impedance,
        col_shared: Collision,
        tiles: wp.array2d(dtype=wp.int32),
        body: wp.array2d(dtype=Body),
        radius: wp.array2d(dtype=float),
        half_size: wp.array2d(dtype=wp.vec2),
        margins: wp.array(dtype=wp.vec2),
        act: act_type,  # the actuator's parameters (a NoActuator without one)
        # State in:
        cmd: wp.array2d(dtype=wp.vec2),
        delay: wp.array(dtype=wp.int32),  # latency only: per-world delay (cycles)
        target_pos: wp.array2d(dtype=wp.vec3),
        target_quat: wp.array2d(dtype=wp.quat),
        force_aux: wp.array3d(dtype=float),
        # State out:
        prev_cmd: wp.array2d(dtype=wp.vec2),  # latency only: the previous step's command, then this step's
        pos: wp.array2d(dtype=wp.vec3),
        quat: wp.array2d(dtype=wp.quat),
        vel: wp.array2d(dtype=wp.vec3),
        omega: wp.array2d(dtype=wp.vec3),
        acc: wp.array2d(dtype=wp.vec2),
        planar: wp.array2d(dtype=Planar64),
        wall: wp.array2d(dtype=wp.int32),
        flags: wp.array2d(dtype=wp.int32),
        flags_any: wp.array2d(dtype=wp.int32),
        partner: wp.array2d(dtype=wp.int32),
        world_pairs: wp.array(dtype=wp.int32),
        world_walls: wp.array(dtype=wp.int32),
        halted: wp.array(dtype=wp.int32),
        cycles: wp.array(dtype=wp.int32),
        pair_list: wp.array2d(dtype=wp.vec2i),
    ):
        w = wp.tid()
        col = world_collision(col_shared, margins, w)
        wr = model_row(radius.shape[0], w)
        wh = model_row(half_size.shape[0], w)
        num_movers = pos.shape[1]
        # The per-step accumulators start here (no separate begin_step launch for fused steps).
        halted[w] = 0
        cycles[w] = 0
        for m in range(num_movers):
            flags_any[w, m] = 0
        for c in range(num_cycles):
            if col.stop_on_collision == 1 and halted[w] == 1:
                break
            for m in range(num_movers):
                advance_mover(w, m, lim, imp, col, tiles, body, radius, half_size, cmd, prev_cmd, delay, c,
                              int(c == num_cycles - 1), act, target_pos, target_quat, force_aux, pos, quat, vel,
                              omega, acc, planar, wall)
            cycles[w] = cycles[w] + 1
            # Brute-force pairs: each pair once, partner = lowest colliding index, same as the per-mover kernels.
            for m in range(num_movers):
                partner[w, m] = -1
            pairs = int(0)
            walls = int(0)
            for i in range(num_movers):
                pi = pos[w, i]
                yi = shape_heading(col, quat[w, i])
                for j in range(i + 1, num_movers):
                    pj = pos[w, j]
                    d = wp.vec2(pi[0] - pj[0], pi[1] - pj[1])
                    if movers_collide_cs(col, d, yi, radius[wr, i], half_size[wh, i], shape_heading(col, quat[w, j]),
                                         radius[wr, j], half_size[wh, j]):
                        if pairs < pair_list.shape[1]:
                            pair_list[w, pairs] = wp.vec2i(i, j)
                        pairs += 1
                        if partner[w, i] < 0:
                            partner[w, i] = j
                        if partner[w, j] < 0:
                            partner[w, j] = i
            for m in range(num_movers):
                f = collision_flags(partner[w, m], wall[w, m])
                if wall[w, m] != 0:
                    walls += 1
                flags[w, m] = f
                flags_any[w, m] = flags_any[w, m] | f
            world_pairs[w] = pairs
            world_walls[w] = walls
            if pairs > 0 or walls > 0:
                halted[w] = 1
        if wp.static(latency):  # the next step's previous command
            for m in range(num_movers):
                prev_cmd[w, m] = cmd[w, m]

    return advance_movers, fused_worlds, advance_pose


@functools.cache
def make_register_kernel(force_fn, num_movers: int, latency: bool = False, nominal: bool = False,
                         register_rows: str = "all", actuator: Actuator | None = None):
    """The fused small-world kernel with every mover's state held in registers for the whole step.

    Specialised for ``num_movers`` (loops over movers unroll), it reads the world's state once, runs all cycles and
    writes the state back once: global memory traffic no longer scales with the cycle count. Same semantics as
    ``fused_worlds``, action latency (``latency``) included. The general variant (``nominal=False``: per-world body
    rows and collision sizes, domain randomisation) loads the world's rows into registers once per step too, where the
    nominal one reads the one shared row (cached) every cycle. ``register_rows`` (:data:`~magwarp.kernels.options.
    REGISTER_ROWS`): which rows the general variant holds: ``"all"``, ``"f32"`` (the body rows' float32 fields and the
    collision sizes; the float64 limits read every cycle), ``"sizes"`` (collision sizes; body rows read every cycle)
    or ``"none"`` (read every cycle, as the nominal variant does); the same results either way.
    """
    M = int(num_movers)
    body_regs = bool(not nominal and register_rows in ("all", "f32"))
    f64_regs = bool(body_regs and register_rows == "all")
    size_regs = bool(not nominal and register_rows in ("all", "f32", "sizes"))
    advance_pose = make_advance_kernel(force_fn, latency, nominal, actuator)[2]
    act_type = actuator.params_type if actuator is not None else NoActuator
    Rows3 = wp.types.matrix(shape=(M, 3), dtype=wp.float32)
    Rows4 = wp.types.matrix(shape=(M, 4), dtype=wp.float32)
    Rows2 = wp.types.matrix(shape=(M, 2), dtype=wp.float32)
    Rows6d = wp.types.matrix(shape=(M, 6), dtype=wp.float64)
    Ints = wp.types.vector(length=M, dtype=wp.int32)
    Sizes = wp.types.vector(length=M, dtype=wp.float32)
    BodyRows = wp.types.matrix(shape=(M, 20), dtype=wp.float32)
    BodyRows64 = wp.types.matrix(shape=(M, 4), dtype=wp.float64)

    @wp.kernel(module="unique", enable_backward=False, module_options=MODULE_OPTIONS)
    def fused_registers(
        num_cycles: int,
        # Model:
        lim: Limits,
        imp: Impedance,
        col_shared: Collision,
        tiles: wp.array2d(dtype=wp.int32),
        body: wp.array2d(dtype=Body),
        radius: wp.array2d(dtype=float),
        half_size: wp.array2d(dtype=wp.vec2),
        margins: wp.array(dtype=wp.vec2),
        act: act_type,  # the actuator's parameters (a NoActuator without one)
        # State in:
        cmd: wp.array2d(dtype=wp.vec2),
        delay: wp.array(dtype=wp.int32),  # latency only: per-world delay (cycles)
        target_pos: wp.array2d(dtype=wp.vec3),
        target_quat: wp.array2d(dtype=wp.quat),
        force_aux: wp.array3d(dtype=float),
        # State out:
        prev_cmd: wp.array2d(dtype=wp.vec2),  # latency only: the previous step's command, then this step's
        pos: wp.array2d(dtype=wp.vec3),
        quat: wp.array2d(dtype=wp.quat),
        vel: wp.array2d(dtype=wp.vec3),
        omega: wp.array2d(dtype=wp.vec3),
        acc: wp.array2d(dtype=wp.vec2),
        planar: wp.array2d(dtype=Planar64),
        wall: wp.array2d(dtype=wp.int32),
        flags: wp.array2d(dtype=wp.int32),
        flags_any: wp.array2d(dtype=wp.int32),
        partner: wp.array2d(dtype=wp.int32),
        world_pairs: wp.array(dtype=wp.int32),
        world_walls: wp.array(dtype=wp.int32),
        halted: wp.array(dtype=wp.int32),
        cycles: wp.array(dtype=wp.int32),
        pair_list: wp.array2d(dtype=wp.vec2i),
    ):
        w = wp.tid()
        col = world_collision(col_shared, margins, w)
        wb = model_row(body.shape[0], w)
        wr = model_row(radius.shape[0], w)
        wh = model_row(half_size.shape[0], w)
        P = Rows3()
        V = Rows3()
        Om = Rows3()
        Q = Rows4()
        A = Rows2()
        XY = Rows6d()
        Wl = Ints()
        F = Ints()
        Fa = Ints()
        Pr = Ints()
        # The acting command: the step's (held for the whole step: loaded once) or, with latency, the previous
        # step's during the world's first ``held`` cycles, the step's from cycle ``held`` on (loaded then, once).
        C = Rows2()
        held = int(0)
        if wp.static(latency):
            held = delay[w]
        TP = Rows3()
        TQ = Rows4()
        # general variant: the world's body rows and collision sizes, once per step
        BF = BodyRows()
        BD = BodyRows64()
        R = Sizes()
        H = Rows2()
        for m in range(M):
            if wp.static(body_regs):
                b = body[wb, m]
                BF[m] = body_f32(b)
                if wp.static(f64_regs):
                    BD[m] = body_f64(b)
            if wp.static(size_regs):
                R[m] = radius[wr, m]
                H[m] = half_size[wh, m]
            C[m] = cmd[w, m]
            if wp.static(latency):
                if held > 0:
                    C[m] = prev_cmd[w, m]
            TP[m] = target_pos[w, m]
            tq = target_quat[w, m]
            TQ[m] = wp.vec4(tq[0], tq[1], tq[2], tq[3])
            P[m] = pos[w, m]
            V[m] = vel[w, m]
            Om[m] = omega[w, m]
            q = quat[w, m]
            Q[m] = wp.vec4(q[0], q[1], q[2], q[3])
            A[m] = acc[w, m]
            XY[m] = sync_planar64(planar[w, m], pos[w, m], vel[w, m], acc[w, m])
            Wl[m] = wall[w, m]
            F[m] = flags[w, m]
            Fa[m] = 0  # per-step accumulators start here: fused steps need no begin_step launch
            Pr[m] = partner[w, m]
        pairs = world_pairs[w]
        walls = world_walls[w]
        stopped = int(0)
        done = int(0)
        for c in range(num_cycles):
            if col.stop_on_collision == 1 and stopped == 1:
                break
            if wp.static(latency):
                if c == held and c > 0:
                    for m in range(M):
                        C[m] = cmd[w, m]
            for m in range(M):
                p = make_pose(P[m], wp.quat(Q[m, 0], Q[m, 1], Q[m, 2], Q[m, 3]), V[m], Om[m])
                u = C[m]
                if wp.static(not body_regs):
                    bm = body[wb, m]
                elif wp.static(f64_regs):
                    bm = row_body(BF[m], BD[m])
                else:
                    bm = row_body(BF[m], body_f64(body[wb, m]))
                n, a, xy = advance_pose(p, XY[m], u, bm, TP[m], wp.quat(TQ[m, 0], TQ[m, 1], TQ[m, 2], TQ[m, 3]),
                                        force_aux[w, m], lim, imp, act, w, m, int(c == num_cycles - 1))
                P[m] = n.pos
                V[m] = n.vel
                Om[m] = n.omega
                Q[m] = wp.vec4(n.quat[0], n.quat[1], n.quat[2], n.quat[3])
                A[m] = a
                XY[m] = xy
                rm = float(0.0)
                hm = wp.vec2(0.0)
                if wp.static(not size_regs):
                    rm = radius[wr, m]
                    hm = half_size[wh, m]
                else:
                    rm = R[m]
                    hm = H[m]
                hit = int(0)
                if hits_wall_cs(tiles, col, wp.vec2(n.pos[0], n.pos[1]), shape_heading(col, n.quat), rm, hm):
                    hit = 1
                Wl[m] = hit
                Pr[m] = -1
            done += 1
            pairs = int(0)
            walls = int(0)
            # Both loops have constant bounds so that they unroll and every index is a constant: a dynamic index
            # would push the whole register block (P, Q, Pr) out to local memory.
            for i in range(M):
                yi = shape_heading(col, wp.quat(Q[i, 0], Q[i, 1], Q[i, 2], Q[i, 3]))
                for j in range(M):
                    if j > i:
                        d = wp.vec2(P[i, 0] - P[j, 0], P[i, 1] - P[j, 1])
                        yj = shape_heading(col, wp.quat(Q[j, 0], Q[j, 1], Q[j, 2], Q[j, 3]))
                        ri = float(0.0)
                        rj = float(0.0)
                        hi = wp.vec2(0.0)
                        hj = wp.vec2(0.0)
                        if wp.static(not size_regs):
                            ri = radius[wr, i]
                            rj = radius[wr, j]
                            hi = half_size[wh, i]
                            hj = half_size[wh, j]
                        else:
                            ri = R[i]
                            rj = R[j]
                            hi = H[i]
                            hj = H[j]
                        if movers_collide_cs(col, d, yi, ri, hi, yj, rj, hj):
                            if pairs < pair_list.shape[1]:
                                pair_list[w, pairs] = wp.vec2i(i, j)
                            pairs += 1
                            if Pr[i] < 0:
                                Pr[i] = j
                            if Pr[j] < 0:
                                Pr[j] = i
            for m in range(M):
                f = collision_flags(Pr[m], Wl[m])
                if Wl[m] != 0:
                    walls += 1
                F[m] = f
                Fa[m] = Fa[m] | f
            if pairs > 0 or walls > 0:
                stopped = 1
        for m in range(M):
            pos[w, m] = P[m]
            vel[w, m] = V[m]
            omega[w, m] = Om[m]
            quat[w, m] = wp.quat(Q[m, 0], Q[m, 1], Q[m, 2], Q[m, 3])
            acc[w, m] = A[m]
            planar[w, m] = XY[m]
            wall[w, m] = Wl[m]
            flags[w, m] = F[m]
            flags_any[w, m] = Fa[m]
            partner[w, m] = Pr[m]
            if wp.static(latency):  # the next step's previous command
                prev_cmd[w, m] = cmd[w, m]
        world_pairs[w] = pairs
        world_walls[w] = walls
        halted[w] = stopped
        cycles[w] = done

    return fused_registers


@wp.kernel
def begin_step(
    flags_any: wp.array2d(dtype=wp.int32), halted: wp.array(dtype=wp.int32), cycles: wp.array(dtype=wp.int32)
):
    """Clear the per-step accumulators (one thread per mover)."""
    w, m = wp.tid()
    flags_any[w, m] = 0
    if m == 0:
        halted[w] = 0
        cycles[w] = 0


@wp.kernel
def hold_commands(cmd: wp.array2d(dtype=wp.vec2), prev_cmd: wp.array2d(dtype=wp.vec2)):
    """Action latency on the per-cycle path: at the end of a step its command becomes the previous one."""
    w, m = wp.tid()
    prev_cmd[w, m] = cmd[w, m]


@wp.kernel
def reset_worlds(
    mask: wp.array(dtype=wp.int32),
    init_pos: wp.array2d(dtype=wp.vec3),
    init_quat: wp.array2d(dtype=wp.quat),
    pos: wp.array2d(dtype=wp.vec3),
    quat: wp.array2d(dtype=wp.quat),
    vel: wp.array2d(dtype=wp.vec3),
    omega: wp.array2d(dtype=wp.vec3),
    acc: wp.array2d(dtype=wp.vec2),
    cmd: wp.array2d(dtype=wp.vec2),
    target_pos: wp.array2d(dtype=wp.vec3),
    target_quat: wp.array2d(dtype=wp.quat),
    flags: wp.array2d(dtype=wp.int32),
    flags_any: wp.array2d(dtype=wp.int32),
    partner: wp.array2d(dtype=wp.int32),
    wall: wp.array2d(dtype=wp.int32),
    world_pairs: wp.array(dtype=wp.int32),
    world_walls: wp.array(dtype=wp.int32),
    halted: wp.array(dtype=wp.int32),
    cycles: wp.array(dtype=wp.int32),
):
    """Put the masked worlds back at their start poses, at rest, hovering, with cleared collision outputs (per mover
    and per world: a reset world reports no pairs, no walls, not halted, no cycles)."""
    w, m = wp.tid()
    if mask[w] == 0:
        return
    if m == 0:
        world_pairs[w] = 0
        world_walls[w] = 0
        halted[w] = 0
        cycles[w] = 0
    p = init_pos[w, m]
    q = init_quat[w, m]
    pos[w, m] = p
    quat[w, m] = q
    vel[w, m] = wp.vec3(0.0)
    omega[w, m] = wp.vec3(0.0)
    acc[w, m] = wp.vec2(0.0)
    cmd[w, m] = wp.vec2(0.0)
    target_pos[w, m] = p
    target_quat[w, m] = q
    flags[w, m] = 0
    flags_any[w, m] = 0
    partner[w, m] = -1
    wall[w, m] = 0
