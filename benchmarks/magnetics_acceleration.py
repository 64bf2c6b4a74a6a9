"""The default magnetic design's acceleration at the current limit: per random pose and hover gap, the largest planar
acceleration each of 8 directions reaches while the mover hovers (force z = m g, no torque) with every coil within
its current limit, by linear programming on the exact model's wrench matrix. The worst direction of each pose is what
a controller can count on; XPlanar's data sheet says 10 m/s^2.

    python benchmarks/magnetics_acceleration.py --poses 300 --json benchmarks/results/magnetics_acceleration_cpu.json

tests/test_magnetics_defaults.py asks for a little less than the minimum this measures.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import numpy as np  # noqa: E402

from common import print_table, provenance, start_run, write_json  # noqa: E402

G = 9.81


def best_acceleration(gamma: np.ndarray, limits: np.ndarray, mass: float, angle: float) -> float:
    """max a such that Gamma i = (m a cos, m a sin, m g, 0, 0, 0) with |i_k| <= limits_k (``gamma`` is 6 x n)."""
    from scipy.optimize import linprog

    n = gamma.shape[1]
    a_eq = np.zeros((6, n + 1))
    a_eq[:, :n] = gamma
    a_eq[0, n], a_eq[1, n] = -mass * np.cos(angle), -mass * np.sin(angle)
    res = linprog(np.r_[np.zeros(n), -1.0], A_eq=a_eq, b_eq=[0, 0, mass * G, 0, 0, 0],
                  bounds=[(-v, v) for v in limits] + [(0, None)], method="highs")
    return float(res.x[n]) if res.success else 0.0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--poses", type=int, default=300, help="random poses per gap (x, y over the middle tile, yaw 0)")
    p.add_argument("--gaps", default="0.003,0.005", help="hover gaps in m, comma separated")
    p.add_argument("--directions", type=int, default=8)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", default=None, help="default: benchmarks/results/magnetics_acceleration_cpu.json")
    args = p.parse_args(argv)
    info, _ = start_run("cpu")
    os.environ.setdefault("MAGWARP_CACHE_DIR", tempfile.mkdtemp())
    from magwarp.layout import Layout, MoverSpec
    from magwarp.magnetics.exact import ExactModel
    from magwarp.magnetics.geometry import MagneticParams, Quadrature

    # the tests' coarse quadrature (1e-3 relative): ample for figures
    model = ExactModel(Layout.grid(3, 3), MagneticParams(quadrature=Quadrature(order=2, max_interval=0.01)),
                       device="cpu")
    mass = MoverSpec().mass
    limits_all = np.broadcast_to(np.asarray(model.coilset.current_limit, float), (model.coilset.num_coils,))
    angles = np.linspace(0, 2 * np.pi, args.directions, endpoint=False)
    rng = np.random.default_rng(args.seed)
    rows = []
    for gap in (float(g) for g in args.gaps.split(",")):
        n = args.poses
        poses = np.c_[rng.uniform(0.24, 0.48, n), rng.uniform(0.24, 0.48, n), np.full(n, gap + 0.006), np.zeros((n, 3))]
        pos, quat = model.as_arrays(poses)
        ids, count = model.active_coils(pos)
        gamma, ids, count = model.wrench_matrix(pos, quat, ids).numpy(), ids.numpy(), count.numpy()
        best = np.array([[best_acceleration(gamma[k][:count[k]].T, limits_all[ids[k][:count[k]]], mass, a)
                          for a in angles] for k in range(n)])
        worst = best.min(axis=1)
        rows.append({"gap_mm": 1e3 * gap, "poses": n, "directions": args.directions,
                     "worst_min": float(worst.min()), "worst_p5": float(np.percentile(worst, 5)),
                     "worst_median": float(np.median(worst)), "all_median": float(np.median(best)),
                     "all_max": float(best.max()), **provenance(info)})
    print_table(rows, ["gap_mm", "poses", ("worst_min", "worst dir. min (m/s^2)"), ("worst_p5", "worst dir. p5"),
                       ("worst_median", "worst dir. median"), ("all_median", "median"), ("all_max", "max")])
    path = args.json or os.path.join(os.path.dirname(os.path.abspath(__file__)), "results",
                                     "magnetics_acceleration_cpu.json")
    write_json(path, rows)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
