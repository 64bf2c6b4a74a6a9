"""The fast wrench model: the magnet array's field sampled once on a grid in the mover frame (from the exact cuboid
model), cached on disk, and trilinearly interpolated inside the same filament quadrature as the exact model.

Each field evaluation costs one interpolation (8 samples) instead of six closed-form faces per magnet (20 magnets
by default: about 100 times fewer operations). The grid covers the array plus ``margin`` in x and y (beyond it the
field is taken as zero) and, in z, every coil filament of a mover whose gap lies in ``gap`` and whose roll and
pitch stay within ``max_tilt`` (beyond it the nearest level is used and counted: :attr:`FastModel.out_of_range`).

Accuracy against the exact model (largest |Gamma_fast - Gamma_exact| over random poses at 2-6 mm gaps, tilts up to
0.02 rad and any yaw, as a share of the largest column's force or torque), default design and table (1.5 mm /
0.75 mm grid, 0.1 m margin, 22 MB; 2 Gauss nodes per 10 mm against the exact model's 4 per 5 mm): 0.17% (force)
and 0.26% (torque) over 8 poses (``benchmarks/magnetics.py``, which records it each run); the margin matters most
(0.04 m: 0.9% and 2.0%). ``tests/test_magnetics_fast.py``
holds a coarser table (2 mm / 1 mm, 0.08 m) to 1%.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass

import numpy as np
import warp as wp

from magwarp.layout import Layout
from magwarp.magnetics.cache import cached_arrays
from magwarp.magnetics.exact import WrenchModel, make_columns_kernel
from magwarp.magnetics.geometry import MagneticParams, MagneticsError, Quadrature
from magwarp.magnetics.sources import FieldTable, magnet_source, sample_field_kernel, source_field_at

__all__ = ["FieldTableSpec", "FastModel", "table_grid"]


@dataclass(frozen=True)
class FieldTableSpec:
    """The field table's grid: ``step`` (x, y) and ``z_step`` (m); ``margin`` (m) around the array in x and y; the
    hover range it serves: gaps ``gap`` (m, tile surface to the mover's bottom) and roll/pitch up to ``max_tilt``
    (rad). ``quadrature``: the fast model's own quadrature along the filaments (``None``: the parameters'; the
    default, 2 nodes per 10 mm, costs about 0.1% of the peak wrench against the exact model's 4 per 5 mm, and a
    quarter of its time)."""

    step: float = 0.0015
    z_step: float = 0.00075
    margin: float = 0.1
    gap: tuple[float, float] = (0.002, 0.006)
    max_tilt: float = 0.03
    quadrature: Quadrature | None = Quadrature(order=2, max_interval=0.01)

    def __post_init__(self):
        for name in ("step", "z_step", "margin"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise MagneticsError(f"FieldTableSpec.{name} must be positive, got {value!r}")
        gap = tuple(float(g) for g in self.gap)
        if len(gap) != 2 or not 0 <= gap[0] <= gap[1] or not np.all(np.isfinite(gap)):
            raise MagneticsError(f"FieldTableSpec.gap must be (low, high) with 0 <= low <= high, got {self.gap!r}")
        object.__setattr__(self, "gap", gap)
        if not 0 <= self.max_tilt < 0.5:
            raise MagneticsError(f"FieldTableSpec.max_tilt must be in [0, 0.5) rad, got {self.max_tilt!r}")


def table_grid(params: MagneticParams, coil_z: np.ndarray, spec: FieldTableSpec) -> tuple[np.ndarray, np.ndarray,
                                                                                            tuple[int, int, int]]:
    """Origin, step and shape of the grid (mover frame) for filaments at world heights ``coil_z``."""
    lo, hi = params.magnets.bounds
    xy_lo, xy_hi = lo[:2] - spec.margin, hi[:2] + spec.margin
    bottom = lo[2]  # the mover's bottom face is its magnets' bottom
    zc_lo, zc_hi = spec.gap[0] - bottom, spec.gap[1] - bottom
    reach = float(np.hypot(*np.maximum(np.abs(xy_lo), np.abs(xy_hi))))
    pad = reach * np.sin(spec.max_tilt) + spec.z_step
    z_lo, z_hi = float(coil_z.min()) - zc_hi - pad, float(coil_z.max()) - zc_lo + pad
    step = np.array([spec.step, spec.step, spec.z_step])
    origin = np.array([xy_lo[0], xy_lo[1], z_lo])
    shape = tuple(int(np.ceil((h - o) / s)) + 1 for o, h, s in zip(origin, (xy_hi[0], xy_hi[1], z_hi), step))
    return origin, step, shape


class FastModel(WrenchModel):
    """The fast model on ``layout`` (same interface as :class:`~magwarp.magnetics.exact.ExactModel`). The table is
    built with the exact model on ``device`` (seconds on a CPU for the defaults) and cached on disk."""

    _columns_kernel = make_columns_kernel(FieldTable)

    def __init__(self, layout: Layout, params: MagneticParams | None = None, spec: FieldTableSpec | None = None,
                 device=None, use_cache: bool = True):
        super().__init__(layout, params, device)
        self.spec = spec or FieldTableSpec()
        if self.spec.quadrature is not None:
            self._quad = self.quadrature_arrays(self.spec.quadrature)
        coil_z = np.concatenate([self.coilset.seg_a[:, 2], self.coilset.seg_b[:, 2]])
        origin, step, shape = table_grid(self.params, coil_z, self.spec)

        def build():
            field = wp.empty(shape, dtype=wp.vec3f, device=self.device)
            wp.launch(sample_field_kernel, dim=shape, device=self.device,
                      inputs=[magnet_source(self.params.magnets, self.device), wp.vec3d(*origin), wp.vec3d(*step)],
                      outputs=[field])
            return {"field": field.numpy(), "origin": origin, "step": step}

        # The table depends on the magnets and the grid only (not on the coils or the quadrature).
        grid = {k: v for k, v in asdict(self.spec).items() if k != "quadrature"}
        text = json.dumps([asdict(self.params.magnets), grid, origin.tolist(), step.tolist(), shape], default=str)
        key = hashlib.sha256(text.encode()).hexdigest()[:16]
        data = cached_arrays("field_table", key, build, use_cache)
        if data["field"].shape[:3] != shape:
            raise MagneticsError(f"cached field table has shape {data['field'].shape}, expected {shape}")
        table = FieldTable()
        table.field = wp.array(data["field"], dtype=wp.vec3f, device=self.device)
        table.origin = wp.vec3d(*data["origin"])
        table.inv_step = wp.vec3d(*(1.0 / data["step"]))
        table.out_of_range = wp.zeros(1, dtype=wp.int32, device=self.device)
        self.source = table
        self.table_bytes = int(data["field"].nbytes)

    def field(self, points) -> np.ndarray:
        """The interpolated B (T, ``(n, 3)`` numpy) at ``points`` (mover frame): the table as the kernels see it."""
        return source_field_at(self.source, points, self.device)

    @property
    def out_of_range(self) -> int:
        """How many field evaluations fell outside the table's z range so far (a host read: not in a hot path)."""
        return int(self.source.out_of_range.numpy()[0])
