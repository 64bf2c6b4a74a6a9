"""Top-down views of big swarms: milliseconds per frame of the whole-world view and of a zoomed window.

One world of N movers at a quarter of the tiles (the swarm env's default occupancy: a square layout of
ceil(sqrt(4 N)) tiles), movers at random spots with random yaw and random states (moving, idle, collided, ...),
drawn by :func:`magwarp.render.swarm.swarm_renderer`: the whole world fitted to ``--max-px`` (dots coloured by
state), and a ``--window`` m square window at 48 pixels per tile (full detail). Prints a table (device, date,
versions, command line above it) and writes JSON.

    python benchmarks/swarm_render.py --small                   # CPU smoke check: 1k and 10k movers
    python benchmarks/swarm_render.py --json benchmarks/results/swarm_render.json   # CPU and cuda:0, up to 1M movers
"""

from __future__ import annotations

import argparse
import math
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from common import print_table, provenance, start_run, time_call, write_json  # noqa: E402

SMALL = (1_000, 10_000)
FULL = (1_000, 10_000, 100_000, 1_000_000)


def scene(movers: int, device: str, seed: int = 0):
    import torch

    from magwarp.layout import Layout

    side = math.ceil(math.sqrt(4 * movers))
    layout = Layout.grid(side, side)
    g = torch.Generator(device="cpu").manual_seed(seed)
    tiles = torch.randperm(side * side, generator=g)[:movers]
    centre = torch.stack([tiles // side, tiles % side], -1).float() + 0.5
    pos = (centre + 0.3 * (torch.rand(movers, 2, generator=g) - 0.5)) * layout.tile.size
    yaw = torch.rand(movers, generator=g) * 2 * math.pi
    state = torch.randint(0, 5, (movers,), generator=g, dtype=torch.int32)
    flags = (state == 2).to(torch.int32)
    return layout, [t[None].to(device) for t in (pos, yaw, flags, state)]


def bench(movers: int, device: str, max_px: int, window_m: float, repeats: int) -> list[dict]:
    import warp as wp

    from magwarp.layout import MoverSpec
    from magwarp.render.swarm import swarm_renderer

    layout, (pos, yaw, flags, state) = scene(movers, device)
    centre = 0.5 * layout.shape[0] * layout.tile.size
    rows = []
    for view, kwargs in (("whole", {"max_image_px": max_px}),
                         ("window", {"window": (centre, centre, window_m, window_m), "px_per_tile": 48})):
        renderer, _ = swarm_renderer(layout, MoverSpec(), device=device, **kwargs)

        def draw():
            renderer.draw(pos, yaw, flags=flags, state=state)

        mean, std, _ = time_call(draw, repeats, warmup=1, sync=lambda: wp.synchronize_device(device))
        rows.append({"device": device, "movers": movers, "tiles": layout.shape[0], "view": view,
                     "px_per_tile": renderer.px_per_tile, "image": f"{renderer.height}x{renderer.width}",
                     "ms_per_frame": mean, "std_ms": std, "frames_per_s": 1e3 / mean})
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--device", default=None, help="cpu or cuda:0 (default: the CPU, and cuda:0 when present)")
    p.add_argument("--movers", type=int, nargs="+", default=None, help="movers per world (default 1k to 1M; "
                   "--small: 1k, 10k)")
    p.add_argument("--small", action="store_true", help="a quick check: 1k and 10k movers")
    p.add_argument("--max-px", type=int, default=1024, help="longest side of the whole-world image (default 1024)")
    p.add_argument("--window", type=float, default=2.0, help="side of the zoomed window, m (default 2)")
    p.add_argument("--repeats", type=int, default=10)
    p.add_argument("--json", default=None, help="write the rows as JSON")
    args = p.parse_args(argv)
    info, devices = start_run(args.device)
    rows = []
    for device in devices:
        sizes = args.movers or (SMALL if args.small or device == "cpu" and args.device is None else FULL)
        for movers in sizes:
            rows += bench(movers, device, args.max_px, args.window, args.repeats)
    print_table(rows, ["device", "movers", "tiles", "view", "px_per_tile", "image", "ms_per_frame", "std_ms",
                       "frames_per_s"])
    if args.json:
        stamp = provenance(info)
        write_json(args.json, [{**r, **stamp} for r in rows])
        print(f"# json: {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
