"""Geometry and parameters of the magnetic model: the mover's magnet array and the tiles' coils.

Frames and units (SI: m, T, A, ohm). The **mover frame** has its origin at the centre of the mover's box
(:class:`magwarp.layout.MoverSpec`, 0.155 x 0.155 x 0.012 m), x/y along the box edges, z up; the magnets fill the
bottom of the box. The **world frame** is the layout's: tile ``(i, j)`` centred at ``((2i+1) h, (2j+1) h)``, tile top
surface at z = 0, coils below it (z < 0).

Defaults and where they come from (XPlanar data are proprietary: these are a documented generic design, chosen so
that the exact model gives XPlanar-like figures; ``tests/test_magnetics_defaults.py`` checks those figures):

* Magnets: sintered NdFeB, polarization 1.25 T (grade N40: Br 1.25-1.28 T in the usual data sheets), density
  7,500 kg/m^3. A 2D Halbach-type array of four 1D Halbach quadrants (the layout of moving-magnet planar motors
  with straight x and y coils, e.g. Planar Motor Inc.'s; a checkerboard array would need coils at 45 degrees): 5 bar
  magnets of 15 x 75 mm per quadrant (150 mm square, inside the 155 mm mover), 6 mm thick: 20 magnets, 1.01 kg of
  the mover's 1.24 kg. Pole pitch (N to S) 30 mm, period 60 mm.
* Coils: two layers per tile (the XPlanar-like "long sides along x in one layer, along y in the other"),
  each coil 120 x 40 mm outer with 10 mm wide, 3 mm thick conductor bundles (the two long sides 30 mm apart: one pole
  pitch, so they sit under opposite poles), 50 turns at a copper fill factor of 0.6: 0.67 ohm at 20 C (see
  :attr:`CoilSpec.resistance`). 6 x 2 coils per layer per tile of 240 mm, 24 coils per tile. Layers below a 1 mm
  cover: the layer with long sides along y on top (z -1..-4 mm), the other under it (-4.5..-7.5 mm).
* Current limit 7 A per coil (33 W in a coil at its limit). With the least-loss commutation at yaw 0 and 3-5 mm
  gaps, a 1.24 kg mover hovering at the current limit reaches in its worst direction at least 10.1 m/s^2 at 3 mm
  and 7.2 m/s^2 at 5 mm (median over poses 21 and 16 m/s^2; 300 random poses, linear programming,
  ``benchmarks/magnetics_acceleration.py``; XPlanar's data sheet: 10 m/s^2, as in :mod:`magwarp.layout`); it holds a
  1 kg payload (:data:`DEFAULT_PAYLOAD`); hovering costs about 15-70 W of copper loss without payload, 80-450 W
  with it (a design where the lower coil layer is the weaker one: y forces come from it).
* Active coils: those within 0.28 m (measured, :func:`~magwarp.magnetics.exact.measure_active_radius`) of the
  mover's centre, about 145 per mover.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass, field

import numpy as np

from magwarp.layout import Layout

__all__ = ["Cuboid", "MagnetArray", "halbach_array", "CoilSpec", "CoilLayer", "TileCoils", "CoilSet",
           "Quadrature", "MagneticParams", "MagneticsError", "DEFAULT_PAYLOAD"]

#: Payload (kg) the default design holds at the hover gap (a design point of the order of XPlanar movers'
#: payloads, not a product figure).
DEFAULT_PAYLOAD = 1.0


class MagneticsError(ValueError):
    """Magnetic model parameters or inputs that cannot be evaluated."""


def _vec(name: str, value, n: int = 3, positive: bool = False) -> tuple[float, ...]:
    try:
        out = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise MagneticsError(f"{name} must be {n} numbers, got {value!r}") from None
    if len(out) != n or not all(math.isfinite(v) for v in out) or (positive and not all(v > 0 for v in out)):
        raise MagneticsError(f"{name} must be {n} finite{' positive' if positive else ''} numbers, got {value!r}")
    return out


def _positive(owner: str, obj, names) -> None:
    for name in names:
        value = getattr(obj, name)
        if not isinstance(value, (int, float, np.number)) or not math.isfinite(value) or value <= 0:
            raise MagneticsError(f"{owner}.{name} must be a positive finite number, got {value!r}")


@dataclass(frozen=True)
class Cuboid:
    """A uniformly polarised cuboid magnet, axis-aligned in the mover frame: ``center`` and ``size`` (full edge
    lengths) in m, ``polarization`` J = mu0 M in T (mover frame)."""

    center: tuple[float, float, float]
    size: tuple[float, float, float]
    polarization: tuple[float, float, float]

    def __post_init__(self):
        object.__setattr__(self, "center", _vec("Cuboid.center", self.center))
        object.__setattr__(self, "size", _vec("Cuboid.size", self.size, positive=True))
        object.__setattr__(self, "polarization", _vec("Cuboid.polarization", self.polarization))


@dataclass(frozen=True)
class MagnetArray:
    """The mover's magnets (a tuple of :class:`Cuboid`, mover frame) and their material density (kg/m^3)."""

    magnets: tuple[Cuboid, ...]
    density: float = 7500.0

    def __post_init__(self):
        magnets = tuple(self.magnets)
        if not magnets or not all(isinstance(m, Cuboid) for m in magnets):
            raise MagneticsError(f"MagnetArray.magnets must be a non-empty sequence of Cuboid, got {self.magnets!r}")
        object.__setattr__(self, "magnets", magnets)
        _positive("MagnetArray", self, ("density",))

    def __len__(self) -> int:
        return len(self.magnets)

    @property
    def centers(self) -> np.ndarray:
        return np.array([m.center for m in self.magnets], dtype=np.float64)

    @property
    def sizes(self) -> np.ndarray:
        return np.array([m.size for m in self.magnets], dtype=np.float64)

    @property
    def polarizations(self) -> np.ndarray:
        return np.array([m.polarization for m in self.magnets], dtype=np.float64)

    @property
    def mass(self) -> float:
        """Mass of the magnets (kg)."""
        return float(np.prod(self.sizes, axis=1).sum() * self.density)

    @property
    def bounds(self) -> np.ndarray:
        """``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` of the array in the mover frame."""
        c, h = self.centers, 0.5 * self.sizes
        return np.stack([(c - h).min(axis=0), (c + h).max(axis=0)])


def halbach_array(magnets_per_quadrant: int = 5, cell: float = 0.015, height: float = 0.006,
                  polarization: float = 1.25, z_bottom: float = -0.006, density: float = 7500.0) -> MagnetArray:
    """A 2D Halbach-type array of four 1D Halbach quadrants (the moving-magnet planar motor layout of Planar Motor
    Inc.'s patents and of Lu & Zhang's and Kim & Trumper's planar motors), centred on the mover's z axis.

    Each quadrant is ``magnets_per_quadrant`` bar magnets of ``cell`` x (``magnets_per_quadrant * cell``) x
    ``height`` (m), their bottoms at ``z_bottom`` (the mover's bottom face: half the 12 mm box). Along the
    quadrant's axis the polarization turns a quarter turn per magnet: +z, toward the -z magnet, -z, toward the -z
    magnet, +z, ... (horizontal magnets pointing toward their -z neighbour concentrate the field below, on the
    coils; checked in the tests). Pole pitch (N to S) is 2 cells. The quadrant at (+x, +y) varies along x (an
    "x array": it meets the coils whose long sides run along y, for x and z forces); the others are its copies
    turned by 90, 180 and 270 degrees about z (a pinwheel: y arrays at (-x, +y) and (+x, -y)), so the array is
    symmetric under quarter turns. ``magnets_per_quadrant`` must be odd (z magnets at both ends).
    """
    n = magnets_per_quadrant
    if int(n) != n or n < 1 or n % 2 == 0:
        raise MagneticsError(f"halbach_array: magnets_per_quadrant must be an odd positive integer, got {n!r}")
    for name, value in (("cell", cell), ("height", height), ("polarization", polarization)):
        if not math.isfinite(value) or value <= 0:
            raise MagneticsError(f"halbach_array: {name} must be positive and finite, got {value!r}")
    n = int(n)
    side = n * cell
    zc = z_bottom + 0.5 * height
    quadrant = []  # the x array at (+x, +y)
    for i in range(n):
        phase = i % 4  # +z, +x, -z, -x: a quarter turn per magnet, strong side below
        pol = ((0.0, 0.0, polarization), (polarization, 0.0, 0.0), (0.0, 0.0, -polarization),
               (-polarization, 0.0, 0.0))[phase]
        quadrant.append(((i + 0.5) * cell, 0.5 * side, (cell, side), pol))
    magnets = []
    for turn in range(4):
        c, s = (1.0, 0.0, -1.0, 0.0)[turn], (0.0, 1.0, 0.0, -1.0)[turn]
        for x, y, (sx, sy), (jx, jy, jz) in quadrant:
            size = (sx, sy) if turn % 2 == 0 else (sy, sx)
            magnets.append(Cuboid((c * x - s * y, s * x + c * y, zc), (*size, height),
                                  (c * jx - s * jy, s * jx + c * jy, jz)))
    return MagnetArray(tuple(magnets), density=density)


@dataclass(frozen=True)
class CoilSpec:
    """A rectangular multi-turn air-core coil, as straight current filaments.

    ``length`` x ``width``: outer size (m), the long sides along the layer's direction; ``bundle_width`` x
    ``thickness``: cross-section of each side's conductor bundle (m); ``turns``; ``fill_factor``: copper share of the
    bundle; ``resistivity`` (ohm m; copper at 20 C: 1.72e-8); ``current_limit`` (A). The coil is modelled as
    ``filaments_width x filaments_height`` closed rectangular loops spread over the bundle cross-section (at the
    centres of an even subdivision), each carrying ``turns / filaments`` times the coil current.
    """

    length: float = 0.12
    width: float = 0.04
    bundle_width: float = 0.01
    thickness: float = 0.003
    turns: int = 50
    fill_factor: float = 0.6
    resistivity: float = 1.72e-8
    current_limit: float = 7.0
    filaments_width: int = 2
    filaments_height: int = 1

    def __post_init__(self):
        _positive("CoilSpec", self, ("length", "width", "bundle_width", "thickness", "turns", "fill_factor",
                                     "resistivity", "current_limit", "filaments_width", "filaments_height"))
        for name in ("turns", "filaments_width", "filaments_height"):
            if int(getattr(self, name)) != getattr(self, name):
                raise MagneticsError(f"CoilSpec.{name} must be an integer, got {getattr(self, name)!r}")
        if self.fill_factor > 1:
            raise MagneticsError(f"CoilSpec.fill_factor must be <= 1, got {self.fill_factor!r}")
        if 2 * self.bundle_width >= min(self.width, self.length):
            raise MagneticsError(f"CoilSpec.bundle_width {self.bundle_width!r} leaves no hole in a "
                                 f"{self.length!r} x {self.width!r} coil")

    @property
    def filaments(self) -> int:
        return int(self.filaments_width) * int(self.filaments_height)

    @property
    def mean_turn_length(self) -> float:
        """Length of the middle turn (m)."""
        return 2.0 * (self.length + self.width - 2.0 * self.bundle_width)

    @property
    def resistance(self) -> float:
        """DC resistance (ohm): resistivity x turns x mean turn length / wire cross-section, where the wire
        cross-section is fill_factor x bundle cross-section / turns."""
        wire = self.fill_factor * self.bundle_width * self.thickness / self.turns
        return self.resistivity * self.turns * self.mean_turn_length / wire

    def loops(self) -> np.ndarray:
        """The filament loops in the coil's own frame (long sides along y, centred at the origin, top at z = 0):
        ``(filaments, 4, 3)`` corners, counter-clockwise seen from +z (a positive current has its moment along +z)."""
        out = []
        for fw in range(int(self.filaments_width)):
            inset = self.bundle_width * (fw + 0.5) / self.filaments_width
            hx, hy = 0.5 * self.width - inset, 0.5 * self.length - inset
            for fh in range(int(self.filaments_height)):
                z = -self.thickness * (fh + 0.5) / self.filaments_height
                out.append([(hx, -hy, z), (hx, hy, z), (-hx, hy, z), (-hx, -hy, z)])
        return np.asarray(out, dtype=np.float64)


@dataclass(frozen=True)
class CoilLayer:
    """One layer of coils in every tile: ``direction`` is the axis their long sides run along (``"x"`` or ``"y"``),
    ``z_top`` the top of the conductors (m, tile surface at 0). Coils tile the tile: ``tile / width`` across and
    ``tile / length`` along (both must be whole numbers)."""

    direction: str
    z_top: float

    def __post_init__(self):
        if self.direction not in ("x", "y"):
            raise MagneticsError(f"CoilLayer.direction must be 'x' or 'y', got {self.direction!r}")
        if not math.isfinite(self.z_top) or self.z_top > 0:
            raise MagneticsError(f"CoilLayer.z_top must be <= 0 (below the tile surface), got {self.z_top!r}")


@dataclass(frozen=True)
class TileCoils:
    """The coils of one tile: a :class:`CoilSpec` repeated over each :class:`CoilLayer`."""

    coil: CoilSpec = field(default_factory=CoilSpec)
    layers: tuple[CoilLayer, ...] = (CoilLayer("y", -0.001), CoilLayer("x", -0.0045))

    def __post_init__(self):
        layers = tuple(self.layers)
        if not layers or not all(isinstance(layer, CoilLayer) for layer in layers):
            raise MagneticsError(f"TileCoils.layers must be a non-empty sequence of CoilLayer, got {self.layers!r}")
        object.__setattr__(self, "layers", layers)

    def template(self, tile_size: float) -> tuple[np.ndarray, np.ndarray]:
        """Coils of one tile centred at the origin: centres ``(n, 3)`` (x, y, z_top) and directions ``(n,)``
        (0: long sides along x, 1: along y)."""
        c = self.coil
        across, along = tile_size / c.width, tile_size / c.length
        for name, n in (("width", across), ("length", along)):
            if abs(n - round(n)) > 1e-9 or round(n) < 1:
                raise MagneticsError(f"tile size {tile_size!r} is not a whole number of coil {name}s "
                                     f"({getattr(c, name)!r})")
        across, along = int(round(across)), int(round(along))
        centers, dirs = [], []
        for layer in self.layers:
            for a in range(across):
                for b in range(along):
                    u = (a + 0.5) * c.width - 0.5 * tile_size
                    v = (b + 0.5) * c.length - 0.5 * tile_size
                    xy = (u, v) if layer.direction == "y" else (v, u)
                    centers.append((xy[0], xy[1], layer.z_top))
                    dirs.append(1 if layer.direction == "y" else 0)
        return np.asarray(centers, dtype=np.float64), np.asarray(dirs, dtype=np.int32)


@dataclass(frozen=True)
class Quadrature:
    """Gauss-Legendre quadrature along each straight filament: ``order`` nodes per sub-interval, sub-intervals at
    most ``max_interval`` m long (the field varies on the scale of the magnet cells and the gap)."""

    order: int = 4
    max_interval: float = 0.005

    def __post_init__(self):
        if int(self.order) != self.order or not 1 <= self.order <= 32:
            raise MagneticsError(f"Quadrature.order must be an integer in 1..32, got {self.order!r}")
        _positive("Quadrature", self, ("max_interval",))

    def nodes_weights(self) -> tuple[np.ndarray, np.ndarray]:
        """Nodes and weights on [0, 1]."""
        x, w = np.polynomial.legendre.leggauss(int(self.order))
        return 0.5 * (x + 1.0), 0.5 * w


@dataclass(frozen=True)
class MagneticParams:
    """Everything the magnetic model needs besides the layout.

    ``active_share``: a coil acts on a mover while its wrench share can reach ``active_share`` of the peak coil
    wrench (force and torque separately); ``active_radius`` (m) is the xy distance from the mover's centre to a
    coil's rectangle within which that holds (``None``: measured with the exact model, see
    :func:`magwarp.magnetics.exact.measure_active_radius`). ``max_active`` caps the coils per mover (an overflow is
    reported). ``payload`` (kg) is the design payload of the defaults' checks.
    """

    magnets: MagnetArray = field(default_factory=halbach_array)
    coils: TileCoils = field(default_factory=TileCoils)
    quadrature: Quadrature = field(default_factory=Quadrature)
    active_share: float = 1e-4
    active_radius: float | None = None
    max_active: int = 192
    payload: float = DEFAULT_PAYLOAD

    def __post_init__(self):
        _positive("MagneticParams", self, ("active_share", "max_active"))
        if self.active_radius is not None:
            _positive("MagneticParams", self, ("active_radius",))
        if not math.isfinite(self.payload) or self.payload < 0:
            raise MagneticsError(f"MagneticParams.payload must be >= 0, got {self.payload!r}")

    def key(self) -> str:
        """A short hash of the parameters (for on-disk caches)."""
        text = json.dumps(asdict(self), sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass(frozen=True)
class CoilSet:
    """All coils of a layout, flattened: coil ``k`` of tile ``t`` is ``t * per_tile + k`` (tiles in
    :meth:`Layout.tile_centers` order). Straight filament segments carry ``weight`` turns each (per unit current)."""

    layout: Layout
    coils: TileCoils
    centers: np.ndarray       # (n_coils, 3) world, z = layer top
    directions: np.ndarray    # (n_coils,) 0: long sides along x, 1: along y
    rects: np.ndarray         # (n_coils, 4) xmin, xmax, ymin, ymax (outer, world)
    seg_a: np.ndarray         # (n_segments, 3) world
    seg_b: np.ndarray         # (n_segments, 3) world
    seg_weight: np.ndarray    # (n_segments,) turns per filament
    seg_start: np.ndarray     # (n_coils + 1,) segment ranges per coil
    tile_map: np.ndarray      # (nx, ny) tile index, -1 for holes
    per_tile: int

    @classmethod
    def build(cls, layout: Layout, coils: TileCoils | None = None) -> "CoilSet":
        coils = coils or TileCoils()
        tcenters, tdirs = coils.template(layout.tile.size)
        tiles = layout.tile_centers()
        per_tile = len(tcenters)
        xy = tiles[:, None, :] + tcenters[None, :, :2]
        z = np.broadcast_to(tcenters[None, :, 2:], (*xy.shape[:2], 1))
        centers = np.concatenate([xy, z], axis=-1).reshape(-1, 3)
        dirs = np.tile(tdirs, len(tiles))
        spec = coils.coil
        loops = spec.loops()  # (F, 4, 3), long sides along y
        half_l, half_w = 0.5 * spec.length, 0.5 * spec.width
        seg_a, seg_b, rects = [], [], []
        for center, d in zip(centers, dirs):
            pts = loops if d == 1 else loops[..., [1, 0, 2]] * np.array([-1.0, 1.0, 1.0])  # turn +90 deg about z
            pts = pts + center
            seg_a.append(pts.reshape(-1, 3))
            seg_b.append(np.roll(pts, -1, axis=1).reshape(-1, 3))
            hx, hy = (half_w, half_l) if d == 1 else (half_l, half_w)
            rects.append((center[0] - hx, center[0] + hx, center[1] - hy, center[1] + hy))
        nseg = 4 * spec.filaments
        tile_map = -np.ones(layout.shape, dtype=np.int32)
        i, j = np.nonzero(layout.tiles)
        tile_map[i, j] = np.arange(len(i), dtype=np.int32)
        return cls(layout, coils, centers, dirs.astype(np.int32), np.asarray(rects, dtype=np.float64),
                   np.concatenate(seg_a), np.concatenate(seg_b),
                   np.full(len(centers) * nseg, spec.turns / spec.filaments, dtype=np.float64),
                   np.arange(len(centers) + 1, dtype=np.int32) * nseg, tile_map, per_tile)

    @property
    def num_coils(self) -> int:
        return len(self.centers)

    @property
    def resistance(self) -> np.ndarray:
        return np.full(self.num_coils, self.coils.coil.resistance)

    @property
    def current_limit(self) -> np.ndarray:
        return np.full(self.num_coils, self.coils.coil.current_limit)
