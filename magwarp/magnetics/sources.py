"""Field sources for the wrench kernels: the magnet array itself (exact, :class:`MagnetSource`) and its sampled
field (fast, :class:`FieldTable`), behind one overloaded ``source_field(src, p)`` (mover frame, T) that the generic
quadrature of :mod:`~magwarp.magnetics.exact` calls.

:class:`FieldTable`: the array's field on a regular grid in the mover frame (float32 samples), trilinearly
interpolated in float64. Beyond the grid in x or y the field is taken as zero (the grid's margin is where the
array's field has decayed; :mod:`~magwarp.magnetics.fast` measures what that costs); beyond it in z the nearest
grid level is used and the evaluation is counted in ``out_of_range`` (the mover left the table's hover range).
"""

import numpy as np
import warp as wp

from magwarp.magnetics.cuboid import ZERO, ONE, cuboid_field


@wp.struct
class MagnetSource:
    """A magnet array (mover frame): centres, half sizes and polarizations of its cuboids."""

    center: wp.array(dtype=wp.vec3d)
    half: wp.array(dtype=wp.vec3d)
    polarization: wp.array(dtype=wp.vec3d)


@wp.func
def source_field(src: MagnetSource, p: wp.vec3d) -> wp.vec3d:
    """B (T) of the whole array at ``p`` (mover frame)."""
    b = wp.vec3d(ZERO, ZERO, ZERO)
    for m in range(src.center.shape[0]):
        b = b + cuboid_field(p - src.center[m], src.half[m], src.polarization[m])
    return b


def make_field_kernel(source_type):
    """A kernel evaluating ``source_field`` of a source type at points (mover frame)."""

    @wp.kernel(module="unique")
    def field_kernel(
        # Model:
        src: source_type,
        # State in:
        points: wp.array(dtype=wp.vec3d),
        # State out:
        field: wp.array(dtype=wp.vec3d),
    ):
        i = wp.tid()
        field[i] = source_field(src, points[i])

    return field_kernel


_FIELD_KERNELS = {}


def source_field_at(src, points, device=None) -> np.ndarray:
    """B (T, float64 numpy ``(n, 3)``) of a field source at ``points`` (mover frame, ``(n, 3)``)."""
    pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    if not np.all(np.isfinite(pts)):
        raise ValueError(f"source_field_at: points must be finite, got {pts[~np.isfinite(pts).all(1)][:3]!r}")
    kind = src._cls  # the wp.struct of the instance
    if kind not in _FIELD_KERNELS:
        _FIELD_KERNELS[kind] = make_field_kernel(kind)
    out = wp.zeros(len(pts), dtype=wp.vec3d, device=device)
    if len(pts):
        wp.launch(_FIELD_KERNELS[kind], dim=len(pts), device=device,
                  inputs=[src, wp.array(pts, dtype=wp.vec3d, device=device)], outputs=[out])
    return out.numpy()


def magnet_source(magnets, device=None) -> MagnetSource:
    """A :class:`MagnetSource` on ``device`` from a :class:`~magwarp.magnetics.geometry.MagnetArray`."""
    src = MagnetSource()
    src.center = wp.array(magnets.centers, dtype=wp.vec3d, device=device)
    src.half = wp.array(0.5 * magnets.sizes, dtype=wp.vec3d, device=device)
    src.polarization = wp.array(magnets.polarizations, dtype=wp.vec3d, device=device)
    return src


def array_field(magnets, points, device=None):
    """B (T, float64 numpy ``(n, 3)``) of a magnet array at ``points`` (mover frame, ``(n, 3)``)."""
    return source_field_at(magnet_source(magnets, device), points, device)


@wp.struct
class FieldTable:
    """A magnet array's field sampled on a grid (mover frame): ``field[i, j, k]`` at ``origin + (i, j, k) * step``."""

    field: wp.array3d(dtype=wp.vec3f)
    origin: wp.vec3d
    inv_step: wp.vec3d
    out_of_range: wp.array(dtype=wp.int32)


@wp.func
def _sample(src: FieldTable, i: int, j: int, k: int) -> wp.vec3d:
    b = src.field[i, j, k]
    return wp.vec3d(wp.float64(b[0]), wp.float64(b[1]), wp.float64(b[2]))


@wp.func
def source_field(src: FieldTable, p: wp.vec3d) -> wp.vec3d:
    """Trilinear interpolation of the table at ``p``; zero beyond the grid in x or y; clamped (and counted) in z."""
    g = wp.cw_mul(p - src.origin, src.inv_step)
    nx = src.field.shape[0]
    ny = src.field.shape[1]
    nz = src.field.shape[2]
    out = wp.vec3d(ZERO, ZERO, ZERO)
    if g[0] >= ZERO and g[0] <= wp.float64(nx - 1) and g[1] >= ZERO and g[1] <= wp.float64(ny - 1):
        gz = g[2]
        if gz < ZERO or gz > wp.float64(nz - 1):
            wp.atomic_add(src.out_of_range, 0, 1)
            gz = wp.clamp(gz, ZERO, wp.float64(nz - 1))
        i = wp.min(int(g[0]), nx - 2)
        j = wp.min(int(g[1]), ny - 2)
        k = wp.min(int(gz), nz - 2)
        fx = g[0] - wp.float64(i)
        fy = g[1] - wp.float64(j)
        fz = gz - wp.float64(k)
        c00 = _sample(src, i, j, k) * (ONE - fx) + _sample(src, i + 1, j, k) * fx
        c10 = _sample(src, i, j + 1, k) * (ONE - fx) + _sample(src, i + 1, j + 1, k) * fx
        c01 = _sample(src, i, j, k + 1) * (ONE - fx) + _sample(src, i + 1, j, k + 1) * fx
        c11 = _sample(src, i, j + 1, k + 1) * (ONE - fx) + _sample(src, i + 1, j + 1, k + 1) * fx
        out = (c00 * (ONE - fy) + c10 * fy) * (ONE - fz) + (c01 * (ONE - fy) + c11 * fy) * fz
    return out


@wp.kernel
def sample_field_kernel(
    # Model:
    src: MagnetSource,
    origin: wp.vec3d,
    step: wp.vec3d,
    # State out:
    field: wp.array3d(dtype=wp.vec3f),
):
    """The exact field of the array at every grid point."""
    i, j, k = wp.tid()
    p = origin + wp.cw_mul(wp.vec3d(wp.float64(i), wp.float64(j), wp.float64(k)), step)
    b = source_field(src, p)
    field[i, j, k] = wp.vec3f(wp.float32(b[0]), wp.float32(b[1]), wp.float32(b[2]))
