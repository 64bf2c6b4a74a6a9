"""The fast model (a cached field table) against the exact model, its interpolation against scipy, its cache."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import RegularGridInterpolator

from magwarp.layout import Layout
from magwarp.magnetics import reference as ref
from magwarp.magnetics.exact import ExactModel
from magwarp.magnetics.fast import FastModel, FieldTableSpec
from magwarp.magnetics.geometry import MagneticParams, Quadrature

# The default array with a coarse quadrature (the same in both models: the test compares the field models, not the
# quadrature), a smaller active radius and a coarser table than the default (2 s to build on a CPU, not 7 s).
PARAMS = MagneticParams(quadrature=Quadrature(order=2, max_interval=0.01), active_radius=0.2)
SPEC = FieldTableSpec(step=0.002, z_step=0.001, margin=0.08)
LAYOUT = Layout.grid(2, 2)


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    mp = pytest.MonkeyPatch()
    cache = tmp_path_factory.mktemp("magnetics_cache")
    mp.setenv("MAGWARP_CACHE_DIR", str(cache))
    fast = FastModel(LAYOUT, PARAMS, SPEC, device="cpu")
    yield ExactModel(LAYOUT, PARAMS, device="cpu"), fast, cache
    mp.undo()


def test_fast_matches_exact_within_one_percent_of_peak(models, rng):
    exact, fast, _ = models
    n = 4
    spec = fast.spec
    poses = np.c_[rng.uniform(0.12, 0.36, n), rng.uniform(0.12, 0.36, n), rng.uniform(*spec.gap, n) + 0.006,
                  rng.uniform(-0.02, 0.02, (n, 2)), rng.uniform(-np.pi, np.pi, n)]
    ids, count, g_exact = exact.evaluate(poses)
    ids_f, count_f, g_fast = fast.evaluate(poses)
    assert np.array_equal(ids, ids_f) and count.min() > 10
    peak_f = np.linalg.norm(g_exact[..., :3], axis=-1).max()
    peak_t = np.linalg.norm(g_exact[..., 3:], axis=-1).max()
    err_f = np.abs(g_fast - g_exact)[..., :3].max() / peak_f
    err_t = np.abs(g_fast - g_exact)[..., 3:].max() / peak_t
    assert err_f < 0.01 and err_t < 0.01, f"{rng}: force error {err_f:.3%}, torque error {err_t:.3%} of the peak"
    assert err_f > 0 and fast.out_of_range == 0


def test_table_interpolation_matches_scipy(models, rng):
    """The kernel's trilinear interpolation of the table equals scipy's on the same samples; zero beyond x/y."""
    _, fast, _ = models
    data = fast.source.field.numpy().astype(np.float64)
    origin = np.array([float(fast.source.origin[i]) for i in range(3)])
    step = 1.0 / np.array([float(fast.source.inv_step[i]) for i in range(3)])
    axes = [origin[i] + step[i] * np.arange(data.shape[i]) for i in range(3)]
    lo, hi = np.array([a[0] for a in axes]), np.array([a[-1] for a in axes])
    pts = rng.uniform(lo, hi, (500, 3))
    want = RegularGridInterpolator(axes, data)(pts)
    assert np.allclose(fast.field(pts), want, rtol=1e-10, atol=1e-12), rng
    outside = pts.copy()
    outside[:, 0] = hi[0] + 0.01
    assert np.all(fast.field(outside) == 0.0)
    # The samples are the exact field (float32).
    i, j, k = (rng.integers(0, s, 20) for s in data.shape[:3])
    grid_pts = np.stack([axes[0][i], axes[1][j], axes[2][k]], axis=1)
    assert np.allclose(data[i, j, k], ref.array_field(PARAMS.magnets, grid_pts), rtol=1e-6, atol=1e-7), rng


def test_out_of_range_is_counted_and_cache_reused(models):
    exact, fast, cache = models
    files = sorted(cache.glob("field_table-*.npz"))
    assert len(files) == 1
    again = FastModel(LAYOUT, PARAMS, SPEC, device="cpu")  # loads the file
    assert np.array_equal(again.source.field.numpy(), fast.source.field.numpy())
    assert sorted(cache.glob("field_table-*.npz")) == files
    other = FastModel(LAYOUT, PARAMS, FieldTableSpec(step=0.004, z_step=0.002, margin=0.04), device="cpu")
    assert len(list(cache.glob("field_table-*.npz"))) == 2 and other.source.field.shape != fast.source.field.shape
    before = again.out_of_range
    again.evaluate(np.array([[0.24, 0.24, 0.03, 0.0, 0.0, 0.0]]))  # 24 mm gap: above the table's range
    assert again.out_of_range > before


def test_gamma_example_runs(tmp_path):
    """examples/magnetics_gamma.py plots Gamma against position and prints its peak force per ampere."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    path = os.pathsep.join([str(root), *filter(None, [os.environ.get("PYTHONPATH")])])  # keep the caller's paths
    env = {**os.environ, "PYTHONPATH": path, "MAGWARP_CACHE_DIR": str(tmp_path)}
    out = tmp_path / "gamma.png"
    proc = subprocess.run([sys.executable, str(root / "examples" / "magnetics_gamma.py"), "--model", "exact",
                           "--coarse", "--points", "4", "--out", str(out)], capture_output=True, text=True, env=env,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "exact model:" in proc.stdout and out.stat().st_size > 10_000, proc.stdout
    peak = float(proc.stdout.split("peak |F| per ampere ")[1].split(" N/A")[0])
    assert 1.0 < peak < 3.0, peak
