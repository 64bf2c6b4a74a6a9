"""The paper's scalability test (MagBotSim paper, Fig. "scalability"), magwarp beside MagBotSim in the same run.

One step = apply controls to all movers, integrate one 1 ms cycle, check mover-mover and wall collisions.
Movers start at tile centres of a full square grid. Paper configurations (movers, tiles): (50, 10x10), (100, 12x12),
(200, 17x17), (400, 27x27), (1000, 57x57), for circle and box collision shapes. On a GPU it adds one world of 10k,
100k and 1M movers, and the RL regime: 16384 worlds x 3 movers (B0 layout) with a 40-cycle step.

    python benchmarks/scaling.py                      # CPU (+ CUDA when present), MagBotSim when installed
    python benchmarks/scaling.py --device cuda:0 --no-magbotsim --json out.json --plot out.png
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import numpy as np  # noqa: E402
import torch  # noqa: E402
import warp as wp  # noqa: E402

from common import print_table, provenance, start_run, write_json  # noqa: E402

PAPER_CONFIGS = ((50, 10), (100, 12), (200, 17), (400, 27), (1000, 57))
GPU_LARGE = ((10_000, 100), (100_000, 317), (1_000_000, 1000))
# Box half size as in MagBotSim's own box examples (mover half size + 1 mm), used for both engines.
BOX_HALF = (0.0785, 0.0785)


def mover_spec(shape: str):
    from magwarp.layout import MoverSpec

    return MoverSpec(collision_shape=shape, collision_half_size=BOX_HALF if shape == "box" else None)


def _sync(device: str) -> None:
    wp.synchronize_device(device)


def magwarp_step_ms(movers: int, tiles: int, shape: str, device: str, steps: int, worlds: int = 1,
                    cycles: int = 1, layout=None) -> dict:
    """Mean and std ms of one ``cycles``-cycle step (fresh commands written on the device every step)."""
    from magwarp.layout import Layout
    from magwarp.sim import Simulator

    lay = layout if layout is not None else Layout.grid(tiles, tiles)
    t0 = time.perf_counter()
    # No stop on collision: every world integrates every cycle (the worst case, and what MagBotSim's step does).
    sim = Simulator(lay, movers, worlds, mover=mover_spec(shape), device=device, check_inputs=False,
                    stop_on_collision=False)
    build_s = time.perf_counter() - t0
    gen = torch.Generator(device=sim.torch_device).manual_seed(0)
    # Small random accelerations (+-1 m/s^2) keep movers near their tiles, as in the MagBotSim measurement.
    cmds = torch.rand((8, worlds, movers, 2), generator=gen, device=sim.torch_device) * 2.0 - 1.0
    cmd = sim.cmd
    for i in range(3):  # compile + capture + warm caches
        cmd.copy_(cmds[i % 8])
        sim.step(cycles)
    _sync(device)
    samples = []
    repeats = max(1, steps // 10)
    for r in range(10):
        t = time.perf_counter()
        for i in range(repeats):
            cmd.copy_(cmds[(r * repeats + i) % 8])
            sim.step(cycles)
        _sync(device)
        samples.append((time.perf_counter() - t) / repeats * 1e3)
    arr = np.asarray(samples)
    return {"ms_per_step": float(np.median(arr)), "std_ms": float(arr.std()), "build_s": build_s,
            "collided_worlds": int((sim.flags_any != 0).any(dim=1).sum())}


def run(args) -> list[dict]:
    rows: list[dict] = []
    devices = [args.device] if args.device else (["cpu", "cuda:0"] if wp.is_cuda_available() else ["cpu"])
    shapes = args.shapes.split(",")
    configs = [c for c in PAPER_CONFIGS if c[0] <= args.max_movers]

    def add(engine, device, movers, tiles, shape, res, worlds=1, cycles=1):
        rows.append({"engine": engine, "device": device, "movers": movers, "tiles": f"{tiles}x{tiles}" if isinstance(tiles, int) else tiles,
                     "shape": shape, "worlds": worlds, "cycles": cycles, **res})
        r = rows[-1]
        print(f"  {engine:22s} {device:7s} {shape:6s} movers={movers:>8} worlds={worlds:>6} cycles={cycles:>2} "
              f"{r['ms_per_step']:.4f} ms", flush=True)

    for device in devices:
        for shape in shapes:
            for movers, tiles in configs:
                add("magwarp", device, movers, tiles, shape, magwarp_step_ms(movers, tiles, shape, device, args.steps))
            if device.startswith("cuda") and not args.skip_large:
                for movers, tiles in GPU_LARGE:
                    add("magwarp", device, movers, tiles, shape, magwarp_step_ms(movers, tiles, shape, device, args.steps))
        if device.startswith("cuda") or args.small_worlds_on_cpu:
            from magwarp.layout import benchmark_layout

            lay, m = benchmark_layout("B0")
            for worlds in ((16384, 65536) if device.startswith("cuda") else (4096,)):
                add("magwarp", device, m, "4x3 (B0)", "circle",
                    magwarp_step_ms(m, 0, "circle", device, args.steps, worlds=worlds, cycles=40, layout=lay),
                    worlds=worlds, cycles=40)

    if not args.no_magbotsim:
        import magbotsim_ref as ref

        if ref.magbotsim_available():
            for shape in shapes:
                for movers, tiles in configs:
                    for controllers in (False, True):
                        if controllers and movers > args.max_controller_movers:
                            continue
                        c_size = np.asarray(BOX_HALF) if shape == "box" else None
                        res = ref.scaling_step_ms(movers, (tiles, tiles), shape, steps=args.ref_steps,
                                                  controllers=controllers, c_size=c_size)
                        # Medians on both sides: a load spike on a shared machine moves a mean, not a median.
                        add(res["engine"], "cpu", movers, tiles, shape,
                            {"ms_per_step": res["median_ms"], "mean_ms": res["ms_per_step"], "std_ms": res["std_ms"],
                             "build_s": res["construct_s"]})
        else:
            print("magbotsim is not installed: `pip install magbotsim` to measure it side by side", file=sys.stderr)
    return rows


def ratios(rows: list[dict]) -> list[dict]:
    """magwarp speed-up over each MagBotSim variant, per (shape, movers), on each device magwarp ran on."""
    ref = {(r["engine"], r["shape"], r["movers"]): r["ms_per_step"] for r in rows if r["engine"].startswith("magbotsim")}
    out = []
    for r in rows:
        if r["engine"] != "magwarp" or r["worlds"] != 1:
            continue
        row = {"device": r["device"], "shape": r["shape"], "movers": r["movers"], "magwarp_ms": r["ms_per_step"]}
        for engine in ("magbotsim", "magbotsim-controllers"):
            base = ref.get((engine, r["shape"], r["movers"]))
            row[f"x_vs_{engine}"] = base / r["ms_per_step"] if base else None
        out.append(row)
    return out


def plot(rows: list[dict], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5), sharey=True)
    for ax, shape in zip(axes, ("circle", "box")):
        series: dict[str, list] = {}
        for r in rows:
            if r["shape"] == shape and r["worlds"] == 1:
                series.setdefault(f"{r['engine']} ({r['device']})", []).append((r["movers"], r["ms_per_step"], r.get("std_ms", 0)))
        for name, pts in sorted(series.items()):
            pts.sort()
            x, y, e = zip(*pts)
            ax.errorbar(x, y, yerr=e, marker="o", capsize=3, label=name)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("number of movers (one world)")
        ax.set_title(f"{shape} collision shape")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    axes[0].set_ylabel("ms per step (controls + 1 ms integration + collision check)")
    fig.suptitle("Scalability: one simulation step, magwarp vs MagBotSim (same machine, same run)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    print(f"wrote {path}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default=None, help="cpu or cuda:N (default: cpu, plus cuda:0 when present)")
    p.add_argument("--shapes", default="circle,box")
    p.add_argument("--steps", type=int, default=200, help="timed steps per configuration")
    p.add_argument("--max-movers", type=int, default=1000, help="largest paper configuration to run")
    p.add_argument("--skip-large", action="store_true", help="skip the 10k/100k/1M GPU configurations")
    p.add_argument("--small-worlds-on-cpu", action="store_true", help="also time 4096 B0 worlds x 40 cycles on CPU")
    p.add_argument("--no-magbotsim", action="store_true")
    p.add_argument("--ref-steps", type=int, default=100)
    p.add_argument("--max-controller-movers", type=int, default=1000)
    p.add_argument("--json", default=None, help="write the rows as JSON")
    p.add_argument("--plot", default=None, help="write a PNG plot like the paper's figure")
    args = p.parse_args(argv)
    info, _ = start_run(args.device)
    rows = run(args)
    cols = ["engine", "device", "shape", "movers", "tiles", "worlds", "cycles", ("ms_per_step", "ms/step"), ("std_ms", "std")]
    print_table(rows, cols)
    rat = ratios(rows)
    if any(r.get("x_vs_magbotsim") for r in rat):
        print("\nspeed-up of magwarp over MagBotSim (same run):")
        print_table(rat, ["device", "shape", "movers", ("magwarp_ms", "magwarp ms"), ("x_vs_magbotsim", "x vectorised"),
                          ("x_vs_magbotsim-controllers", "x with controllers")])
    if args.json:
        # A list of rows; each row carries what reproduces it (device name, date, versions, command).
        stamp = provenance(info)
        write_json(args.json, [{**r, **stamp} for r in rows])
    if args.plot:
        plot(rows, args.plot)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
