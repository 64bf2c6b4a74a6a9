"""Commutation: the coil currents that deliver a wanted wrench with the least copper loss, as a Warp kernel.

Per mover: minimise ``sum_k R_k i_k^2`` subject to ``Gamma i = w`` (Gamma: 6 x active coils, from
:mod:`~magwarp.magnetics.exact` or :mod:`~magwarp.magnetics.fast`). Without limits the answer is
``i = R^-1 Gamma^T (Gamma R^-1 Gamma^T)^-1 w``, one 6 x 6 solve. With per-coil limits ``|i_k| <= i_max_k``: coils
that reach their limit are fixed there (sign kept) and the free coils re-solved with the fixed coils' wrench taken
off ``w``, at most ``max_iter`` solves (default 64; each fixes at least one coil). Each solve is a step of a primal
active-set method: from the current currents (within the limits; zero at first) toward the new optimum, as far as
the first coil to reach its limit (which is then fixed there); a step that reaches the optimum ends it. The
currents never leave the limits, and the delivered wrench moves toward ``w`` at every step (after the first it is
``alpha w``: the wanted direction, scaled down). It never frees a fixed coil (not a full box-constrained QP), so
where it stops short, the wrench it could not deliver is reported, never hidden.

The 6 x 6 matrix is scaled to a unit diagonal (forces and torques differ by about the lever arm) and factorised by
Cholesky; where a pivot of the scaled matrix falls below ``regularization`` (few coils under the mover: some wrench
direction is nearly out of reach), ``regularization`` times the identity is added (Tikhonov) and the mover is
flagged. Outputs per mover: currents (in the active slots' order), the delivered wrench ``Gamma i``, the residual
``w - Gamma i``, the copper loss (W), saturated coils (per slot) and flags (:data:`FLAG_REGULARISED`,
:data:`FLAG_NOT_CONVERGED`, :data:`FLAG_NO_COILS`, :data:`FLAG_OVERFLOW`).

Execution: one block of ``block_dim`` threads per mover (:data:`GPU_BLOCK_DIM` = 32 on a GPU, 1 on a CPU); each
thread takes every ``block_dim``-th slot, and the per-slot sums (the 6 x 6 matrix, the step length, the fixed coils'
wrench, the delivered wrench and the loss) are reduced over the block with ``wp.tile_sum``; every thread then solves
the same 6 x 6 system (float64 throughout). The free coils' currents are carried as one 6-vector ``Y`` (a free
coil's current is ``g . Y / R``), so a step is two passes over the slots (the step length; the coils it fixes and
the rebuilt matrix, lower triangle only) and no per-coil current is stored between steps. With one thread per mover
(the previous kernel: three passes per step reading and writing every slot's current, the columns read back in
``[mover][slot]`` order) a saturating mover's chain of dependent memory reads set the GPU time (1.55 ms for 1000
movers on an H100). :mod:`~magwarp.magnetics.cycle` fuses the wrench-table look-up into the same launch.
"""

from dataclasses import dataclass
from typing import Any

import numpy as np
import warp as wp

from magwarp.magnetics.cuboid import ONE, ZERO
from magwarp.magnetics.exact import vec6d

vec6f = wp.types.vector(length=6, dtype=wp.float32)
from magwarp.magnetics.geometry import MagneticsError

mat66d = wp.types.matrix(shape=(6, 6), dtype=wp.float64)

#: The 6 x 6 system was ill-conditioned and regularised (the wrench may be delivered only approximately).
FLAG_REGULARISED = 1
#: The last allowed solve still hit a limit: the wanted wrench was not reached (see the residual).
FLAG_NOT_CONVERGED = 2
#: No active coil at all (the mover is off the tiles): zero currents, the whole wrench undelivered.
FLAG_NO_COILS = 4
#: More coils were within the active radius than slots (the extra coils were left out).
FLAG_OVERFLOW = 8


@dataclass(frozen=True)
class CommutationOptions:
    """``max_iter``: most 6 x 6 solves per mover (each fixes the coils that reach their limit); ``regularization``: the
    pivot threshold and Tikhonov shift of the unit-diagonal 6 x 6 system."""

    max_iter: int = 64
    regularization: float = 1e-6

    def __post_init__(self):
        if int(self.max_iter) != self.max_iter or self.max_iter < 1:
            raise MagneticsError(f"CommutationOptions.max_iter must be a positive integer, got {self.max_iter!r}")
        if not np.isfinite(self.regularization) or not 0 < self.regularization < 1:
            raise MagneticsError(f"CommutationOptions.regularization must be in (0, 1), got {self.regularization!r}")


@wp.func
def as_vec6d(g: vec6d) -> vec6d:
    return g


@wp.func
def as_vec6d(g: vec6f) -> vec6d:  # noqa: F811 (an overload for float32 columns)
    return vec6d(wp.float64(g[0]), wp.float64(g[1]), wp.float64(g[2]), wp.float64(g[3]), wp.float64(g[4]),
                 wp.float64(g[5]))


@wp.func
def add_outer_lower(a: Any, g: Any, s: Any):
    """``a + s g g^T`` on the lower triangle only (the upper triangle is never read); any float type (a 6 x 6
    matrix, a 6-vector and a scalar of it)."""
    out = a
    for r in range(6):
        sg = s * g[r]
        for c in range(r + 1):
            out[r, c] = out[r, c] + sg * g[c]
    return out


@wp.func
def add_fixed(a: mat66d, gi: vec6d):
    """A coil fixed at its limit, packed into the upper triangle of a lower-triangle matrix (one reduction sums both):
    its wrench ``gi`` (``g`` times its current) into ``a[0, 1..5]`` and ``a[1, 2]``, one more fixed coil into
    ``a[2, 3]`` (:func:`fixed_of` reads them back)."""
    out = a
    out[0, 1] = out[0, 1] + gi[0]
    out[0, 2] = out[0, 2] + gi[1]
    out[0, 3] = out[0, 3] + gi[2]
    out[0, 4] = out[0, 4] + gi[3]
    out[0, 5] = out[0, 5] + gi[4]
    out[1, 2] = out[1, 2] + gi[5]
    out[2, 3] = out[2, 3] + ONE
    return out


@wp.func
def fixed_of(a: mat66d):
    """The fixed coils' wrench and count packed by :func:`add_fixed` (after the reduction)."""
    return vec6d(a[0, 1], a[0, 2], a[0, 3], a[0, 4], a[0, 5], a[1, 2]), int(a[2, 3])


def make_scaled_solver(real=wp.float64, refine: bool = False):
    """``solve_scaled(a, rhs, reg) -> (y, regularised)`` (a ``@wp.func``) in ``real`` arithmetic: y with A y = rhs from
    A's lower triangle (a 6 x 6 matrix of ``real``), scaled to a unit diagonal and factorised by Cholesky;
    regularised (+ reg I on the scaled system) when a pivot falls below ``reg``. ``refine``: one step of iterative
    refinement (the scaled system's residual solved again; float32 uses it)."""
    mat66r = wp.types.matrix(shape=(6, 6), dtype=real)
    vec6r = wp.types.vector(length=6, dtype=real)
    big, tiny = (1.0e300, 1.0e-300) if real == wp.float64 else (1.0e30, 1.0e-30)

    @wp.func
    def cholesky6(a: mat66r, shift: real):
        """Lower Cholesky factor of ``a + shift I`` and its smallest squared pivot (<= 0: not positive definite)."""
        lo = mat66r()
        piv = real(big)
        for c in range(6):
            s = a[c, c] + shift
            for k in range(c):
                s = s - lo[c, k] * lo[c, k]
            piv = wp.min(piv, s)
            d = wp.sqrt(wp.max(s, real(tiny)))
            lo[c, c] = d
            for r in range(c + 1, 6):
                t = a[r, c]
                for k in range(c):
                    t = t - lo[r, k] * lo[c, k]
                lo[r, c] = t / d
        return lo, piv

    @wp.func
    def cholesky6_solve(lo: mat66r, b: vec6r) -> vec6r:
        """x with L L^T x = b."""
        y = vec6r()
        for r in range(6):
            t = b[r]
            for k in range(r):
                t = t - lo[r, k] * y[k]
            y[r] = t / lo[r, r]
        x = vec6r()
        for rr in range(6):
            r = 5 - rr
            t = y[r]
            for k in range(r + 1, 6):
                t = t - lo[k, r] * x[k]
            x[r] = t / lo[r, r]
        return x

    @wp.func
    def sym_mul(a: mat66r, y: vec6r) -> vec6r:
        """``A y`` from A's lower triangle."""
        out = vec6r()
        for r in range(6):
            t = real(0.0)
            for c in range(6):
                if c <= r:
                    t = t + a[r, c] * y[c]
                else:
                    t = t + a[c, r] * y[c]
            out[r] = t
        return out

    @wp.func
    def solve_scaled(a: mat66r, rhs: vec6r, reg: real):
        """y with A y = rhs (see :func:`make_scaled_solver`) and whether it was regularised."""
        scale = vec6r()
        for r in range(6):
            scale[r] = real(1.0)
            if a[r, r] > real(0.0):
                scale[r] = real(1.0) / wp.sqrt(a[r, r])
        a_s = mat66r()
        for r in range(6):
            for c in range(r + 1):
                a_s[r, c] = a[r, c] * scale[r] * scale[c]
        lo, piv = cholesky6(a_s, real(0.0))
        regd = bool(False)
        if piv < reg:
            lo, piv = cholesky6(a_s, reg)
            regd = True
        b = wp.cw_mul(rhs, scale)
        y = cholesky6_solve(lo, b)
        if wp.static(refine):
            if not regd:
                y = y + cholesky6_solve(lo, b - sym_mul(a_s, y))
        return wp.cw_mul(y, scale), regd

    return solve_scaled


#: The float64 solve of the commutation kernels.
solve_scaled = make_scaled_solver(wp.float64)


vec8d = wp.types.vector(length=8, dtype=wp.float64)

#: Threads per mover on a GPU (a warp; the table model's window has 42 slots, so 10 threads take two).
GPU_BLOCK_DIM = 32
#: The most threads per mover (:func:`block_min` gathers one value per thread in a 6 x 6 matrix).
MAX_BLOCK_DIM = 36


@wp.func
def block_sum(a: mat66d) -> mat66d:
    """The sum of ``a`` over the block's threads, on every thread."""
    s = wp.tile_sum(wp.tile(a, preserve_type=True))
    return s[0]


@wp.func
def block_sum(a: vec8d) -> vec8d:  # noqa: F811 (an overload)
    s = wp.tile_sum(wp.tile(a, preserve_type=True))
    return s[0]


@wp.func
def block_min(a: wp.float64, lane: int) -> wp.float64:
    """The least ``a`` over the block's threads (at most :data:`MAX_BLOCK_DIM`), on every thread: each thread's
    value in its own entry of a matrix, the block's sum (exact: one value and zeros per entry), then the least
    entry. (A plain ``wp.tile_min`` of a float64 tile corrupted other values in Warp 1.19's CPU blocks.)"""
    v = mat66d()
    v[lane / 6, lane % 6] = a
    v = block_sum(v)
    out = a
    for i in range(wp.block_dim()):
        out = wp.min(out, v[i / 6, i % 6])
    return out


@wp.func
def step_reach(g: vec6d, y: vec6d, big_y: vec6d, r_inv: wp.float64, lim: wp.float64):
    """A free coil (column ``g``, 1 / resistance ``r_inv``, limit ``lim``) on a step from the currents of ``big_y``
    toward those of ``y``: its current at the step's end, and the share of the step at which it reaches its limit
    (2 where it never does)."""
    t = wp.dot(g, y) * r_inv
    reach = wp.float64(2.0)
    if wp.abs(t) > lim:
        now = wp.dot(g, big_y) * r_inv
        reach = (wp.sign(t) * lim - now) / (t - now)
    return t, reach


def make_commutation_func(col_type):
    """The commutation of one mover by a block of threads (a ``@wp.func``; thread ``lane`` of ``wp.block_dim()``
    takes the slots ``lane, lane + block_dim, ...``) for columns of ``col_type`` (``vec6d`` or ``vec6f``; the
    arithmetic is float64 either way). ``a``: this thread's share of the free coils' matrix at the start (every coil
    free; lower triangle) with its coil count in ``a[0, 5]`` (see :func:`first_pass`). Writes the mover's
    ``currents`` and ``saturated`` rows; returns the delivered wrench, the copper loss, the flags and the coil count.

    The free coils' currents are ``g_j . Y / R_j`` for one 6-vector ``Y`` (zero at first, then ``Y + alpha (y - Y)``
    after each step), so no per-coil current is stored between steps; a coil that reaches its limit is written once
    (``currents``, ``saturated``) and its wrench taken off the right-hand side. Per solve: one pass for the step
    length, one that fixes the coils reaching their limit and rebuilds the free coils' matrix; one final pass writes
    the free currents, the delivered wrench and the loss. Every pass's sums are reduced over the block (the upper
    triangle of the matrix carries the counts and the fixed coils' wrench through the same reduction) and every
    thread solves the same 6 x 6 system, so control flow stays uniform over the block."""

    @wp.func
    def column(gamma: wp.array2d(dtype=col_type), m: int, j: int) -> vec6d:
        return as_vec6d(gamma[m, j])

    @wp.func
    def commutate_block(
        m: int,
        lane: int,
        resistance: wp.array(dtype=wp.float64),
        limit: wp.array(dtype=wp.float64),
        max_iter: int,
        reg: wp.float64,
        gamma: wp.array2d(dtype=col_type),
        coil_ids: wp.array2d(dtype=wp.int32),
        wanted: vec6d,
        a_lane: mat66d,
        currents: wp.array2d(dtype=wp.float64),
        saturated: wp.array2d(dtype=wp.int32),
    ):
        nb = wp.block_dim()
        slots = gamma.shape[1]
        a = block_sum(a_lane)
        n_coils = int(a[0, 5])
        n_free = n_coils
        flag = int(0)
        if n_coils == 0:
            flag = flag | 4
        rhs = wanted
        big_y = vec6d()  # the free coils' currents are g . Y / R
        converged = bool(n_coils == 0)
        it = int(0)
        while it < max_iter and not converged and n_free > 0:
            it += 1
            y, regd = solve_scaled(a, rhs, reg)
            if regd:
                flag = flag | 1
            # How far toward the free coils' optimum the limits allow.
            alpha = ONE
            for j in range(lane, slots, nb):
                k = coil_ids[m, j]
                if k >= 0:
                    if saturated[m, j] == 0:
                        t, reach = step_reach(column(gamma, m, j), y, big_y, ONE / resistance[k], limit[k])
                        alpha = wp.min(alpha, reach)
            alpha = block_min(alpha, lane)
            if alpha >= ONE:
                big_y = y
                converged = True
            else:
                # Fix the coils that reach their limit (within rounding of the step), rebuild the others' matrix.
                # Upper triangle: a[0, 1..5], a[1, 2] the fixed coils' wrench, a[2, 3] how many were fixed.
                hit = alpha * (ONE + wp.float64(1.0e-12))
                a = mat66d()
                for j in range(lane, slots, nb):
                    k = coil_ids[m, j]
                    if k >= 0:
                        if saturated[m, j] == 0:
                            g = column(gamma, m, j)
                            r_inv = ONE / resistance[k]
                            t, reach = step_reach(g, y, big_y, r_inv, limit[k])
                            if reach <= hit:
                                i = wp.sign(t) * limit[k]
                                currents[m, j] = i
                                saturated[m, j] = 1
                                a = add_fixed(a, g * i)
                            else:
                                a = add_outer_lower(a, g, r_inv)
                a = block_sum(a)
                fixed, n_fixed = fixed_of(a)
                rhs = rhs - fixed
                n_free = n_free - n_fixed
                big_y = big_y + alpha * (y - big_y)
        if not converged:
            flag = flag | 2
        # The currents; the delivered wrench (0..5) and the loss (6).
        acc = vec8d()
        for j in range(lane, slots, nb):
            k = coil_ids[m, j]
            i = ZERO
            if k >= 0:
                g = column(gamma, m, j)
                if saturated[m, j] != 0:
                    i = currents[m, j]
                else:
                    i = wp.dot(g, big_y) / resistance[k]
                for r in range(6):
                    acc[r] = acc[r] + g[r] * i
                acc[6] = acc[6] + resistance[k] * i * i
            currents[m, j] = i
        acc = block_sum(acc)
        return vec6d(acc[0], acc[1], acc[2], acc[3], acc[4], acc[5]), acc[6], flag, n_coils

    return commutate_block


@wp.func
def add_coil(a: mat66d, g: vec6d, resistance: wp.float64) -> mat66d:
    """A free coil's share of the 6 x 6 matrix (lower triangle) and of the coil count (``a[0, 5]``)."""
    out = add_outer_lower(a, g, ONE / resistance)
    out[0, 5] = out[0, 5] + ONE
    return out


def make_commutation_kernel(col_type):
    """The commutation kernel (one block of threads per mover: :func:`make_commutation_func`) for columns of
    ``col_type`` (``vec6d``: the exact and fast models; ``vec6f``: the table model)."""
    commutate_block = COMMUTATE[col_type]

    @wp.kernel(module="unique")
    def commutation_kernel(
        # Model:
        resistance: wp.array(dtype=wp.float64),
        limit: wp.array(dtype=wp.float64),
        max_iter: int,
        reg: wp.float64,
        # State in:
        gamma: wp.array2d(dtype=col_type),
        coil_ids: wp.array2d(dtype=wp.int32),
        count: wp.array(dtype=wp.int32),
        wrench: wp.array(dtype=vec6d),
        # State out:
        currents: wp.array2d(dtype=wp.float64),
        saturated: wp.array2d(dtype=wp.int32),
        delivered: wp.array(dtype=vec6d),
        residual: wp.array(dtype=vec6d),
        loss: wp.array(dtype=wp.float64),
        flags: wp.array(dtype=wp.int32),
    ):
        """Least-copper-loss currents under per-coil limits (see the module docstring)."""
        m, lane = wp.tid()
        a = mat66d()
        for j in range(lane, gamma.shape[1], wp.block_dim()):
            saturated[m, j] = 0
            k = coil_ids[m, j]
            if k >= 0:
                a = add_coil(a, as_vec6d(gamma[m, j]), resistance[k])
        out, p, flag, n = commutate_block(m, lane, resistance, limit, max_iter, reg, gamma, coil_ids, wrench[m], a,
                                          currents, saturated)
        if lane == 0:
            if count[m] > gamma.shape[1]:
                flag = flag | 8
            delivered[m] = out
            residual[m] = wrench[m] - out
            loss[m] = p
            flags[m] = flag

    return commutation_kernel


#: The one-mover commutation (``@wp.func``, one block per mover) per column type, for kernels that fuse it.
COMMUTATE = {vec6d: make_commutation_func(vec6d), vec6f: make_commutation_func(vec6f)}
KERNELS = {vec6d: make_commutation_kernel(vec6d), vec6f: make_commutation_kernel(vec6f)}


@dataclass
class CommutationResult:
    """Per mover (warp arrays): ``currents`` and ``saturated`` ``(n, slots)``, ``delivered`` and ``residual``
    ``(n,)`` 6-vectors, ``loss`` ``(n,)`` W, ``flags`` ``(n,)`` (the module's FLAG_* bits)."""

    currents: wp.array
    saturated: wp.array
    delivered: wp.array
    residual: wp.array
    loss: wp.array
    flags: wp.array

    @classmethod
    def zeros(cls, n: int, slots: int, device) -> "CommutationResult":
        """Zeroed buffers for ``n`` movers of ``slots`` slots on ``device``."""
        return cls(wp.zeros((n, slots), dtype=wp.float64, device=device),
                   wp.zeros((n, slots), dtype=wp.int32, device=device), wp.zeros(n, dtype=vec6d, device=device),
                   wp.zeros(n, dtype=vec6d, device=device), wp.zeros(n, dtype=wp.float64, device=device),
                   wp.zeros(n, dtype=wp.int32, device=device))


class Commutation:
    """Commutation for the coils of a :class:`~magwarp.magnetics.geometry.CoilSet` (resistances and limits per
    coil id) on ``device``."""

    def __init__(self, coilset, options: CommutationOptions | None = None, device=None,
                 resistance: np.ndarray | None = None, limit: np.ndarray | None = None, block_dim: int | None = None):
        self.options = options or CommutationOptions()
        self.device = wp.get_device(device)
        self.coilset = coilset
        if block_dim is None:
            block_dim = GPU_BLOCK_DIM if self.device.is_cuda else 1
        if int(block_dim) != block_dim or not 1 <= block_dim <= MAX_BLOCK_DIM:
            raise MagneticsError(f"Commutation block_dim must be an integer in [1, {MAX_BLOCK_DIM}], got "
                                 f"{block_dim!r}")
        #: Threads per mover (a CPU runs one unless ``warp.config.enable_cpu_blocks`` is set).
        self.block_dim = int(block_dim)
        resistance = coilset.resistance if resistance is None else np.asarray(resistance, dtype=np.float64)
        limit = coilset.current_limit if limit is None else np.asarray(limit, dtype=np.float64)
        for name, v in (("resistance", resistance), ("limit", limit)):
            if v.shape != (coilset.num_coils,) or not np.all(np.isfinite(v)) or np.any(v <= 0):
                raise MagneticsError(f"Commutation: {name} must be {coilset.num_coils} positive finite values, "
                                     f"got shape {v.shape}, min {v.min() if v.size else None!r}")
        self.resistance = wp.array(resistance, dtype=wp.float64, device=self.device)
        self.limit = wp.array(limit, dtype=wp.float64, device=self.device)

    def solve(self, gamma: wp.array, coil_ids: wp.array, count: wp.array, wrench: wp.array,
              out: CommutationResult | None = None) -> CommutationResult:
        """Currents for the wanted wrenches ``wrench`` (``(n,)`` 6-vectors: force N, torque N m about the mover's
        centre, world frame), given the active coils (ids and counts, from ``active_coils``) and their Gamma."""
        n, slots = gamma.shape
        if coil_ids.shape != gamma.shape or wrench.shape != (n,) or count.shape != (n,):
            raise MagneticsError(f"Commutation.solve: gamma {gamma.shape}, coil_ids {coil_ids.shape}, count "
                                 f"{count.shape} and wrench {wrench.shape} must agree on (movers, slots)")
        d = self.device
        if out is None:
            out = CommutationResult.zeros(n, slots, d)
        if gamma.dtype not in KERNELS:
            raise MagneticsError(f"Commutation.solve: gamma must hold vec6d or vec6f columns, got {gamma.dtype}")
        wp.launch_tiled(KERNELS[gamma.dtype], dim=[n], block_dim=self.block_dim, device=d,
                  inputs=[self.resistance, self.limit, int(self.options.max_iter),
                          wp.float64(self.options.regularization), gamma, coil_ids, count, wrench],
                  outputs=[out.currents, out.saturated, out.delivered, out.residual, out.loss, out.flags])
        return out
