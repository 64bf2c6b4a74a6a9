"""Layouts, tile and mover specs, start-pose validation and the benchmark layouts B0..B9."""

from __future__ import annotations

import re

import numpy as np
import pytest
from magwarp.layout import (BENCHMARK_LAYOUTS, Layout, LayoutError, MoverSpec, TileSpec, benchmark_layout,
                            mover_params_kwargs)
from magwarp.reference import validate_starts
from magwarp.sim import Simulator


def test_grid_geometry():
    lay = Layout.grid(4, 3)
    assert lay.shape == (4, 3) and lay.num_tiles == 12
    np.testing.assert_allclose(lay.extent, (0.96, 0.72))
    centers = lay.tile_centers()
    assert centers.shape == (12, 2)
    # tile (i, j) centred at ((2i + 1) * 0.12, (2j + 1) * 0.12), ordered by x index then y index
    np.testing.assert_allclose(centers[0], (0.12, 0.12))
    np.testing.assert_allclose(centers[1], (0.12, 0.36))
    np.testing.assert_allclose(centers[3], (0.36, 0.12))
    np.testing.assert_allclose(centers[-1], (0.84, 0.60))
    with pytest.raises(LayoutError, match="0x3"):
        Layout.grid(0, 3)
    with pytest.raises(LayoutError, match="100000x100000 tiles is above 16,777,216"):  # not a 37 GiB MemoryError
        Layout.grid(100000, 100000)


def test_custom_tile_size():
    lay = Layout(np.ones((2, 2)), TileSpec(size=0.12))
    np.testing.assert_allclose(lay.tile_centers()[0], (0.06, 0.06))
    np.testing.assert_allclose(lay.extent, (0.24, 0.24))
    with pytest.raises(LayoutError, match="size.*-0.1"):
        TileSpec(size=-0.1)


def test_holes_and_on_tiles(rng):
    tiles = np.array([[1, 1, 1], [1, 0, 0], [1, 1, 0]])  # holes at (1, 1), (1, 2), (2, 2)
    lay = Layout(tiles)
    assert lay.num_tiles == 6
    assert not lay.tiles.flags.writeable
    centers = lay.tile_centers()
    assert len(centers) == 6 and not any(np.allclose(c, (0.36, 0.36)) for c in centers)
    pts = rng.uniform(-0.2, 0.9, (2000, 2))
    ij = np.floor(pts / 0.24).astype(int)
    inside = (ij >= 0).all(1) & (ij < 3).all(1)
    expected = np.zeros(len(pts), bool)
    expected[inside] = tiles[ij[inside, 0], ij[inside, 1]] == 1
    np.testing.assert_array_equal(lay.on_tiles(pts), expected, err_msg=str(rng))


def test_default_starts():
    lay = Layout(np.array([[1, 0], [1, 1]]))
    np.testing.assert_allclose(lay.default_starts(2), [[0.12, 0.12], [0.36, 0.12]])
    with pytest.raises(LayoutError, match=r"num_movers=4.*only 3 tiles"):
        lay.default_starts(4)


def test_mover_spec_defaults():
    m = MoverSpec()
    assert m.size == (0.155, 0.155, 0.012) and m.mass == 1.24
    assert m.collision_shape == "circle" and m.collision_radius == 0.11
    assert m.collision_half_size == (0.0775, 0.0775)
    assert m.hover_z == pytest.approx(0.004 + 0.006)
    ix, iy, iz = m.inertia
    assert ix == pytest.approx(1.24 * (0.155**2 + 0.012**2) / 12) and iz == pytest.approx(1.24 * 2 * 0.155**2 / 12)
    assert m.bounding_radius(0.01) == pytest.approx(0.12)
    box = MoverSpec(collision_shape="box", collision_half_size=(0.03, 0.04))
    assert box.bounding_radius() == pytest.approx(0.05)


def test_mover_params_follow_magbotsim_half_sizes():
    # MagBotSim's published runs: size [0.113/2, 0.113/2, 0.012/2] (half sizes), mass 0.639
    kw = mover_params_kwargs({"size": [0.113 / 2, 0.113 / 2, 0.006], "mass": 0.639, "shape": "box"})
    assert kw == {"size": pytest.approx((0.113, 0.113, 0.012)), "mass": 0.639}
    spec = MoverSpec(**kw)
    assert spec.collision_half_size == pytest.approx((0.0565, 0.0565))  # the default box shape follows the body
    # per-mover arrays are accepted when every mover is the same
    same = mover_params_kwargs({"size": np.tile([0.05, 0.05, 0.006], (3, 1)), "mass": [0.6, 0.6, 0.6]})
    assert same == {"size": pytest.approx((0.1, 0.1, 0.012)), "mass": 0.6}
    assert mover_params_kwargs(None) == {}


@pytest.mark.parametrize("bad, names", [
    ({"size": [0.05, 0.05]}, "[0.05, 0.05]"),
    ({"size": [[0.05, 0.05, 0.006], [0.06, 0.05, 0.006]]}, "0.06"),
    ({"mass": [0.6, 0.7]}, "[0.6, 0.7]"),
    ({"size": "big"}, "'big'"),
    ({"shape": "cylinder"}, "'cylinder'"),
    ({"colour": "red"}, "colour"),
    ([0.05, 0.05, 0.006], "[0.05, 0.05, 0.006]"),
])
def test_mover_params_errors_name_the_bad_value(bad, names):
    with pytest.raises(LayoutError, match=re.escape(names)):
        mover_params_kwargs(bad)


def test_validate_starts_rules():
    lay = Layout(np.array([[1, 1], [1, 0]]))
    mover = MoverSpec()
    ok = validate_starts(lay, mover, [[0.12, 0.12], [0.12, 0.36]])
    assert ok.dtype == np.float64 and ok.shape == (2, 2)
    with pytest.raises(LayoutError, match="mover 1 starts at .*off the tiles"):
        validate_starts(lay, mover, [[0.12, 0.12], [0.36, 0.36]])  # on the hole
    with pytest.raises(LayoutError, match="movers 0 and 1 overlap"):
        validate_starts(lay, mover, [[0.12, 0.12], [0.12, 0.30]])
    with pytest.raises(LayoutError, match=r"shape \(num_movers, 2\), got \(2, 3\)"):
        validate_starts(lay, mover, np.zeros((2, 3)))
    with pytest.raises(LayoutError, match="finite"):
        validate_starts(lay, mover, [[np.nan, 0.12]])
    # per-mover sizes: small circles fit closer together
    validate_starts(lay, mover, [[0.12, 0.12], [0.12, 0.24]], radii=[0.05, 0.05])


def connected_parts(tiles: np.ndarray) -> int:
    """Number of 4-connected regions of present tiles (flood fill)."""
    seen = np.zeros(tiles.shape, bool)
    parts = 0
    for start in zip(*np.nonzero(tiles)):
        if seen[start]:
            continue
        parts += 1
        stack = [start]
        while stack:
            i, j = stack.pop()
            if not (0 <= i < tiles.shape[0] and 0 <= j < tiles.shape[1]) or seen[i, j] or not tiles[i, j]:
                continue
            seen[i, j] = True
            stack += [(i + 1, j), (i - 1, j), (i, j + 1), (i, j - 1)]
    return parts


def test_connected_parts_helper():
    assert connected_parts(np.array([[1, 0], [0, 1]])) == 2 and connected_parts(np.ones((3, 2))) == 1


# Mover counts of MagBotSim's trajectory-planning benchmark (DESIGN.md): 3,3,4,4,4,3,4,4,5,5.
COUNTS = dict(zip([f"B{i}" for i in range(10)], [3, 3, 4, 4, 4, 3, 4, 4, 5, 5]))


@pytest.mark.parametrize("name", BENCHMARK_LAYOUTS)
def test_benchmark_layouts(name):
    lay, movers = benchmark_layout(name)
    assert movers == COUNTS[name]
    nx, ny = lay.shape
    assert 3 <= min(nx, ny) and max(nx, ny) <= 11
    # the tiled area is one 4-connected region, and has room for every mover at a tile centre
    assert connected_parts(lay.tiles) == 1
    assert lay.num_tiles >= movers
    sim = Simulator(lay, num_movers=movers, device="cpu")
    sim.step(1)
    assert int(sim.flags.sum()) == 0


def test_benchmark_layout_shapes():
    assert benchmark_layout("B0")[0].shape == (4, 3)
    assert benchmark_layout("B9")[0].shape == (8, 8)
    assert benchmark_layout("B1")[0].num_tiles == 11  # B0 with one hole
    with pytest.raises(LayoutError, match="'B10'"):
        benchmark_layout("B10")
