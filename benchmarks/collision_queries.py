"""Batched collision queries (:mod:`magwarp.collision`) per second, beside MagBotSim's utilities in the same run.

A query answers, for one mover pose of a configuration of ``--movers`` movers, MagBotSim's two questions: does it
collide with another mover (``check_mover_collision``) and is it on the tiles (``qpos_is_valid``), with per-mover
sizes and ``add_safety_offset=True``; magwarp also returns the signed clearances (pairs, walls). Poses are random
configurations on a layout (B0's full 4x3 tiles, and a 4x4 layout with holes), circles and boxes.

magwarp is timed on each device at 1e3 .. 1e7 poses (``--max-poses-cpu`` caps the CPU sizes, default 1e5) as one
batched call; MagBotSim answers one configuration per call, so it is timed on ``--magbotsim-configs`` configurations
(its cost per configuration does not depend on the batch) and the same configurations' labels are compared.

    python benchmarks/collision_queries.py                        # CPU (+ cuda:0 when present)
    python benchmarks/collision_queries.py --devices cuda:0 --json benchmarks/results/collision_queries_gpu.json
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import numpy as np  # noqa: E402
import torch  # noqa: E402
import warp as wp  # noqa: E402

from common import header_line, machine_info, print_table, provenance, time_samples, write_json  # noqa: E402

LAYOUTS = {
    "B0": np.ones((4, 3), dtype=np.int8),
    "holes4x4": np.array([[1, 1, 1, 0], [1, 0, 1, 1], [1, 1, 1, 1], [0, 1, 1, 1]], dtype=np.int8),
}
OFFSET, OFFSET_WALL = 0.01, 0.005
SIZES = (1_000, 10_000, 100_000, 1_000_000, 10_000_000)


def random_configs(rng: np.random.Generator, tiles: np.ndarray, shape: str, configs: int, movers: int):
    """Configurations ``(configs, movers, 3)`` (x, y, yaw) spread over the layout, and per-mover sizes."""
    ext = np.array(tiles.shape) * 0.24
    xy = rng.uniform(0.0, 1.0, (configs, movers, 2)) * ext
    yaw = rng.uniform(-np.pi, np.pi, (configs, movers, 1))
    size = rng.uniform(0.05, 0.11, (configs, movers)) if shape == "circle" else rng.uniform(0.05, 0.08,
                                                                                           (configs, movers, 2))
    return np.concatenate([xy, yaw], -1).astype(np.float32), size.astype(np.float32)


def time_magwarp(tiles, shape, poses, size, device, repeats):
    from magwarp.collision import CollisionQuery

    q = CollisionQuery(tiles, shape, offset=OFFSET, offset_wall=OFFSET_WALL, device=device)
    dev = q.torch_device
    p, s = torch.as_tensor(poses, device=dev), torch.as_tensor(size, device=dev)
    out = {}

    def call():
        out["r"] = q(p, s, add_safety_offset=True)

    wall, _ = time_samples(call, repeats, warmup=2, sync=lambda: wp.synchronize_device(q.device))
    return float(np.median(wall)), out["r"]


def magbotsim_env(tiles, shape, movers):
    from magbotsim import BasicMagBotEnv

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        size = 0.1 if shape == "circle" else np.array([0.08, 0.08])
        return BasicMagBotEnv(layout_tiles=tiles, num_movers=movers, render_mode=None,
                              collision_params={"shape": shape, "size": size, "offset": OFFSET,
                                                "offset_wall": OFFSET_WALL})


def time_magbotsim(env, poses, size):
    """ms per configuration of check_mover_collision + qpos_is_valid, and its labels."""
    import time

    q = np.zeros((*poses.shape[:2], 7))
    q[..., :2] = poses[..., :2]
    q[..., 3] = np.cos(0.5 * poses[..., 2])
    q[..., 6] = np.sin(0.5 * poses[..., 2])
    size = size.astype(np.float64)
    any_hit = np.zeros(len(q), bool)
    valid = np.zeros(poses.shape[:2], bool)
    t0 = time.perf_counter()
    for k in range(len(q)):
        any_hit[k] = env.check_mover_collision(env.mover_names, size[k], True, q[k])
        valid[k] = env.qpos_is_valid(q[k], size[k], True).astype(bool)
    return (time.perf_counter() - t0) * 1e3 / len(q), any_hit, valid


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--devices", nargs="+", default=None, help="default: cpu, and cuda:0 when present")
    ap.add_argument("--movers", type=int, default=3, help="movers per configuration (B0: 3)")
    ap.add_argument("--max-poses-cpu", type=float, default=1e5, help="largest batch on the CPU (poses)")
    ap.add_argument("--max-poses-gpu", type=float, default=1e7, help="largest batch on a GPU (poses)")
    ap.add_argument("--magbotsim-configs", type=int, default=2000, help="configurations timed in MagBotSim (0: skip)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--torch-threads", type=int, default=1,
                    help="torch CPU threads (default 1: Warp's CPU kernels and MagBotSim run on one core, and torch's "
                         "pool oversubscribes a shared CPU)")
    ap.add_argument("--json", default=None, help="default: benchmarks/results/collision_queries_{cpu,gpu}.json")
    args = ap.parse_args(argv)

    wp.config.quiet = True
    wp.init()
    torch.set_num_threads(args.torch_threads)
    devices = args.devices or (["cpu", "cuda:0"] if wp.is_cuda_available() else ["cpu"])
    on_gpu = any(d.startswith("cuda") for d in devices)
    info = machine_info(next((d for d in devices if d.startswith("cuda")), "cpu"))
    print(header_line(info))
    rng = np.random.default_rng(args.seed)
    m = args.movers
    rows = []
    for layout_name, tiles in LAYOUTS.items():
        for shape in ("circle", "box"):
            largest = max(args.max_poses_gpu if on_gpu else 0, args.max_poses_cpu)
            poses_all, size_all = random_configs(rng, tiles, shape, int(largest) // m + 1, m)
            ref_ms, agree = None, None
            if args.magbotsim_configs > 0:
                try:
                    env = magbotsim_env(tiles, shape, m)
                except ImportError:
                    env = None
                if env is not None:
                    k = args.magbotsim_configs
                    ref_ms, ref_any, ref_valid = time_magbotsim(env, poses_all[:k], size_all[:k])
                    _, r = time_magwarp(tiles, shape, poses_all[:k], size_all[:k], "cpu", 1)
                    agree = float(np.mean(np.concatenate([
                        (r.any_collision.numpy() == ref_any), (r.wall_valid.numpy() == ref_valid).all(-1)])))
                    rows.append({"engine": "magbotsim", "device": "cpu", "layout": layout_name, "shape": shape,
                                 "poses": k * m, "ms": ref_ms * k, "poses_per_s": m * 1e3 / ref_ms,
                                 "speedup": 1.0, "label_agreement": agree, **provenance(info)})
            for dev in devices:
                cap = args.max_poses_gpu if dev.startswith("cuda") else args.max_poses_cpu
                for n in SIZES:
                    if n > cap:
                        break
                    c = max(1, n // m)
                    ms, _ = time_magwarp(tiles, shape, poses_all[:c], size_all[:c], dev, args.repeats)
                    rate = c * m * 1e3 / ms
                    rows.append({"engine": "magwarp", "device": dev, "layout": layout_name, "shape": shape,
                                 "poses": c * m, "ms": ms, "poses_per_s": rate,
                                 "speedup": rate / (m * 1e3 / ref_ms) if ref_ms else None,
                                 "label_agreement": None, **provenance(info)})
            print_table([r for r in rows if r["layout"] == layout_name and r["shape"] == shape],
                        ["engine", "device", "layout", "shape", "poses", "ms", "poses_per_s",
                         ("speedup", "x MagBotSim"), "label_agreement"])
    path = args.json or os.path.join(os.path.dirname(os.path.abspath(__file__)), "results",
                                     f"collision_queries_{'gpu' if on_gpu else 'cpu'}.json")
    print("wrote", write_json(path, rows))


if __name__ == "__main__":
    main()
