"""The wrench matrix Gamma(q) of the default magnetic design against position: a mover slides along x at a 4 mm
gap (yaw 0) over a tile, and the force per ampere of the coils near its centre is plotted against its x.

Each coil's x force and z force swing with the magnet array's period (60 mm) as its conductors pass under the poles;
a coil whose long sides run along x (the lower layer) gives y and z forces instead. The script prints the peak
force per ampere and writes a PNG.

    python examples/magnetics_gamma.py [--model fast|exact] [--points 61] [--out gamma.png]
"""

from __future__ import annotations

import argparse

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from magwarp.layout import Layout  # noqa: E402
from magwarp.magnetics.exact import ExactModel  # noqa: E402
from magwarp.magnetics.fast import FastModel  # noqa: E402
from magwarp.magnetics.geometry import MagneticParams, Quadrature  # noqa: E402


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", choices=("fast", "exact"), default="fast")
    parser.add_argument("--points", type=int, default=61)
    parser.add_argument("--coarse", action="store_true", help="a coarse quadrature (1e-3 instead of 1e-6)")
    parser.add_argument("--out", default="gamma.png")
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args(argv)

    params = MagneticParams(quadrature=Quadrature(2, 0.01)) if args.coarse else MagneticParams()
    layout = Layout.grid(2, 2)
    model = (FastModel if args.model == "fast" else ExactModel)(layout, params, device=args.device)
    xs = np.linspace(0.18, 0.30, args.points)  # one 120 mm coil length (two array periods) around the tile edge
    z = 0.004 - params.magnets.bounds[0, 2]
    poses = np.c_[xs, np.full_like(xs, 0.30), np.full_like(xs, z), np.zeros((len(xs), 3))]
    ids, count, gamma = model.evaluate(poses)
    cs = model.coilset
    # The three coils of each layer nearest the mover's path centre, followed along the whole sweep.
    mid = np.array([0.24, 0.30])
    picks = []
    for d in (1, 0):
        order = np.argsort(np.linalg.norm(cs.centers[:, :2] - mid, axis=1) + 1e3 * (cs.directions != d))
        picks += list(order[:3])
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharex=True)
    for k in picks:
        col = np.array([gamma[n][ids[n] == k][0] if (ids[n] == k).any() else np.zeros(6) for n in range(len(xs))])
        along = "y" if cs.directions[k] == 1 else "x"
        planar = 0 if along == "y" else 1
        label = f"coil {k} (long sides along {along})"
        axes[0].plot(xs * 1e3, col[:, planar], label=f"{label}: F{'xy'[planar]}")
        axes[1].plot(xs * 1e3, col[:, 2], label=f"{label}: Fz")
    for ax, title in zip(axes, ("planar force per ampere (N/A)", "vertical force per ampere (N/A)")):
        ax.set_xlabel("mover x (mm), y = 300 mm, gap 4 mm, yaw 0")
        ax.set_title(title)
        ax.grid(alpha=0.3)
    axes[1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(args.out, dpi=100)
    peak = np.abs(gamma[..., :3]).max()
    print(f"{args.model} model: {count.mean():.0f} active coils per mover on average, peak |F| per ampere "
          f"{peak:.3f} N/A; wrote {args.out}")


if __name__ == "__main__":
    main()
