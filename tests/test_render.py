"""Top-down renderer: shapes, pixel-exact footprints against a numpy reference, mosaics, layers, errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from magwarp.layout import Layout, MoverSpec, benchmark_layout
from magwarp.render import TopDownRenderer, colors, object_parts
from magwarp.render.synthetic import SyntheticScene


def pixel_centres(r: TopDownRenderer, cell: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World x, y of every pixel centre of a cell, plus the image rows/cols (float64 numpy reference)."""
    r0, c0 = r.cell_origin(cell)
    rows, cols = np.meshgrid(np.arange(r.cell_h), np.arange(r.cell_w), indexing="ij")
    x = (cols + 0.5) / r.px_per_m
    y = (r.cell_h - rows - 0.5) / r.px_per_m
    return x, y, (rows + r0, cols + c0)


def box_sdf(x, y, cx, cy, yaw, hx, hy):
    c, s = np.cos(yaw), np.sin(yaw)
    dx, dy = x - cx, y - cy
    qx, qy = c * dx + s * dy, -s * dx + c * dy
    ex, ey = np.abs(qx) - hx, np.abs(qy) - hy
    return np.hypot(np.maximum(ex, 0), np.maximum(ey, 0)) + np.minimum(np.maximum(ex, ey), 0)


def test_frame_shape_dtype_and_changes_when_movers_move(devices):
    layout, m = benchmark_layout("B0")
    for device in devices:
        scene = SyntheticScene(layout, num_worlds=4, num_movers=m, device=torch.device("cpu" if device == "cpu" else "cuda"))
        r = scene.make_renderer(px_per_tile=16)
        a = scene.arrays()
        first = r.draw(a["pos"], a["quat"], flags=a["collision"], goals=a["goals"]).clone()
        assert isinstance(first, torch.Tensor) and first.dtype == torch.uint8
        assert tuple(first.shape) == r.shape == (2 * (3 * 16 + 2) + 2, 2 * (4 * 16 + 2) + 2, 3)
        assert first.device.type == ("cpu" if device == "cpu" else "cuda")
        same = r.draw(a["pos"], a["quat"], flags=a["collision"], goals=a["goals"])
        assert torch.equal(first, same), "drawing the same state twice must give the same frame"
        moved = a["pos"].clone()
        moved[..., 0] += 0.03
        second = r.draw(moved, a["quat"], flags=a["collision"], goals=a["goals"])
        assert not torch.equal(first, second), "moving the movers must change the frame"
        as_np = r.draw_numpy(moved, a["quat"])
        assert isinstance(as_np, np.ndarray) and as_np.dtype == np.uint8 and as_np.shape == r.shape


@pytest.mark.parametrize("shape", ["circle", "box"])
def test_mover_footprint_covers_expected_pixels(rng, shape):
    """A mover at a random pose: the pixels that change are exactly those whose centre is inside the rotated
    0.155 m footprint (numpy reference), up to pixels whose centre lies on the boundary (float32 vs float64)."""
    layout = Layout.grid(3, 2)
    mover = MoverSpec(collision_shape=shape)
    r = TopDownRenderer(layout, mover, px_per_tile=int(rng.integers(24, 64)), safety_zone=False, heading=False,
                        device="cpu")
    xy = rng.uniform([0.15, 0.15], [0.57, 0.33])
    yaw = rng.uniform(-np.pi, np.pi)
    empty = r.draw_numpy(np.zeros((1, 0, 3), np.float32))
    img = r.draw_numpy(np.array([[[xy[0], xy[1], 0.01]]], np.float32), np.array([[yaw]], np.float32))
    changed = np.any(img != empty, axis=-1)

    x, y, (rows, cols) = pixel_centres(r)
    sdf = box_sdf(x, y, xy[0], xy[1], yaw, 0.5 * mover.size[0], 0.5 * mover.size[1])
    expected = np.zeros(changed.shape, bool)
    expected[rows, cols] = sdf <= 0
    boundary = np.zeros(changed.shape, bool)
    boundary[rows, cols] = np.abs(sdf) < 1e-5
    wrong = (changed != expected) & ~boundary
    assert not wrong.any(), f"{rng}: {wrong.sum()} pixels differ from the footprint, first at {np.argwhere(wrong)[:3]}"
    assert expected.sum() > 20
    # Inside: the mover's colour, or its darker rim.
    mc = np.array(colors.mover_color(0))
    rim = np.floor(mc * 0.6 + 0.5)
    inside = img[expected & ~boundary]
    ok = np.all(inside == mc, axis=-1) | np.all(np.abs(inside - rim) <= 1, axis=-1)
    assert ok.all(), f"{rng}: footprint pixels with other colours: {np.unique(inside[~ok], axis=0)[:5]}"


def test_collided_mover_has_red_halo_and_keeps_its_colour():
    layout = Layout.grid(2, 2)
    r = TopDownRenderer(layout, px_per_tile=60, heading=False, device="cpu")
    pos = np.array([[[0.24, 0.24, 0.01], [0.9, 0.9, 0.01]]], np.float32)  # second mover far outside: not drawn
    calm = r.draw_numpy(pos, flags=np.array([[0, 0]]))
    hit = r.draw_numpy(pos, flags=np.array([[1, 0]]))
    x, y, (rows, cols) = pixel_centres(r)
    d = np.hypot(x - 0.24, y - 0.24)
    ring = np.zeros(calm.shape[:2], bool)
    ring[rows, cols] = (d > 0.11 - 0.5 / r.px_per_m) & (d < 0.11 - 0.1 / r.px_per_m) & (np.abs(x - 0.24) > 0.09)
    assert ring.sum() > 10
    assert np.all(hit[ring] == colors.COLLISION), "a collided mover's safety-zone rim is red"
    assert np.all(calm[ring] == colors.mover_color(0)), "a calm mover's rim has its own colour"
    centre = tuple(np.floor(r.world_to_pixel([0.25, 0.23])).astype(int))
    assert np.all(hit[centre] == colors.mover_color(0)), "the footprint keeps the mover's colour"


def test_quaternion_and_yaw_give_the_same_frame(rng):
    layout, m = benchmark_layout("B1")
    r = TopDownRenderer(layout, worlds=2, px_per_tile=20, device="cpu")
    xy = np.stack([layout.default_starts(m)] * 2) + rng.uniform(-0.01, 0.01, (2, m, 2))
    yaw = rng.uniform(-np.pi, np.pi, (2, m))
    quat = np.stack([np.zeros_like(yaw), np.zeros_like(yaw), np.sin(yaw / 2), np.cos(yaw / 2)], axis=-1)
    a = r.draw_numpy(xy.astype(np.float32), yaw.astype(np.float32))
    b = r.draw_numpy(torch.tensor(xy, dtype=torch.float64), torch.tensor(quat))
    assert (np.abs(a.astype(int) - b.astype(int)) > 0).mean() < 1e-3, f"{rng}"


def test_mosaic_places_each_world_in_its_cell():
    layout = Layout.grid(2, 2)
    worlds = [5, 0, 3, 1, 4]  # cells show these worlds, row-major, 3 columns
    r = TopDownRenderer(layout, worlds=worlds, cols=3, px_per_tile=20, border_px=3, device="cpu")
    assert r.shape == (2 * (40 + 3) + 3, 3 * (40 + 3) + 3, 3)
    # World w has one mover, at a position that encodes w (left column of tiles for even w, right for odd).
    pos = np.zeros((6, 1, 3), np.float32)
    for w in range(6):
        pos[w, 0, :2] = (0.12 if w % 2 == 0 else 0.36, 0.12 + 0.24 * (w // 4))
    img = r.draw_numpy(pos)
    mover = np.array(colors.mover_color(0))
    for cell, w in enumerate(worlds):
        for probe_world in range(6):
            probe = pos[probe_world, 0, :2] - [0.0, 0.04]  # below the centre: off the white heading mark
            rc = np.floor(r.world_to_pixel(probe, cell)).astype(int)
            covered = np.all(img[rc[0], rc[1]] == mover)
            same_spot = np.allclose(pos[probe_world, 0, :2], pos[w, 0, :2])
            assert covered == same_spot, f"cell {cell} (world {w}) at world {probe_world}'s mover position"
    # Separators and the unused sixth cell are background.
    assert np.all(img[:3] == colors.BACKGROUND) and np.all(img[:, :3] == colors.BACKGROUND)
    r0, c0 = r.cell_origin(5)
    assert np.all(img[r0:r0 + 40, c0:c0 + 40] == colors.BACKGROUND)
    # select() swaps the worlds shown without changing the image size.
    r.select([0, 1, 2, 3, 4])
    assert r.draw_numpy(pos).shape == r.shape


def test_tiles_holes_goals_objects_and_obstacles():
    layout = Layout(np.array([[1, 1], [1, 0], [1, 1]]))  # hole at tile (1, 1)
    r = TopDownRenderer(layout, px_per_tile=48, object_shapes=[object_parts("box", (0.04, 0.03))], device="cpu",
                        goal_lines=False)
    img = r.draw_numpy(
        np.array([[[0.12, 0.12, 0.01]]], np.float32),
        goals=np.array([[[0.6, 0.12]]], np.float32),
        object_poses=np.array([[0.6, 0.36, 0.0]], np.float32),
        object_goals=np.array([[0.12, 0.38, 0.3]], np.float32),
        obstacles=np.array([[0.36, 0.1, 0.03, 0.02]], np.float32),
    )

    def at(x, y):
        rc = np.floor(r.world_to_pixel([x, y])).astype(int)
        return tuple(int(v) for v in img[rc[0], rc[1]])

    assert at(0.3, 0.05) == colors.TILE
    assert at(0.36, 0.36) in (colors.HOLE, colors.HOLE_HATCH)
    assert at(0.6, 0.12) == colors.mover_color(0), "goal disc in the mover's colour"
    assert at(0.6, 0.36) == colors.OBJECT
    assert at(0.36, 0.1) == colors.OBSTACLE
    g = np.array(at(0.12, 0.38))
    expected = np.array(colors.TILE) + (np.array(colors.OBJECT_GOAL) - np.array(colors.TILE)) * colors.OBJECT_GOAL_ALPHA
    assert np.all(np.abs(g - expected) <= 1), "object goal: translucent green over the tile"
    # grid line on the tile edge x = 0.24
    assert at(0.24 + 0.2 / r.px_per_m, 0.05) == colors.TILE_LINE


def test_object_parts_shapes():
    for kind in ("box", "square_box", "cylinder", "T", "L", "X"):
        parts = object_parts(kind)
        assert len(parts) >= 1 and all(len(p) == 4 for p in parts)
    with pytest.raises(ValueError, match="unknown object kind 'Z'"):
        object_parts("Z")


def test_bad_inputs_raise_clear_errors():
    layout = Layout.grid(2, 2)
    r = TopDownRenderer(layout, worlds=4, px_per_tile=8, device="cpu")
    with pytest.raises(ValueError, match="pos must have shape"):
        r.draw(np.zeros((4, 3), np.float32)[None, None])
    with pytest.raises(ValueError, match="only 2 world"):
        r.draw(np.zeros((2, 3, 3), np.float32))
    with pytest.raises(ValueError, match="flags must have 3 items"):
        r.draw(np.zeros((4, 3, 3), np.float32), flags=np.zeros((4, 2)))
    with pytest.raises(ValueError, match="object_poses given"):
        r.draw(np.zeros((4, 3, 3), np.float32), object_poses=np.zeros((4, 3)))
    with pytest.raises(ValueError, match="worlds must be"):
        TopDownRenderer(layout, worlds=0)
    with pytest.raises(ValueError, match="px_per_tile"):
        TopDownRenderer(layout, px_per_tile=0)  # 1 and up: whole views of big swarms
    with pytest.raises(TypeError, match="layout must be"):
        TopDownRenderer(np.ones((2, 2)))


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(px_per_tile=0, border_px=-1, min_mover_px=-1.0), "px_per_tile must be >= 1"),
        (dict(min_mover_px=float("nan"), border_px=-1), "min_mover_px must be"),
        (dict(border_px=-1, window=(1.0, 2.0), worlds=0), "border_px must be >= 0"),
        (dict(window=(5.0, 5.0, 1.0, 1.0), worlds=0), "lies outside the layout"),
        (dict(worlds=0, cols=0, state_colors=[1, 2]), "worlds must be"),
        (dict(cols=0, state_colors=[1, 2]), "cols must be >= 1"),
        (dict(state_colors=[[1, 2, 300]], object_shapes=[[]]), "state_colors must be"),
        (dict(object_shapes=[[(0.0, 0.0, -1.0, 0.0)]]), "object 0: parts must be finite"),
    ],
)
def test_constructor_reports_the_first_bad_option(kwargs, match):
    with pytest.raises(ValueError, match=match):
        TopDownRenderer(Layout.grid(2, 2), device="cpu", **kwargs)


@pytest.mark.parametrize("width", [120, 400, 900])
def test_legend_strip_fits_under_frames(width):
    from magwarp.render.legend import legend_strip, with_legend

    strip = legend_strip(width, objects=True, obstacles=True)
    assert strip.dtype == np.uint8 and strip.shape[1] == width and strip.shape[2] == 3 and strip.shape[0] >= 18
    assert (strip != np.array(colors.BACKGROUND)).any(axis=-1).mean() > 0.02, "the strip shows swatches and text"
    frame = np.zeros((30, width, 3), np.uint8)
    assert with_legend(frame, strip).shape == (30 + strip.shape[0], width, 3)
    with pytest.raises(ValueError, match="does not match the frame width"):
        with_legend(np.zeros((30, width + 1, 3), np.uint8), strip)


@pytest.mark.parametrize("crowded", [False, True])
def test_big_swarms_binned_path_matches_the_direct_path(monkeypatch, crowded):
    """Above BAND_MOVERS movers the kernel sorts movers into per-tile bins first; the picture must not change.
    ``crowded`` piles 12 movers onto one tile: the bin overflows and the cell falls back to testing every mover."""
    from magwarp.render import kernels as K

    layout = Layout.grid(8, 6)
    num_movers = 40
    pos = np.zeros((2, num_movers, 3), np.float32)
    centres = layout.tile_centers()
    pos[:, :, :2] = centres[:num_movers]
    if crowded:
        pos[1, :12, :2] = centres[0] + np.linspace(-0.05, 0.05, 12)[:, None]
    goals = np.roll(pos[:, :, :2], 3, axis=1) + 0.05
    yaw = np.linspace(0, 3, 2 * num_movers, dtype=np.float32).reshape(2, num_movers)
    flags = (np.arange(2 * num_movers).reshape(2, num_movers) % 5 == 0).astype(np.int32)
    r = TopDownRenderer(layout, worlds=2, px_per_tile=20, goal_lines=False, device="cpu")
    binned = r.draw_numpy(pos, yaw, flags=flags, goals=goals)
    assert r._bins is not None, "40 movers use the binned path"
    assert r._bins[4].numpy().tolist() == ([0, 1] if crowded else [0, 0])
    monkeypatch.setattr(K, "BAND_MOVERS", 1000)
    direct = TopDownRenderer(layout, worlds=2, px_per_tile=20, goal_lines=False, device="cpu").draw_numpy(
        pos, yaw, flags=flags, goals=goals)
    differ = np.any(binned != direct, axis=-1)
    if crowded:  # overlapping movers may be painted in another order in the crowded tile only
        r0, c0 = r.cell_origin(1)
        differ[r0 + r.cell_h - 30:r0 + r.cell_h, c0:c0 + 30] = False
    assert not differ.any(), f"{differ.sum()} pixels differ, first at {np.argwhere(differ)[:3]}"
