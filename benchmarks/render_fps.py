"""Frames per second of the top-down renderer (magwarp.render.TopDownRenderer).

Draws a mosaic of worlds of a benchmark layout (default B0: 4 x 3 tiles, 3 movers) from a synthetic scene, for a
few resolutions, and prints a table with the device, date, versions and the command line. Timing is the best of
several repeats of ``--frames`` draws (the machine may be shared), with a device synchronisation at the end.

    python benchmarks/render_fps.py                       # 64 worlds (8 x 8) of B0, Warp's default device
    python benchmarks/render_fps.py --device cpu --worlds 1 16 64 --px-per-tile 16 24 32 --plot out/render_fps.png
"""

from __future__ import annotations

import argparse
import datetime
import math
import os
import platform
import sys
import time


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--layout", default="B0", help="benchmark layout B0..B9 (default B0)")
    p.add_argument("--worlds", type=int, nargs="+", default=[64], help="worlds in the mosaic (default 64)")
    p.add_argument("--px-per-tile", type=int, nargs="+", default=[16, 24, 32], help="resolutions (pixels per tile)")
    p.add_argument("--swarm", type=int, nargs="*", default=[], help="also: one world with this many movers on a "
                   "square grid of tiles, one mover per tile (e.g. --swarm 100 1000)")
    p.add_argument("--frames", type=int, default=50, help="draws per repeat")
    p.add_argument("--repeats", type=int, default=5, help="repeats; the best is reported")
    p.add_argument("--device", default=None, help="Warp device (default: Warp's preferred device)")
    p.add_argument("--png", default=None, help="also write one frame per configuration to this PNG prefix")
    p.add_argument("--plot", default=None, help="write a plot of frames/s against image size to this PNG")
    p.add_argument("--json", default=None, help="write the rows (with device, date, versions, command) as JSON")
    return p.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    import numpy as np
    import torch
    import warp as wp

    wp.config.quiet = True
    from magwarp.layout import Layout, benchmark_layout
    from magwarp.render import SyntheticScene, save_png

    wp.init()
    device = wp.get_device(args.device)
    layout, num_movers = benchmark_layout(args.layout)
    print(f"# magwarp top-down renderer fps   date {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M UTC}")
    print(f"# device {device.alias} ({device.name}), host {platform.processor() or platform.machine()}, "
          f"python {platform.python_version()}, warp {wp.__version__}, torch {torch.__version__}, numpy {np.__version__}")
    print(f"# command: {' '.join([sys.executable.split('/')[-1]] + sys.argv)}")
    if hasattr(os, "getloadavg"):  # the machine may be shared: say how busy it was
        print(f"# load average at start: {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs")
    print(f"# layout {args.layout} {layout.shape[0]}x{layout.shape[1]} tiles, {num_movers} movers (swarms: one per tile), "
          f"goals and collision flags drawn; best of {args.repeats} repeats of {args.frames} frames (/10 for swarms)")
    print(f"{'layout':>6} {'worlds':>6} {'movers':>6} {'px/tile':>7} {'image HxW':>11} {'ms/frame':>9} {'frames/s':>9} "
          f"{'Mpixel/s':>9}")
    rows = []
    configs = [(layout, n, num_movers, f"{args.layout}") for n in args.worlds]
    for n in args.swarm:
        side = math.ceil(math.sqrt(n))
        configs.append((Layout.grid(side, side), 1, n, f"{side}x{side}"))
    for lay, num_worlds, movers, name in configs:
        scene = SyntheticScene(lay, num_worlds=num_worlds, num_movers=movers, seed=0, device=wp.device_to_torch(device))
        for _ in range(10):
            scene.step()
        a = scene.arrays()
        for ppt in args.px_per_tile:
            renderer = scene.make_renderer(px_per_tile=ppt)
            frame = renderer.draw(a["pos"], a["quat"], flags=a["collision"], goals=a["goals"])  # compile + warm up
            wp.synchronize_device(device)
            best = float("inf")
            frames = args.frames if movers <= 100 else max(2, args.frames // 10)
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                for _ in range(frames):
                    frame = renderer.draw(a["pos"], a["quat"], flags=a["collision"], goals=a["goals"])
                wp.synchronize_device(device)
                best = min(best, (time.perf_counter() - t0) / frames)
            h, w = renderer.height, renderer.width
            rows.append((num_worlds, ppt, h, w, best, movers, name))
            print(f"{name:>6} {num_worlds:>6} {movers:>6} {ppt:>7} {f'{h}x{w}':>11} {best * 1e3:>9.2f} {1.0 / best:>9.1f} "
                  f"{h * w / best / 1e6:>9.1f}")
            if args.png:
                save_png(f"{args.png}_{name}_{num_worlds}w_{movers}m_{ppt}px.png", frame)
    if args.plot:
        plot(rows, args, device)
    if args.json:
        write_rows(args.json, rows, device)
    return 0


def write_rows(path: str, rows, device) -> None:
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from common import machine_info, provenance, write_json

    info = machine_info("cuda" if device.is_cuda else "cpu")
    stamp = provenance(info)
    write_json(path, [{"layout": name, "worlds": n, "movers": m, "px_per_tile": ppt, "height": h, "width": w,
                       "ms_per_frame": t * 1e3, "frames_per_s": 1.0 / t, "device": device.alias, **stamp}
                      for n, ppt, h, w, t, m, name in rows])
    print(f"# json: {path}")


def plot(rows, args, device) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4), dpi=120)
    for key in dict.fromkeys((r[6], r[0], r[5]) for r in rows):
        pts = [(h * w / 1e6, 1.0 / t, ppt) for n, ppt, h, w, t, m, name in rows if (name, n, m) == key]
        ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", label=f"{key[1]} world(s) of {key[0]}, {key[2]} movers")
        for mp, fps, ppt in pts:
            ax.annotate(f"{ppt} px/tile", (mp, fps), textcoords="offset points", xytext=(4, 4), fontsize=7)
    ax.axhline(100, color="grey", ls="--", lw=0.8, label="100 frames/s")
    ax.set_xlabel("image size (megapixels)")
    ax.set_ylabel("frames / s (log scale)")
    ax.set_yscale("log")
    ax.set_title(f"magwarp top-down renderer, one Warp launch per frame ({device.alias})", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(args.plot)
    print(f"# plot: {args.plot}")


if __name__ == "__main__":
    sys.exit(main())
