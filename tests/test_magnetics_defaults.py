"""The default magnetic design gives XPlanar-like figures, checked with the exact model and the commutation kernel:
it holds a mover plus the design payload at 3-5 mm gaps, reaches about XPlanar's 10 m/s^2 in every direction while
hovering at the current limit (and is not a far stronger motor), with plausible coil losses."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from magwarp.layout import Layout, MoverSpec
from magwarp.magnetics.commutation import FLAG_NOT_CONVERGED, Commutation
from magwarp.magnetics.exact import ExactModel, measure_active_radius, vec6d
from magwarp.magnetics.geometry import DEFAULT_PAYLOAD, CoilSpec, MagneticParams, Quadrature

G = 9.81
# A coarser quadrature than the default (1e-3 instead of 1e-6 relative): ample for figures, 4x faster.
COARSE = Quadrature(order=2, max_interval=0.01)


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    mp = pytest.MonkeyPatch()
    mp.setenv("MAGWARP_CACHE_DIR", str(tmp_path_factory.mktemp("magnetics_cache")))
    yield ExactModel(Layout.grid(3, 3), MagneticParams(quadrature=COARSE), device="cpu")
    mp.undo()


def test_design_figures():
    mover = MoverSpec()
    params = MagneticParams()
    assert params.magnets.mass < mover.mass  # the magnets fit the XPlanar-like mover's mass (1.01 of 1.24 kg)
    lo, hi = params.magnets.bounds
    assert np.all(hi[:2] - lo[:2] <= np.array(mover.size[:2])) and lo[2] >= -0.5 * mover.size[2]
    coil = CoilSpec()
    assert 0.3 < coil.resistance < 1.5, coil.resistance  # ohm
    assert 10.0 < coil.resistance * coil.current_limit ** 2 < 60.0  # W per coil at its limit


def test_active_radius_cutoff(model, rng):
    """The measured radius: a coil just beyond it acts with under 1e-4 of the peak coil force and torque."""
    assert model.active_radius == pytest.approx(0.28, abs=0.011)
    assert measure_active_radius(model.params) == model.active_radius  # cached, same value
    cs = model.coilset
    k = int(np.argmin(np.linalg.norm(cs.centers[:, :2] - 0.36, axis=1)))  # a coil of the middle tile
    rect = cs.rects[k]
    z = 0.003 + 0.006
    # Peak: the mover over and around the coil (offsets up to 0.1 m, 3 yaws); far: its centre just beyond the radius.
    grid = np.linspace(-0.1, 0.1, 11)
    near = [(0.5 * (rect[0] + rect[1]) + dx, 0.5 * (rect[2] + rect[3]) + dy, z, 0, 0, yaw)
            for dx in grid for dy in grid for yaw in (0.0, np.pi / 8, np.pi / 4)]
    r = model.active_radius + 0.003
    cx, cy = 0.5 * (rect[0] + rect[1]), 0.5 * (rect[2] + rect[3])
    hx, hy = 0.5 * (rect[1] - rect[0]), 0.5 * (rect[3] - rect[2])
    far = []  # at distance r from the rectangle: beyond its 4 edges and around its 4 corners
    for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1)):
        th = rng.uniform(0, np.pi / 2)
        far.append((cx + sx * (hx + r * np.cos(th)), cy + sy * (hy + r * np.sin(th))))
        far.append((cx + sx * (hx + r), cy + rng.uniform(-hy, hy)) if sy > 0 else (cx + rng.uniform(-hx, hx),
                                                                                    cy + sy * (hy + r)))
    far = [(x, y, z, 0, 0, rng.uniform(-np.pi, np.pi)) for x, y in far]
    pos, quat = model.as_arrays(np.array(near + far, dtype=float))
    ids = wp.array(np.full((len(near) + len(far), 1), k, dtype=np.int32), dtype=wp.int32, device="cpu")
    g = model.wrench_matrix(pos, quat, ids).numpy()[:, 0]
    f, t = np.linalg.norm(g[:, :3], axis=1), np.linalg.norm(g[:, 3:], axis=1)
    n = len(near)
    assert f[n:].max() < 1e-4 * f[:n].max() and t[n:].max() < 1e-4 * t[:n].max(), (rng, f[n:].max() / f[:n].max())


def poses_at_yaw0(rng, n, gap):
    return np.c_[rng.uniform(0.24, 0.48, n), rng.uniform(0.24, 0.48, n), np.full(n, gap + 0.006),
                 np.zeros((n, 3))]


# The worst direction's largest acceleration while hovering at the current limit, by linear programming over 300
# random poses per gap (8 directions each): at 3 mm at least 10.1 m/s^2 (median 21), at 5 mm at least 7.2 m/s^2
# (median 16); the best direction of any pose at most 38.5 m/s^2 (benchmarks/magnetics_acceleration.py). XPlanar's
# data sheet says 10 m/s^2. The test asks for a little less than the measured minimum, and that 50 is out of reach.
@pytest.mark.parametrize("gap, a_min", [(0.003, 8.0), (0.005, 6.0)])
def test_hover_payload_and_acceleration_at_the_limit(model, rng, gap, a_min):
    mass = MoverSpec().mass
    poses = poses_at_yaw0(rng, 3, gap)
    pos, quat = model.as_arrays(poses)
    ids, count = model.active_coils(pos)
    assert count.numpy().max() <= model.max_active, "no active coil may be left out"
    gamma = model.wrench_matrix(pos, quat, ids).numpy()
    # Per pose: hover with the payload; hover and accelerate at a_min and at 50 m/s^2 in 8 directions.
    angles = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    wanted = []
    for _ in poses:
        wanted.append([0, 0, (mass + DEFAULT_PAYLOAD) * G, 0, 0, 0])
        for a in (a_min, 50.0):
            wanted += [[mass * a * np.cos(t), mass * a * np.sin(t), mass * G, 0, 0, 0] for t in angles]
    per = 1 + 2 * len(angles)
    wanted = np.asarray(wanted)
    rep = np.repeat(np.arange(len(poses)), per)
    com = Commutation(model.coilset, device="cpu")
    res = com.solve(wp.array(gamma[rep], dtype=vec6d, device="cpu"),
                    wp.array(ids.numpy()[rep], dtype=wp.int32, device="cpu"),
                    wp.array(count.numpy()[rep], dtype=wp.int32, device="cpu"),
                    wp.array(wanted, dtype=vec6d, device="cpu"))
    resid = np.linalg.norm(res.residual.numpy(), axis=1) / np.linalg.norm(wanted, axis=1)
    flags, loss = res.flags.numpy(), res.loss.numpy()
    kind = np.tile(np.r_[0, np.ones(len(angles)), np.full(len(angles), 2)], len(poses))
    assert np.all(resid[kind == 0] < 1e-9) and not np.any(flags[kind == 0] & FLAG_NOT_CONVERGED), (rng, resid)
    assert np.all(resid[kind == 1] < 1e-9), f"{rng}: {a_min} m/s^2 not reached: {resid[kind == 1]}"
    assert np.all(resid[kind == 2] > 1e-3), f"{rng}: 50 m/s^2 reached: a far stronger motor than XPlanar's"
    assert np.all((loss[kind == 0] > 20.0) & (loss[kind == 0] < 600.0)), (rng, loss[kind == 0])
