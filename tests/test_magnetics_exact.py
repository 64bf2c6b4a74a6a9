"""The exact magnetic model: the cuboid field and the coil wrenches against magpylib (an independent library,
test-only), against the numpy references, and against virtual work (F = I dPsi/dq of the flux linkage)."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from magwarp.layout import Layout
from magwarp.magnetics import reference as ref
from magwarp.magnetics.sources import array_field
from magwarp.magnetics.exact import ExactModel, pose_to_pos_quat, vec6d
from magwarp.magnetics.geometry import Cuboid, MagneticParams, MagneticsError, MagnetArray, Quadrature, halbach_array

magpy = pytest.importorskip("magpylib")

SMALL = halbach_array(magnets_per_quadrant=1, cell=0.03)  # 4 magnets, 60 mm square


def random_magnets(rng, n: int) -> MagnetArray:
    return MagnetArray(tuple(Cuboid(rng.uniform(-0.03, 0.03, 3), rng.uniform(0.002, 0.03, 3), rng.normal(0, 1, 3))
                             for _ in range(n)))


def away_from_surfaces(magnets: MagnetArray, pts: np.ndarray, gap: float) -> np.ndarray:
    """Points farther than ``gap`` from every face plane of every magnet, inside the face's extent grown by gap."""
    keep = np.ones(len(pts), dtype=bool)
    for c, s in zip(magnets.centers, magnets.sizes):
        d = np.abs(pts - c) - 0.5 * s  # > 0 outside along that axis
        near_face = (np.abs(d) < gap) & np.all(d < gap, axis=1, keepdims=True).repeat(3, 1)
        keep &= ~near_face.any(axis=1)
    return keep


def magpy_collection(magnets: MagnetArray):
    return magpy.Collection(*[magpy.magnet.Cuboid(polarization=j, dimension=s, position=c)
                              for c, s, j in zip(magnets.centers, magnets.sizes, magnets.polarizations)])


def test_cuboid_field_matches_magpylib(rng):
    magnets = random_magnets(rng, 3)
    # Near (inside, between and around the magnets) and far points (up to 2 m).
    near = rng.uniform(-0.06, 0.06, (3000, 3))
    far = rng.normal(size=(500, 3))
    far *= rng.uniform(0.1, 2.0, (500, 1)) / np.linalg.norm(far, axis=1, keepdims=True)
    inside = [c + rng.uniform(-0.45, 0.45, (20, 3)) * s for c, s in zip(magnets.centers, magnets.sizes)]
    pts = np.concatenate([near, far, *inside])
    pts = pts[away_from_surfaces(magnets, pts, 1e-4)]
    want = magpy.getB(magpy_collection(magnets), pts)
    for got in (array_field(magnets, pts, device="cpu"), ref.array_field(magnets, pts)):
        err = np.linalg.norm(got - want, axis=1) / np.linalg.norm(want, axis=1)
        assert err.max() < 1e-6, f"{rng}: worst relative error {err.max():.3g} at {pts[err.argmax()]}"
    inside = np.zeros(len(pts), dtype=bool)
    for c, s in zip(magnets.centers, magnets.sizes):
        inside |= np.all(np.abs(pts - c) < 0.5 * s, axis=1)
    assert inside.sum() > 10, f"{rng}: the test must cover points inside the magnets"


def test_cuboid_field_finite_on_surfaces_and_edges():
    """On faces, edges and corners the kernel returns finite numbers (the ideal edge field is infinite)."""
    magnets = MagnetArray((Cuboid((0, 0, 0), (0.02, 0.01, 0.004), (0.3, -0.2, 1.2)),))
    pts = np.array([[0.01, 0.0, 0.0], [0.01, 0.005, 0.0], [0.01, 0.005, 0.002], [0.0, 0.0, 0.002],
                    [0.03, 0.005, 0.002], [0.03, 0.0, 0.0], [0.0, 0.0, 0.0]])
    got = array_field(magnets, pts, device="cpu")
    assert np.all(np.isfinite(got))
    assert np.all(np.isfinite(ref.array_field(magnets, pts)))
    # In a face's plane but outside the face, the field is continuous: compare with points 1e-9 m off the plane.
    off = pts[[4, 5]] + np.array([0.0, 0.0, 1e-9])
    off_b = array_field(magnets, off, device="cpu")
    assert np.allclose(got[[5]], off_b[[1]], rtol=1e-6, atol=0), (got[5], off_b[1])


def test_halbach_field_is_strong_below():
    """The default orientation puts the strong side of the array under the mover (on the coils)."""
    arr = halbach_array()
    lo, hi = arr.bounds
    xy = np.stack(np.meshgrid(np.linspace(-0.03, 0.03, 7), np.linspace(-0.03, 0.03, 7)), -1).reshape(-1, 2)
    below = np.c_[xy, np.full(len(xy), lo[2] - 0.005)]
    above = np.c_[xy, np.full(len(xy), hi[2] + 0.005)]
    b_below = np.linalg.norm(ref.array_field(arr, below), axis=1).mean()
    b_above = np.linalg.norm(ref.array_field(arr, above), axis=1).mean()
    assert b_below > 3.0 * b_above, (b_below, b_above)
    assert 0.2 < b_below < 1.0, b_below  # mean |B| (T) 5 mm under an NdFeB Halbach array


def test_pose_to_quat_matches_rotation_matrix(rng):
    pose = np.c_[rng.normal(size=(20, 3)), rng.uniform(-np.pi, np.pi, (20, 3))]
    _, quat = pose_to_pos_quat(pose)
    v = rng.normal(size=3)
    got = np.array([wp.quat_rotate(wp.quatd(*q), wp.vec3d(*v)) for q in quat])
    assert np.allclose(got, ref.rotation(pose) @ v, atol=1e-12), rng


def small_model(quadrature=Quadrature(), magnets=SMALL, radius=0.04, layout=None):
    params = MagneticParams(magnets=magnets, quadrature=quadrature, active_radius=radius)
    return ExactModel(layout or Layout.grid(1, 1), params, device="cpu"), params


def random_poses(rng, n, layout: Layout, gap=(0.003, 0.005), tilt=0.02):
    ext = layout.extent
    return np.c_[rng.uniform(0.02, ext[0] - 0.02, n), rng.uniform(0.02, ext[1] - 0.02, n),
                 rng.uniform(*gap, n) + 0.006, rng.uniform(-tilt, tilt, (n, 2)), rng.uniform(-np.pi, np.pi, n)]


def test_columns_match_numpy_reference(rng):
    # An interval length that divides no coil side, so both sides cut every filament into the same pieces.
    model, params = small_model(Quadrature(order=3, max_interval=0.0077))
    poses = random_poses(rng, 3, model.layout)
    ids, count, gamma = model.evaluate(poses)
    assert count.min() > 2, (rng, count)
    for n in range(len(poses)):
        want = ref.coil_columns(params, model.coilset, poses[n], ids[n])
        assert np.allclose(gamma[n], want, rtol=1e-9, atol=1e-12 * np.abs(want).max()), rng


def test_active_coils_match_reference(rng):
    layout = Layout(np.array([[1, 1, 0], [1, 0, 1]]))  # holes included
    model, _ = small_model(radius=0.07, layout=layout)
    pos = np.c_[rng.uniform(-0.05, 0.55, 200), rng.uniform(-0.05, 0.77, 200), np.full(200, 0.01)]
    ids, count = model.active_coils(wp.array(pos, dtype=wp.vec3d, device="cpu"))
    ids, count = ids.numpy(), count.numpy()
    for n, want in enumerate(ref.active_coils(model.coilset, pos[:, :2], 0.07)):
        assert count[n] == len(want), (rng, n)
        slots = min(len(want), ids.shape[1])
        assert np.array_equal(ids[n, :slots], want[:slots]) and np.all(ids[n, slots:] == -1), (rng, n)
    assert count.max() > 0 and count.min() == 0, "the sample must include movers off the tiles"


def test_wrench_matches_magpylib_getft(rng):
    """Force and torque (about the mover's centre) of current polylines on the magnet array, both ways round."""
    model, params = small_model()
    pose = random_poses(rng, 1, model.layout)
    ids, count, gamma = model.evaluate(pose)
    k = ids[0, : count[0]]
    currents = rng.uniform(-5.0, 5.0, len(k))
    want_w = gamma[0, : len(k)].T @ currents
    cs = model.coilset
    rot = __import__("scipy.spatial.transform", fromlist=["Rotation"]).Rotation.from_matrix(ref.rotation(pose)[0])
    coll = magpy_collection(params.magnets).rotate(rot, anchor=0).move(pose[0, :3])
    lines = [magpy.current.Polyline(current=cs.seg_weight[s] * i, vertices=[cs.seg_a[s], cs.seg_b[s]])
             for kk, i in zip(k, currents) for s in range(cs.seg_start[kk], cs.seg_start[kk + 1])]
    ft = np.asarray(magpy.getFT(coll, lines, pivot=pose[0, :3], meshing=1500)).sum(axis=1)
    got = -ft.ravel()  # getFT gives the force on the lines; the mover gets the reaction
    for part, name in ((slice(0, 3), "force"), (slice(3, 6), "torque")):
        err = np.linalg.norm(got[part] - want_w[part]) / np.linalg.norm(want_w[part])
        assert err < 1e-3, f"{rng}: {name} differs by {err:.3g} relative: {want_w[part]} vs magpylib {got[part]}"


def test_force_is_current_times_flux_gradient(rng):
    """Virtual work: at constant current, the mover's force along q is I dPsi/dq (Psi: the coil's flux linkage);
    the yaw torque is I dPsi/dyaw. Checked on the coil that acts the most, by central differences."""
    model, params = small_model()
    pose = random_poses(rng, 1, model.layout, tilt=0.0)[0]
    ids, count, gamma = model.evaluate(pose[None])
    j = int(np.argmax(np.linalg.norm(gamma[0, :, :3], axis=1)))
    k = ids[0, j]
    cs = model.coilset
    loops = cs.seg_a[cs.seg_start[k]: cs.seg_start[k + 1]].reshape(-1, 4, 3)
    weight = cs.seg_weight[cs.seg_start[k]]
    h = 1e-5
    col = gamma[0, j]
    for axis, comp in ((0, 0), (1, 1), (2, 2), (5, 5)):
        dp = np.zeros(6)
        dp[axis] = h
        dpsi = (ref.flux_linkage(params.magnets, loops, weight, pose + dp, order=10, cells=12)
                - ref.flux_linkage(params.magnets, loops, weight, pose - dp, order=10, cells=12)) / (2 * h)
        scale = np.linalg.norm(col[:3]) if comp < 3 else np.linalg.norm(col[3:])
        assert abs(dpsi - col[comp]) < 1e-4 * scale, f"{rng}: component {comp}: dPsi/dq {dpsi} vs {col[comp]}"


def test_bad_poses_raise():
    model, _ = small_model()
    with pytest.raises(MagneticsError, match="poses must be finite"):
        model.evaluate(np.array([[0.1, 0.1, np.nan, 0, 0, 0]]))
    with pytest.raises(MagneticsError, match="shape"):
        model.evaluate(np.zeros((2, 5)))
    with pytest.raises(MagneticsError, match="unit quaternions"):
        model.as_arrays(pos=np.zeros((1, 3)), quat=np.array([[0.0, 0.0, 0.0, 2.0]]))
    with pytest.raises(MagneticsError, match="odd"):
        halbach_array(magnets_per_quadrant=4)


def test_wrench_is_gamma_times_currents(rng):
    model, _ = small_model()
    gamma = rng.normal(size=(7, 5, 6))
    cur = rng.normal(size=(7, 5))
    got = model.wrench(wp.array(gamma, dtype=vec6d, device="cpu"), wp.array(cur, dtype=wp.float64, device="cpu"))
    assert np.allclose(got.numpy(), np.einsum("msk,ms->mk", gamma, cur), rtol=1e-12, atol=1e-14), rng
