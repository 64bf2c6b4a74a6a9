"""The magnetic control cycle with a few lanes per mover: wrench-table look-up and commutation, the no-saturation answer
first.

    cycle = FastCycle(table_model, commutation)       # lanes: 16 per mover on a GPU, 1 on a CPU
    cycle.run(pos, quat, wanted, result, count=None, coil_ids=None, gamma=None)  # ids, columns: written when given

The same problem, algorithm and float64 arithmetic as :mod:`~magwarp.magnetics.cycle` (the block cycle: one block of
32 threads per mover, :func:`~magwarp.magnetics.commutation.make_commutation_func`), with the same results to
rounding (``tests/test_magnetics_fast_cycle.py``), in another launch shape:

* ``lanes`` adjacent threads per mover (a GPU warp holds 32 / lanes movers); lane ``l`` takes the window slots
  ``l, l + lanes, ...`` (6 of the default 42 at 8 lanes, 2 or 3 at the GPU's default 16), looks their columns up once
  (:func:`~magwarp.magnetics.table.slot_coil`, :func:`~magwarp.magnetics.table.table_column_at`; the height cell and
  the yaw samples once per mover) and keeps them, their coil ids and saturation signs in registers for the whole
  commutation (no column is read back from memory);
* the mover's sums are reduced over its lanes by warp shuffles (a butterfly: every lane gets the same bits, so every
  lane takes the same branches and solves the same 6 x 6 system): the free coils' matrix (lower triangle, 21 values)
  with the coil count and the fixed coils' wrench packed into the upper triangle (28 values, one reduction), and the
  delivered wrench, the loss and the step length (8 values, one reduction);
* the fast path: the first solve of the active-set loop (every coil free: the unconstrained least-loss currents
  ``i_k = g_k . Y / R_k``) writes every current and sums the delivered wrench and the loss in the pass that checks
  the limits; a mover whose coils all stay within their limits (most movers) is done after one solve and two passes.
  A mover with a coil past its limit goes on with the active-set steps (step to the first limit, fix the coils that
  reach it, re-solve) and a last pass, exactly as in the block cycle;
* the coil ids and columns are written only when asked (24 bytes per slot and mover, 1 GB at 1M movers).

The cost per mover (default window, at 8 lanes): the look-up's 16 float16 corner reads per coil (about 28 coils),
21 + 13 float64 multiply-adds per coil, one float64 6 x 6 scaled Cholesky solve per step shared by the mover's 8 lanes
(four movers' solves run side by side in a warp), two reductions on the fast path (28 and 8 float64 values, 3 shuffle
rounds each); the writes are the currents (float64) and saturation flags per slot and the mover's wrench, residual,
loss, flags and count. On a GPU the cycle is split by default (:func:`make_fast_cycle`): every mover's fast path, then
the active-set steps of the movers it listed (about 22% in ``benchmarks/magnetics.py``'s wrenches), so the
register-hungry loop stays out of the kernel every mover runs.

Status (2026-12-07): measured on an H100 (``bash benchmarks/gpu_round.sh mag_vs_ref``,
``benchmarks/results/magnetics_fast_new_s41_gpu.json``): 24.3 ms per cycle of 1M movers at 16 lanes (the block cycle
72.0 ms), 2.73 ms at 1e5 movers, with the block cycle's currents, flags and saturations; its CUDA tests pass. With
the active-set launch at :data:`REST_BLOCK` = 64 threads per block, 23.7 ms at 1M movers
(``magnetics_rest_block_s42_gpu.json``). By
Nsight Compute (``ncu17``) the first kernel (every mover) takes 8.1 ms, bound by the table's gathers (the default
57 MB table misses the 50 MB L2: 63% hits), and the active-set steps of the 22% of movers that saturate 16.2 ms
(about 6.6 solves each, 255 registers, spills). It is the magnetic drive's and the wrench-mode actuator's cycle on a
GPU (``cycle="fast"``, :func:`resolve_cycle`); the issue's 2 ms per cycle of 1M movers stays missed by 12x.

On a CPU the default is one lane per mover (no reduction at all). ``lanes > 1`` on a CPU emulates the GPU's lane
groups with one block of ``lanes`` threads per mover and ``wp.tile_sum`` reductions (``warp.config.enable_cpu_blocks``
must be set; the tests do, to run the lane logic without a GPU); on a GPU the groups are reduced with
``__shfl_xor_sync`` over each group's own lane mask.
"""

# (no "from __future__ import annotations": the kernels annotate with types made in make_fast_cycle)

import functools

import warp as wp

from magwarp._checks import as_count
from magwarp.magnetics.commutation import (FLAG_NO_COILS, FLAG_NOT_CONVERGED, FLAG_REGULARISED, CommutationResult,
                                           add_fixed, add_outer_lower, as_vec6d, block_sum, fixed_of, mat66d,
                                           step_reach, vec6f)
from magwarp.magnetics.cuboid import ONE, ZERO
from magwarp.magnetics.cycle import CycleParams, check_arrays, cycle_params
from magwarp.magnetics.exact import vec6d
from magwarp.magnetics.geometry import MagneticsError
from magwarp.magnetics.table import TableModel, column_context, quat_yaw, slot_coil, table_column_at
from magwarp.magnetics.thread_cycle import ThreadOutputs, thread_outputs

__all__ = ["CYCLES", "FastCycle", "GPU_LANES", "LANE_CHOICES", "REST_BLOCK", "make_fast_cycle", "resolve_cycle"]

#: Lanes per mover on a GPU (2 movers per warp; 2 or 3 of the default 42 slots per lane). On an H100 (2026-12-07,
#: ``benchmarks/results/magnetics_fast_new_s41_gpu.json``) 16 lanes took 24.3 ms per cycle of 1M movers, 8 lanes
#: 29.2 ms, 32 lanes 28.2 ms and the block cycle 72.0 ms.
GPU_LANES = 16
#: CUDA threads per block of the split cycle's active-set launch (``FastCycle(rest_block=)``): the movers it runs take
#: 2 to 29 solves each, and a block holds its registers until its slowest mover is done. On an H100 (2026-12-07,
#: ``benchmarks/results/magnetics_rest_block_s42_gpu.json``, 1M movers, 16 lanes) the cycle took 23.67 ms with 64
#: threads, 23.78 with 32, 24.47 with 128 and 29.99 with 16, the same currents.
REST_BLOCK = 64
#: The lane counts a cycle may use (a power of two: the groups are aligned within a warp).
LANE_CHOICES = (1, 2, 4, 8, 16, 32)
#: The control cycle's launch shapes (the magnetic drive's and the wrench-mode actuator's ``cycle``): ``"block"``
#: (:mod:`~magwarp.magnetics.cycle`, one launch, a block of threads per mover) and ``"fast"`` (:class:`FastCycle`).
CYCLES = ("block", "fast")


def resolve_cycle(cycle: str | None, device) -> str:
    """``cycle`` checked against :data:`CYCLES`; None: ``"fast"`` on a GPU (2.3-2.8x the block cycle's speed on an
    H100 at 1e5-1e6 movers, the same currents to rounding), ``"block"`` on a CPU (the same time there)."""
    if cycle is None:
        return "fast" if wp.get_device(device).is_cuda else "block"
    if cycle not in CYCLES:
        raise MagneticsError(f"cycle must be one of {CYCLES} (or None for the device's default), got {cycle!r}")
    return cycle

vec8d = wp.types.vector(length=8, dtype=wp.float64)

# The butterfly over a mover's lane group (lanes a power of two, the group aligned in its warp; a CPU thread is a
# group of one). Every lane sums the same pairs in the same order (a + b == b + a), so all get the same bits.
_GROUP_MASK = """
#if defined(__CUDA_ARCH__)
    const unsigned lane_id = threadIdx.x & 31u;
    const unsigned group_mask = lanes >= 32 ? 0xffffffffu
                                            : (((1u << lanes) - 1u) << (lane_id & ~((unsigned)lanes - 1u)));
"""


@wp.func_native(_GROUP_MASK + """
    for (int off = lanes >> 1; off > 0; off >>= 1) {
        #pragma unroll
        for (int r = 0; r < 6; ++r) {
            #pragma unroll
            for (int c = 0; c <= r; ++c)
                a.data[r][c] += __shfl_xor_sync(group_mask, a.data[r][c], off);
        }
        #pragma unroll
        for (int c = 1; c < 6; ++c)
            a.data[0][c] += __shfl_xor_sync(group_mask, a.data[0][c], off);
        a.data[1][2] += __shfl_xor_sync(group_mask, a.data[1][2], off);
        a.data[2][3] += __shfl_xor_sync(group_mask, a.data[2][3], off);
    }
#endif
    return a;
""")
def group_sum_packed(a: mat66d, lanes: int) -> mat66d:
    """The sum over the mover's lanes of ``a``'s lower triangle and of ``a[0, 1..5]``, ``a[1, 2]``, ``a[2, 3]`` (the
    rest of the upper triangle is left as it is: it carries nothing)."""
    ...


@wp.func_native(_GROUP_MASK + """
    for (int off = lanes >> 1; off > 0; off >>= 1) {
        #pragma unroll
        for (int r = 0; r < 7; ++r)
            v.c[r] += __shfl_xor_sync(group_mask, v.c[r], off);
        v.c[7] = fmin(v.c[7], __shfl_xor_sync(group_mask, v.c[7], off));
    }
#endif
    return v;
""")
def group_sum_min(v: vec8d, lanes: int) -> vec8d:
    """The sum over the mover's lanes of ``v[0..6]`` and the least ``v[7]``."""
    ...


@wp.func
def chol_scaled(a: mat66d, scale: vec6d, shift: wp.float64):
    """Cholesky factor (lower; its diagonal holds the reciprocal pivots) of diag(scale) A diag(scale) + shift I, and
    its smallest squared pivot."""
    lo = mat66d()
    piv = wp.float64(1.0e300)
    for c in range(6):
        s = a[c, c] * scale[c] * scale[c] + shift
        for k in range(6):
            if k < c:
                s = s - lo[c, k] * lo[c, k]
        piv = wp.min(piv, s)
        inv = ONE / wp.sqrt(wp.max(s, wp.float64(1.0e-300)))
        lo[c, c] = inv
        for r in range(6):
            if r > c:
                t = a[r, c] * scale[r] * scale[c]
                for k in range(6):
                    if k < c:
                        t = t - lo[r, k] * lo[c, k]
                lo[r, c] = t * inv
    return lo, piv

@wp.func
def unit_scale(a: mat66d) -> vec6d:
    """The scaling of A's rows and columns to a unit diagonal (1 where a diagonal entry is not positive)."""
    scale = vec6d()
    for r in range(6):
        scale[r] = ONE
        if a[r, r] > wp.float64(0.0):
            scale[r] = ONE / wp.sqrt(a[r, r])
    return scale


@wp.func
def chol_solve(lo: mat66d, scale: vec6d, rhs: vec6d) -> vec6d:
    """x with A x = rhs from :func:`chol_scaled`'s factor of the scaled A (forward, then back substitution)."""
    y = vec6d()
    for r in range(6):
        t = rhs[r] * scale[r]
        for k in range(6):
            if k < r:
                t = t - lo[r, k] * y[k]
        y[r] = t * lo[r, r]
    x = vec6d()
    for rr in range(6):
        r = 5 - rr
        t = y[r]
        for k in range(6):
            if k > r:
                t = t - lo[k, r] * x[k]
        x[r] = t * lo[r, r]
    return wp.cw_mul(x, scale)


@wp.func
def lean_solve(a: mat66d, rhs: vec6d, reg: wp.float64):
    """y with A y = rhs and whether it was regularised: :func:`~magwarp.magnetics.commutation.solve_scaled`'s
    arithmetic (A's lower triangle scaled to a unit diagonal, Cholesky, + reg I when a pivot falls below reg), with
    one reciprocal per pivot instead of a division per entry and every loop unrolled (126 registers on sm_90
    against 178)."""
    scale = unit_scale(a)
    lo, piv = chol_scaled(a, scale, wp.float64(0.0))
    regd = bool(False)
    if piv < reg:
        lo, piv = chol_scaled(a, scale, reg)
        regd = True
    return chol_solve(lo, scale, rhs), regd


@wp.func
def plain_solve(a: mat66d, rhs: vec6d, reg: wp.float64):
    """:func:`lean_solve` where no regularisation is needed (the same bits), and False (no answer) where it is: A is
    dead once factorised, so its registers hold the factor."""
    scale = unit_scale(a)
    lo, piv = chol_scaled(a, scale, wp.float64(0.0))
    if piv < reg:
        return vec6d(), False
    return chol_solve(lo, scale, rhs), True


@wp.func
def finish_mover(o: ThreadOutputs, m: int, lane: int, n: int, wanted: vec6d, sums: vec8d, flag: int) -> vec6d:
    """Mover ``m``'s row of the outputs (by its lane 0) from its summed delivered wrench (``sums[0..5]``) and loss
    (``sums[6]``); returns the delivered wrench."""
    delivered = vec6d(sums[0], sums[1], sums[2], sums[3], sums[4], sums[5])
    if lane == 0:
        o.count[m] = n
        o.delivered[m] = delivered
        o.residual[m] = wanted - delivered
        o.loss[m] = sums[6]
        o.flags[m] = flag
    return delivered


def _count_or_none(value, minimum: int) -> int | None:
    """``value`` as :func:`magwarp._checks.as_count` reads it (an integer >= ``minimum``; no bool, NaN, infinity,
    string or fraction), or None where it refuses it: the caller raises its own error, which names the option."""
    try:
        return as_count(value, "value", minimum=minimum)
    except (TypeError, ValueError):
        return None


@functools.cache
def make_fast_cycle(slots: int, lanes: int, tiles: bool = False, max_registers: int = 0, straight: bool = True):
    """``(mover_func, kernel, first_kernel, rest_kernel)`` of the cycle for a window of ``slots`` slots with ``lanes``
    threads per mover (see the module docstring). ``tiles``: reduce over a block of ``lanes`` threads with
    ``wp.tile_sum`` (a CPU with ``warp.config.enable_cpu_blocks``; launch one block per mover) instead of warp shuffles.

    ``mover_func(c, m, lane, x, y, z, yaw, wanted, o)`` (a ``@wp.func``) runs mover ``m``'s cycle on lane ``lane`` of
    its group and writes row ``m`` of the :class:`~magwarp.magnetics.thread_cycle.ThreadOutputs` ``o``; it returns the
    delivered wrench, the copper loss and the flags (the same on every lane). ``kernel`` runs it for every mover of
    float64 pose arrays, thread ``m * lanes + lane``. The split cycle: ``first_kernel`` (every mover: the fast path;
    a mover with a coil past its limit at the first solve is listed instead) then ``rest_kernel`` (the listed movers'
    whole cycle): the same results, and the register-hungry active-set loop (its columns, matrix and step state live
    across a loop) stays out of the kernel every mover runs (sm_90, 8 lanes, 255 registers: 360 B of stack against
    1.9 KB). ``max_registers`` > 0 caps the registers per thread of the kernels (more threads per SM, more spills).
    ``straight``: the first kernel's fast path as straight-line code (no loop; the same bits), else the general mover
    stopped after its first solve."""
    if lanes not in LANE_CHOICES:
        raise MagneticsError(f"lanes per mover must be one of {LANE_CHOICES}, got {lanes!r}")
    S = int(slots)
    L = int(lanes)
    P = (S + L - 1) // L  # slots per lane
    Cols = wp.types.matrix(shape=(P, 6), dtype=wp.float32)
    Ints = wp.types.vector(length=P, dtype=wp.int32)
    # (Warp unrolls the per-lane slot loops, up to 16 slots a lane: the columns stay in registers on a GPU)
    options = {"enable_backward": False}
    caps = {"cuda_max_registers": int(max_registers)} if max_registers > 0 else {}

    @wp.func
    def reduce_packed(a: mat66d) -> mat66d:
        if wp.static(tiles):
            return block_sum(a)
        return group_sum_packed(a, L)

    @wp.func
    def reduce_sum_min(v: vec8d, lane: int) -> vec8d:
        if wp.static(tiles):
            # the least v[7]: each lane's value in its own entry of a 6 x 6 matrix, summed (exact), then the least
            # entry (a float64 wp.tile_min corrupted other values in Warp 1.19's CPU blocks)
            m = mat66d()
            m[lane / 6, lane % 6] = v[7]
            for r in range(7):
                m[5 - r / 6, 5 - r % 6] = v[r]
            m = block_sum(m)
            out = vec8d()
            for r in range(7):
                out[r] = m[5 - r / 6, 5 - r % 6]
            least = v[7]
            for i in range(L):
                least = wp.min(least, m[i / 6, i % 6])
            out[7] = least
            return out
        return group_sum_min(v, L)

    @wp.func
    def look_up(c: CycleParams, m: int, lane: int, x: float, y: float, z: float, yaw: float, o: ThreadOutputs):
        """The lane's slots: their columns and coil ids (-1: none), and the mover's free-coil matrix (lower triangle,
        the coil count in ``a[0, 5]``) summed over its lanes; whether ``z`` lies outside the table's heights. The ids
        and columns are written when asked."""
        cols = Cols()
        ids = Ints()
        a = mat66d()  # lower triangle: the free coils' matrix; a[0, 5]: the coil count
        kz, fz, y0, fy, rot, out = column_context(c.table, z, yaw)
        for s in range(P):
            j = lane + s * L
            k = int(-1)
            if j < S:
                k, l, dx, dy = slot_coil(c.table, c.slot_layer, c.slot_offset, j, x, y)
                col = vec6f()
                if k >= 0:
                    col = table_column_at(c.table, l, dx, dy, kz, fz, y0, fy, rot)
                    cols[s] = col
                    a = add_outer_lower(a, as_vec6d(col), ONE / c.resistance[k])
                    a[0, 5] = a[0, 5] + ONE
                if o.store_ids != 0:
                    o.coil_ids[m, j] = k
                if o.store_gamma != 0:
                    o.gamma[m, j] = col
            ids[s] = k
        return cols, ids, reduce_packed(a), out

    @wp.func
    def straight_first(c: CycleParams, m: int, lane: int, x: float, y: float, z: float, yaw: float, wanted: vec6d,
                       o: ThreadOutputs):
        """The fast path without the active-set loop: the first solve (every coil free) and its pass. A mover with a
        coil past its limit returns the flag -1 with its outputs unwritten, as ``make_mover(True)``'s does, and so does
        one whose system needs regularisation or that may take no iteration (the rest kernel runs their whole cycle).
        The others get the general mover's arithmetic in the same order (the same bits). Straight-line code: the
        matrix is dead once factorised, not carried around a loop or kept for a regularised retry."""
        cols, ids, a, out = look_up(c, m, lane, x, y, z, yaw, o)
        n = int(a[0, 5])
        if n == 0:  # no coil: zero currents, the wanted wrench undelivered (the same on every lane of the mover)
            for s in range(P):
                if lane + s * L < S:
                    o.currents[m, lane + s * L] = ZERO
                    o.saturated[m, lane + s * L] = 0
            return finish_mover(o, m, lane, 0, wanted, vec8d(), FLAG_NO_COILS), ZERO, FLAG_NO_COILS
        if c.max_iter < 1:  # (the general mover's path: left to the rest kernel)
            return vec6d(), ZERO, int(-1)
        yv, ok = plain_solve(a, wanted, c.reg)
        if not ok:  # a system that needs regularisation: left to the rest kernel (the same on every lane)
            return vec6d(), ZERO, int(-1)
        flag = int(0)
        part = vec8d()
        part[7] = ONE
        for s in range(P):
            k = ids[s]
            j = lane + s * L
            if k >= 0:
                g = as_vec6d(cols[s])
                lim = c.limit[k]
                t, reach = step_reach(g, yv, vec6d(), ONE / c.resistance[k], lim)
                part[7] = wp.min(part[7], reach)
                t = wp.clamp(t, -lim, lim)
                for r in range(6):
                    part[r] = part[r] + g[r] * t
                part[6] = part[6] + c.resistance[k] * t * t
                o.currents[m, j] = t
                o.saturated[m, j] = 0
            elif j < S:
                o.currents[m, j] = ZERO
                o.saturated[m, j] = 0
        part = reduce_sum_min(part, lane)
        if part[7] < ONE:
            return vec6d(), ZERO, int(-1)
        if out and lane == 0:  # as many look-ups outside the table's heights as the window's coils
            wp.atomic_add(c.table.out_of_range, 0, n)
        return finish_mover(o, m, lane, n, wanted, part, flag), part[6], flag

    def make_mover(first_only: bool):
        """The mover function; ``first_only``: stop after the first solve where a coil passes its limit (the
        mover's outputs are not written: the caller lists it for the full steps) and return the flag -1."""

        @wp.func
        def fast_mover(c: CycleParams, m: int, lane: int, x: float, y: float, z: float, yaw: float, wanted: vec6d,
                       o: ThreadOutputs):
            """Mover ``m``'s look-up and commutation by lane ``lane`` of its group (see the module docstring)."""
            cols, ids, a, out = look_up(c, m, lane, x, y, z, yaw, o)
            sat = Ints()  # 0: free; +1 / -1: held at the limit with that sign
            n = int(a[0, 5])
            flag = int(0)
            if n == 0:
                flag = flag | FLAG_NO_COILS
            rhs = wanted
            big_y = vec6d()  # the free coils' currents are g . Y / R
            converged = bool(n == 0)
            n_free = n
            it = int(0)
            sums = vec8d()  # the delivered wrench (0..5) and the loss (6)
            deferred = bool(False)
            while it < c.max_iter and not converged and n_free > 0:
                it += 1
                yv, regd = lean_solve(a, rhs, c.reg)
                if regd:
                    flag = flag | FLAG_REGULARISED
                # How far toward the free coils' optimum the limits allow. On the first solve (every coil free) also
                # the currents (written), the delivered wrench and the loss: if no coil passes its limit, that is the
                # answer.
                first = it == 1
                part = vec8d()
                part[7] = ONE
                for s in range(P):
                    k = ids[s]
                    if k >= 0 and sat[s] == 0:
                        g = as_vec6d(cols[s])
                        lim = c.limit[k]
                        t, reach = step_reach(g, yv, big_y, ONE / c.resistance[k], lim)
                        part[7] = wp.min(part[7], reach)
                        if first:
                            t = wp.clamp(t, -lim, lim)  # (a current beyond its limit means another pass follows)
                            for r in range(6):
                                part[r] = part[r] + g[r] * t
                            part[6] = part[6] + c.resistance[k] * t * t
                            o.currents[m, lane + s * L] = t
                            o.saturated[m, lane + s * L] = 0
                    elif first and lane + s * L < S:
                        o.currents[m, lane + s * L] = ZERO
                        o.saturated[m, lane + s * L] = 0
                part = reduce_sum_min(part, lane)
                alpha = part[7]
                if alpha >= ONE:
                    big_y = yv
                    converged = True
                    sums = part
                elif wp.static(first_only):
                    deferred = True
                    break
                else:
                    # Fix the coils that reach their limit (within rounding of the step), rebuild the others' matrix.
                    # Upper triangle: a[0, 1..5], a[1, 2] the fixed coils' wrench, a[2, 3] how many were fixed.
                    hit = alpha * (ONE + wp.float64(1.0e-12))
                    a = mat66d()
                    for s in range(P):
                        k = ids[s]
                        if k >= 0 and sat[s] == 0:
                            g = as_vec6d(cols[s])
                            r_inv = ONE / c.resistance[k]
                            t, reach = step_reach(g, yv, big_y, r_inv, c.limit[k])
                            if reach <= hit:
                                sat[s] = int(wp.sign(t))
                                a = add_fixed(a, g * (wp.sign(t) * c.limit[k]))
                            else:
                                a = add_outer_lower(a, g, r_inv)
                    a = reduce_packed(a)
                    fixed, n_fixed = fixed_of(a)
                    rhs = rhs - fixed
                    n_free = n_free - n_fixed
                    big_y = big_y + alpha * (yv - big_y)
            if deferred:
                return vec6d(), ZERO, int(-1)
            if out and n > 0 and lane == 0:  # as many look-ups outside the table's heights as the window's coils
                wp.atomic_add(c.table.out_of_range, 0, n)
            if not converged:
                flag = flag | FLAG_NOT_CONVERGED
            if it != 1 or not converged:  # not the first solve's answer: the last pass
                part = vec8d()
                for s in range(P):
                    j = lane + s * L
                    if j < S:
                        k = ids[s]
                        i = ZERO
                        if k >= 0:
                            g = as_vec6d(cols[s])
                            lim = c.limit[k]
                            if sat[s] != 0:
                                i = wp.float64(sat[s]) * lim
                            else:  # (held within the limit: rounding)
                                i = wp.clamp(wp.dot(g, big_y) / c.resistance[k], -lim, lim)
                            for r in range(6):
                                part[r] = part[r] + g[r] * i
                            part[6] = part[6] + c.resistance[k] * i * i
                        o.currents[m, j] = i
                        o.saturated[m, j] = wp.where(sat[s] != 0, 1, 0)
                sums = reduce_sum_min(part, lane)
            return finish_mover(o, m, lane, n, wanted, sums, flag), sums[6], flag

        return fast_mover

    fast_mover = make_mover(False)
    first_mover = straight_first if straight else make_mover(True)

    @wp.kernel(module="unique", module_options=options, **caps)
    def fast_cycle_kernel(
        # Model:
        c: CycleParams,
        # State in:
        pos: wp.array(dtype=wp.vec3d),
        quat: wp.array(dtype=wp.quatd),
        wanted: wp.array(dtype=vec6d),
        # State out:
        o: ThreadOutputs,
    ):
        """``lanes`` threads per mover: the look-up of its window, then least-loss currents within the limits."""
        i = wp.tid()
        m = i / L
        p = pos[m]
        fast_mover(c, m, i % L, float(p[0]), float(p[1]), float(p[2]), quat_yaw(quat[m]), wanted[m], o)

    @wp.kernel(module="unique", module_options=options, **caps)
    def first_kernel(
        # Model:
        c: CycleParams,
        # State in:
        pos: wp.array(dtype=wp.vec3d),
        quat: wp.array(dtype=wp.quatd),
        wanted: wp.array(dtype=vec6d),
        # State out:
        o: ThreadOutputs,
        rest: wp.array(dtype=wp.int32),
        rest_count: wp.array(dtype=wp.int32),
    ):
        """The fast path of every mover (``lanes`` threads each): its outputs where no coil passes its limit at the
        first solve, else the mover is appended to ``rest`` (``rest_count[0]``: zeroed before)."""
        i = wp.tid()
        m = i / L
        lane = i % L
        p = pos[m]
        d, loss, flag = first_mover(c, m, lane, float(p[0]), float(p[1]), float(p[2]), quat_yaw(quat[m]), wanted[m], o)
        if flag < 0 and lane == 0:
            rest[wp.atomic_add(rest_count, 0, 1)] = m

    @wp.kernel(module="unique", module_options=options, **caps)
    def rest_kernel(
        # Model:
        c: CycleParams,
        # State in:
        pos: wp.array(dtype=wp.vec3d),
        quat: wp.array(dtype=wp.quatd),
        wanted: wp.array(dtype=vec6d),
        rest: wp.array(dtype=wp.int32),
        rest_count: wp.array(dtype=wp.int32),
        # State out:
        o: ThreadOutputs,
    ):
        """The whole cycle of the movers listed in ``rest`` (``lanes`` threads each; groups past the count return)."""
        i = wp.tid()
        g = i / L
        if g >= rest_count[0]:
            return
        m = rest[g]
        p = pos[m]
        fast_mover(c, m, i % L, float(p[0]), float(p[1]), float(p[2]), quat_yaw(quat[m]), wanted[m], o)

    return fast_mover, fast_cycle_kernel, first_kernel, rest_kernel


class FastCycle:
    """The wrench-table look-up of ``model`` and the commutation of ``commutation`` (its resistances, limits and
    options; not its threads per mover) with ``lanes`` threads per mover (default :data:`GPU_LANES` on a GPU, 1 on a
    CPU; more than 1 on a CPU needs ``warp.config.enable_cpu_blocks``), in one launch or (``split``, the default on a
    GPU) the fast path of every mover, then the active-set steps of the movers it left (3 launches with the
    counter's zeroing, no host sync: graph-capturable). ``max_registers``: a cap on the kernels' registers per thread
    (0: the compiler's choice); ``straight``: the split cycle's first kernel as straight-line code (the default; False:
    the general mover stopped after its first solve, the same results); ``rest_block``: CUDA threads per block of the
    active-set launch (default :data:`REST_BLOCK`; a multiple of ``lanes``)."""

    def __init__(self, model: TableModel, commutation, lanes: int | None = None, split: bool | None = None,
                 max_registers: int = 0, straight: bool = True, rest_block: int | None = None):
        self.params = cycle_params(model, commutation)
        self.model, self.commutation = model, commutation
        dev = model.device
        if lanes is None:
            lanes = GPU_LANES if dev.is_cuda else 1
        if lanes not in LANE_CHOICES:
            raise MagneticsError(f"FastCycle lanes must be one of {LANE_CHOICES}, got {lanes!r}")
        self.tiles = dev.is_cpu and lanes > 1
        if self.tiles and lanes > 16:
            raise MagneticsError(f"FastCycle lanes on a CPU must be at most 16, got {lanes!r}")
        if self.tiles and not wp.config.enable_cpu_blocks:
            raise MagneticsError(f"FastCycle lanes={lanes} on a CPU needs warp.config.enable_cpu_blocks (a CPU runs "
                                 "one lane per mover by default)")
        self.lanes = int(lanes)
        if split is None:
            split = dev.is_cuda
        #: Two launches (the fast path of every mover, then the full steps of those a limit stopped): see
        #: :func:`make_fast_cycle`.
        self.split = bool(split)
        if not isinstance(straight, bool):
            raise MagneticsError(f"FastCycle straight must be True or False, got {straight!r}")
        self.straight = straight
        regs = _count_or_none(max_registers, 0)
        if regs is None:
            raise MagneticsError(f"FastCycle max_registers must be a non-negative integer, got {max_registers!r}")
        if rest_block is None:
            rest_block = REST_BLOCK
        block = _count_or_none(rest_block, 1)
        if block is None or block > 1024 or block % self.lanes:
            raise MagneticsError(f"FastCycle rest_block must be a multiple of lanes={self.lanes} in 1..1024, got "
                                 f"{rest_block!r}")
        #: CUDA threads per block of the active-set launch (a block retires when its slowest mover is done)
        self.rest_block = block
        self.mover_func, self.kernel, self.first_kernel, self.rest_kernel = make_fast_cycle(
            model.max_active, self.lanes, self.tiles, regs, self.straight)
        self._rest = self._rest_count = None

    def reserve(self, n: int) -> "FastCycle":
        """Allocate the split cycle's list of ``n`` movers now (before a CUDA graph capture runs :meth:`run`)."""
        if self._rest is None or self._rest.shape[0] < n:
            dev = self.model.device
            self._rest = wp.empty(max(int(n), 1), dtype=wp.int32, device=dev)
            self._rest_count = wp.zeros(1, dtype=wp.int32, device=dev)
        return self

    def run(self, pos: wp.array, quat: wp.array, wanted: wp.array, out: CommutationResult,
            count: wp.array | None = None, coil_ids: wp.array | None = None,
            gamma: wp.array | None = None) -> CommutationResult:
        """The commutation's result ``out`` (as :meth:`Commutation.solve`; the coil counts into ``count`` when given)
        for movers at ``pos``/``quat`` (float64) wanting ``wanted`` (``vec6d``); the coil ids and columns (as
        :meth:`TableModel.columns`) into ``coil_ids`` and ``gamma`` when given."""
        n, slots, dev = pos.shape[0], self.model.max_active, self.model.device
        count = count if count is not None else wp.empty(n, dtype=wp.int32, device=dev)
        shapes = {"quat": (quat.shape, (n,)), "wanted": (wanted.shape, (n,)), "count": (count.shape, (n,)),
                  "currents": (out.currents.shape, (n, slots)), "saturated": (out.saturated.shape, (n, slots)),
                  "delivered": (out.delivered.shape, (n,)), "loss": (out.loss.shape, (n,))}
        if coil_ids is not None:
            shapes["coil_ids"] = (coil_ids.shape, (n, slots))
        if gamma is not None:
            shapes["gamma"] = (gamma.shape, (n, slots))
        arrays = {"pos": pos, "quat": quat, "wanted": wanted, "count": count, "currents": out.currents,
                  "coil_ids": coil_ids, "gamma": gamma}
        check_arrays("FastCycle.run", shapes, arrays, dev)
        if n == 0:
            return out
        # CUDA: 128 threads a block (8 movers at 16 lanes; a group never straddles a warp); a CPU: one block per mover
        block = self.lanes if self.tiles else (1 if dev.is_cpu else 128)
        o = thread_outputs(out, count, coil_ids, gamma)
        if not self.split:
            wp.launch(self.kernel, dim=n * self.lanes, block_dim=block, device=dev,
                      inputs=[self.params, pos, quat, wanted], outputs=[o])
            return out
        self.reserve(n)
        self._rest_count.zero_()
        wp.launch(self.first_kernel, dim=n * self.lanes, block_dim=block, device=dev,
                  inputs=[self.params, pos, quat, wanted], outputs=[o, self._rest, self._rest_count])
        wp.launch(self.rest_kernel, dim=n * self.lanes, block_dim=block if dev.is_cpu else self.rest_block, device=dev,
                  inputs=[self.params, pos, quat, wanted, self._rest, self._rest_count], outputs=[o])
        return out

    @property
    def rest_movers(self) -> int:
        """How many movers the last split run sent on to the active-set steps (a host read)."""
        return 0 if self._rest_count is None else int(self._rest_count.numpy()[0])
