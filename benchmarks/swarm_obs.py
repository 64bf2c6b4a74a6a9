"""The swarm observation kernel alone (#18), by variant and by part: where its time goes.

One :class:`~magwarp.swarm.LocalObservations` per variant on the same random state (positions uniform on the
benchmark's full square layout, ``benchmarks/swarm.py``'s ``_layout``: about 0.25 movers per tile; velocities, goals
normal), each call its ``observe`` into the env's row layout (own state, k = 8 neighbour slots, 8 rays, radius and
ray range 1 m: the env's defaults). Variants (the rows of one part are compared bit for bit, ``match``):

* ``world``: the block-per-world search, staged rows, the chain into the slots, the tile walk for the rays (the
  kernel before the variants below; at 100 movers not the default on CUDA, which is ``grid``);
* ``world+rect``: the rays in closed form (:func:`~magwarp.kernels.neighbors.ray_to_rect`: the layout is full);
* ``world+merge``: the branch-free merge of every candidate into the slots;
* ``world+merge+rect``: both;
* ``world+merge+rect+sift``: and only the candidates within the radius merged (a word of 32 at a time);
* ``grid``: the grid search (binning included, three launches), the tile walk.

Parts (``world``, ``world+merge+rect`` and ``world+merge+rect+sift`` only): ``full``; ``no_rays`` (num_rays 0);
``no_nbrs`` (k 0: own state and rays); ``own`` (k 0, no rays: the row writes and the launch, a floor). Each time is
the median of 5 batches of ``--calls`` back-to-back calls (one synchronisation per batch), per call; on CUDA also
``graph_ms``, the same call recorded as one CUDA graph and replayed back to back (the kernel's device time, without
the host's per-call work that the eager time may be bound by).

    python benchmarks/swarm_obs.py --device cuda:0 --json benchmarks/results/swarm_obs_gpu.json   # 16,384 worlds
    python benchmarks/swarm_obs.py --device cpu                                                   # smoke: 8 worlds
"""

from __future__ import annotations

import argparse
import math
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from common import batched_ms, finish, start_run  # noqa: E402

OCCUPANCY = 0.25  # movers per tile (benchmarks/swarm.py)
VARIANTS = {  # name: (search, merge, rect, sift)
    "world": ("world", False, False, False),
    "world+rect": ("world", False, True, False),
    "world+merge": ("world", True, False, False),
    "world+merge+rect": ("world", True, True, False),
    "world+merge+rect+sift": ("world", True, True, True),
    "grid": ("grid", False, False, False),
}
PARTS = {"full": (8, 8), "no_rays": (8, 0), "no_nbrs": (0, 8), "own": (0, 0)}  # (k, num_rays)
PART_VARIANTS = ("world", "world+merge+rect", "world+merge+rect+sift")


def _layout(movers: int):
    from magwarp.layout import Layout

    side = int(math.ceil(math.sqrt(movers / OCCUPANCY)))
    return Layout.grid(side, side)


def _graph_ms(call, device: str, calls: int, out, want) -> float | None:
    """ms per call of ``call`` recorded as one CUDA graph and replayed back to back: the kernel's device time without
    the host's per-call work (argument conversion, launch), which the eager ``ms`` may be bound by (at 16,384 x 64 the
    ``own`` part, 16 MB of rows, took as long as ``full``, 208 MB: swarm_obs_s34_gpu.json). None if the capture fails
    or a replay writes other rows than the eager call (NaN if so)."""
    import torch

    from magwarp.envs.step_graph import record_cuda_graph

    try:
        rec = record_cuda_graph(call, torch.device(device))
    except Exception as e:  # noqa: BLE001 - the eager time stands; say why the graph one is missing
        print(f"    graph capture failed: {type(e).__name__}: {e}", flush=True)
        return None
    out.fill_(float("nan"))
    ms = batched_ms(rec.graph.replay, device, calls, warmup=3)
    return ms if torch.equal(out, want) else float("nan")


def bench(worlds: int, movers: int, device: str, calls: int) -> list[dict]:
    import torch
    import warp as wp

    from magwarp.swarm.observations import LocalObservations

    layout = _layout(movers)
    ext = np.asarray(layout.extent)
    rng = np.random.default_rng(0)
    xy = (rng.random((worlds, movers, 2)) * ext).astype(np.float32)
    pos = np.concatenate([xy, np.full((worlds, movers, 1), 0.01, np.float32)], -1)
    vel = np.concatenate([rng.normal(size=(worlds, movers, 2)), np.zeros((worlds, movers, 1))], -1).astype(np.float32)
    pos_wp = wp.array(pos, dtype=wp.vec3, device=device)
    vel_wp = wp.array(vel, dtype=wp.vec3, device=device)
    tdev = wp.device_to_torch(device)
    goals = torch.as_tensor(rng.random((worlds, movers, 2)) * ext, dtype=torch.float32, device=tdev)
    rows, ref = [], {}
    for part, (k, rays) in PARTS.items():
        for name, (search, merge, rect, sift) in VARIANTS.items():
            if part != "full" and name not in PART_VARIANTS:
                continue
            if search == "grid" and part != "full":
                continue
            obs = LocalObservations(layout, worlds, movers, k=k, num_rays=rays, radius=1.0, max_range=1.0,
                                    search=search, device=device)
            obs.merge, obs.rect, obs.sift = merge, rect, sift
            out = torch.empty(worlds, movers, 4 + obs.dim, device=tdev)

            def call(obs=obs, out=out):
                obs.observe(pos_wp, vel_wp, out, goals=goals)

            ms = batched_ms(call, device, calls, warmup=3)
            got = (out.clone(), obs.index.clone())
            graph_ms = _graph_ms(call, device, calls, out, got[0]) if device.startswith("cuda") else None
            first = ref.setdefault(part, got)
            match = bool(torch.equal(got[0], first[0]) and torch.equal(got[1], first[1]))
            row = {"device": device, "worlds": worlds, "movers": movers, "part": part, "variant": name,
                   "tiled": bool(obs.tiled and search == "world"), "ms": ms,
                   "agent_steps_per_s_obs": worlds * movers / (ms * 1e-3), "match": match,
                   "graph_ms": graph_ms, "out_mb": out.numel() * 4 / 2**20}
            rows.append(row)
            gtxt = "" if graph_ms is None else f"  graph {graph_ms:8.4f} ms"
            print(f"  {device} {worlds} x {movers} {part:8s} {name:20s} {ms:8.4f} ms{gtxt}  match {match}", flush=True)
            del obs, out
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default=None, help="cuda:0 or cpu (default: cuda:0 if present, else cpu)")
    p.add_argument("--worlds", type=int, default=None, help="worlds (default 16384 on CUDA, 8 on the CPU)")
    p.add_argument("--movers", type=int, nargs="+", default=[64, 100], help="movers per world (default 64 100)")
    p.add_argument("--calls", type=int, default=None, help="calls per timed batch (default 20 on CUDA, 2 on the CPU)")
    p.add_argument("--json", default=None, help="write the rows here")
    args = p.parse_args(argv)
    info, devices = start_run(args.device)
    device = devices[-1]
    cuda = device.startswith("cuda")
    worlds = args.worlds or (16384 if cuda else 8)
    calls = args.calls or (20 if cuda else 2)
    rows = []
    for movers in args.movers:
        rows += bench(worlds, movers, device, calls)
    bad = [r for r in rows if not r["match"]]
    if bad:
        print(f"MISMATCH: {len(bad)} variant(s) wrote other rows than the first of their part", flush=True)
    return finish(rows, ["device", "worlds", "movers", "part", "variant", "tiled", ("ms", "ms/call"),
                         ("graph_ms", "graph ms/call"),
                         ("agent_steps_per_s_obs", "agent-steps/s"), "match"], info, args.json) or int(bool(bad))


if __name__ == "__main__":
    raise SystemExit(main())
