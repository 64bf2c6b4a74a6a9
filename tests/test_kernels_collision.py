"""Collision kernels vs the numpy oracles in :mod:`magwarp.reference`, on random inputs.

* ``movers_collide`` (circles, oriented boxes at any yaw, per-mover sizes, margins) pair by pair;
* ``hits_wall`` on layouts with holes, L-shapes and the benchmark layouts B0..B9 (circle and box, wall margin);
* the simulator's three mover-mover paths (fused per world, brute force per mover, grid broad phase) on densely
  packed worlds: every mover's flags and partner and every world's pair and wall counts.

Configurations within 1e-5 m of a touching boundary are resampled (float32 cannot decide them), but near-touching
ones (gaps of 1e-4 .. 1e-3 m, both signs) are placed on purpose.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
import warp as wp

from magwarp import reference as ref
from magwarp.kernels.collision import collision_flags, hits_wall, movers_collide
from magwarp.layout import BENCHMARK_LAYOUTS, Layout, LayoutError, MoverSpec, benchmark_layout
from magwarp.sim import Simulator
from magwarp.types import COLLIDE_MOVER, COLLIDE_WALL, SHAPE_BOX, SHAPE_CIRCLE, Collision

EPS = 1e-5  # width of the undecidable band around a touching boundary (float32 geometry)
SHAPES = {"circle": SHAPE_CIRCLE, "box": SHAPE_BOX}


def f32(x):
    return np.asarray(x, dtype=np.float32).astype(np.float64)


def make_col(shape: str, margin=0.0, wall_margin=0.0, tile_size=0.24) -> Collision:
    col = Collision()
    col.shape = SHAPES[shape]
    col.margin = float(margin)
    col.wall_margin = float(wall_margin)
    col.tile_size = float(tile_size)
    col.stop_on_collision = 0
    return col


def yaw_from_quat(q: np.ndarray) -> np.ndarray:
    """Heading of (x, y, z, w) quaternions: angle of the rotated body x axis, as the kernels define it."""
    q = np.asarray(q, dtype=np.float64)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.arctan2(2.0 * (x * y + w * z), 1.0 - 2.0 * (y * y + z * z))


def touching_distance(shape, yaw_i, yaw_j, r_i, r_j, h_i, h_j, margin, u) -> float:
    """Centre distance along unit ``u`` at which mover j just touches mover i (bisection on the reference)."""
    lo, hi = 0.0, 2.0 * (r_i + r_j + float(np.hypot(*h_i)) + float(np.hypot(*h_j)) + 4 * margin) + 1.0
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        if ref.mover_pair_collides(shape, np.zeros(2), yaw_i, mid * u, yaw_j, r_i, r_j, h_i, h_j, margin):
            lo = mid
        else:
            hi = mid
    return hi


def pair_ambiguous(shape, d, yaw_i, yaw_j, r_i, r_j, h_i, h_j, margin) -> bool:
    a = ref.mover_pair_collides(shape, np.zeros(2), yaw_i, -d, yaw_j, r_i, r_j, h_i, h_j, margin - EPS)
    b = ref.mover_pair_collides(shape, np.zeros(2), yaw_i, -d, yaw_j, r_i, r_j, h_i, h_j, margin + EPS)
    return a != b


# ---------------------------------------------------------------------------------------------- pair function
@wp.kernel
def _pair_kernel(
    col: Collision,
    d: wp.array(dtype=wp.vec2),
    yaw_a: wp.array(dtype=float),
    r_a: wp.array(dtype=float),
    h_a: wp.array(dtype=wp.vec2),
    yaw_b: wp.array(dtype=float),
    r_b: wp.array(dtype=float),
    h_b: wp.array(dtype=wp.vec2),
    out: wp.array(dtype=wp.int32),
):
    i = wp.tid()
    hit = int(0)
    if movers_collide(col, d[i], yaw_a[i], r_a[i], h_a[i], yaw_b[i], r_b[i], h_b[i]):
        hit = 1
    out[i] = hit


@pytest.mark.parametrize("shape", ["circle", "box"])
def test_movers_collide_matches_reference(shape, rng):
    n = 1500
    margin = float(rng.uniform(0.0, 0.02))
    yaw_a, yaw_b = f32(rng.uniform(-np.pi, np.pi, n)), f32(rng.uniform(-np.pi, np.pi, n))
    r_a, r_b = f32(rng.uniform(0.02, 0.12, n)), f32(rng.uniform(0.02, 0.12, n))
    h_a, h_b = f32(rng.uniform(0.01, 0.1, (n, 2))), f32(rng.uniform(0.01, 0.1, (n, 2)))
    d = rng.uniform(-0.35, 0.35, (n, 2))
    # A third of the pairs sit within 1e-4 .. 1e-3 m of touching, on either side, at random directions and yaws.
    near = np.arange(0, n, 3)
    for k in near:
        u = rng.normal(size=2)
        u /= np.linalg.norm(u)
        t = touching_distance(SHAPES[shape], yaw_a[k], yaw_b[k], r_a[k], r_b[k], h_a[k], h_b[k], margin, u)
        d[k] = -(t + rng.choice([-1, 1]) * rng.uniform(1e-4, 1e-3)) * u  # d = p_a - p_b, with p_a at the origin
    d = f32(d)
    expected = np.array([
        ref.mover_pair_collides(SHAPES[shape], d[k], yaw_a[k], np.zeros(2), yaw_b[k], r_a[k], r_b[k], h_a[k], h_b[k], margin)
        for k in range(n)
    ])
    ambiguous = np.array([
        pair_ambiguous(SHAPES[shape], d[k], yaw_a[k], yaw_b[k], r_a[k], r_b[k], h_a[k], h_b[k], margin) for k in range(n)
    ])
    assert ambiguous[near].sum() == 0, rng  # the near-touching cases are decidable ...
    assert 0.15 < expected.mean() < 0.85, rng  # ... and the sample has both outcomes in quantity

    out = wp.zeros(n, dtype=wp.int32, device="cpu")
    arr = lambda x, dt=float: wp.array(np.asarray(x, dtype=np.float32), dtype=dt, device="cpu")  # noqa: E731
    wp.launch(_pair_kernel, dim=n, device="cpu",
              inputs=[make_col(shape, margin), arr(d, wp.vec2), arr(yaw_a), arr(r_a), arr(h_a, wp.vec2), arr(yaw_b),
                      arr(r_b), arr(h_b, wp.vec2), out])
    got = out.numpy().astype(bool)
    keep = ~ambiguous
    bad = np.flatnonzero((got != expected) & keep)
    assert bad.size == 0, f"{rng}: {bad.size} mismatches, first {bad[:5]}, d={d[bad[:1]]}, yaw={yaw_a[bad[:1]]},{yaw_b[bad[:1]]}"
    # Near-touching pairs include both colliding and separated ones.
    assert 0 < got[near].sum() < len(near), rng


# ---------------------------------------------------------------------------------------------- wall function
@wp.kernel
def _wall_kernel(
    tiles: wp.array2d(dtype=wp.int32),
    col: Collision,
    p: wp.array(dtype=wp.vec2),
    yaw: wp.array(dtype=float),
    radius: wp.array(dtype=float),
    half: wp.array(dtype=wp.vec2),
    out: wp.array(dtype=wp.int32),
):
    i = wp.tid()
    hit = int(0)
    if hits_wall(tiles, col, p[i], yaw[i], radius[i], half[i]):
        hit = 1
    out[i] = hit


def _footprint_extent(shape, yaw, r, h, axis):
    if shape == "circle":
        return r
    c, s = np.cos(yaw), np.sin(yaw)
    return h[..., 0] * np.abs(axis[0] * c + axis[1] * s) + h[..., 1] * np.abs(-axis[0] * s + axis[1] * c)


WALL_LAYOUTS = {
    "L": np.array([[1, 1, 1], [1, 0, 0], [1, 0, 0]]),
    "holes": np.array([[1, 1, 1, 1], [1, 0, 1, 1], [1, 1, 1, 0], [0, 1, 1, 1]]),
    "single": np.array([[1]]),
    "diagonal": np.array([[1, 0], [0, 1]]),
    **{name: benchmark_layout(name)[0].tiles for name in BENCHMARK_LAYOUTS},
}


@pytest.mark.parametrize("shape", ["circle", "box"])
@pytest.mark.parametrize("layout_name", list(WALL_LAYOUTS))
def test_hits_wall_matches_reference(layout_name, shape, rng):
    layout = Layout(WALL_LAYOUTS[layout_name])
    size = layout.tile.size
    n = 160
    wall_margin = float(rng.choice([0.0, rng.uniform(0.0, 0.02)]))
    mover = MoverSpec(collision_shape=shape, wall_margin=wall_margin)
    ext = np.array(layout.extent)
    yaw = f32(rng.uniform(-np.pi, np.pi, n))
    r = f32(rng.uniform(0.02, 0.13, n))
    h = f32(rng.uniform(0.01, 0.09, (n, 2)))
    xy = rng.uniform(-0.05, 1.0, (n, 2)) * (ext + 0.05)
    # Half of the samples have their footprint edge 1e-4 .. 1e-3 m from a tile boundary line (inside or outside).
    for k in range(0, n, 2):
        for ax in rng.permutation(2)[: rng.integers(1, 3)]:
            axis = np.eye(2)[ax]
            reach = _footprint_extent(shape, yaw[k], r[k] + wall_margin, h[k] + wall_margin, axis)
            line = size * rng.integers(0, layout.shape[ax] + 1)
            xy[k, ax] = line + rng.choice([-1, 1]) * reach + rng.choice([-1, 1]) * rng.uniform(1e-4, 1e-3)
    xy = f32(xy)

    def reference(wm):
        return ref.wall_collisions(layout, mover, xy[None], yaw[None], r, h, wall_margin=wm)[0]

    expected = reference(wall_margin)
    ambiguous = reference(wall_margin - EPS) != reference(wall_margin + EPS)
    assert ambiguous.mean() < 0.05, rng
    assert expected.any() and not expected.all(), rng

    out = wp.zeros(n, dtype=wp.int32, device="cpu")
    arr = lambda x, dt=float: wp.array(np.asarray(x, dtype=np.float32), dtype=dt, device="cpu")  # noqa: E731
    wp.launch(_wall_kernel, dim=n, device="cpu",
              inputs=[wp.array(layout.tiles, dtype=wp.int32, device="cpu"), make_col(shape, 0.0, wall_margin, size),
                      arr(xy, wp.vec2), arr(yaw), arr(r), arr(h, wp.vec2), out])
    got = out.numpy().astype(bool)
    bad = np.flatnonzero((got != expected) & ~ambiguous)
    assert bad.size == 0, (
        f"{rng}: {bad.size} wall mismatches on {layout_name}/{shape}; first: xy={xy[bad[0]]}, yaw={yaw[bad[0]]}, "
        f"r={r[bad[0]]}, h={h[bad[0]]}, wall_margin={wall_margin}, got={got[bad[0]]}"
    )


def test_hits_wall_hole_fully_surrounded(rng):
    """A footprint sitting entirely inside a missing tile, and one straddling the hole's corner, both hit the wall."""
    layout = Layout(np.array([[1, 1, 1], [1, 0, 1], [1, 1, 1]]))
    xy = f32([[0.36, 0.36], [0.24 - 0.02, 0.24 - 0.02], [0.12, 0.12], [0.36, 0.60]])
    yaw = f32(rng.uniform(-np.pi, np.pi, 4))
    for shape in ("circle", "box"):
        mover = MoverSpec(collision_shape=shape, collision_radius=0.05, collision_half_size=(0.04, 0.04))
        expected = ref.wall_collisions(layout, mover, xy[None], yaw[None])[0]
        np.testing.assert_array_equal(expected, [True, True, False, False])
        out = wp.zeros(4, dtype=wp.int32, device="cpu")
        wp.launch(_wall_kernel, dim=4, device="cpu",
                  inputs=[wp.array(layout.tiles, dtype=wp.int32, device="cpu"), make_col(shape),
                          wp.array(xy.astype(np.float32), dtype=wp.vec2, device="cpu"),
                          wp.array(yaw.astype(np.float32), dtype=float, device="cpu"),
                          wp.array(np.full(4, 0.05, np.float32), dtype=float, device="cpu"),
                          wp.array(np.full((4, 2), 0.04, np.float32), dtype=wp.vec2, device="cpu"), out])
        np.testing.assert_array_equal(out.numpy().astype(bool), expected, err_msg=f"{shape}, {rng}")


# ---------------------------------------------------------------------------------------------- simulator paths
DENSE_LAYOUT = np.array([[1, 1, 1], [1, 0, 1], [1, 1, 0]])  # holes and an L-shaped outline, 0.72 m square


def random_world(rng, shape, m, margin, wall_margin, radii, half, layout):
    """Start poses for one densely packed world (float32-exact), resampled until no pair or wall check is
    within EPS of its boundary. About a fifth of the movers are placed near-touching their predecessor."""
    s = SHAPES[shape]
    ext = np.array(layout.extent)
    mover = MoverSpec(collision_shape=shape, margin=margin, wall_margin=wall_margin)
    for _attempt in range(50):
        xy = rng.uniform(-0.03, 1.03, (m, 2)) * ext
        yaw = rng.uniform(-np.pi, np.pi, m)
        for k in range(1, m, 5):
            u = rng.normal(size=2)
            u /= np.linalg.norm(u)
            t = touching_distance(s, yaw[k - 1], yaw[k], radii[k - 1], radii[k], half[k - 1], half[k], margin, u)
            xy[k] = xy[k - 1] + (t + rng.choice([-1, 1]) * rng.uniform(1e-4, 1e-3)) * u
        xy = f32(xy)
        yaw = yaw_from_quat(np.stack([0 * yaw, 0 * yaw, np.sin(0.5 * yaw), np.cos(0.5 * yaw)], -1).astype(np.float32))
        lo = set(ref.mover_collision_pairs(mover, xy, yaw, radii, half, margin=margin - EPS))
        hi = set(ref.mover_collision_pairs(mover, xy, yaw, radii, half, margin=margin + EPS))
        w_lo = ref.wall_collisions(layout, mover, xy[None], yaw[None], radii, half, wall_margin - EPS)
        w_hi = ref.wall_collisions(layout, mover, xy[None], yaw[None], radii, half, wall_margin + EPS)
        if lo == hi and np.array_equal(w_lo, w_hi):
            return xy, yaw
    raise AssertionError(f"{rng}: could not sample an unambiguous world")


def expected_outputs(mover, layout, xy, yaw, radii, half):
    m = len(xy)
    pairs = ref.mover_collision_pairs(mover, xy, yaw, radii, half)
    wall = ref.wall_collisions(layout, mover, xy[None], yaw[None], radii, half)[0]
    partner = np.full(m, -1)
    for i, j in pairs:  # lowest colliding index
        partner[i] = j if partner[i] < 0 else min(partner[i], j)
        partner[j] = i if partner[j] < 0 else min(partner[j], i)
    flags = np.where(partner >= 0, COLLIDE_MOVER, 0) | np.where(wall, COLLIDE_WALL, 0)
    return flags, partner, len(pairs), int(wall.sum())


PATHS = {
    # name: (movers per world, fused_max_movers); the per-cycle path uses the grid broad phase when M > 32
    "fused": (12, 16),
    "fused-dense": (70, 1000),
    "brute": (24, 0),
    "grid": (90, 0),
    "grid-large": (140, 0),
}


@pytest.mark.parametrize("shape", ["circle", "box"])
@pytest.mark.parametrize("path", list(PATHS))
def test_simulator_collisions_match_reference(path, shape, rng):
    m, fused_max = PATHS[path]
    w = 3
    layout = Layout(DENSE_LAYOUT)
    margin = float(rng.uniform(0.0, 0.01))
    wall_margin = float(rng.uniform(0.0, 0.01))
    mover = MoverSpec(collision_shape=shape, margin=margin, wall_margin=wall_margin)
    # Per-mover sizes; denser worlds get smaller movers so that each mover has a few neighbours, not all.
    scale = min(1.0, np.sqrt(24.0 / m))
    radii = f32(rng.uniform(0.02, 0.07, m) * scale)
    half = f32(rng.uniform(0.025, 0.065, (m, 2)) * scale)
    worlds = [random_world(rng, shape, m, margin, wall_margin, radii, half, layout) for _ in range(w)]
    xy = np.stack([x for x, _ in worlds])
    yaw = np.stack([y for _, y in worlds])

    sim = Simulator(layout, num_worlds=w, mover=mover, start_xy=xy, start_yaw=yaw, collision_radii=radii,
                    collision_half_sizes=half, device="cpu", fused_max_movers=fused_max, validate_starts=False,
                    stop_on_collision=False)
    assert sim._fused == (m <= fused_max)
    sim.step(1)
    pos = sim.pos.numpy().astype(np.float64)
    np.testing.assert_array_equal(pos[..., :2], xy)  # at rest: x/y do not move
    got_yaw = yaw_from_quat(sim.quat.numpy())
    total_pairs = 0
    for k in range(w):
        flags, partner, pairs, walls = expected_outputs(mover, layout, xy[k], got_yaw[k], radii, half)
        total_pairs += pairs
        msg = f"{rng}, {path}/{shape}, world {k}"
        np.testing.assert_array_equal(sim.flags[k].numpy(), flags, err_msg=msg)
        np.testing.assert_array_equal(sim.partner[k].numpy(), partner, err_msg=msg)
        np.testing.assert_array_equal(sim.flags_any[k].numpy(), flags, err_msg=msg)
        assert int(sim.world_pairs[k]) == pairs, msg
        assert int(sim.world_walls[k]) == walls, msg
        assert int(sim.halted[k]) == int(pairs > 0 or walls > 0), msg
    # The sample is dense enough that many pairs collide (and not all of them).
    assert total_pairs >= max(w, w * m // 8), f"{rng}: only {total_pairs} colliding pairs"
    assert total_pairs < w * m * (m - 1) // 2, rng

    # Same poses, moved around: a second cycle after rewriting the state gives the new answer, not a stale one.
    perm = rng.permutation(m)
    sim.pos[:, :, :2] = torch.as_tensor(xy[:, perm], dtype=torch.float32)
    sim.quat.copy_(sim.quat[:, perm].clone())
    sim.step(1)
    got_yaw = yaw_from_quat(sim.quat.numpy())
    for k in range(w):
        # the permutation moves sizes relative to poses, so re-check ambiguity-free only through the reference:
        lo = ref.mover_collision_pairs(mover, xy[k, perm], got_yaw[k], radii, half, margin=margin - EPS)
        hi = ref.mover_collision_pairs(mover, xy[k, perm], got_yaw[k], radii, half, margin=margin + EPS)
        if lo != hi:
            continue
        flags, partner, pairs, walls = expected_outputs(mover, layout, xy[k, perm], got_yaw[k], radii, half)
        msg = f"{rng}, {path}/{shape}, permuted world {k}"
        np.testing.assert_array_equal(sim.flags[k].numpy() & COLLIDE_MOVER, flags & COLLIDE_MOVER, err_msg=msg)
        np.testing.assert_array_equal(sim.partner[k].numpy(), partner, err_msg=msg)
        assert int(sim.world_pairs[k]) == pairs, msg


def test_grid_path_finds_pairs_outside_the_layout(rng):
    """Movers beyond the layout edge are clamped into border cells; pairs there are still found."""
    layout = Layout.grid(2, 2)
    m = 40
    xy = np.zeros((m, 2))
    xy[:20] = np.stack([0.05 + 0.019 * np.arange(20), np.full(20, 0.12)], 1)  # 19 mm apart
    xy[20:] = np.stack([np.full(20, -0.5), -0.5 - 0.015 * np.arange(20)], 1)  # far outside, 15 mm apart
    mover = MoverSpec(collision_radius=0.01)
    sim = Simulator(layout, start_xy=xy, mover=mover, device="cpu", fused_max_movers=0, validate_starts=False,
                    stop_on_collision=False)
    sim.step(1)
    pairs = ref.mover_collision_pairs(mover, f32(xy), np.zeros(m))
    assert int(sim.world_pairs[0]) == len(pairs) == 19 + 19, rng
    assert (sim.flags[0, 20:].numpy() == COLLIDE_MOVER | COLLIDE_WALL).all()


@pytest.mark.parametrize("shape", ["circle", "box"])
@pytest.mark.parametrize("layout_name", ["L", "holes", "B3", "B9"])
def test_footprints_on_tiles_matches_reference(layout_name, shape, rng):
    """The sampling kernel (start poses, goals): valid = the axis-aligned footprint grown by ``extra`` (on top of
    the wall margin) stays on the tiles."""
    from magwarp.kernels.collision import footprints_on_tiles

    layout = Layout(WALL_LAYOUTS[layout_name])
    n = 400
    radius, half = float(rng.uniform(0.03, 0.08)), f32(rng.uniform(0.02, 0.08, 2))  # fits a 1-tile-wide L
    extra, wall_margin = float(rng.uniform(0.0, 0.02)), float(rng.uniform(0.0, 0.01))
    ext = np.array(layout.extent)
    xy = f32(rng.uniform(-0.02, 1.02, (n, 2)) * ext)
    mover = MoverSpec(collision_shape=shape)
    r = np.full(n, radius + extra)
    h = np.tile(half + extra, (n, 1))

    def reference(wm):
        return ~ref.wall_collisions(layout, mover, xy[None], np.zeros((1, n)), r, h, wall_margin=wm)[0]

    expected = reference(wall_margin)
    ambiguous = reference(wall_margin - EPS) != reference(wall_margin + EPS)
    valid = wp.zeros(n, dtype=wp.int32, device="cpu")
    wp.launch(footprints_on_tiles, dim=n, device="cpu",
              inputs=[wp.array(layout.tiles, dtype=wp.int32, device="cpu"), make_col(shape, 0.0, wall_margin),
                      radius, wp.vec2(*half), extra, wp.array(xy.astype(np.float32), dtype=wp.vec2, device="cpu"), valid])
    got = valid.numpy().astype(bool)
    bad = np.flatnonzero((got != expected) & ~ambiguous)
    assert bad.size == 0, f"{rng}: {bad.size} mismatches, first xy={xy[bad[:1]]}"
    assert expected.any() and not expected.all(), rng


@pytest.mark.parametrize("shape", ["circle", "box"])
@pytest.mark.parametrize("m", [12, 90])  # brute force (M <= 32) and grid broad phase
def test_check_collisions_matches_reference(m, shape, rng):
    """``Simulator.check_collisions`` (detect_walls + pair kernels) on poses written into the state: no motion."""
    w = 2
    layout = Layout(DENSE_LAYOUT)
    margin, wall_margin = float(rng.uniform(0.0, 0.01)), float(rng.uniform(0.0, 0.01))
    mover = MoverSpec(collision_shape=shape, margin=margin, wall_margin=wall_margin)
    scale = min(1.0, np.sqrt(24.0 / m))
    radii = f32(rng.uniform(0.02, 0.07, m) * scale)
    half = f32(rng.uniform(0.015, 0.055, (m, 2)) * scale)
    sim = Simulator(layout, num_worlds=w, mover=mover, start_xy=np.full((m, 2), 0.0), collision_radii=radii,
                    collision_half_sizes=half, device="cpu", validate_starts=False)
    worlds = [random_world(rng, shape, m, margin, wall_margin, radii, half, layout) for _ in range(w)]
    xy = np.stack([x for x, _ in worlds])
    yaw = np.stack([y for _, y in worlds])
    sim.pos[..., :2] = torch.as_tensor(xy, dtype=torch.float32)
    sim.quat[..., 2] = torch.as_tensor(np.sin(0.5 * yaw), dtype=torch.float32)
    sim.quat[..., 3] = torch.as_tensor(np.cos(0.5 * yaw), dtype=torch.float32)
    pos_before = sim.pos.clone()
    sim.check_collisions()
    assert torch.equal(sim.pos, pos_before)
    got_yaw = yaw_from_quat(sim.quat.numpy())
    for k in range(w):
        flags, partner, pairs, walls = expected_outputs(mover, layout, xy[k], got_yaw[k], radii, half)
        msg = f"{rng}, M={m}/{shape}, world {k}"
        np.testing.assert_array_equal(sim.flags[k].numpy(), flags, err_msg=msg)
        np.testing.assert_array_equal(sim.partner[k].numpy(), partner, err_msg=msg)
        assert int(sim.world_pairs[k]) == pairs and int(sim.world_walls[k]) == walls, msg


@pytest.mark.parametrize("shape", ["circle", "box"])
def test_start_validation_agrees_with_reference(shape, rng):
    """The simulator's kernel-based start check rejects exactly the start poses the numpy reference rejects."""
    layout = Layout(np.array([[1, 1, 1], [1, 0, 1], [1, 1, 1]]))
    mover = MoverSpec(collision_shape=shape, collision_radius=0.09, collision_half_size=(0.07, 0.06),
                      margin=0.005, wall_margin=0.003)
    outcomes = []
    for trial in range(40):
        m = int(rng.integers(2, 5))
        centres = layout.tile_centers()[rng.permutation(layout.num_tiles)[:m]]
        xy = centres + rng.uniform(-0.03, 0.03, (m, 2))  # jittered tile centres: mostly valid, some off the tiles
        if trial % 3 == 0:  # mover 1 right next to mover 0: overlapping or not
            u = rng.normal(size=2)
            xy[1] = xy[0] + u / np.linalg.norm(u) * rng.uniform(0.15, 0.25)
        xy = f32(xy)
        yaw = yaw_from_quat(np.stack([np.zeros(m), np.zeros(m), np.sin(0.5 * (y := rng.uniform(-np.pi, np.pi, m))),
                                      np.cos(0.5 * y)], -1).astype(np.float32))
        verdicts = set()
        for eps in (-EPS, 0.0, EPS):
            bad_pair = bool(ref.mover_collision_pairs(mover, xy, yaw, margin=mover.margin + eps))
            bad_wall = bool(ref.wall_collisions(layout, mover, xy[None], yaw[None], wall_margin=mover.wall_margin + eps).any())
            verdicts.add(bad_pair or bad_wall)
        if len(verdicts) > 1:
            continue  # within float32 reach of a boundary
        invalid = verdicts.pop()
        outcomes.append(invalid)
        if invalid:
            with pytest.raises(LayoutError, match="off the tiles|overlap"):
                Simulator(layout, start_xy=xy, start_yaw=y, mover=mover, device="cpu")
        else:
            sim = Simulator(layout, start_xy=xy, start_yaw=y, mover=mover, device="cpu")
            assert int(sim.flags.sum()) == 0 and int(sim.flags_any.sum()) == 0
    assert any(outcomes) and not all(outcomes), f"{rng}: only one outcome in {len(outcomes)} trials"


@wp.kernel
def _collision_flags_kernel(partner: wp.array(dtype=wp.int32), wall: wp.array(dtype=wp.int32),
                            out: wp.array(dtype=wp.int32)):
    i = wp.tid()
    out[i] = collision_flags(partner[i], wall[i])


def test_collision_flags_match_reference(rng):
    """The collision bits every path writes: mover bit for a partner (index >= 0, -1 for none), wall bit for a hit."""
    n = 64
    partner = rng.integers(-1, 8, n).astype(np.int32)
    wall = rng.integers(0, 2, n).astype(np.int32)
    partner[:4], wall[:4] = (-1, -1, 3, 0), (0, 1, 0, 1)  # every combination, whatever the draw (P(miss) was ~1e-3)
    out = wp.zeros(n, dtype=wp.int32, device="cpu")
    wp.launch(_collision_flags_kernel, dim=n, inputs=[wp.array(partner, device="cpu"), wp.array(wall, device="cpu")],
              outputs=[out], device="cpu")
    want = np.where(partner >= 0, COLLIDE_MOVER, 0) | np.where(wall != 0, COLLIDE_WALL, 0)
    assert np.array_equal(out.numpy(), want), rng
    assert {0, COLLIDE_MOVER, COLLIDE_WALL, COLLIDE_MOVER | COLLIDE_WALL} <= set(want.tolist()), rng
