"""The magnetic control cycle with one thread per mover: wrench-table look-up and commutation, in float32 or float64.

    cycle = ThreadCycle(table_model, commutation)          # precision="float32" (default) or "float64"
    cycle.run(pos, quat, wanted, result, count=None, coil_ids=None, gamma=None)  # ids, columns: written when given

In the simulator it runs inside the step kernels (:class:`~magwarp.magnetics.drive.MagneticDrive`, ``in_step``).

The same problem as :mod:`~magwarp.magnetics.commutation` (least copper loss under per-coil limits, the same primal
active-set steps, the same flags), solved by one thread per mover with its window's columns in its own local array
(slots x 6; on a GPU local memory is interleaved across a warp's threads, so the reads are coalesced) instead of a
block of threads with reductions over shared memory:

1. one pass over the window: each slot's coil and its interpolated column
   (:func:`~magwarp.magnetics.table.slot_coil`, :func:`~magwarp.magnetics.table.table_column_at`: the height cell
   and the yaw samples, with their sines and cosines, once per mover), kept locally, and the free coils' 6 x 6
   matrix (lower triangle);
2. the fast path: one scaled Cholesky solve (plus, in float32, one step of iterative refinement: the residual
   ``rhs - A y`` solved again, which brings the delivered wrench to float32 rounding of the wanted one), then one pass
   that writes every coil's current and sums the delivered wrench and the loss; if no coil passes its limit, that is
   the answer (no coil saturated: most movers);
3. otherwise the active-set steps of the float64 kernel (step toward the free coils' optimum as far as the first
   limit, fix the coils that reach it, re-solve), on the local columns, and a last pass.

A current computed as ``g . Y / R`` can pass its limit by rounding in the last digit (float32: about 1e-7 of the
limit); such a free current is held at the limit, so a written current never exceeds its limit.

Precision: the columns are kept as float32 (what the float16 table interpolates to) either way; ``precision`` is the
arithmetic of the 6 x 6 matrix, its solve and the per-slot sums. ``"float64"`` gives the block kernel's results to
rounding (``tests/test_magnetics_thread_cycle.py``). ``"float32"`` (against the float64 least-squares reference on
the same columns, movers that need no regularisation): currents within 1e-3 of the limit, the delivered wrench within
1e-5 of the wanted wrench's size when feasible, the same saturated coils but for near-ties. Where the system needs
regularisation (a pivot of the unit-diagonal matrix below ``regularization``, 1e-6: few free coils left after many
saturated), float32 rounding is amplified by about its inverse: the currents and the delivered wrench differ from
float64's by percents and jitter from cycle to cycle (flagged :data:`FLAG_REGULARISED` either way). The simulator's
drive uses float64 by default for that reason.

The coil ids and Gamma columns are written only when asked (``gamma``: 24 bytes per slot and mover, 1 GB per cycle at
1M movers); the currents (float64, as :class:`~magwarp.magnetics.commutation.CommutationResult`) always (the in-step
drive: in a step's last cycle only).
"""

# (no "from __future__ import annotations": the kernels annotate with types made in make_thread_cycle)

import functools

import warp as wp

from magwarp.magnetics.commutation import (FLAG_NO_COILS, FLAG_NOT_CONVERGED, FLAG_REGULARISED, CommutationResult,
                                           add_outer_lower, make_scaled_solver, vec6f)
from magwarp.magnetics.cycle import CycleParams, check_arrays, cycle_params
from magwarp.magnetics.exact import vec6d
from magwarp.magnetics.geometry import MagneticsError
from magwarp.magnetics.table import TableModel, column_context, quat_yaw, slot_coil, table_column_at

__all__ = ["PRECISIONS", "ThreadCycle", "ThreadOutputs", "make_thread_cycle"]

#: The arithmetic of the 6 x 6 matrix, its solve and the per-slot sums.
PRECISIONS = {"float32": wp.float32, "float64": wp.float64}


@wp.struct
class ThreadOutputs:
    """What the one-thread cycle writes per mover (flat index): the commutation's result, the look-up's coil ids when
    ``store_ids`` is 1 and its columns when ``store_gamma`` is 1 (the arrays may be empty otherwise)."""

    currents: wp.array2d(dtype=wp.float64)
    saturated: wp.array2d(dtype=wp.int32)
    delivered: wp.array(dtype=vec6d)
    residual: wp.array(dtype=vec6d)
    loss: wp.array(dtype=wp.float64)
    flags: wp.array(dtype=wp.int32)
    count: wp.array(dtype=wp.int32)
    store_ids: int
    store_gamma: int
    coil_ids: wp.array2d(dtype=wp.int32)
    gamma: wp.array2d(dtype=vec6f)


@functools.cache
def make_thread_cycle(slots: int, precision: str = "float32"):
    """``(mover_func, kernel)`` of the one-thread cycle for a window of ``slots`` slots in ``precision``.

    ``mover_func(c, i, x, y, z, yaw, wanted, o, write)`` (a ``@wp.func``) runs mover ``i``'s cycle at (x, y, z, yaw)
    and, where ``write`` is 1, writes row ``i`` of the :class:`ThreadOutputs` ``o`` (0: nothing written, e.g. the
    cycles of a simulator step but its last); it returns the delivered wrench
    (``vec6f``), the copper loss (float32, W) and the flags. ``kernel`` runs it for every mover of float64 pose
    arrays (as the :class:`~magwarp.magnetics.cycle.ControlCycle`)."""
    if precision not in PRECISIONS:
        raise MagneticsError(f"precision must be one of {sorted(PRECISIONS)}, got {precision!r}")
    S = int(slots)
    real = PRECISIONS[precision]
    f32 = precision == "float32"
    vec6r = wp.types.vector(length=6, dtype=real)
    mat66r = wp.types.matrix(shape=(6, 6), dtype=real)
    Cols = wp.types.matrix(shape=(S, 6), dtype=wp.float32)  # the columns are float32 (from a float16 table)
    Ints = wp.types.vector(length=S, dtype=wp.int32)
    # The share of a step within which a coil that reaches its limit counts as reaching it with the first one.
    hit_tol = 1.0e-6 if f32 else 1.0e-12

    solve = make_scaled_solver(real, refine=f32)

    @wp.func
    def to_real(v: vec6f) -> vec6r:
        return vec6r(real(v[0]), real(v[1]), real(v[2]), real(v[3]), real(v[4]), real(v[5]))

    @wp.func
    def to_f32(v: vec6r) -> vec6f:
        return vec6f(float(v[0]), float(v[1]), float(v[2]), float(v[3]), float(v[4]), float(v[5]))

    @wp.func
    def to_f64(v: vec6r) -> vec6d:
        return vec6d(wp.float64(v[0]), wp.float64(v[1]), wp.float64(v[2]), wp.float64(v[3]), wp.float64(v[4]),
                     wp.float64(v[5]))

    @wp.func
    def row(cols: Cols, j: int) -> vec6r:
        return vec6r(real(cols[j, 0]), real(cols[j, 1]), real(cols[j, 2]), real(cols[j, 3]), real(cols[j, 4]),
                     real(cols[j, 5]))

    @wp.func
    def coil_step(c: CycleParams, k: int, g: vec6r, yv: vec6r, big_y: vec6r):
        """A free coil on a step from the currents of ``big_y`` toward those of ``yv``: its current at the step's end,
        the share of the step at which it reaches its limit (2 where it never does), 1 / R and its limit."""
        r_inv = real(1.0) / real(c.resistance[k])
        lim = real(c.limit[k])
        t = wp.dot(g, yv) * r_inv
        reach = real(2.0)
        if wp.abs(t) > lim:
            now = wp.dot(g, big_y) * r_inv
            reach = (wp.sign(t) * lim - now) / (t - now)
        return t, reach, r_inv, lim

    @wp.func
    def current(c: CycleParams, k: int, g: vec6r, big_y: vec6r, sat: int) -> real:
        """A coil's current: at its limit with the sign ``sat`` (+1, -1) where saturated, else ``g . Y / R`` (held
        within the limit: rounding)."""
        lim = real(c.limit[k])
        if sat != 0:
            return real(sat) * lim
        return wp.clamp(wp.dot(g, big_y) / real(c.resistance[k]), -lim, lim)

    @wp.func
    def mover_cycle(c: CycleParams, i: int, x: float, y: float, z: float, yaw: float, wanted: vec6r,
                    o: ThreadOutputs, write: int):
        """Mover ``i``'s look-up and commutation by this thread (see the module docstring). Per slot the thread keeps
        the column, the coil id and the saturation (0, or the sign of the current held at the limit)."""
        cols = Cols()
        ids = Ints()
        sat = Ints()
        a = mat66r()
        n = int(0)
        # the height cell and yaw samples are the same for every slot: once per mover
        kz, fz, y0, fy, rot, out = column_context(c.table, z, yaw)
        for j in range(S):
            k, l, dx, dy = slot_coil(c.table, c.slot_layer, c.slot_offset, j, x, y)
            col = vec6f()
            if k >= 0:
                col = table_column_at(c.table, l, dx, dy, kz, fz, y0, fy, rot)
            ids[j] = k
            if write != 0:
                if o.store_ids != 0:
                    o.coil_ids[i, j] = k
                if o.store_gamma != 0:
                    o.gamma[i, j] = col
            if k >= 0:
                for r in range(6):
                    cols[j, r] = col[r]
                a = add_outer_lower(a, to_real(col), real(1.0) / real(c.resistance[k]))
                n += 1
        if out and n > 0:  # as many look-ups outside the table's heights as the window's coils
            wp.atomic_add(c.table.out_of_range, 0, n)
        reg = real(c.reg)
        flag = int(0)
        if n == 0:
            flag = flag | FLAG_NO_COILS
        rhs = wanted
        big_y = vec6r()  # the free coils' currents are g . Y / R
        converged = bool(n == 0)
        n_free = n
        it = int(0)
        delivered = vec6r()
        loss = real(0.0)
        while it < c.max_iter and not converged and n_free > 0:
            it += 1
            yv, regd = solve(a, rhs, reg)
            if regd:
                flag = flag | FLAG_REGULARISED
            # How far toward the free coils' optimum the limits allow. On the first solve (every coil free) also the
            # currents (written), the delivered wrench and the loss: if no coil passes its limit, that is the answer.
            alpha = real(1.0)
            first = it == 1
            for j in range(S):
                k = ids[j]
                if k >= 0 and sat[j] == 0:
                    g = row(cols, j)
                    t, reach, r_inv, lim = coil_step(c, k, g, yv, big_y)
                    alpha = wp.min(alpha, reach)
                    if first:
                        t = wp.clamp(t, -lim, lim)  # (a current beyond its limit means another pass follows)
                        delivered = delivered + g * t
                        loss = loss + real(c.resistance[k]) * t * t
                        if write != 0:
                            o.currents[i, j] = wp.float64(t)
                            o.saturated[i, j] = 0
                elif first and write != 0:
                    o.currents[i, j] = wp.float64(0.0)
                    o.saturated[i, j] = 0
            if alpha >= real(1.0):
                big_y = yv
                converged = True
            else:
                # Fix the coils that reach their limit (within rounding of the step), rebuild the others' matrix.
                hit = alpha * (real(1.0) + real(hit_tol))
                a = mat66r()
                for j in range(S):
                    k = ids[j]
                    if k >= 0 and sat[j] == 0:
                        g = row(cols, j)
                        t, reach, r_inv, lim = coil_step(c, k, g, yv, big_y)
                        if reach <= hit:
                            sat[j] = int(wp.sign(t))
                            rhs = rhs - g * (wp.sign(t) * lim)
                            n_free -= 1
                        else:
                            a = add_outer_lower(a, g, r_inv)
                big_y = big_y + alpha * (yv - big_y)
        if not converged:
            flag = flag | FLAG_NOT_CONVERGED
        if it != 1 or not converged:  # not the first solve's answer: the last pass
            delivered = vec6r()
            loss = real(0.0)
            for j in range(S):
                k = ids[j]
                t = real(0.0)
                if k >= 0:
                    g = row(cols, j)
                    t = current(c, k, g, big_y, sat[j])
                    delivered = delivered + g * t
                    loss = loss + real(c.resistance[k]) * t * t
                if write != 0:
                    o.currents[i, j] = wp.float64(t)
                    o.saturated[i, j] = wp.where(sat[j] != 0, 1, 0)
        if write != 0:
            d64 = to_f64(delivered)
            o.count[i] = n
            o.delivered[i] = d64
            o.residual[i] = to_f64(wanted) - d64
            o.loss[i] = wp.float64(loss)
            o.flags[i] = flag
        return to_f32(delivered), float(loss), flag

    @wp.kernel(module="unique")
    def thread_cycle_kernel(
        # Model:
        c: CycleParams,
        # State in:
        pos: wp.array(dtype=wp.vec3d),
        quat: wp.array(dtype=wp.quatd),
        wanted: wp.array(dtype=vec6d),
        # State out:
        o: ThreadOutputs,
    ):
        """One thread per mover: the look-up of its window, then least-loss currents within the limits."""
        i = wp.tid()
        p = pos[i]
        w = wanted[i]
        mover_cycle(c, i, float(p[0]), float(p[1]), float(p[2]), quat_yaw(quat[i]),
                    vec6r(real(w[0]), real(w[1]), real(w[2]), real(w[3]), real(w[4]), real(w[5])), o, 1)

    return mover_cycle, thread_cycle_kernel


def thread_outputs(res: CommutationResult, count: wp.array, coil_ids: wp.array | None = None,
                   gamma: wp.array | None = None) -> ThreadOutputs:
    """The :class:`ThreadOutputs` of these arrays (``coil_ids`` and ``gamma``: written only when given)."""
    o = ThreadOutputs()
    o.currents, o.saturated, o.delivered, o.residual = res.currents, res.saturated, res.delivered, res.residual
    o.loss, o.flags, o.count = res.loss, res.flags, count
    dev = res.currents.device
    o.store_ids = 0 if coil_ids is None else 1
    o.store_gamma = 0 if gamma is None else 1
    o.coil_ids = coil_ids if coil_ids is not None else wp.empty((0, 0), dtype=wp.int32, device=dev)
    o.gamma = gamma if gamma is not None else wp.empty((0, 0), dtype=vec6f, device=dev)
    return o


class ThreadCycle:
    """The wrench-table look-up of ``model`` and the commutation of ``commutation`` (its resistances, limits and
    options; not its threads per mover) in one launch of one thread per mover, in ``precision``."""

    def __init__(self, model: TableModel, commutation, precision: str = "float32"):
        self.params = cycle_params(model, commutation)
        self.model, self.commutation, self.precision = model, commutation, precision
        self.mover_func, self.kernel = make_thread_cycle(model.max_active, precision)

    def run(self, pos: wp.array, quat: wp.array, wanted: wp.array, out: CommutationResult,
            count: wp.array | None = None, coil_ids: wp.array | None = None,
            gamma: wp.array | None = None) -> CommutationResult:
        """The commutation's result ``out`` (as :meth:`Commutation.solve`; the coil counts into ``count`` when given)
        for movers at ``pos``/``quat`` (float64) wanting ``wanted`` (``vec6d``); the coil ids and columns (as
        :meth:`TableModel.columns`) into ``coil_ids`` and ``gamma`` when given."""
        n, slots, dev = pos.shape[0], self.model.max_active, self.model.device
        count = count if count is not None else wp.empty(n, dtype=wp.int32, device=dev)
        shapes = {"quat": (quat.shape, (n,)), "wanted": (wanted.shape, (n,)), "count": (count.shape, (n,)),
                  "currents": (out.currents.shape, (n, slots))}
        if coil_ids is not None:
            shapes["coil_ids"] = (coil_ids.shape, (n, slots))
        if gamma is not None:
            shapes["gamma"] = (gamma.shape, (n, slots))
        arrays = {"pos": pos, "quat": quat, "wanted": wanted, "count": count, "currents": out.currents,
                  "coil_ids": coil_ids, "gamma": gamma}
        check_arrays("ThreadCycle.run", shapes, arrays, dev)
        wp.launch(self.kernel, dim=n, device=dev, inputs=[self.params, pos, quat, wanted],
                  outputs=[thread_outputs(out, count, coil_ids, gamma)])
        return out
