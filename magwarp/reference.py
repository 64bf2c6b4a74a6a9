"""Plain numpy reference implementations of magwarp's kernels (float64, loops allowed, clarity over speed).

These are the test oracles for the Warp kernels, and they validate start poses on the host. They state each rule
once, in the most obvious form:

* mover-mover: circles collide when ``|p_i - p_j| <= r_i + r_j``; boxes (yaw-rotated rectangles) collide when
  they overlap or touch (separating-axis test). Both shapes are grown by the safety ``margin`` first.
* mover-wall: the footprint (grown by ``wall_margin``) overlaps a missing tile or leaves the grid. A footprint that
  only touches an edge of the tiled area is still inside (MagBotSim's strict inequality).
* dynamics: semi-implicit Euler at the cycle time, x/y acceleration (or jerk) norm-clipped per mover with the
  velocity cap enforced by shortening the step, z/roll/pitch/yaw held by a critically damped impedance law.
"""

from __future__ import annotations

import numpy as np

from magwarp.layout import Layout, LayoutError, MoverSpec

SHAPE_CIRCLE = 0
SHAPE_BOX = 1


def collision_sizes(mover: MoverSpec, num_movers: int, radii=None, half_sizes=None) -> tuple[np.ndarray, np.ndarray]:
    """Per-mover circle radii ``(M,)`` and box half sizes ``(M, 2)`` (defaults from the spec)."""
    r = np.full(num_movers, mover.collision_radius) if radii is None else np.asarray(radii, dtype=np.float64).reshape(num_movers)
    h = np.tile(np.asarray(mover.collision_half_size, dtype=np.float64), (num_movers, 1)) if half_sizes is None else (
        np.asarray(half_sizes, dtype=np.float64).reshape(num_movers, 2)
    )
    return r, h


def box_corners(xy: np.ndarray, yaw: float, half: np.ndarray) -> np.ndarray:
    """The 4 corners (4, 2) of a rectangle centred at ``xy`` with half sizes ``half``, rotated by ``yaw``."""
    c, s = np.cos(yaw), np.sin(yaw)
    local = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=np.float64) * half
    rot = np.array([[c, -s], [s, c]])
    return xy + local @ rot.T


def polygons_overlap(a: np.ndarray, b: np.ndarray) -> bool:
    """Separating-axis test for two convex polygons (corner lists); touching counts as overlap."""
    for poly in (a, b):
        for k in range(len(poly)):
            edge = poly[(k + 1) % len(poly)] - poly[k]
            axis = np.array([-edge[1], edge[0]])
            pa, pb = a @ axis, b @ axis
            if pa.max() < pb.min() or pb.max() < pa.min():
                return False
    return True


def mover_pair_collides(shape: int, xy_i, yaw_i, xy_j, yaw_j, r_i, r_j, h_i, h_j, margin: float) -> bool:
    if shape == SHAPE_CIRCLE:
        return float(np.linalg.norm(np.asarray(xy_i) - np.asarray(xy_j))) <= r_i + r_j + 2.0 * margin
    return polygons_overlap(box_corners(xy_i, yaw_i, h_i + margin), box_corners(xy_j, yaw_j, h_j + margin))


def mover_collision_pairs(mover: MoverSpec, xy: np.ndarray, yaw: np.ndarray, radii=None, half_sizes=None,
                          margin: float | None = None) -> list[tuple[int, int]]:
    """All colliding pairs ``(i, j)``, ``i < j``, of one world (brute force)."""
    xy = np.asarray(xy, dtype=np.float64)
    m = len(xy)
    r, h = collision_sizes(mover, m, radii, half_sizes)
    shape = SHAPE_CIRCLE if mover.collision_shape == "circle" else SHAPE_BOX
    margin = mover.margin if margin is None else margin
    return [
        (i, j)
        for i in range(m)
        for j in range(i + 1, m)
        if mover_pair_collides(shape, xy[i], yaw[i], xy[j], yaw[j], r[i], r[j], h[i], h[j], margin)
    ]


def _footprint_hits_square(shape: int, xy, yaw, radius, half, lo, hi) -> bool:
    """Does the footprint overlap the open square [lo, hi] with positive area?"""
    if shape == SHAPE_CIRCLE:
        nearest = np.clip(xy, lo, hi)
        return float(np.linalg.norm(np.asarray(xy) - nearest)) < radius
    corners = box_corners(np.asarray(xy, dtype=np.float64), yaw, half)
    square = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
    for poly in (corners, square):
        for k in range(4):
            edge = poly[(k + 1) % 4] - poly[k]
            axis = np.array([-edge[1], edge[0]])
            pa, pb = corners @ axis, square @ axis
            if pa.max() <= pb.min() or pb.max() <= pa.min():
                return False
    return True


def wall_collisions(layout: Layout, mover: MoverSpec, xy: np.ndarray, yaw: np.ndarray, radii=None, half_sizes=None,
                    wall_margin: float | None = None) -> np.ndarray:
    """Per-mover wall flags ``(W, M)`` for positions ``(W, M, 2)``: the grown footprint overlaps a hole or leaves the grid."""
    xy = np.asarray(xy, dtype=np.float64)
    yaw = np.asarray(yaw, dtype=np.float64)
    num_worlds, m = xy.shape[:2]
    r, h = collision_sizes(mover, m, radii, half_sizes)
    wall_margin = mover.wall_margin if wall_margin is None else wall_margin
    shape = SHAPE_CIRCLE if mover.collision_shape == "circle" else SHAPE_BOX
    size = layout.tile.size
    nx, ny = layout.shape
    out = np.zeros((num_worlds, m), dtype=bool)
    for w in range(num_worlds):
        for k in range(m):
            reach = r[k] + wall_margin if shape == SHAPE_CIRCLE else float(np.hypot(*(h[k] + wall_margin)))
            lo_i, lo_j = np.floor((xy[w, k] - reach) / size).astype(int)
            hi_i, hi_j = np.floor((xy[w, k] + reach) / size).astype(int)
            for i in range(lo_i, hi_i + 1):
                for j in range(lo_j, hi_j + 1):
                    present = 0 <= i < nx and 0 <= j < ny and layout.tiles[i, j] == 1
                    if present:
                        continue
                    lo = np.array([i * size, j * size])
                    if _footprint_hits_square(shape, xy[w, k], yaw[w, k], r[k] + wall_margin, h[k] + wall_margin, lo, lo + size):
                        out[w, k] = True
    return out


def clip_norm(v: np.ndarray, limit: float) -> np.ndarray:
    """Scale rows of ``v`` down to norm ``limit`` where they exceed it (MagBotSim's action clipping)."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.where(n > limit, v * (limit / np.maximum(n, 1e-30)), v)


def limit_next(current: np.ndarray, deriv: np.ndarray, limit: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Next value ``current + dt * deriv`` with its norm capped at ``limit``; returns (next, effective deriv)."""
    nxt = current + dt * deriv
    n = np.linalg.norm(nxt, axis=-1, keepdims=True)
    over = n >= limit
    capped = np.where(over, nxt * (limit / np.maximum(n, 1e-30)), nxt)
    return capped, np.where(over, (capped - current) / dt, deriv)


def planar_cycle(vel_xy, acc_xy, cmd, *, dt, v_max, a_max, j_max, jerk_mode: bool):
    """x/y part of one control cycle for arrays ``(..., 2)``: returns (acceleration applied, new velocity, delta pos)."""
    if jerk_mode:
        jerk = clip_norm(cmd, j_max)
        acc_tmp, _ = limit_next(acc_xy, jerk, a_max, dt)
        _, acc = limit_next(vel_xy, acc_tmp, v_max, dt)
    else:
        _, acc = limit_next(vel_xy, clip_norm(cmd, a_max), v_max, dt)
    vel = vel_xy + dt * acc
    return acc, vel, dt * vel


def yaw_cycle(c_vel: float, acc_c: float, cmd: float, yaw: float, *, dt, v_max, a_max, j_max, p_max,
              jerk_mode: bool) -> float:
    """Yaw ("c") axis of one control cycle: the yaw acceleration applied (see :mod:`magwarp.physics.control`)."""
    a = float(np.clip(cmd, -a_max, a_max))
    if jerk_mode:
        a = float(np.clip(acc_c + np.clip(cmd, -j_max, j_max) * dt, -a_max, a_max))
    v_safe = v_max
    if p_max is not None:
        braking = c_vel * c_vel / (2.0 * a_max) + 0.05
        dist = p_max - abs(yaw)
        if ((a > 0 and yaw > 0) or (a < 0 and yaw < 0)) and dist < braking:
            v_safe = min(v_max, np.sqrt(max(0.0, 2.0 * a_max * dist)) * 0.65)
    return (float(np.clip(c_vel + a * dt, -v_safe, v_safe)) - c_vel) / dt


def wrap_angle(a):
    """Angles wrapped to [-pi, pi)."""
    return a - 2.0 * np.pi * np.floor((a + np.pi) / (2.0 * np.pi))


def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """Rotation vector of a unit quaternion (x, y, z, w), shortest arc."""
    v, w = q[:3], q[3]
    if w < 0:
        v, w = -v, -w
    s = np.linalg.norm(v)
    if s < 1e-12:
        return 2.0 * v
    return v * (2.0 * np.arctan2(s, w) / s)


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    ])


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    p = quat_mul(quat_mul(q, np.array([v[0], v[1], v[2], 0.0])), q * np.array([-1, -1, -1, 1.0]))
    return p[:3]


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion (x, y, z, w)."""
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def angular_acceleration(q: np.ndarray, omega: np.ndarray, torque: np.ndarray, inertia: np.ndarray) -> np.ndarray:
    """World-frame angular acceleration from Euler's equations in the body frame (diagonal inertia)."""
    r = quat_to_matrix(q)
    wb, tb = r.T @ omega, r.T @ torque
    return r @ ((tb - np.cross(wb, inertia * wb)) / inertia)


def yaw_quat(yaw: float) -> np.ndarray:
    return np.array([0.0, 0.0, np.sin(0.5 * yaw), np.cos(0.5 * yaw)])


def impedance_wrench(pos, quat, vel, omega, target_pos, target_quat, k_lin, k_rot, d_lin, d_rot, mask_lin, mask_rot):
    """Force and torque (world frame) of the impedance law for one mover.

    The orientation error is the rotation vector taking the current orientation to the target, expressed in the
    world frame; stiffness and damping act per world axis (the mover stays near level, so world axes ~ body axes).
    """
    f = mask_lin * (k_lin * (target_pos - pos) - d_lin * vel)
    err = quat_rotate(quat, quat_to_rotvec(quat_mul(quat * np.array([-1, -1, -1, 1.0]), target_quat)))
    t = mask_rot * (k_rot * err - d_rot * omega)
    return f, t


def integrate_rotation(quat: np.ndarray, omega: np.ndarray, dt: float) -> np.ndarray:
    """Advance a quaternion by world-frame angular velocity over ``dt`` (exact exponential map), renormalised."""
    angle = np.linalg.norm(omega) * dt
    if angle < 1e-15:
        return quat
    axis = omega / np.linalg.norm(omega)
    dq = np.concatenate([axis * np.sin(0.5 * angle), [np.cos(0.5 * angle)]])
    q = quat_mul(dq, quat)
    return q / np.linalg.norm(q)


def validate_starts(layout: Layout, mover: MoverSpec, starts_xy: np.ndarray, yaw: np.ndarray | None = None,
                    radii=None, half_sizes=None) -> np.ndarray:
    """Check start positions: shape ``(num_movers, 2)``, finite, footprints on tiles, no two overlapping.

    Returns the positions as a float64 array. Uses the exact numpy collision reference, so the rule is the same one
    the simulator applies every cycle (with margins).
    """
    starts = np.asarray(starts_xy, dtype=np.float64)
    if starts.ndim != 2 or starts.shape[1] != 2:
        raise LayoutError(f"start positions must have shape (num_movers, 2), got {starts.shape}")
    if not np.all(np.isfinite(starts)):
        raise LayoutError(f"start positions must be finite, got {starts[~np.isfinite(starts).all(axis=1)][:3]!r}")
    yaw = np.zeros(len(starts)) if yaw is None else np.asarray(yaw, dtype=np.float64).reshape(len(starts))
    wall = wall_collisions(layout, mover, starts[None], yaw[None], radii, half_sizes)[0]
    if wall.any():
        k = int(np.flatnonzero(wall)[0])
        raise LayoutError(f"mover {k} starts at {tuple(np.round(starts[k], 4))}, which is off the tiles (or too close to "
                          "an edge)")
    pairs = mover_collision_pairs(mover, starts, yaw, radii, half_sizes)
    if len(pairs):
        a, b = pairs[0]
        raise LayoutError(f"movers {a} and {b} overlap at their start positions {tuple(np.round(starts[a], 4))} and "
                          f"{tuple(np.round(starts[b], 4))}")
    return starts
