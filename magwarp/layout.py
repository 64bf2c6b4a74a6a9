"""Tile layouts, tile and mover specs, and start-pose validation.

A layout is a 0/1 array of shape ``(num_tiles_x, num_tiles_y)``: ``tiles[i, j] == 1`` means a tile is present at
column ``i`` (x) and row ``j`` (y). Tile ``(i, j)`` is centred at ``((2i + 1) * h, (2j + 1) * h)`` where ``h`` is half
the tile width, so the layout's lower-left corner is the world origin (MagBotSim's convention). Missing tiles are
holes: a mover whose footprint overlaps a hole or leaves the grid has hit a "wall".
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from magwarp._checks import as_count

#: the most tiles :meth:`Layout.grid` builds (a bigger request is a mistake, not a layout: 2**24 cells, 64 MB)
GRID_CELLS_MAX = 2**24

__all__ = ["TileSpec", "MoverSpec", "Layout", "LayoutError", "BENCHMARK_LAYOUTS", "benchmark_layout",
           "mover_params_kwargs"]


class LayoutError(ValueError):
    """A layout, spec or start pose that cannot be simulated."""


def _number(value, name: str) -> float:
    """``value`` as a float, or a LayoutError naming it (strings such as "heavy", None, arrays)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise LayoutError(f"{name} must be a number, got {value!r} ({type(value).__name__})")
    return float(value)


def _numbers(values, name: str) -> tuple[float, ...]:
    try:
        return tuple(_number(v, name) for v in values)
    except TypeError:  # not iterable
        raise LayoutError(f"{name} must be a sequence of numbers, got {values!r}") from None


@dataclass(frozen=True)
class TileSpec:
    """An XPlanar APM4330-like tile: 0.24 m square; ``height`` is its thickness (top surface at z = 0)."""

    size: float = 0.24
    height: float = 0.0352
    mass: float = 5.6

    def __post_init__(self):
        for name in ("size", "height", "mass"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise LayoutError(f"TileSpec.{name} must be a positive finite number, got {value!r}")

    @property
    def half(self) -> float:
        return 0.5 * self.size


@dataclass(frozen=True)
class MoverSpec:
    """An XPlanar APM4330-like mover (box 0.155 x 0.155 x 0.012 m, 1.24 kg), hovering ``hover_gap`` above the tiles.

    ``collision_shape`` is ``"circle"`` (radius ``collision_radius``) or ``"box"`` (half extents
    ``collision_half_size``, default half the mover's footprint). ``margin`` is a safety margin added to the collision
    shape for mover-mover checks; ``wall_margin`` is added for mover-wall checks.
    """

    size: tuple[float, float, float] = (0.155, 0.155, 0.012)
    mass: float = 1.24
    hover_gap: float = 0.004
    collision_shape: str = "circle"
    collision_radius: float = 0.11
    collision_half_size: tuple[float, float] | None = None
    margin: float = 0.0
    wall_margin: float = 0.0

    def __post_init__(self):
        size = _numbers(self.size, "MoverSpec.size")
        if len(size) != 3 or not all(np.isfinite(s) and s > 0 for s in size):
            raise LayoutError(f"MoverSpec.size must be three positive finite numbers, got {self.size!r}")
        object.__setattr__(self, "size", size)
        for name in ("mass", "hover_gap", "collision_radius", "margin", "wall_margin"):
            object.__setattr__(self, name, _number(getattr(self, name), f"MoverSpec.{name}"))
        if not np.isfinite(self.mass) or self.mass <= 0:
            raise LayoutError(f"MoverSpec.mass must be positive and finite, got {self.mass!r}")
        if not np.isfinite(self.hover_gap) or self.hover_gap < 0:
            raise LayoutError(f"MoverSpec.hover_gap must be >= 0, got {self.hover_gap!r}")
        if self.collision_shape not in ("circle", "box"):
            raise LayoutError(f"MoverSpec.collision_shape must be 'circle' or 'box', got {self.collision_shape!r}")
        if not np.isfinite(self.collision_radius) or self.collision_radius <= 0:
            raise LayoutError(f"MoverSpec.collision_radius must be positive, got {self.collision_radius!r}")
        if self.collision_half_size is None:
            object.__setattr__(self, "collision_half_size", (0.5 * size[0], 0.5 * size[1]))
        half = _numbers(self.collision_half_size, "MoverSpec.collision_half_size")
        if len(half) != 2 or not all(np.isfinite(s) and s > 0 for s in half):
            raise LayoutError(f"MoverSpec.collision_half_size must be two positive numbers, got {self.collision_half_size!r}")
        object.__setattr__(self, "collision_half_size", half)
        for name in ("margin", "wall_margin"):
            value = getattr(self, name)
            if not np.isfinite(value) or value < 0:
                raise LayoutError(f"MoverSpec.{name} must be >= 0 and finite, got {value!r}")

    @property
    def inertia(self) -> tuple[float, float, float]:
        """Principal moments of inertia of a solid box (the mover's body frame)."""
        sx, sy, sz = self.size
        m = self.mass
        return (m * (sy * sy + sz * sz) / 12.0, m * (sx * sx + sz * sz) / 12.0, m * (sx * sx + sy * sy) / 12.0)

    @property
    def hover_z(self) -> float:
        """Height of the mover's centre when it hovers at its target gap above the tile surface (z = 0)."""
        return self.hover_gap + 0.5 * self.size[2]

    def bounding_radius(self, extra: float = 0.0) -> float:
        """Radius of a circle around the mover's collision shape grown by ``extra``."""
        if self.collision_shape == "circle":
            return self.collision_radius + extra
        hx, hy = self.collision_half_size
        return float(np.hypot(hx + extra, hy + extra))


_MOVER_PARAMS_KEYS = ("size", "mass", "shape")


def _shared_row(mover_params: dict, key: str, row_shape: tuple, what: str) -> np.ndarray:
    """``mover_params[key]`` as one row of ``row_shape``: given once, or once per mover (a leading axis) with every
    mover's row the same."""
    try:
        value = np.asarray(mover_params[key], dtype=float)
    except (TypeError, ValueError):
        raise LayoutError(f"mover_params[{key!r}] must be numeric, got {mover_params[key]!r}") from None
    per_mover = value.ndim == len(row_shape) + 1 and value.shape[1:] == row_shape and len(value) > 0
    rows = value.reshape((-1, *row_shape)) if value.shape == row_shape or per_mover else None
    if rows is None or not np.all(rows == rows[:1]):
        raise LayoutError(f"mover_params[{key!r}] must be {what} shared by every mover, got {mover_params[key]!r}")
    return rows[0]


def mover_params_kwargs(mover_params: dict | None) -> dict:
    """:class:`MoverSpec` keyword arguments from MagBotSim's ``mover_params`` dict: ``size`` is the box's half sizes
    (x, y, z) in m, as MagBotSim writes them (MoverSpec takes full sizes), ``mass`` in kg, ``shape`` only ``"box"``.
    Every mover of an env shares one spec, so per-mover arrays must hold equal rows."""
    if mover_params is None:
        return {}
    if not isinstance(mover_params, dict):
        raise LayoutError(f"mover_params must be a dict with keys {list(_MOVER_PARAMS_KEYS)}, got {mover_params!r}")
    unknown = sorted(set(mover_params) - set(_MOVER_PARAMS_KEYS))
    if unknown:
        raise LayoutError(f"mover_params has unsupported keys {unknown}; supported: {list(_MOVER_PARAMS_KEYS)}")
    shape = mover_params.get("shape", "box")
    if shape != "box":
        raise LayoutError(f"mover_params['shape'] must be 'box' (the only mover body simulated), got {shape!r}")
    out: dict = {}
    if "size" in mover_params:
        out["size"] = tuple(float(2.0 * v) for v in _shared_row(mover_params, "size", (3,), "3 half sizes"))
    if "mass" in mover_params:
        out["mass"] = float(_shared_row(mover_params, "mass", (), "one mass"))
    return out  # MoverSpec validates the values themselves (positive, finite)


@dataclass(frozen=True)
class Layout:
    """A tile layout plus the tile spec. ``tiles`` is a 0/1 integer array of shape ``(num_tiles_x, num_tiles_y)``."""

    tiles: np.ndarray
    tile: TileSpec = field(default_factory=TileSpec)

    def __post_init__(self):
        try:
            tiles = np.asarray(self.tiles)
        except ValueError:  # numpy refuses ragged nested lists
            raise LayoutError(f"layout must be a rectangular 2-D 0/1 array; its rows differ in length: "
                              f"{self.tiles!r}") from None
        if tiles.dtype == object:
            raise LayoutError(f"layout must be a rectangular 2-D 0/1 array, got {self.tiles!r}")
        if tiles.ndim != 2:
            raise LayoutError(f"layout must be a 2-D 0/1 array (num_tiles_x, num_tiles_y), got shape {tiles.shape}")
        if tiles.size == 0:
            raise LayoutError(f"layout is empty: shape {tiles.shape}")
        if tiles.dtype == bool:
            tiles = tiles.astype(np.int32)
        if not np.issubdtype(tiles.dtype, np.number) or not np.all(np.isin(tiles, (0, 1))):
            bad = tiles[~np.isin(tiles, (0, 1))] if np.issubdtype(tiles.dtype, np.number) else tiles.dtype
            raise LayoutError(f"layout must contain only 0 and 1, found {np.unique(bad)[:5]!r}")
        tiles = tiles.astype(np.int32)
        if tiles.sum() == 0:
            raise LayoutError(f"layout has no tiles (all zeros, shape {tiles.shape})")
        tiles.setflags(write=False)
        object.__setattr__(self, "tiles", tiles)

    def __eq__(self, other) -> bool:
        """Equal tile maps (by value: the array is read-only) and tile specs; the generated dataclass comparison
        would ask numpy for the truth value of an array and raise (so would every config holding a layout)."""
        if not isinstance(other, Layout):
            return NotImplemented
        return self.tile == other.tile and bool(np.array_equal(self.tiles, other.tiles))

    def __hash__(self) -> int:
        return hash((self.tiles.shape, self.tiles.tobytes(), self.tile))

    @classmethod
    def grid(cls, num_tiles_x: int, num_tiles_y: int, tile: TileSpec | None = None) -> "Layout":
        """A full rectangular grid of tiles."""
        try:
            nx, ny = as_count(num_tiles_x, "num_tiles_x"), as_count(num_tiles_y, "num_tiles_y")
        except (TypeError, ValueError) as e:
            raise LayoutError(f"grid needs at least 1x1 tiles, got {num_tiles_x!r}x{num_tiles_y!r}: {e}") from None
        if nx * ny > GRID_CELLS_MAX:
            raise LayoutError(f"grid of {nx}x{ny} tiles is above {GRID_CELLS_MAX:,} tiles (2**24: a 4096 x 4096 grid, "
                              "about 1 km on a side with XPlanar tiles), the largest layout magwarp builds")
        return cls(np.ones((nx, ny), dtype=np.int32), tile or TileSpec())

    @property
    def shape(self) -> tuple[int, int]:
        return self.tiles.shape

    @property
    def num_tiles(self) -> int:
        return int(self.tiles.sum())

    @property
    def extent(self) -> tuple[float, float]:
        """Width and height of the layout's bounding rectangle (lower-left corner at the origin)."""
        return self.shape[0] * self.tile.size, self.shape[1] * self.tile.size

    def tile_centers(self) -> np.ndarray:
        """Centres of the present tiles, shape ``(num_tiles, 2)``, ordered by x index then y index."""
        i, j = np.nonzero(self.tiles)
        return np.stack([(2 * i + 1) * self.tile.half, (2 * j + 1) * self.tile.half], axis=1).astype(np.float64)

    def tile_index(self, xy: np.ndarray) -> np.ndarray:
        """Integer tile indices ``(i, j)`` under points ``xy`` (shape ``(..., 2)``); may lie outside the grid."""
        return np.floor(np.asarray(xy, dtype=np.float64) / self.tile.size).astype(np.int64)

    def on_tiles(self, xy: np.ndarray) -> np.ndarray:
        """True where a point lies above a present tile."""
        ij = self.tile_index(xy)
        nx, ny = self.shape
        inside = (ij[..., 0] >= 0) & (ij[..., 0] < nx) & (ij[..., 1] >= 0) & (ij[..., 1] < ny)
        result = np.zeros(inside.shape, dtype=bool)
        result[inside] = self.tiles[ij[inside][:, 0], ij[inside][:, 1]] == 1
        return result

    def default_starts(self, num_movers: int) -> np.ndarray:
        """Start positions at tile centres, one mover per tile, in :meth:`tile_centers` order."""
        centers = self.tile_centers()
        if num_movers > len(centers):
            raise LayoutError(
                f"num_movers={num_movers} movers need default start poses at tile centres, "
                f"but the layout has only {len(centers)} tiles; pass start positions explicitly"
            )
        return centers[:num_movers].copy()


# MagBotSim's trajectory planning benchmark variants B0..B9 (the paper's benchmark definition, not code): each
# string is one x index (column of tiles), its characters the y indices; 0 marks a hole. Second item: mover count.
_BENCHMARK_TILES = {
    "B0": (("111", "111", "111", "111"), 3),
    "B1": (("111", "111", "011", "111"), 3),
    "B2": (("11111", "11111", "00011", "11111", "11111", "11000", "11111", "11111"), 4),
    "B3": (("0011100", "0011100", "1111111", "1110111", "1111111", "0011100", "0011100"), 4),
    "B4": (("111111", "111111", "111111", "100011", "110001", "111111", "111111", "111111"), 4),
    "B5": (("111111", "111111", "111111", "001100", "001100", "001100", "001100", "001100", "111111", "111111", "111111"), 3),
    "B6": (("000111", "000111", "000111", "111111", "111111", "111000", "111000", "111000"), 4),
    "B7": (("1110111", "1110111", "1100011", "1100011", "1100011", "1111111", "1111111"), 4),
    "B8": (("111111", "111111", "111100", "111100", "111111", "101111", "001111", "000100"), 5),
    "B9": (("11111000", "11111100", "00111110", "00111111", "10011011", "11111011", "11111111", "11111110"), 5),
}
BENCHMARK_LAYOUTS = tuple(_BENCHMARK_TILES)


def benchmark_layout(name: str) -> tuple[Layout, int]:
    """The layout and mover count of a trajectory planning benchmark variant ``"B0"``..``"B9"``."""
    if name not in _BENCHMARK_TILES:
        raise LayoutError(f"unknown benchmark layout {name!r}; choose one of {list(_BENCHMARK_TILES)}")
    rows, movers = _BENCHMARK_TILES[name]
    return Layout(np.array([[int(c) for c in row] for row in rows], dtype=np.int32)), movers
