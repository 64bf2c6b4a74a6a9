"""How many active-set solves the commutation takes per mover (#17): the float64 reference
(:func:`magwarp.magnetics.reference.commutate`, the same steps as the Warp commutation) on the columns of
``benchmarks/magnetics.py``'s random movers (its poses on ``--tiles`` x ``--tiles`` tiles and its wanted wrenches: hover
plus planar accelerations up to 5 m/s^2). The fast cycle's second launch runs the movers that need more than one
solve; this gives its work per mover, split by whether the last system needed regularisation (near-infeasible
wrenches, most coils at their limits). ``--newton`` also counts a semi-smooth Newton method's solves on the saturating
movers whose wrench is delivered (a candidate for fewer solves; not what the commutation runs).

    python benchmarks/magnetics_solves.py --movers 3000 --newton --json benchmarks/results/magnetics_solves_cpu.json
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import finish, start_run  # noqa: E402
from magnetics import random_poses, wanted_wrench  # noqa: E402


def newton_solves(gamma, resistance, limit, wrench, want, max_iter: int = 64, tol: float = 1e-9) -> int:
    """Solves a semi-smooth Newton method on the wrench's 6 multipliers takes to reach the currents ``want`` (within
    ``tol`` A): the currents are ``clamp(g_k . y / R_k, -limit, limit)``, each step solves with the free coils' matrix
    (as an active-set solve does) for the multipliers that deliver the wrench, starting from the unconstrained solve;
    -1 where it does not get there in ``max_iter`` solves (a full step, no line search)."""
    y = np.zeros(6)
    for n in range(1, max_iter + 1):
        cur = np.clip((gamma.T @ y) / resistance, -limit, limit)
        free = np.abs(gamma.T @ y / resistance) < limit if n > 1 else np.ones(len(limit), dtype=bool)
        a = (gamma[:, free] / resistance[free]) @ gamma[:, free].T
        residual = wrench - gamma @ cur if n > 1 else wrench
        y = y + np.linalg.solve(a + 1e-12 * np.eye(6), residual)
        if np.abs(np.clip((gamma.T @ y) / resistance, -limit, limit) - want).max() <= tol:
            return n
    return -1


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--movers", type=int, default=3000)
    p.add_argument("--tiles", type=int, default=8)
    p.add_argument("--device", default="cpu", help="where the table's columns are looked up")
    p.add_argument("--newton", action="store_true",
                   help="also count a semi-smooth Newton method's solves on the saturating movers it can reach")
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    from magwarp.layout import Layout
    from magwarp.magnetics import reference as ref
    from magwarp.magnetics.geometry import MagneticParams
    from magwarp.magnetics.table import TableModel

    info, _ = start_run(args.device)
    params = MagneticParams()
    table = TableModel(Layout.grid(args.tiles, args.tiles), params, device=args.device)
    rng = np.random.default_rng(0)
    poses = random_poses(rng, args.movers, args.tiles, float(params.magnets.bounds[0, 2]))
    wanted = wanted_wrench(rng, args.movers)
    ids, gamma, _ = table.columns(*table.as_arrays(poses))
    ids, gamma = ids.numpy(), gamma.numpy().astype(np.float64)
    res, lim = table.coilset.resistance, table.coilset.current_limit
    solves, coils, at_limit, converged, newton, regularised = [], [], [], [], [], []
    for m in range(args.movers):
        act = ids[m] >= 0
        k = ids[m][act]
        stats = {}
        cur, _, sat, regd, conv = ref.commutate(gamma[m][act].T, res[k], lim[k], wanted[m], stats=stats)
        solves.append(stats["solves"])
        regularised.append(bool(regd))
        if args.newton:
            newton.append(newton_solves(gamma[m][act].T, res[k], lim[k], wanted[m], cur)
                          if conv and not regd and stats["solves"] > 1 else 0)
        coils.append(int(act.sum()))
        at_limit.append(int(sat.sum()))
        converged.append(bool(conv))
    solves, at_limit, regularised = np.array(solves), np.array(at_limit), np.array(regularised)
    more = solves > 1
    row = {"movers": args.movers, "tiles": args.tiles, "coils_per_mover": float(np.mean(coils)),
           "share_more_than_one_solve": float(more.mean()), "not_converged": int((~np.array(converged)).sum())}
    groups = {"all": np.ones_like(more), "saturating": more, "saturating_regularised": more & regularised,
              "saturating_unregularised": more & ~regularised}
    for name, sel in groups.items():
        row[f"{name}_movers"] = int(sel.sum())
        if not sel.any():
            continue
        s = solves[sel]
        row.update({f"{name}_solves_mean": float(s.mean()), f"{name}_solves_median": float(np.median(s)),
                    f"{name}_solves_p90": float(np.percentile(s, 90)), f"{name}_solves_max": int(s.max()),
                    f"{name}_coils_at_limit_mean": float(at_limit[sel].mean())})
    if args.newton:  # the saturating movers whose wrench the reference delivers (converged, not regularised)
        nw = np.array(newton)
        done = nw > 0
        row.update({"newton_movers": int(done.sum() + (nw < 0).sum()), "newton_failed": int((nw < 0).sum()),
                    "newton_solves_mean": float(nw[done].mean()), "newton_solves_max": int(nw[done].max()),
                    "active_set_solves_mean_same_movers": float(solves[done].mean())})
    for key, value in row.items():
        print(f"  {key}: {value}")
    return finish([row], list(row), info, args.json)


if __name__ == "__main__":
    raise SystemExit(main())
