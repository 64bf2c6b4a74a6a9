"""The wrench-table model: Gamma(q) from a precomputed per-coil table, for the control cycle of many movers.

A coil's wrench column (force N/A, torque N m/A about the mover's centre, world frame) depends only on the mover's
pose relative to the coil. For every coil layer the table holds that column for a level mover (roll = pitch = 0) on
a regular grid of

* the offset of the mover's centre from the coil's centre, across the coil (perpendicular to its long sides) and
  along it (``step``), over every offset at which the coil's rectangle lies within ``footprint`` of the mover's
  centre;
* the mover's height (``z_step``, over the gaps ``gap``);
* the mover's yaw over the magnet array's own period (``yaw_steps`` samples; a quarter turn for the default
  pinwheel Halbach array, which is the same array after a quarter turn: the field, hence every column, repeats).

It is built once from the field-table quadrature model (:class:`~magwarp.magnetics.fast.FastModel`, itself sampled
from the exact cuboid model; 4.8 M columns, about 15 s on one CPU core, well under a second on a GPU), stored in
float16 (57 MB for the defaults, 2-6 mm gaps; 34 MB over the hover range 3-5 mm, which fits a GPU's L2 cache but
clamps movers that sink: the B0 policy's success at a 2 A current limit falls from 88% to 52% with it) and cached on
disk (:mod:`~magwarp.magnetics.cache`), and interpolated in one kernel with one thread per (mover, window slot):
linear in height and yaw, bilinear in the offset (2 yaw samples x 4 corners x 2 heights, adjacent in memory), the
yaw rotation-compensated (each yaw sample is read where the coil sits at the same place relative to the magnets, so
only the coil's turn about its own centre is interpolated: this halves the error of a plain linear yaw interpolation
at the same memory). The window of a mover is, per layer, the block of the layer's coil grid that holds every coil
within ``footprint`` (42 slots for the defaults; coils beyond the footprint get id -1 and are not driven). The
commutation (:mod:`~magwarp.magnetics.commutation`) runs as one more kernel.

Footprint: coils whose rectangle lies within 0.1 m (xy) of the mover's centre (28 coils on average for the default
design, the 150 mm array's footprint): hovering with them alone costs 0.2% more copper loss on average (0.9% at
most) than with every coil within the 1e-4 radius (0.285 m, about 147 coils; 8 random level poses,
``benchmarks/magnetics.py``, ``footprint`` rows). Coils outside the footprint carry no current, so the realised
wrench Gamma i is exact for the coils used: the footprint is a controller choice, not a model error.

Accuracy against the exact model (``benchmarks/magnetics.py``, ``accuracy`` rows: largest column error as a share
of the peak column over 8 random poses at the table's gaps and any yaw): the default table (2.5 mm offsets, 1 mm
heights, 32 yaw samples over a quarter turn, 2-6 mm) is within 0.74% (force) and 0.66% (torque) for a level mover
(0.67% and 0.53% over 3-5 mm). Roll and pitch are not in the table: a tilted mover is looked up level, which costs
1.3% (force) and 1.4% (torque) at tilts up to 2 mrad (the impedance hold keeps movers level to well below that;
the Levitation env's movers tilt more while they settle). Heights beyond the table's gaps are clamped and counted
in ``out_of_range``. Resolution trade-off measured while choosing the defaults (level poses, 3-5 mm, against the
field-table model): 4 mm / 16 yaw samples 2.2%, 3 mm / 24 1.1%, 2 mm / 32 0.48% of the peak.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass, field

import numpy as np
import warp as wp

from magwarp.layout import Layout
from magwarp.magnetics.cache import cached_arrays
from magwarp.magnetics.commutation import vec6f

vec6h = wp.types.vector(length=6, dtype=wp.float16)
from magwarp.magnetics.exact import WrenchModel
from magwarp.magnetics.fast import FastModel, FieldTableSpec
from magwarp.magnetics.geometry import CoilSet, MagneticParams, MagneticsError

__all__ = ["WrenchTableSpec", "TableModel", "yaw_period", "vec6f"]



def yaw_period(magnets, tol: float = 1e-9) -> float:
    """The smallest turn about the mover's z axis (2 pi / 4, 2 pi / 2 or 2 pi) that maps the array onto itself
    (centres, sizes and polarizations; sizes as the unordered x/y pair)."""
    c, s, j = magnets.centers, magnets.sizes, magnets.polarizations
    for order in (4, 2):
        a = 2.0 * np.pi / order
        rot = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
        rc, rj = c @ rot.T, j @ rot.T
        rs = s[:, [1, 0, 2]] if order == 4 else s
        ok = True
        for k in range(len(c)):
            d = (np.abs(c - rc[k]).max(1) < tol) & (np.abs(s - rs[k]).max(1) < tol) & (np.abs(j - rj[k]).max(1) < tol)
            if not d.any():
                ok = False
                break
        if ok:
            return a
    return 2.0 * np.pi


@dataclass(frozen=True)
class WrenchTableSpec:
    """The wrench table's grid: ``step`` (m, offsets across and along the coil), ``z_step`` (m) over the gaps
    ``gap`` (m, tile surface to the mover's bottom; the simulator holds movers at 4 mm; the default 2-6 mm also
    covers movers that sink when their coils saturate: beyond the gaps a look-up is clamped, which makes a sinking
    mover's coils too weak), ``yaw_steps`` samples over the array's yaw period;
    ``footprint`` (m): the coils a mover uses are those whose rectangle lies within it (xy) of the mover's centre;
    ``field``: the field table the columns are computed with (its quadrature too)."""

    step: float = 0.0025
    z_step: float = 0.001
    gap: tuple[float, float] = (0.002, 0.006)
    yaw_steps: int = 32
    footprint: float = 0.1
    field: FieldTableSpec = field(default_factory=FieldTableSpec)

    def __post_init__(self):
        for name in ("step", "z_step", "footprint"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise MagneticsError(f"WrenchTableSpec.{name} must be a positive finite number, got {value!r}")
        gap = tuple(float(g) for g in self.gap)
        if len(gap) != 2 or not 0 <= gap[0] < gap[1] or not all(math.isfinite(g) for g in gap):
            raise MagneticsError(f"WrenchTableSpec.gap must be (low, high) with 0 <= low < high, got {self.gap!r}")
        object.__setattr__(self, "gap", gap)
        if int(self.yaw_steps) != self.yaw_steps or self.yaw_steps < 2:
            raise MagneticsError(f"WrenchTableSpec.yaw_steps must be an integer >= 2, got {self.yaw_steps!r}")
        if not isinstance(self.field, FieldTableSpec):
            raise MagneticsError(f"WrenchTableSpec.field must be a FieldTableSpec, got {self.field!r}")
        if self.field.gap[0] > gap[0] or self.field.gap[1] < gap[1]:
            raise MagneticsError(f"WrenchTableSpec.gap {gap} must lie within its field table's gaps "
                                 f"{self.field.gap}")


@wp.struct
class WrenchTable:
    """Per layer ``l`` and yaw sample ``y``: ``data[l * ny + y, across, along, height]`` columns (world frame, level
    mover; float16, the heights innermost so that a look-up reads few cache lines), the grid's first offsets ``lo``
    (across, along), the layer's coil ``direction`` (0: long sides along x, 1: along y), coil ``half`` sizes (x, y)
    and grid ``pitch`` (x, y); the height axis (mover centre z) and the yaw axis."""

    data: wp.array4d(dtype=vec6h)
    lo: wp.array(dtype=wp.vec2)
    direction: wp.array(dtype=wp.int32)
    half: wp.array(dtype=wp.vec2)
    pitch: wp.array(dtype=wp.vec2)
    coil_grid: wp.array3d(dtype=wp.int32)
    inv_step: float
    z0: float
    inv_z_step: float
    ny: int
    yaw_scale: float  # samples per radian
    footprint: float
    out_of_range: wp.array(dtype=wp.int32)


@wp.func
def _corner(t: WrenchTable, ly: int, i: int, j: int, k: int) -> vec6f:
    c = t.data[ly, i, j, k]
    return vec6f(float(c[0]), float(c[1]), float(c[2]), float(c[3]), float(c[4]), float(c[5]))


@wp.func
def _trilinear(t: WrenchTable, ly: int, across: float, along: float, k: int, fk: float) -> vec6f:
    """Trilinear interpolation of one yaw sample's table at an offset (clamped to the grid) and height cell."""
    gi = wp.clamp((across - t.lo[0][0]) * t.inv_step, 0.0, float(t.data.shape[1] - 1))
    gj = wp.clamp((along - t.lo[0][1]) * t.inv_step, 0.0, float(t.data.shape[2] - 1))
    i = wp.min(int(gi), t.data.shape[1] - 2)
    j = wp.min(int(gj), t.data.shape[2] - 2)
    fi = gi - float(i)
    fj = gj - float(j)
    out = vec6f()
    for di in range(2):
        wi = wp.where(di == 0, 1.0 - fi, fi)
        for dj in range(2):
            wij = wi * wp.where(dj == 0, 1.0 - fj, fj)
            out = out + (wij * (1.0 - fk)) * _corner(t, ly, i + di, j + dj, k)
            out = out + (wij * fk) * _corner(t, ly, i + di, j + dj, k + 1)
    return out


@wp.func
def column_context(t: WrenchTable, z: float, yaw: float):
    """What every look-up of a mover at height ``z`` and ``yaw`` shares: the height cell ``k`` and weight ``fk``,
    the first yaw sample ``y0`` and weight ``fy``, the rotations (cos, sin of psi_k - yaw) of the two yaw samples,
    and whether ``z`` lies outside the table's heights (then clamped)."""
    ny = t.ny
    nz = t.data.shape[3]
    gk = (z - t.z0) * t.inv_z_step
    out = bool(False)
    if gk < 0.0 or gk > float(nz - 1):
        out = True
        gk = wp.clamp(gk, 0.0, float(nz - 1))
    k = wp.min(int(gk), nz - 2)
    fk = gk - float(k)
    gy = yaw * t.yaw_scale
    fy0 = wp.floor(gy)
    fy = gy - fy0
    y0 = int(fy0) % ny
    if y0 < 0:
        y0 = y0 + ny
    d0 = -fy / t.yaw_scale  # psi_k - yaw
    d1 = (1.0 - fy) / t.yaw_scale
    return k, fk, y0, fy, wp.vec4(wp.cos(d0), wp.sin(d0), wp.cos(d1), wp.sin(d1)), out


@wp.func
def table_column_at(t: WrenchTable, l: int, dx: float, dy: float, k: int, fk: float, y0: int, fy: float,
                    rot: wp.vec4) -> vec6f:
    """:func:`table_column` given the mover's :func:`column_context`."""
    out = vec6f()
    for dyaw in range(2):
        wy = wp.where(dyaw == 0, 1.0 - fy, fy)
        yy = (y0 + dyaw) % t.ny
        c = rot[2 * dyaw]
        s = rot[2 * dyaw + 1]
        rx = c * dx - s * dy
        ry = s * dx + c * dy
        across = rx
        along = ry
        if t.direction[l] == 0:
            across = ry
            along = rx
        col = _trilinear(t, l * t.ny + yy, across, along, k, fk)
        # turn the sample's column back by -delta
        f = wp.vec3(c * col[0] + s * col[1], -s * col[0] + c * col[1], col[2])
        tq = wp.vec3(c * col[3] + s * col[4], -s * col[3] + c * col[4], col[5])
        out = out + wy * vec6f(f[0], f[1], f[2], tq[0], tq[1], tq[2])
    return out


@wp.func
def table_column(t: WrenchTable, l: int, dx: float, dy: float, z: float, yaw: float) -> vec6f:
    """The interpolated column (world frame) of a layer-``l`` coil for a mover at offset (dx, dy) from the coil's
    centre (world, mover minus coil), height ``z`` and ``yaw``.

    Linear in height and yaw, bilinear in the offset. Between the two yaw samples psi_k the look-up is
    rotation-compensated: sample k is read at the offset turned by psi_k - yaw (where the coil sits at the same
    place relative to the magnets) and its column turned back, so only the coil's turn about its own centre is
    interpolated (a lever of the coil's size, not of its distance)."""
    k, fk, y0, fy, rot, out = column_context(t, z, yaw)
    if out:
        wp.atomic_add(t.out_of_range, 0, 1)
    return table_column_at(t, l, dx, dy, k, fk, y0, fy, rot)


@wp.func
def quat_yaw(q: wp.quatd) -> float:
    """The yaw (rad) of R = Rz(yaw) Ry(pitch) Rx(roll) from a quaternion (x, y, z, w)."""
    x = float(q[0])
    y = float(q[1])
    z = float(q[2])
    w = float(q[3])
    return wp.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


@wp.func
def slot_coil(
    t: WrenchTable, slot_layer: wp.array(dtype=wp.int32), slot_offset: wp.array(dtype=wp.vec2i), s: int, x: float,
    y: float,
):
    """Window slot ``s`` of a mover at (x, y): its coil (-1 beyond the footprint, a hole or the layout), its layer
    and the mover's offset from the coil's centre."""
    l = slot_layer[s]
    off = slot_offset[s]
    h = t.half[l]
    p = t.pitch[l]
    reach_x = h[0] + t.footprint
    reach_y = h[1] + t.footprint
    ix = int(wp.ceil((x - reach_x) / p[0] - 0.5)) + off[0]
    iy = int(wp.ceil((y - reach_y) / p[1] - 0.5)) + off[1]
    k = int(-1)
    dx = float(0.0)
    dy = float(0.0)
    if ix >= 0 and iy >= 0 and ix < t.coil_grid.shape[1] and iy < t.coil_grid.shape[2]:
        k = t.coil_grid[l, ix, iy]
        if k >= 0:
            dx = x - (float(ix) + 0.5) * p[0]
            dy = y - (float(iy) + 0.5) * p[1]
            ex = wp.max(wp.abs(dx) - h[0], 0.0)
            ey = wp.max(wp.abs(dy) - h[1], 0.0)
            if ex * ex + ey * ey >= t.footprint * t.footprint:
                k = -1
    return k, l, dx, dy


@wp.func
def slot_column(
    t: WrenchTable, slot_layer: wp.array(dtype=wp.int32), slot_offset: wp.array(dtype=wp.vec2i), s: int, x: float,
    y: float, z: float, yaw: float,
):
    """Window slot ``s`` of a mover at (x, y, z, yaw): its coil (-1 beyond the footprint, a hole or the layout) and
    its interpolated column (zeros for -1)."""
    k, l, dx, dy = slot_coil(t, slot_layer, slot_offset, s, x, y)
    col = vec6f()
    if k >= 0:
        col = table_column(t, l, dx, dy, z, yaw)
    return k, col


@wp.kernel
def table_columns_kernel(
    # Model:
    t: WrenchTable,
    slot_layer: wp.array(dtype=wp.int32),
    slot_offset: wp.array(dtype=wp.vec2i),
    # State in:
    pos: wp.array(dtype=wp.vec3d),
    quat: wp.array(dtype=wp.quatd),
    # State out:
    coil_ids: wp.array2d(dtype=wp.int32),
    gamma: wp.array2d(dtype=vec6f),
    count: wp.array(dtype=wp.int32),
):
    """One thread per (mover, window slot): the slot's coil (id -1 beyond the footprint, a hole or the layout) and
    its interpolated column (zeros for id -1); ``count`` (zeroed before) gets the mover's coils."""
    m, s = wp.tid()
    k, col = slot_column(t, slot_layer, slot_offset, s, float(pos[m][0]), float(pos[m][1]), float(pos[m][2]),
                         quat_yaw(quat[m]))
    if k >= 0:
        wp.atomic_add(count, m, 1)
    coil_ids[m, s] = k
    gamma[m, s] = col


def _layer_geometry(coilset: CoilSet):
    """Per layer: direction, coil half sizes (x, y), grid pitch (x, y), and each coil's (layer, ix, iy)."""
    coils = coilset.coils
    spec = coils.coil
    per_layer = coilset.per_tile // len(coils.layers)
    direction, half, pitch = [], [], []
    for layer in coils.layers:
        d = 1 if layer.direction == "y" else 0
        hx, hy = (0.5 * spec.width, 0.5 * spec.length) if d == 1 else (0.5 * spec.length, 0.5 * spec.width)
        direction.append(d)
        half.append((hx, hy))
        pitch.append((2 * hx, 2 * hy))
    local = np.arange(coilset.num_coils) % coilset.per_tile
    layer_of = local // per_layer
    pitch_a = np.asarray(pitch)
    ix = np.floor(coilset.centers[:, 0] / pitch_a[layer_of, 0]).astype(np.int64)
    iy = np.floor(coilset.centers[:, 1] / pitch_a[layer_of, 1]).astype(np.int64)
    return (np.asarray(direction, dtype=np.int32), np.asarray(half, dtype=np.float64), pitch_a, layer_of, ix, iy)


class TableModel(WrenchModel):
    """The wrench-table model on ``layout``: ``active_coils`` + ``wrench_matrix`` in one kernel (:meth:`columns`),
    float32 columns (``vec6f``). The table is built on ``device`` and cached on disk."""

    def __init__(self, layout: Layout, params: MagneticParams | None = None, spec: WrenchTableSpec | None = None,
                 device=None, use_cache: bool = True):
        params = params or MagneticParams()
        super().__init__(layout, MagneticParams(params.magnets, params.coils, params.quadrature, params.active_share,
                                                1.0, params.max_active, params.payload), device)
        self.params = params
        self.spec = spec or WrenchTableSpec()
        sp, cs, dev = self.spec, self.coilset, self.device
        direction, half, pitch, layer_of, ix, iy = _layer_geometry(cs)
        n_layers = len(direction)
        # The window: per layer, every grid cell whose coil centre lies within half size + footprint.
        slots = []
        for l in range(n_layers):
            nwx = int(np.floor(2 * (half[l, 0] + sp.footprint) / pitch[l, 0] + 1e-9)) + 1
            nwy = int(np.floor(2 * (half[l, 1] + sp.footprint) / pitch[l, 1] + 1e-9)) + 1
            slots += [(l, a, b) for a in range(nwx) for b in range(nwy)]
        self.max_active = len(slots)
        self.slot_layer = wp.array(np.array([s[0] for s in slots], dtype=np.int32), dtype=wp.int32, device=dev)
        self.slot_offset = wp.array(np.array([s[1:] for s in slots], dtype=np.int32), dtype=wp.vec2i, device=dev)
        grid = -np.ones((n_layers, int(ix.max()) + 1, int(iy.max()) + 1), dtype=np.int32)
        grid[layer_of, ix, iy] = np.arange(cs.num_coils, dtype=np.int32)
        self.yaw_period = yaw_period(params.magnets)
        # The table's offsets: across and along each layer's coils (the same extents for every layer).
        h_across, h_along = 0.5 * params.coils.coil.width, 0.5 * params.coils.coil.length
        # padded for the rotation-compensated look-ups (offsets turned by up to one yaw sample)
        pad = float(np.hypot(h_across + sp.footprint, h_along + sp.footprint)) * self.yaw_period / sp.yaw_steps
        n_across = int(np.ceil((h_across + sp.footprint + pad) / sp.step)) + 1
        n_along = int(np.ceil((h_along + sp.footprint + pad) / sp.step)) + 1
        lo = np.array([-n_across * sp.step, -n_along * sp.step])
        shape_xy = (2 * n_across + 1, 2 * n_along + 1)
        bottom = float(params.magnets.bounds[0, 2])
        z0 = sp.gap[0] - bottom
        nz = int(np.ceil((sp.gap[1] - sp.gap[0]) / sp.z_step - 1e-9)) + 1
        self.z_range = (z0, z0 + (nz - 1) * sp.z_step)

        def build():
            return {"data": build_table(params, self.spec, lo, shape_xy, z0, nz, self.yaw_period, dev)}

        # What shapes the columns: the magnets, the coils' geometry and turns (not their limits or resistance).
        coils = asdict(params.coils)
        for name in ("current_limit", "resistivity", "fill_factor"):
            coils["coil"].pop(name)
        text = json.dumps(["float16, heights innermost", asdict(params.magnets), coils, asdict(self.spec),
                           lo.tolist(), shape_xy, z0, nz, self.yaw_period], default=str)
        key = hashlib.sha256(text.encode()).hexdigest()[:16]
        data = cached_arrays("wrench_table", key, build, use_cache)["data"]
        want = (n_layers * int(sp.yaw_steps), *shape_xy, nz, 6)
        if data.shape != want:
            raise MagneticsError(f"cached wrench table has shape {data.shape}, expected {want}")
        t = WrenchTable()
        t.data = wp.array(data, dtype=vec6h, device=dev)
        t.lo = wp.array(np.tile(lo, (n_layers, 1)), dtype=wp.vec2, device=dev)
        t.direction = wp.array(direction, dtype=wp.int32, device=dev)
        t.half = wp.array(half, dtype=wp.vec2, device=dev)
        t.pitch = wp.array(pitch, dtype=wp.vec2, device=dev)
        t.coil_grid = wp.array(grid, dtype=wp.int32, device=dev)
        t.inv_step = 1.0 / sp.step
        t.z0 = z0
        t.inv_z_step = 1.0 / sp.z_step
        t.ny = int(sp.yaw_steps)
        t.yaw_scale = sp.yaw_steps / self.yaw_period
        t.footprint = sp.footprint
        t.out_of_range = wp.zeros(1, dtype=wp.int32, device=dev)
        self.table = t
        self.lo, self.z0, self.nz, self.directions = lo, z0, nz, direction
        self.table_bytes = int(data.nbytes)
        self.source = None

    def columns(self, pos: wp.array, quat: wp.array, coil_ids: wp.array | None = None, gamma: wp.array | None = None,
                count: wp.array | None = None, zero_count: bool = True):
        """Coil ids ``(n, slots)`` (-1: not driven), float32 columns ``(n, slots)`` and coil counts ``(n,)`` of
        movers at ``pos``/``quat`` (one launch, plus zeroing the counts unless ``zero_count=False``: the caller's
        kernel zeroed them)."""
        n, k, dev = pos.shape[0], self.max_active, self.device
        coil_ids = coil_ids if coil_ids is not None else wp.empty((n, k), dtype=wp.int32, device=dev)
        gamma = gamma if gamma is not None else wp.empty((n, k), dtype=vec6f, device=dev)
        count = count if count is not None else wp.zeros(n, dtype=wp.int32, device=dev)
        if zero_count:
            count.zero_()
        wp.launch(table_columns_kernel, dim=(n, k), device=dev,
                  inputs=[self.table, self.slot_layer, self.slot_offset, pos, quat], outputs=[coil_ids, gamma, count])
        return coil_ids, gamma, count

    def active_coils(self, pos, coil_ids=None, count=None):
        raise MagneticsError("TableModel finds its coils and columns in one launch: use columns(pos, quat)")

    def wrench_matrix(self, pos, quat, coil_ids, gamma=None):
        raise MagneticsError("TableModel finds its coils and columns in one launch: use columns(pos, quat)")

    def evaluate(self, pose) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Convenience (host arrays): coil ids, counts and Gamma ``(n, slots, 6)`` (float64) for poses ``(n, 6)``."""
        pos, quat = self.as_arrays(pose)
        ids, gamma, count = self.columns(pos, quat)
        return ids.numpy(), count.numpy(), gamma.numpy().astype(np.float64)

    @property
    def out_of_range(self) -> int:
        """How many column look-ups fell outside the table's heights so far (a host read)."""
        return int(self.table.out_of_range.numpy()[0])


def build_table(params: MagneticParams, spec: WrenchTableSpec, lo, shape_xy, z0: float, nz: int, period: float,
                device) -> np.ndarray:
    """The table ``(layers * yaw_steps, n_across, n_along, nz, 6)`` (float16): columns of the first coil of each
    layer of a one-tile layout, computed with the field-table quadrature model (spec.field)."""
    layout = Layout.grid(1, 1)
    fixed = MagneticParams(params.magnets, params.coils, params.quadrature, active_radius=1.0, max_active=1)
    model = FastModel(layout, fixed, spec.field, device=device)
    cs = model.coilset
    per_layer = cs.per_tile // len(params.coils.layers)
    a = lo[0] + spec.step * np.arange(shape_xy[0])
    b = lo[1] + spec.step * np.arange(shape_xy[1])
    yaws = period * np.arange(spec.yaw_steps) / spec.yaw_steps
    zs = z0 + spec.z_step * np.arange(nz)
    out = []
    for l in range(len(params.coils.layers)):
        k = l * per_layer
        c = cs.centers[k]
        d = int(cs.directions[k])
        zz, yy, aa, bb = np.meshgrid(zs, yaws, a, b, indexing="ij")
        dx, dy = (aa, bb) if d == 1 else (bb, aa)
        poses = np.stack([c[0] + dx, c[1] + dy, zz, np.zeros_like(zz), np.zeros_like(zz), yy], -1).reshape(-1, 6)
        cols = np.empty((len(poses), 6), dtype=np.float32)
        chunk = 1 << 20
        for s in range(0, len(poses), chunk):
            pos, quat = model.as_arrays(poses[s:s + chunk])
            ids = wp.full((pos.shape[0], 1), k, dtype=wp.int32, device=model.device)
            cols[s:s + chunk] = model.wrench_matrix(pos, quat, ids).numpy()[:, 0]
        out.append(cols.reshape(nz, spec.yaw_steps, *shape_xy, 6).transpose(1, 2, 3, 0, 4))
    return np.concatenate(out, axis=0).astype(np.float16)
