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
"""

from dataclasses import dataclass

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
def cholesky6(a: mat66d, shift: wp.float64):
    """Lower Cholesky factor of ``a + shift I`` and its smallest squared pivot (<= 0: not positive definite)."""
    lo = mat66d()
    piv = wp.float64(1.0e300)
    for c in range(6):
        s = a[c, c] + shift
        for k in range(c):
            s = s - lo[c, k] * lo[c, k]
        piv = wp.min(piv, s)
        d = wp.sqrt(wp.max(s, wp.float64(1.0e-300)))
        lo[c, c] = d
        for r in range(c + 1, 6):
            t = a[r, c]
            for k in range(c):
                t = t - lo[r, k] * lo[c, k]
            lo[r, c] = t / d
    return lo, piv


@wp.func
def cholesky6_solve(lo: mat66d, b: vec6d) -> vec6d:
    """x with L L^T x = b."""
    y = vec6d()
    for r in range(6):
        t = b[r]
        for k in range(r):
            t = t - lo[r, k] * y[k]
        y[r] = t / lo[r, r]
    x = vec6d()
    for rr in range(6):
        r = 5 - rr
        t = y[r]
        for k in range(r + 1, 6):
            t = t - lo[k, r] * x[k]
        x[r] = t / lo[r, r]
    return x


@wp.func
def as_vec6d(g: vec6d) -> vec6d:
    return g


@wp.func
def as_vec6d(g: vec6f) -> vec6d:  # noqa: F811 (an overload for float32 columns)
    return vec6d(wp.float64(g[0]), wp.float64(g[1]), wp.float64(g[2]), wp.float64(g[3]), wp.float64(g[4]),
                 wp.float64(g[5]))


def make_commutation_kernel(col_type):
    """The commutation kernel for columns of ``col_type`` (``vec6d``: the exact and fast models; ``vec6f``: the
    table model); the arithmetic is float64 either way."""

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
        """Least-copper-loss currents under per-coil limits, one mover per thread (see the module docstring)."""
        m = wp.tid()
        slots = gamma.shape[1]
        flag = int(0)
        n_coils = int(0)
        for j in range(slots):
            currents[m, j] = ZERO
            saturated[m, j] = 0
            if coil_ids[m, j] >= 0:
                n_coils += 1
        if n_coils == 0:
            flag = flag | 4
        if count[m] > slots:
            flag = flag | 8
        converged = bool(False)
        done = bool(n_coils == 0)
        out = vec6d()
        p = ZERO
        for it in range(max_iter):
            if not done:
                a = mat66d()
                rhs = wrench[m]
                n_free = int(0)
                for j in range(slots):
                    k = coil_ids[m, j]
                    if k >= 0:
                        g = as_vec6d(gamma[m, j])
                        if saturated[m, j] != 0:
                            rhs = rhs - g * currents[m, j]
                        else:
                            a = a + wp.outer(g / resistance[k], g)
                            n_free += 1
                if n_free == 0:
                    done = True
                else:
                    scale = vec6d()
                    for r in range(6):
                        scale[r] = ONE
                        if a[r, r] > ZERO:
                            scale[r] = ONE / wp.sqrt(a[r, r])
                    a_s = mat66d()
                    for r in range(6):
                        for c in range(6):
                            a_s[r, c] = a[r, c] * scale[r] * scale[c]
                    lo, piv = cholesky6(a_s, ZERO)
                    if piv < reg:
                        lo, piv = cholesky6(a_s, reg)
                        flag = flag | 1
                    y = cholesky6_solve(lo, wp.cw_mul(rhs, scale))
                    y = wp.cw_mul(y, scale)
                    # Step from the current (feasible) currents toward the free coils' optimum, as far as the limits
                    # allow.
                    alpha = ONE
                    for j in range(slots):
                        k = coil_ids[m, j]
                        if k >= 0 and saturated[m, j] == 0:
                            t = wp.dot(as_vec6d(gamma[m, j]), y) / resistance[k]
                            if wp.abs(t) > limit[k]:
                                alpha = wp.min(alpha, (wp.sign(t) * limit[k] - currents[m, j]) / (t - currents[m, j]))
                    hit = alpha * (ONE + wp.float64(1.0e-12))
                    # The step, and (used when it ends the solve: no final pass) the delivered wrench and the loss.
                    out = vec6d()
                    p = ZERO
                    for j in range(slots):
                        k = coil_ids[m, j]
                        if k >= 0:
                            g = as_vec6d(gamma[m, j])
                            i = currents[m, j]
                            if saturated[m, j] == 0:
                                t = wp.dot(g, y) / resistance[k]
                                i0 = i
                                i = i0 + alpha * (t - i0)
                                if wp.abs(t) > limit[k]:
                                    if (wp.sign(t) * limit[k] - i0) / (t - i0) <= hit:
                                        i = wp.sign(t) * limit[k]
                                        saturated[m, j] = 1
                                currents[m, j] = i
                            out = out + g * i
                            p = p + resistance[k] * i * i
                    if alpha >= ONE:
                        converged = True
                        done = True
        if not converged:
            if n_coils > 0:
                flag = flag | 2
            out = vec6d()
            p = ZERO
            for j in range(slots):
                k = coil_ids[m, j]
                if k >= 0:
                    i = currents[m, j]
                    out = out + as_vec6d(gamma[m, j]) * i
                    p = p + resistance[k] * i * i
        delivered[m] = out
        residual[m] = wrench[m] - out
        loss[m] = p
        flags[m] = flag

    return commutation_kernel


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
                 resistance: np.ndarray | None = None, limit: np.ndarray | None = None):
        self.options = options or CommutationOptions()
        self.device = wp.get_device(device)
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
        wp.launch(KERNELS[gamma.dtype], dim=n, device=d,
                  inputs=[self.resistance, self.limit, int(self.options.max_iter),
                          wp.float64(self.options.regularization), gamma, coil_ids, count, wrench],
                  outputs=[out.currents, out.saturated, out.delivered, out.residual, out.loss, out.flags])
        return out
