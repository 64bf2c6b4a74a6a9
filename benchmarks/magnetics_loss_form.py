"""Could the magnetic drive skip the per-coil work in the control cycle? A probe of the "loss form" (#17).

When no coil saturates, the least-loss commutation delivers the wanted wrench ``w`` exactly, and its copper loss is
``w^T M(q) w`` with ``M(q) = (Gamma R^-1 Gamma^T)^-1`` (6 x 6, 21 numbers), so a cycle would need only ``M`` at the
mover's pose (and a bound that no coil saturates), not the ~28 columns of Gamma. That is cheap only if ``M`` can be
tabulated over the pose (x, y over the coil pattern's period, height, yaw) and interpolated. This script samples
``M`` with the wrench-table model (:class:`~magwarp.magnetics.table.TableModel`, the default design, an interior
tile of a 5 x 5 layout, the hover gap) along x at 1 mm steps and along yaw at 1 degree steps, and reports the loss
error of linear interpolation from coarser samples, for three wrenches (hover; hover with 10 m/s^2 along x; along y
with torques), the number of driven coils, and the largest coil leverage ``Gamma_k^T M Gamma_k / R_k`` (which bounds
a coil's share of the loss: |i_k|^2 R_k <= leverage x loss, the saturation test a loss-form cycle would use).

    python benchmarks/magnetics_loss_form.py --json benchmarks/results/magnetics_loss_form_cpu.json
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from common import finish, start_run  # noqa: E402

WRENCHES = {"hover": [0, 0, 12.2, 0, 0, 0], "hover+x": [12.4, 0, 12.2, 0, 0, 0],
            "hover+y+torque": [0, 12.4, 12.2, 0.1, 0.1, 0.05]}


def loss_form(model, poses: np.ndarray):
    """M(q) (n, 6, 6), the driven coils per pose and the largest coil leverage, uniform coil resistance."""
    ids, count, gamma = model.evaluate(poses)
    res = np.asarray(model.coilset.resistance, dtype=np.float64)
    r_inv = np.where(ids >= 0, 1.0 / res[np.maximum(ids, 0)], 0.0)  # empty slots carry nothing
    a = np.einsum("nki,nk,nkj->nij", gamma, r_inv, gamma)
    m = np.linalg.inv(a)
    leverage = (np.einsum("nki,nij,nkj->nk", gamma, m, gamma) * r_inv).max(1)
    return m, count, leverage


def interp_error(m: np.ndarray, step: int) -> dict:
    """Largest relative loss error of M linearly interpolated from every ``step``-th sample, per wrench."""
    n = m.shape[0]
    idx = np.arange(0, n, step)
    mi = np.empty_like(m)
    for a in range(6):
        for b in range(6):
            mi[:, a, b] = np.interp(np.arange(n), idx, m[idx, a, b])
    ws = np.array(list(WRENCHES.values()), dtype=np.float64)
    exact = np.einsum("wi,nij,wj->nw", ws, m, ws)
    approx = np.einsum("wi,nij,wj->nw", ws, mi, ws)
    err = np.abs(approx / exact - 1.0).max(0)
    return {name: float(e) for name, e in zip(WRENCHES, err)}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--gap", type=float, default=0.004, help="m, tile surface to the mover's bottom")
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    import warp as wp

    from magwarp.layout import Layout
    from magwarp.magnetics.table import TableModel

    info, _ = start_run("cpu")
    wp.config.quiet = True
    model = TableModel(Layout.grid(5, 5), device="cpu")
    zc = model.z0 + (args.gap - model.spec.gap[0])  # the table's first height is its lowest gap
    rows = []
    xs = 0.48 + 0.001 * np.arange(241)  # 240 mm (two coil periods) across the centre tile, 1 mm apart
    poses = np.zeros((len(xs), 6))
    poses[:, 0], poses[:, 1], poses[:, 2] = xs, 0.6, zc
    m, count, lev = loss_form(model, poses)
    for step in (2, 5, 10):
        rows.append({"axis": "x", "sample_step": f"{step} mm", **interp_error(m, step),
                     "coils_min": int(count.min()), "coils_max": int(count.max()),
                     "leverage_min": float(lev.min()), "leverage_max": float(lev.max())})
    yaws = np.radians(np.arange(91.0))  # a quarter turn (the array's period), 1 degree apart
    poses = np.zeros((len(yaws), 6))
    poses[:, 0], poses[:, 1], poses[:, 2], poses[:, 5] = 0.6, 0.6, zc, yaws
    m, count, lev = loss_form(model, poses)
    for step in (3, 6, 12):
        rows.append({"axis": "yaw", "sample_step": f"{step} deg", **interp_error(m, step),
                     "coils_min": int(count.min()), "coils_max": int(count.max()),
                     "leverage_min": float(lev.min()), "leverage_max": float(lev.max())})
    for r in rows:
        print(f"  {r['axis']} every {r['sample_step']}: loss error " +
              ", ".join(f"{k} {100 * r[k]:.1f}%" for k in WRENCHES) +
              f"; {r['coils_min']}-{r['coils_max']} coils, leverage {r['leverage_min']:.2f}-{r['leverage_max']:.2f}")
    return finish(rows, ["axis", "sample_step", *WRENCHES, "coils_min", "coils_max", "leverage_min", "leverage_max"],
                  info, args.json)


if __name__ == "__main__":
    raise SystemExit(main())
