"""How many active-set solves the commutation takes per mover (#17): the float64 reference
(:func:`magwarp.magnetics.reference.commutate`, the same steps as the Warp commutation) on the columns of
``benchmarks/magnetics.py``'s random movers (its poses on ``--tiles`` x ``--tiles`` tiles and its wanted wrenches: hover
plus planar accelerations up to 5 m/s^2). The fast cycle's second launch runs the movers that need more than one
solve; this gives its work per mover.

    python benchmarks/magnetics_solves.py --movers 3000 --json benchmarks/results/magnetics_solves_cpu.json
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import finish, start_run  # noqa: E402
from magnetics import random_poses, wanted_wrench  # noqa: E402


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--movers", type=int, default=3000)
    p.add_argument("--tiles", type=int, default=8)
    p.add_argument("--device", default="cpu", help="where the table's columns are looked up")
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
    solves, coils, at_limit, converged = [], [], [], []
    for m in range(args.movers):
        act = ids[m] >= 0
        k = ids[m][act]
        stats = {}
        _, _, sat, _, conv = ref.commutate(gamma[m][act].T, res[k], lim[k], wanted[m], stats=stats)
        solves.append(stats["solves"])
        coils.append(int(act.sum()))
        at_limit.append(int(sat.sum()))
        converged.append(bool(conv))
    solves, at_limit = np.array(solves), np.array(at_limit)
    more = solves > 1
    row = {"movers": args.movers, "tiles": args.tiles, "coils_per_mover": float(np.mean(coils)),
           "share_more_than_one_solve": float(more.mean()), "not_converged": int((~np.array(converged)).sum())}
    for name, sel in (("all", np.ones_like(more)), ("saturating", more)):
        s = solves[sel]
        row.update({f"{name}_solves_mean": float(s.mean()), f"{name}_solves_median": float(np.median(s)),
                    f"{name}_solves_p90": float(np.percentile(s, 90)), f"{name}_solves_max": int(s.max()),
                    f"{name}_coils_at_limit_mean": float(at_limit[sel].mean())})
    for key, value in row.items():
        print(f"  {key}: {value}")
    return finish([row], list(row), info, args.json)


if __name__ == "__main__":
    raise SystemExit(main())
