"""magwarp.collision against MagBotSim's own utilities (``check_mover_collision``, ``qpos_is_valid``) on thousands of
random configurations (circles and boxes, per-mover sizes, both values of ``add_safety_offset``, a full layout and
one with holes), and its clearance against a float64 numpy geometry. Cases within 1e-6 m of contact (where MagBotSim's
own answer changes when every size moves by 1e-6 m) are left out."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch

from magwarp import reference as ref
from magwarp.collision import CollisionQuery
from magwarp.layout import Layout

LAYOUTS = {
    "full": np.ones((4, 3), dtype=np.int8),
    "holes": np.array([[1, 1, 1, 0], [1, 0, 1, 1], [1, 1, 1, 1], [0, 1, 1, 1]], dtype=np.int8),
}
OFFSET, OFFSET_WALL = 0.012, 0.006
M = 3
EPS = 1e-6


def random_cases(rng, layout: np.ndarray, shape: str, n: int):
    """Poses (n, M, 3) clustered so that about half of the configurations collide, and per-mover sizes."""
    ext = np.array(layout.shape) * 0.24
    centre = rng.uniform(-0.05, ext + 0.05, (n, 1, 2))
    xy = centre + rng.normal(scale=0.12, size=(n, M, 2))
    yaw = rng.uniform(-np.pi, np.pi, (n, M, 1))
    poses = np.concatenate([xy, yaw], axis=-1)
    size = rng.uniform(0.03, 0.11, (n, M)) if shape == "circle" else rng.uniform(0.03, 0.09, (n, M, 2))
    # float32-representable inputs: both engines see the same numbers
    return poses.astype(np.float32).astype(np.float64), size.astype(np.float32).astype(np.float64)


def qpos_of(poses: np.ndarray) -> np.ndarray:
    """MagBotSim's qpos rows (x, y, z, w, qx, qy, qz) of poses (M, 3)."""
    q = np.zeros((len(poses), 7))
    q[:, :2] = poses[:, :2]
    q[:, 3] = np.cos(0.5 * poses[:, 2])
    q[:, 6] = np.sin(0.5 * poses[:, 2])
    return q


def magbotsim_labels(env, poses, size, add: bool, grow: float = 0.0):
    q = qpos_of(poses)
    s = size + grow
    return bool(env.check_mover_collision(env.mover_names, s, add, q)), env.qpos_is_valid(q, s, add).astype(bool)


@pytest.fixture(scope="module")
def envs():
    pytest.importorskip("magbotsim")
    from magbotsim import BasicMagBotEnv

    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # its "mover not completely included in collision shape" notes
        for name, tiles in LAYOUTS.items():
            for shape in ("circle", "box"):
                size = 0.1 if shape == "circle" else np.array([0.08, 0.08])
                out[name, shape] = BasicMagBotEnv(
                    layout_tiles=tiles, num_movers=M, render_mode=None,
                    collision_params={"shape": shape, "size": size, "offset": OFFSET, "offset_wall": OFFSET_WALL})
    return out


@pytest.mark.parametrize("layout_name", sorted(LAYOUTS))
@pytest.mark.parametrize("shape", ["circle", "box"])
@pytest.mark.parametrize("add", [False, True])
def test_labels_match_magbotsim(envs, layout_name, shape, add, rng):
    env = envs[layout_name, shape]
    n = 600
    poses, size = random_cases(rng, LAYOUTS[layout_name], shape, n)
    query = CollisionQuery(LAYOUTS[layout_name], shape, offset=OFFSET, offset_wall=OFFSET_WALL, device="cpu")
    out = query(poses, size, add_safety_offset=add)
    got_any = out.any_collision.numpy()
    got_valid = out.wall_valid.numpy()
    compared_pairs = compared_walls = 0
    counts = np.zeros(2, int)
    for k in range(n):
        want_any, want_valid = magbotsim_labels(env, poses[k], size[k], add)
        lo_any, lo_valid = magbotsim_labels(env, poses[k], size[k], add, -EPS)
        hi_any, hi_valid = magbotsim_labels(env, poses[k], size[k], add, EPS)
        if lo_any == hi_any:  # not within 1e-6 m of a mover-mover contact
            assert got_any[k] == want_any, f"{rng}: case {k} poses {poses[k].tolist()} sizes {size[k].tolist()}"
            compared_pairs += 1
            counts[int(want_any)] += 1
        stable = lo_valid == hi_valid
        np.testing.assert_array_equal(got_valid[k][stable], want_valid[stable],
                                      err_msg=f"{rng}: case {k} poses {poses[k].tolist()} sizes {size[k].tolist()}")
        compared_walls += int(stable.sum())
    # the cases really test both answers
    # (at least 10% of each answer: a seed drew 19% of one)
    assert compared_pairs > 0.95 * n and counts.min() > 0.1 * n, (str(rng), counts)
    assert compared_walls > 0.95 * n * M and 0.1 < got_valid.mean() < 0.9, (str(rng), got_valid.mean())


def _segment_distance(a0, a1, b0, b1) -> float:
    """Distance between two segments that do not cross (the smallest of the four end-point distances)."""
    def point_seg(p, s0, s1):
        d = s1 - s0
        t = np.clip(np.dot(p - s0, d) / np.dot(d, d), 0.0, 1.0)
        return np.linalg.norm(p - (s0 + t * d))
    return min(point_seg(a0, b0, b1), point_seg(a1, b0, b1), point_seg(b0, a0, a1), point_seg(b1, a0, a1))


def box_clearance(pi, pj, hi, hj) -> float:
    """Float64 signed distance of two rectangles: edge-to-edge distance apart, minus the penetration depth (the
    shortest push that separates them, over the four edge normals) when they overlap."""
    ci, cj = ref.box_corners(pi[:2], pi[2], hi), ref.box_corners(pj[:2], pj[2], hj)
    if ref.polygons_overlap(ci, cj):
        depth = np.inf
        for poly in (ci, cj):
            for k in range(4):
                e = poly[(k + 1) % 4] - poly[k]
                axis = np.array([-e[1], e[0]]) / np.linalg.norm(e)
                a, b = ci @ axis, cj @ axis
                depth = min(depth, a.max() - b.min(), b.max() - a.min())  # shortest push apart along the axis
        return -depth
    return min(_segment_distance(ci[k], ci[(k + 1) % 4], cj[q], cj[(q + 1) % 4]) for k in range(4) for q in range(4))


@pytest.mark.parametrize("shape", ["circle", "box"])
def test_clearance_and_pair_flags_match_float64_geometry(shape, rng):
    n = 300
    poses, size = random_cases(rng, LAYOUTS["full"], shape, n)
    query = CollisionQuery(LAYOUTS["full"], shape, offset=OFFSET, device="cpu")
    out = query(torch.as_tensor(poses), torch.as_tensor(size), add_safety_offset=True)
    clear = out.pair_clearance.numpy()
    pair = out.pair_collision.numpy()
    for k in range(n):
        for i in range(M):
            assert not pair[k, i, i] and clear[k, i, i] == np.inf
            for j in range(i + 1, M):
                if shape == "circle":
                    want = np.linalg.norm(poses[k, i, :2] - poses[k, j, :2]) - size[k, i] - size[k, j] - 2 * OFFSET
                else:
                    want = box_clearance(poses[k, i], poses[k, j], size[k, i] + OFFSET, size[k, j] + OFFSET)
                assert abs(clear[k, i, j] - want) < 2e-6, f"{rng}: case {k} pair {i},{j}: {clear[k, i, j]} vs {want}"
                assert clear[k, j, i] == clear[k, i, j] and pair[k, j, i] == pair[k, i, j]
                if abs(want) > EPS:
                    assert pair[k, i, j] == (want < 0), f"{rng}: case {k} pair {i},{j}"
    np.testing.assert_array_equal(out.mover_collision.numpy(), pair.any(-1))
    np.testing.assert_array_equal(out.clearance.numpy(), clear.min(-1))
    assert 0.2 < out.mover_collision.float().mean() < 0.8, str(rng)


def test_batch_shapes_and_shared_sizes():
    q = CollisionQuery(Layout.grid(3, 3), "box", device="cpu")
    poses = torch.zeros(2, 5, 4, 3)
    poses[..., 0] = torch.linspace(0.1, 0.6, 4)
    poses[..., 1] = 0.36
    out = q(poses, (0.05, 0.05))  # one half-size pair for every mover
    assert out.pair_collision.shape == (2, 5, 4, 4) and out.wall_valid.shape == (2, 5, 4)
    assert out.any_collision.shape == (2, 5)
    assert not out.any_collision.any()  # 0.167 m apart, 0.1 m wide
    out = q(poses, torch.full((4, 2), 0.09))  # per-mover sizes shared by every configuration
    assert out.mover_collision.all()
    single = q(torch.tensor([[0.36, 0.36, 0.0]]), [[0.05, 0.05]])
    assert single.clearance.item() == np.inf and single.wall_valid.item()


@pytest.mark.parametrize("kwargs, poses, size, match", [
    ({}, [[0.1, 0.1]], 0.1, r"\[\.\.\., M, 3\]"),
    ({}, [[float("nan"), 0.1, 0.0]], 0.1, "poses contains a non-finite value at index \\[0, 0\\]: nan"),
    ({}, [[0.1, 0.1, 0.0]], -0.1, "circle radii must be positive, got -0.1"),
    ({}, [[0.1, 0.1, 0.0], [0.3, 0.1, 0.0]], [0.1, 0.1, 0.1], r"must broadcast to \(2,\)"),
    ({"shape": "box"}, [[0.1, 0.1, 0.0]], [0.1, float("inf")], "size contains a non-finite value"),
])
def test_bad_inputs_name_the_value(kwargs, poses, size, match):
    q = CollisionQuery(Layout.grid(2, 2), device="cpu", **kwargs)
    with pytest.raises(ValueError, match=match):
        q(poses, size)


def test_bad_construction_names_the_value():
    with pytest.raises(ValueError, match="'hexagon'"):
        CollisionQuery(Layout.grid(2, 2), "hexagon", device="cpu")
    with pytest.raises(ValueError, match="offset must be a finite number >= 0, got -0.1"):
        CollisionQuery(Layout.grid(2, 2), offset=-0.1, device="cpu")
    with pytest.raises(TypeError, match="add_safety_offset must be a bool"):
        CollisionQuery(Layout.grid(2, 2), device="cpu")([[0.1, 0.1, 0.0]], 0.1, add_safety_offset="yes")


def missing_squares(tiles: np.ndarray, ring: int = 2) -> list[np.ndarray]:
    """Lower-left corners of the missing tiles and of a ring of squares around the layout (the outside)."""
    nx, ny = tiles.shape
    return [np.array([i, j]) * 0.24 for i in range(-ring, nx + ring) for j in range(-ring, ny + ring)
            if not (0 <= i < nx and 0 <= j < ny and tiles[i, j] == 1)]


@pytest.mark.parametrize("layout_name", sorted(LAYOUTS))
@pytest.mark.parametrize("shape", ["circle", "box"])
def test_wall_clearance_matches_float64_geometry(layout_name, shape, rng):
    tiles = LAYOUTS[layout_name]
    n = 150 if shape == "circle" else 60  # the float64 box distance is a Python loop
    poses, size = random_cases(rng, tiles, shape, n)
    out = CollisionQuery(tiles, shape, offset_wall=OFFSET_WALL, device="cpu")(poses, size)
    got, valid = out.wall_clearance.numpy(), out.wall_valid.numpy()
    tile = 0.24
    # the outside as missing squares far enough out to hold every mover (a normal tail put one 0.57 m beyond the layout,
    # past a ring of two squares: the reference then saw no wall near it)
    ext = np.array(tiles.shape) * tile
    overshoot = max(0.0, float(np.max(-poses[..., :2])), float(np.max(poses[..., :2] - ext)))
    squares = missing_squares(tiles, ring=2 + int(np.ceil(overshoot / tile)))
    for k in range(n):
        for i in range(M):
            p, grown = poses[k, i], size[k, i] + OFFSET_WALL
            # squares farther than a tile from the footprint cannot change the (capped) answer
            near = [lo for lo in squares if np.linalg.norm(p[:2] - lo - tile / 2) < 2.2 * tile + np.linalg.norm(grown)]
            if shape == "circle":
                d = [np.linalg.norm(p[:2] - np.clip(p[:2], lo, lo + tile)) - grown for lo in near]
            else:
                d = [box_clearance(p, np.array([*(lo + tile / 2), 0.0]), grown, np.full(2, tile / 2)) for lo in near]
            want = min(d + [tile])
            if want > EPS:
                assert abs(got[k, i] - want) < 2e-6, f"{rng}: case {k} mover {i}: {got[k, i]} vs {want}"
            elif want < -EPS:
                assert got[k, i] < 0, f"{rng}: case {k} mover {i}: {got[k, i]} vs {want}"
            if abs(got[k, i]) > EPS:
                assert valid[k, i] == (got[k, i] > 0), f"{rng}: case {k} mover {i}"
    assert 0.1 < valid.mean() < 0.9, str(rng)
