"""The numpy oracles themselves, checked against independent computations: shapely geometry for collisions and
walls, closed forms for limits and rotations. (The kernels are then tested against these oracles.)"""

from __future__ import annotations

import numpy as np
import pytest

from magwarp import reference as ref
from magwarp.layout import Layout, MoverSpec

shapely = pytest.importorskip("shapely")
from shapely.geometry import Point, Polygon, box  # noqa: E402
from shapely.ops import unary_union  # noqa: E402

TOL = 1e-4  # configurations this close to a touching boundary are skipped (shapely circles are polygons)


def test_box_corners():
    c = ref.box_corners(np.array([1.0, 2.0]), np.pi / 2, np.array([0.3, 0.1]))
    np.testing.assert_allclose(c.mean(0), [1.0, 2.0])
    np.testing.assert_allclose(Polygon(c).area, 4 * 0.3 * 0.1)
    np.testing.assert_allclose(np.ptp(c, axis=0), [0.2, 0.6], atol=1e-12)  # rotated by 90 degrees


@pytest.mark.parametrize("shape", ["circle", "box"])
def test_mover_pairs_match_shapely(shape, rng):
    n = 60
    margin = float(rng.uniform(0, 0.01))
    mover = MoverSpec(collision_shape=shape, margin=margin)
    xy = rng.uniform(0, 0.8, (n, 2))
    yaw = rng.uniform(-np.pi, np.pi, n)
    radii = rng.uniform(0.02, 0.08, n)
    half = rng.uniform(0.01, 0.06, (n, 2))

    def geom(k, grow):
        if shape == "circle":
            return Point(xy[k]).buffer(radii[k] + margin + grow, quad_segs=256)
        return Polygon(ref.box_corners(xy[k], yaw[k], half[k] + margin + grow))

    pairs = set(ref.mover_collision_pairs(mover, xy, yaw, radii, half))
    assert all(i < j for i, j in pairs)
    checked = 0
    for i in range(n):
        for j in range(i + 1, n):
            lo, hi = geom(i, -TOL).intersects(geom(j, -TOL)), geom(i, TOL).intersects(geom(j, TOL))
            if lo != hi:
                continue
            checked += 1
            assert ((i, j) in pairs) == lo, f"{rng}: pair {i, j}"
    assert checked > 0.9 * n * (n - 1) / 2 and len(pairs) > 20, rng


@pytest.mark.parametrize("shape", ["circle", "box"])
def test_wall_collisions_match_shapely(shape, rng):
    tiles = np.array([[1, 1, 1, 0], [1, 0, 1, 1], [1, 1, 1, 1]])
    layout = Layout(tiles)
    s = layout.tile.size
    area = unary_union([box(i * s, j * s, (i + 1) * s, (j + 1) * s) for i, j in zip(*np.nonzero(tiles))])
    wall_margin = float(rng.uniform(0, 0.02))
    mover = MoverSpec(collision_shape=shape, wall_margin=wall_margin)
    n = 300
    xy = rng.uniform(-0.1, 1.05, (n, 2))
    yaw = rng.uniform(-np.pi, np.pi, n)
    radii = rng.uniform(0.02, 0.12, n)
    half = rng.uniform(0.01, 0.09, (n, 2))
    got = ref.wall_collisions(layout, mover, xy[None], yaw[None], radii, half)[0]

    def footprint(k, grow):
        if shape == "circle":
            return Point(xy[k]).buffer(radii[k] + wall_margin + grow, quad_segs=256)
        return Polygon(ref.box_corners(xy[k], yaw[k], half[k] + wall_margin + grow))

    checked = 0
    for k in range(n):
        lo = footprint(k, -TOL).difference(area).area > 1e-12
        hi = footprint(k, TOL).difference(area).area > 1e-12
        if lo != hi:
            continue
        checked += 1
        assert got[k] == lo, f"{rng}: mover {k} at {xy[k]}, yaw {yaw[k]}"
    assert checked > 0.9 * n and 0.2 < got.mean() < 0.95, rng


def test_wall_touching_edge_is_inside():
    """A footprint that only touches the outer edge of the tiled area is inside (MagBotSim's strict rule)."""
    layout = Layout.grid(1, 1)
    for shape in ("circle", "box"):
        mover = MoverSpec(collision_shape=shape, collision_radius=0.12, collision_half_size=(0.12, 0.12))
        assert not ref.wall_collisions(layout, mover, np.array([[[0.12, 0.12]]]), np.zeros((1, 1)))[0, 0]
        assert ref.wall_collisions(layout, mover, np.array([[[0.1201, 0.12]]]), np.zeros((1, 1)))[0, 0]


def test_planar_cycle_limits_and_pass_through(rng):
    n = 2000
    vel = rng.normal(size=(n, 2))
    vel *= rng.uniform(0, 2, (n, 1)) / np.linalg.norm(vel, axis=1, keepdims=True)
    acc = rng.normal(size=(n, 2)) * 4
    cmd = rng.normal(size=(n, 2)) * 20
    kw = dict(dt=0.001, v_max=2.0, a_max=10.0, j_max=100.0)
    for jerk in (False, True):
        a, v, dp = ref.planar_cycle(vel, acc, cmd, jerk_mode=jerk, **kw)
        assert np.linalg.norm(v, axis=1).max() <= 2.0 + 1e-12, rng
        assert np.linalg.norm(a, axis=1).max() <= 10.0 + 1e-9, rng
        np.testing.assert_allclose(v, vel + 0.001 * a)
        np.testing.assert_allclose(dp, 0.001 * v)
    # within every limit the command passes through unchanged
    slow = np.linalg.norm(vel, axis=1) < 1.9
    small = rng.normal(size=(n, 2))
    a, _, _ = ref.planar_cycle(vel, acc, small, jerk_mode=False, **kw)
    np.testing.assert_allclose(a[slow], small[slow])
    acc_small = acc / np.maximum(1, np.linalg.norm(acc, axis=1, keepdims=True)) * 5
    a, _, _ = ref.planar_cycle(vel, acc_small, small, jerk_mode=True, **kw)
    np.testing.assert_allclose(a[slow], acc_small[slow] + 0.001 * small[slow])
    # over the acceleration limit: same direction, norm a_max
    big = np.array([[30.0, 40.0]])
    a, _, _ = ref.planar_cycle(np.zeros((1, 2)), np.zeros((1, 2)), big, jerk_mode=False, **kw)
    np.testing.assert_allclose(a, [[6.0, 8.0]])


def test_quaternion_helpers(rng):
    for _ in range(50):
        v = rng.normal(size=3)
        v *= rng.uniform(0, 3.1) / np.linalg.norm(v)
        q = np.concatenate([v / np.linalg.norm(v) * np.sin(np.linalg.norm(v) / 2), [np.cos(np.linalg.norm(v) / 2)]])
        np.testing.assert_allclose(ref.quat_to_rotvec(q), v, atol=1e-12)
        np.testing.assert_allclose(ref.quat_to_rotvec(-q), v, atol=1e-12)  # sign-invariant
        # rotating a vector: Rodrigues' formula
        x = rng.normal(size=3)
        th = np.linalg.norm(v)
        k = v / th
        rod = x * np.cos(th) + np.cross(k, x) * np.sin(th) + k * np.dot(k, x) * (1 - np.cos(th))
        np.testing.assert_allclose(ref.quat_rotate(q, x), rod, atol=1e-12)
    # constant angular velocity: 1000 small exact steps = one rotation by omega * T
    omega = rng.normal(size=3)
    q = ref.yaw_quat(0.3)
    for _ in range(1000):
        q = ref.integrate_rotation(q, omega, 0.001)
    want = ref.quat_mul(np.concatenate([omega / np.linalg.norm(omega) * np.sin(np.linalg.norm(omega) / 2),
                                        [np.cos(np.linalg.norm(omega) / 2)]]), ref.yaw_quat(0.3))
    np.testing.assert_allclose(q * np.sign(q @ want), want, atol=1e-10)


def test_impedance_wrench_basics():
    k_lin, k_rot = np.array([1.0, 1.0, 100.0]), np.array([0.1, 0.1, 1.0])
    d_lin, d_rot = 2 * np.sqrt(k_lin * 1.24), 2 * np.sqrt(k_rot * 0.005)
    mask = np.array([0.0, 0.0, 1.0]), np.ones(3)
    q0 = ref.yaw_quat(0.7)
    args = (k_lin, k_rot, d_lin, d_rot, *mask)
    f, t = ref.impedance_wrench(np.zeros(3), q0, np.zeros(3), np.zeros(3), np.zeros(3), q0, *args)
    np.testing.assert_allclose(f, 0)
    np.testing.assert_allclose(t, 0)
    # 1 cm below the target, moving up at 0.1 m/s: spring up, damping down; x/y are not held
    f, _ = ref.impedance_wrench(np.array([0.5, 0.5, -0.01]), q0, np.array([1.0, 0, 0.1]), np.zeros(3), np.zeros(3), q0,
                                *args)
    np.testing.assert_allclose(f, [0, 0, 100 * 0.01 - d_lin[2] * 0.1])
    # yawed 0.2 rad past the target: the torque turns it back about -z
    _, t = ref.impedance_wrench(np.zeros(3), ref.yaw_quat(0.9), np.zeros(3), np.zeros(3), np.zeros(3), q0, *args)
    np.testing.assert_allclose(t, [0, 0, -0.2], atol=1e-12)
    # the shortest way: 350 degrees of yaw error is -10 degrees
    _, t = ref.impedance_wrench(np.zeros(3), ref.yaw_quat(np.radians(350)), np.zeros(3), np.zeros(3), np.zeros(3),
                                ref.yaw_quat(0.0), *args)
    np.testing.assert_allclose(t, [0, 0, np.radians(10)], atol=1e-12)
