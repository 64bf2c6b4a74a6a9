"""The exact wrench model: coil currents -> wrench on each mover, w = Gamma(q) i, as Warp kernels (float64).

A straight filament a -> b with current I feels ``F = I int (b - a) x B(r(s)) ds`` and, about a point c,
``tau = I int (r(s) - c) x ((b - a) x B(r(s))) ds`` (r(s) = a + s (b - a), s in [0, 1]), integrated by compound
Gauss-Legendre quadrature (:class:`~magwarp.magnetics.geometry.Quadrature`). The filaments are moved into the
mover's frame, where the magnet array's field is the sum of its cuboids' closed-form fields. The mover gets the
reaction, -F and -tau about its centre (exact for closed loops), rotated back to the world frame. Column ``j`` of
``Gamma`` is that wrench (force N/A, torque N m/A) for a unit current in the mover's ``j``-th active coil.

Active coils: those whose rectangle lies within ``active_radius`` (xy) of the mover's centre, in increasing coil id
order, at most ``max_active`` (more is reported as an overflow, never silently dropped from the count). The default
radius is measured (:func:`measure_active_radius`): the distance beyond which every coil's force and torque stay
below ``active_share`` (1e-4) of the peak coil force and torque.

Poses are (x, y, z, roll, pitch, yaw), R = Rz(yaw) Ry(pitch) Rx(roll), or positions plus quaternions (x, y, z, w).
"""

from typing import Any

import numpy as np
import warp as wp

from magwarp.layout import Layout
from magwarp.magnetics.cache import cached_arrays
from magwarp.magnetics.cuboid import ZERO
from magwarp.magnetics.sources import MagnetSource, magnet_source, source_field
from magwarp.magnetics.geometry import CoilSet, MagneticParams, MagneticsError

vec6d = wp.types.vector(length=6, dtype=wp.float64)


@wp.func
def segment_wrench(src: Any, a: wp.vec3d, b: wp.vec3d, nodes: wp.array(dtype=wp.float64),
                   weights: wp.array(dtype=wp.float64), max_interval: wp.float64) -> vec6d:
    """Force and torque about the origin on a unit-current filament a -> b (source frame)."""
    dl = b - a
    n_sub = wp.max(int(wp.ceil(wp.length(dl) / max_interval)), 1)
    inv = wp.float64(1.0) / wp.float64(n_sub)
    f = wp.vec3d(ZERO, ZERO, ZERO)
    t = wp.vec3d(ZERO, ZERO, ZERO)
    for s in range(n_sub):
        for q in range(nodes.shape[0]):
            r = a + dl * ((wp.float64(s) + nodes[q]) * inv)
            df = wp.cross(dl, source_field(src, r)) * (weights[q] * inv)
            f = f + df
            t = t + wp.cross(r, df)
    return vec6d(f[0], f[1], f[2], t[0], t[1], t[2])


@wp.func
def coil_column(src: Any, seg_a: wp.array(dtype=wp.vec3d), seg_b: wp.array(dtype=wp.vec3d),
                seg_weight: wp.array(dtype=wp.float64), start: int, end: int, nodes: wp.array(dtype=wp.float64),
                weights: wp.array(dtype=wp.float64), max_interval: wp.float64, pos: wp.vec3d,
                quat: wp.quatd) -> vec6d:
    """Reaction wrench on the mover (world frame, torque about its centre) for a unit current in one coil."""
    acc = vec6d()
    for s in range(start, end):
        a = wp.quat_rotate_inv(quat, seg_a[s] - pos)
        b = wp.quat_rotate_inv(quat, seg_b[s] - pos)
        acc = acc + segment_wrench(src, a, b, nodes, weights, max_interval) * seg_weight[s]
    f = -wp.quat_rotate(quat, wp.vec3d(acc[0], acc[1], acc[2]))
    t = -wp.quat_rotate(quat, wp.vec3d(acc[3], acc[4], acc[5]))
    return vec6d(f[0], f[1], f[2], t[0], t[1], t[2])


def make_columns_kernel(source_type):
    """The wrench-matrix kernel for a field source type (:class:`MagnetSource` here; the fast model's table)."""

    @wp.kernel(module="unique")
    def columns_kernel(
        # Model:
        src: source_type,
        seg_a: wp.array(dtype=wp.vec3d),
        seg_b: wp.array(dtype=wp.vec3d),
        seg_weight: wp.array(dtype=wp.float64),
        seg_start: wp.array(dtype=wp.int32),
        nodes: wp.array(dtype=wp.float64),
        weights: wp.array(dtype=wp.float64),
        max_interval: wp.float64,
        # State in:
        pos: wp.array(dtype=wp.vec3d),
        quat: wp.array(dtype=wp.quatd),
        coil_ids: wp.array2d(dtype=wp.int32),
        # State out:
        gamma: wp.array2d(dtype=vec6d),
    ):
        """One wrench column per (mover, active slot); empty slots (id -1) get zeros."""
        m, j = wp.tid()
        k = coil_ids[m, j]
        col = vec6d()
        if k >= 0:
            col = coil_column(src, seg_a, seg_b, seg_weight, seg_start[k], seg_start[k + 1], nodes, weights,
                              max_interval, pos[m], quat[m])
        gamma[m, j] = col

    return columns_kernel


@wp.kernel
def active_coils_kernel(
    # Model:
    tile_map: wp.array2d(dtype=wp.int32),
    tile_size: wp.float64,
    per_tile: int,
    rects: wp.array(dtype=wp.vec4d),
    radius: wp.float64,
    # State in:
    pos: wp.array(dtype=wp.vec3d),
    # State out:
    coil_ids: wp.array2d(dtype=wp.int32),
    count: wp.array(dtype=wp.int32),
):
    """Ids of the coils within ``radius`` (xy) of each mover's centre, tile by tile in id order; ``count`` may
    exceed the slots (an overflow)."""
    m = wp.tid()
    x = pos[m][0]
    y = pos[m][1]
    i0 = wp.max(int(wp.floor((x - radius) / tile_size)), 0)
    i1 = wp.min(int(wp.floor((x + radius) / tile_size)), tile_map.shape[0] - 1)
    j0 = wp.max(int(wp.floor((y - radius) / tile_size)), 0)
    j1 = wp.min(int(wp.floor((y + radius) / tile_size)), tile_map.shape[1] - 1)
    n = int(0)
    slots = coil_ids.shape[1]
    r2 = radius * radius
    for i in range(i0, i1 + 1):
        for j in range(j0, j1 + 1):
            t = tile_map[i, j]
            if t >= 0:
                for c in range(t * per_tile, (t + 1) * per_tile):
                    r = rects[c]
                    dx = wp.max(wp.max(r[0] - x, ZERO), x - r[1])
                    dy = wp.max(wp.max(r[2] - y, ZERO), y - r[3])
                    if dx * dx + dy * dy < r2:
                        if n < slots:
                            coil_ids[m, n] = c
                        n += 1
    for s in range(wp.min(n, slots), slots):
        coil_ids[m, s] = -1
    count[m] = n


@wp.kernel
def apply_currents_kernel(
    # State in:
    gamma: wp.array2d(dtype=vec6d),
    currents: wp.array2d(dtype=wp.float64),
    # State out:
    wrench: wp.array(dtype=vec6d),
):
    """w = Gamma i per mover."""
    m = wp.tid()
    w = vec6d()
    for j in range(gamma.shape[1]):
        w = w + gamma[m, j] * currents[m, j]
    wrench[m] = w


def pose_to_pos_quat(pose) -> tuple[np.ndarray, np.ndarray]:
    """Positions ``(n, 3)`` and quaternions ``(n, 4)`` (x, y, z, w) of poses ``(n, 6)`` (x, y, z, roll, pitch,
    yaw; R = Rz(yaw) Ry(pitch) Rx(roll))."""
    pose = np.atleast_2d(np.asarray(pose, dtype=np.float64))
    if pose.ndim != 2 or pose.shape[1] != 6 or not np.all(np.isfinite(pose)):
        raise MagneticsError(f"poses must be finite, shape (n, 6) (x, y, z, roll, pitch, yaw); got shape "
                             f"{pose.shape}")
    hr, hp, hy = 0.5 * pose[:, 3], 0.5 * pose[:, 4], 0.5 * pose[:, 5]
    cr, sr, cp, sp, cy, sy = np.cos(hr), np.sin(hr), np.cos(hp), np.sin(hp), np.cos(hy), np.sin(hy)
    quat = np.stack([sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy,
                     cr * cp * cy + sr * sp * sy], axis=1)
    return pose[:, :3].copy(), quat


class WrenchModel:
    """Shared plumbing of the exact and fast models: the layout's coils on a device, the active-coil search, the
    wrench-matrix launch for the model's field source, and w = Gamma i."""

    def __init__(self, layout: Layout, params: MagneticParams | None = None, device=None):
        self.params = params or MagneticParams()
        self.layout = layout
        self.device = wp.get_device(device)
        self.coilset = CoilSet.build(layout, self.params.coils)
        cs, d = self.coilset, self.device
        self._seg = (wp.array(cs.seg_a, dtype=wp.vec3d, device=d), wp.array(cs.seg_b, dtype=wp.vec3d, device=d),
                     wp.array(cs.seg_weight, dtype=wp.float64, device=d),
                     wp.array(cs.seg_start, dtype=wp.int32, device=d))
        self._quad = self.quadrature_arrays(self.params.quadrature)
        self._tile_map = wp.array(cs.tile_map, dtype=wp.int32, device=d)
        self._rects = wp.array(cs.rects, dtype=wp.vec4d, device=d)
        self.active_radius = (float(self.params.active_radius) if self.params.active_radius is not None
                              else measure_active_radius(self.params, device=self.device))
        self.max_active = int(self.params.max_active)

    def quadrature_arrays(self, quadrature):
        """Nodes, weights (device arrays on [0, 1]) and the longest sub-interval of a quadrature."""
        nodes, weights = quadrature.nodes_weights()
        return (wp.array(nodes, dtype=wp.float64, device=self.device),
                wp.array(weights, dtype=wp.float64, device=self.device), wp.float64(quadrature.max_interval))

    # Subclasses set these.
    source = None
    _columns_kernel = None

    def as_arrays(self, pose=None, pos=None, quat=None):
        """Device arrays (vec3d positions, quatd quaternions) from poses ``(n, 6)`` or from positions and
        quaternions (numpy or warp arrays)."""
        if pose is not None:
            pos, quat = pose_to_pos_quat(pose)
        if not isinstance(pos, wp.array):
            pos = np.asarray(pos, dtype=np.float64).reshape(-1, 3)
            if not np.all(np.isfinite(pos)):
                raise MagneticsError(f"positions must be finite, got {pos[~np.isfinite(pos).all(1)][:3]!r}")
            pos = wp.array(pos, dtype=wp.vec3d, device=self.device)
        if not isinstance(quat, wp.array):
            quat = np.asarray(quat, dtype=np.float64).reshape(-1, 4)
            bad = ~np.isfinite(quat).all(1) | (np.abs(np.linalg.norm(quat, axis=1) - 1.0) > 1e-6)
            if bad.any():
                raise MagneticsError(f"quaternions (x, y, z, w) must be finite unit quaternions, got {quat[bad][:3]!r}")
            quat = wp.array(quat, dtype=wp.quatd, device=self.device)
        if pos.shape != quat.shape:
            raise MagneticsError(f"positions {pos.shape} and quaternions {quat.shape} must have one row per mover")
        return pos, quat

    def active_coils(self, pos: wp.array, coil_ids: wp.array | None = None, count: wp.array | None = None):
        """Active coil ids ``(n, max_active)`` (-1: empty slot) and counts ``(n,)`` of movers at ``pos``;
        a count above ``max_active`` is an overflow (the extra coils are left out)."""
        n = pos.shape[0]
        coil_ids = coil_ids if coil_ids is not None else wp.empty((n, self.max_active), dtype=wp.int32,
                                                                  device=self.device)
        count = count if count is not None else wp.empty(n, dtype=wp.int32, device=self.device)
        wp.launch(active_coils_kernel, dim=n, device=self.device,
                  inputs=[self._tile_map, wp.float64(self.layout.tile.size), self.coilset.per_tile, self._rects,
                          wp.float64(self.active_radius), pos], outputs=[coil_ids, count])
        return coil_ids, count

    def wrench_matrix(self, pos: wp.array, quat: wp.array, coil_ids: wp.array, gamma: wp.array | None = None):
        """Gamma ``(n, slots)`` of 6-vectors (force, torque about the mover's centre; world frame; per ampere)."""
        gamma = gamma if gamma is not None else wp.empty(coil_ids.shape, dtype=vec6d, device=self.device)
        wp.launch(self._columns_kernel, dim=coil_ids.shape, device=self.device,
                  inputs=[self.source, *self._seg, *self._quad, pos, quat, coil_ids], outputs=[gamma])
        return gamma

    def evaluate(self, pose) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Convenience (host arrays): coil ids, counts and Gamma ``(n, slots, 6)`` for poses ``(n, 6)``."""
        pos, quat = self.as_arrays(pose)
        ids, count = self.active_coils(pos)
        gamma = self.wrench_matrix(pos, quat, ids)
        return ids.numpy(), count.numpy(), gamma.numpy()

    def wrench(self, gamma: wp.array, currents: wp.array, out: wp.array | None = None) -> wp.array:
        """w = Gamma i per mover (``currents`` ``(n, slots)`` float64, in the slots' order)."""
        out = out if out is not None else wp.empty(gamma.shape[0], dtype=vec6d, device=self.device)
        wp.launch(apply_currents_kernel, dim=gamma.shape[0], device=self.device, inputs=[gamma, currents],
                  outputs=[out])
        return out


class ExactModel(WrenchModel):
    """The exact model: closed-form cuboid fields, Gauss-Legendre quadrature along every filament."""

    _columns_kernel = make_columns_kernel(MagnetSource)

    def __init__(self, layout: Layout, params: MagneticParams | None = None, device=None):
        super().__init__(layout, params, device)
        self.source = magnet_source(self.params.magnets, self.device)


def _scan_columns(params: MagneticParams, step: float, reach: float, z: float, device=None):
    """Distances (coil rectangle to mover centre), column norms |F|, |tau| ``(n, 2)`` and offsets from the coil's
    centre over rays from a coil of each direction (in a single tile) at 0, 22.5, ..., 90 degrees, yaws 0, 22.5
    and 45 degrees, at height ``z``."""
    layout = Layout.grid(1, 1)
    fixed = MagneticParams(params.magnets, params.coils, params.quadrature, active_radius=1.0, max_active=1)
    model = ExactModel(layout, fixed, device=device)
    cs = model.coilset
    picks = [int(np.nonzero(cs.directions == d)[0][0]) for d in np.unique(cs.directions)]
    offsets = np.arange(0.0, reach + 0.5 * step, step)
    rows, dists, ids, offs = [], [], [], []
    for k in picks:
        c = cs.centers[k]
        for ang in np.linspace(0.0, np.pi / 2, 5):
            u = np.array([np.cos(ang), np.sin(ang)])
            for t in offsets:
                xy = c[:2] + t * u
                r = cs.rects[k]
                dx = max(r[0] - xy[0], 0.0, xy[0] - r[1])
                dy = max(r[2] - xy[1], 0.0, xy[1] - r[3])
                for yaw in (0.0, np.pi / 8, np.pi / 4):
                    rows.append((xy[0], xy[1], z, 0.0, 0.0, yaw))
                    dists.append(np.hypot(dx, dy))
                    ids.append(k)
                    offs.append(t)
    pos, quat = model.as_arrays(np.asarray(rows))
    coil_ids = wp.array(np.asarray(ids, dtype=np.int32)[:, None], dtype=wp.int32, device=model.device)
    g = model.wrench_matrix(pos, quat, coil_ids).numpy()[:, 0]
    norms = np.stack([np.linalg.norm(g[:, :3], axis=1), np.linalg.norm(g[:, 3:], axis=1)], 1)
    return np.asarray(dists), norms, np.asarray(offs)


def measure_active_radius(params: MagneticParams, step: float = 0.005, reach: float = 0.4, z: float | None = None,
                          use_cache: bool = True, device=None) -> float:
    """The xy distance from a mover's centre to a coil's rectangle beyond which the coil's force and torque stay
    below ``params.active_share`` of the peak coil force and torque (each over the scan), plus one ``step``.

    The scan puts the mover at ``z`` (default: its bottom 3 mm above the tile, the lowest hover gap of the
    defaults, where coils act the most) on rays from a coil's centre along 0, 22.5, ..., 90 degrees (the coil and
    the array are symmetric), every ``step`` up to ``reach``, at yaws 0, 22.5 and 45 degrees, for a coil of each
    direction. Cached on disk (:mod:`cache`).
    """
    z = float(z) if z is not None else 0.003 - float(params.magnets.bounds[0, 2])

    def build():
        dist, norms, offset = _scan_columns(params, step, reach, z, device)
        share = norms / norms.max(axis=0)
        above = np.any(share >= params.active_share, axis=1)
        if above[offset >= reach - 0.5 * step].any():
            raise MagneticsError(f"coils still reach {params.active_share} of the peak wrench at {reach} m: "
                                 f"scan further (reach=)")
        return {"radius": np.array(dist[above].max() + step)}

    key = f"{params.key()}-{step}-{reach}-{z}"
    return float(cached_arrays("active_radius", key, build, use_cache)["radius"])
