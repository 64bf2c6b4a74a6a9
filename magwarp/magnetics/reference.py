"""Plain float64 numpy references of the magnetics kernels (test oracles; slow, never in a hot path).

Each function mirrors one kernel: the cuboid field (:mod:`~magwarp.magnetics.cuboid`), the wrench columns and the
active coils (:mod:`~magwarp.magnetics.exact`), the commutation (:mod:`~magwarp.magnetics.commutation`). The flux
linkage (for the virtual-work check of the force) has no kernel: it is an independent route to the same physics.
"""

from __future__ import annotations

import numpy as np

__all__ = ["cuboid_field", "array_field", "rotation", "coil_columns", "active_coils", "commutate", "flux_linkage",
           "table_column"]


def _log_ratio(vl, vh, a2):
    rl, rh = np.sqrt(vl * vl + a2), np.sqrt(vh * vh + a2)
    with np.errstate(divide="ignore", invalid="ignore"):
        pos = np.log((vh + rh) / (vl + rl))
        neg = np.log((rl - vl) / (rh - vh))
        mixed = np.log((vh + rh) * (rl - vl) / a2)
    out = np.where(vl >= 0, pos, np.where(vh <= 0, neg, mixed))
    return np.where(np.isfinite(out), out, 0.0)


def _corner_atan(u, v, w):
    r = np.sqrt(u * u + v * v + w * w)
    return np.sign(w) * np.arctan2(u * v, np.abs(w) * r)


def _face_pair(pu, pv, pw, hu, hv, hw, jw):
    ul, uh, vl, vh = pu - hu, pu + hu, pv - hv, pv + hv
    out = 0.0
    for w0, sigma in ((hw, jw), (-hw, -jw)):
        w = pw - w0
        bw = _corner_atan(uh, vh, w) - _corner_atan(uh, vl, w) - _corner_atan(ul, vh, w) + _corner_atan(ul, vl, w)
        bu = _log_ratio(vl, vh, ul * ul + w * w) - _log_ratio(vl, vh, uh * uh + w * w)
        bv = _log_ratio(ul, uh, vl * vl + w * w) - _log_ratio(ul, uh, vh * vh + w * w)
        out = out + np.stack([bu, bv, bw], axis=-1) * (sigma / (4.0 * np.pi))[..., None]
    return out


def cuboid_field(p, half, pol) -> np.ndarray:
    """B (T) at points ``p`` (``(..., 3)``, relative to the centre, cuboid axes) of cuboids with half sizes
    ``half`` and polarizations ``pol`` (broadcast against ``p``)."""
    p, half, pol = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (p, half, pol)))
    x, y, z = np.moveaxis(p, -1, 0)
    hx, hy, hz = np.moveaxis(half, -1, 0)
    jx, jy, jz = np.moveaxis(pol, -1, 0)
    bz = _face_pair(x, y, z, hx, hy, hz, jz)
    bx = _face_pair(y, z, x, hy, hz, hx, jx)
    by = _face_pair(z, x, y, hz, hx, hy, jy)
    b = np.stack([bz[..., 0] + bx[..., 2] + by[..., 1], bz[..., 1] + bx[..., 0] + by[..., 2],
                  bz[..., 2] + bx[..., 1] + by[..., 0]], axis=-1)
    inside = np.all(np.abs(p) < half, axis=-1)
    return b + np.where(inside[..., None], pol, 0.0)


def array_field(magnets, points) -> np.ndarray:
    """B (T) of a :class:`~magwarp.magnetics.geometry.MagnetArray` at ``points`` (``(..., 3)``, mover frame)."""
    pts = np.asarray(points, dtype=np.float64)
    c, h, j = magnets.centers, 0.5 * magnets.sizes, magnets.polarizations
    out = np.zeros(pts.shape)
    for m in range(len(c)):
        out += cuboid_field(pts - c[m], h[m], j[m])
    return out


def rotation(pose) -> np.ndarray:
    """Rotation matrices ``(n, 3, 3)`` of poses ``(n, 6)`` = (x, y, z, roll, pitch, yaw): R = Rz(yaw) Ry(pitch)
    Rx(roll)."""
    pose = np.atleast_2d(np.asarray(pose, dtype=np.float64))
    cr, sr = np.cos(pose[:, 3]), np.sin(pose[:, 3])
    cp, sp = np.cos(pose[:, 4]), np.sin(pose[:, 4])
    cy, sy = np.cos(pose[:, 5]), np.sin(pose[:, 5])
    return np.stack([
        np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
        np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
        np.stack([-sp, cp * sr, cp * cr], -1),
    ], axis=1)


def _quadrature_points(a, b, quadrature):
    """Points ``(q, 3)`` and weights ``(q,)`` (in units of the parameter s in [0, 1]) along segment a -> b."""
    nodes, weights = quadrature.nodes_weights()
    n_sub = max(1, int(np.ceil(np.linalg.norm(b - a) / quadrature.max_interval)))
    s = ((np.arange(n_sub)[:, None] + nodes[None, :]) / n_sub).ravel()
    w = np.tile(weights / n_sub, n_sub)
    return a + s[:, None] * (b - a), w


def segment_wrench(magnets, a, b, quadrature) -> np.ndarray:
    """Force and torque (about the origin) ``(6,)`` on a unit-current filament a -> b in the array's frame."""
    pts, w = _quadrature_points(a, b, quadrature)
    dl = b - a
    f = np.cross(dl, array_field(magnets, pts))
    return np.concatenate([(w[:, None] * f).sum(0), (w[:, None] * np.cross(pts, f)).sum(0)])


def coil_columns(params, coilset, pose, coil_ids) -> np.ndarray:
    """Wrench columns ``(len(coil_ids), 6)`` (force N/A, torque N m/A about the mover's centre, world frame) on a
    mover at ``pose`` (x, y, z, roll, pitch, yaw) for unit currents in the given coils; -1 ids give zeros."""
    pose = np.asarray(pose, dtype=np.float64)
    rot = rotation(pose)[0]
    out = np.zeros((len(coil_ids), 6))
    for n, k in enumerate(coil_ids):
        if k < 0:
            continue
        col = np.zeros(6)
        for s in range(coilset.seg_start[k], coilset.seg_start[k + 1]):
            a = rot.T @ (coilset.seg_a[s] - pose[:3])
            b = rot.T @ (coilset.seg_b[s] - pose[:3])
            col += coilset.seg_weight[s] * segment_wrench(params.magnets, a, b, params.quadrature)
        out[n] = -np.concatenate([rot @ col[:3], rot @ col[3:]])
    return out


def active_coils(coilset, xy, radius: float) -> list[np.ndarray]:
    """Per mover, the ids of coils whose rectangle lies within ``radius`` of the mover's centre ``xy`` (xy
    distance), in increasing id order."""
    xy = np.atleast_2d(np.asarray(xy, dtype=np.float64))
    r = coilset.rects
    out = []
    for x, y in xy:
        dx = np.maximum(np.maximum(r[:, 0] - x, 0.0), x - r[:, 1])
        dy = np.maximum(np.maximum(r[:, 2] - y, 0.0), y - r[:, 3])
        out.append(np.nonzero(dx * dx + dy * dy < radius * radius)[0])
    return out


def flux_linkage(magnets, coil_loops, weight: float, pose, order: int = 24, cells: int = 24) -> float:
    """Flux linkage (Wb per unit current's turns) of horizontal rectangular loops ``(F, 4, 3)`` (world frame,
    counter-clockwise from +z) with a mover at ``pose``: sum of ``weight * integral(B . z dA)`` over each loop's
    area, by tensor Gauss-Legendre quadrature on ``cells x cells`` sub-rectangles."""
    rot = rotation(pose)[0]
    x, w = np.polynomial.legendre.leggauss(order)
    x, w = 0.5 * (x + 1.0), 0.5 * w
    total = 0.0
    for loop in np.asarray(coil_loops, dtype=np.float64):
        lo, hi = loop.min(0), loop.max(0)
        su = ((np.arange(cells)[:, None] + x[None, :]) / cells).ravel()
        ws = np.tile(w / cells, cells)
        gx, gy = lo[0] + su * (hi[0] - lo[0]), lo[1] + su * (hi[1] - lo[1])
        pts = np.stack([*np.meshgrid(gx, gy, indexing="ij"), np.full((len(gx), len(gy)), loop[0, 2])], -1)
        local = (pts.reshape(-1, 3) - pose[:3]) @ rot  # rot.T @ (p - c) for each row
        b_world = array_field(magnets, local) @ rot.T
        area = (hi[0] - lo[0]) * (hi[1] - lo[1])
        total += weight * area * (np.outer(ws, ws).ravel() * b_world[:, 2]).sum()
    return float(total)


def _cholesky(a, shift):
    """Lower factor of a + shift I and its smallest squared pivot (as the kernel's ``cholesky6``)."""
    lo = np.zeros((6, 6))
    piv = np.inf
    for c in range(6):
        s = a[c, c] + shift - lo[c, :c] @ lo[c, :c]
        piv = min(piv, s)
        d = np.sqrt(max(s, 1e-300))
        lo[c, c] = d
        with np.errstate(over="ignore", invalid="ignore"):
            lo[c + 1:, c] = (a[c + 1:, c] - lo[c + 1:, :c] @ lo[c, :c]) / d
    return lo, piv


def commutate(gamma, resistance, limit, wrench, max_iter: int = 64, reg: float = 1e-6, stats: dict | None = None):
    """Least-copper-loss currents for one mover (float64): ``gamma (6, K)``, ``resistance (K,)``, ``limit (K,)``,
    ``wrench (6,)``. Mirrors :func:`magwarp.magnetics.commutation.make_commutation_kernel`: solve for the free coils,
    step from the current currents toward that optimum as far as the limits allow, fix the coils that reach their
    limit, repeat; at most ``max_iter`` solves.
    The unit-diagonal 6 x 6 system is regularised (+ reg I) when a Cholesky pivot falls below ``reg``.
    Returns currents, delivered wrench, saturated mask, regularised flag, converged flag; ``stats`` (a dict), when
    given, receives the number of solves (``"solves"``)."""
    gamma = np.asarray(gamma, dtype=np.float64)
    resistance, limit = np.asarray(resistance, dtype=np.float64), np.asarray(limit, dtype=np.float64)
    k = gamma.shape[1]
    sat = np.zeros(k, dtype=bool)
    cur = np.zeros(k)
    regularised, converged = False, k == 0
    solves = 0
    for _ in range(max_iter):
        free = ~sat
        if converged or not free.any():
            break
        solves += 1
        a = (gamma[:, free] / resistance[free]) @ gamma[:, free].T
        rhs = wrench - gamma[:, sat] @ cur[sat]
        diag = np.diag(a)
        scale = np.where(diag > 0, 1.0 / np.sqrt(np.where(diag > 0, diag, 1.0)), 1.0)
        a_s = a * np.outer(scale, scale)
        lo, piv = _cholesky(a_s, 0.0)
        if piv < reg:
            (lo, _), regularised = _cholesky(a_s, reg), True
        y = np.linalg.solve(lo.T, np.linalg.solve(lo, rhs * scale)) * scale
        target = (gamma[:, free].T @ y) / resistance[free]
        now, lim = cur[free], limit[free]
        over = np.abs(target) > lim
        with np.errstate(divide="ignore", invalid="ignore"):
            reach = np.where(over, (np.sign(target) * lim - now) / (target - now), np.inf)
        alpha = min(1.0, reach.min()) if reach.size else 1.0
        new = now + alpha * (target - now)
        hit = over & (reach <= alpha * (1.0 + 1e-12))
        new[hit] = np.sign(target[hit]) * lim[hit]
        cur[free] = new
        sat[np.nonzero(free)[0][hit]] = True
        converged = alpha >= 1.0
    if stats is not None:
        stats["solves"] = solves
    return cur, gamma @ cur, sat, regularised, converged



def table_column(data, lo, step: float, z0: float, z_step: float, yaw_steps: int, yaw_scale: float,
                 direction: int, layer: int, dx: float, dy: float, z: float, yaw: float) -> np.ndarray:
    """One column (world frame) of the wrench table, mirroring :func:`magwarp.magnetics.table.table_column`:
    ``data`` ``(layers * yaw_steps, n_across, n_along, nz, 6)``, ``lo`` the first (across, along) offset; linear
    in height (clamped to the table) and yaw, bilinear in the offset (mover minus coil centre, world); each of the
    two yaw samples is read at the offset turned by (sample yaw - yaw) and its column turned back."""
    data = np.asarray(data, dtype=np.float64)
    ni, nj, nz = data.shape[1:4]
    gk = np.clip((z - z0) / z_step, 0.0, nz - 1)
    k = min(int(gk), nz - 2)
    fk = gk - k
    gy = yaw * yaw_scale
    fy = gy - np.floor(gy)
    y0 = int(np.floor(gy)) % yaw_steps
    out = np.zeros(6)
    for d in (0, 1):
        delta = (d - fy) / yaw_scale
        c, s = np.cos(delta), np.sin(delta)
        rx, ry = c * dx - s * dy, s * dx + c * dy
        across, along = (rx, ry) if direction == 1 else (ry, rx)
        gi = np.clip((across - lo[0]) / step, 0.0, ni - 1)
        gj = np.clip((along - lo[1]) / step, 0.0, nj - 1)
        i, j = min(int(gi), ni - 2), min(int(gj), nj - 2)
        fi, fj = gi - i, gj - j
        block = data[layer * yaw_steps + (y0 + d) % yaw_steps]
        col = np.zeros(6)
        for kk, wk in ((k, 1.0 - fk), (k + 1, fk)):
            b = block[..., kk, :]
            col += wk * ((b[i, j] * (1 - fi) + b[i + 1, j] * fi) * (1 - fj)
                         + (b[i, j + 1] * (1 - fi) + b[i + 1, j + 1] * fi) * fj)
        rot = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])  # turn back by -delta
        out += (1.0 - fy if d == 0 else fy) * np.concatenate([rot @ col[:3], rot @ col[3:]])
    return out
