"""The swarm env's placement alone (#18), by the shape of its rounds (``search="world"``): one thread per mover of
every world (threads past the list's count exit) checking a round's tries in one of the :attr:`magwarp.swarm.
Placer.scan` shapes (``serial``: :func:`~magwarp.kernels.placement.propose`, one try and one mover after another;
``chunked``: :func:`~magwarp.kernels.placement.make_scan_propose`, the world's movers read a chunk at a time),
against the lane shape (a group of ``lanes`` threads per listed mover in a fixed grid walking the list,
:attr:`~magwarp.swarm.Placer.lanes`) and the grid's cell lists (``search="grid"``), with a bit-for-bit check of the
spots and of the movers left against ``serial`` (``match``).

Each row is one call as the env's step makes it (:meth:`~magwarp.swarm.Placer.place_device`: the list, two rounds of
``propose`` and ``resolve``, ``hold``) from the same state and the same random streams every call:

* ``respawn``: the respawn placer (offset ``collision_offset + respawn_clearance / 2``) re-placing a random
  ``--respawn-fraction`` of the movers (default 0.18: measured on the CPU at 256 worlds x 64 movers with
  ``benchmarks/swarm.py``'s ``seek_goals`` actions, 2,790-2,950 of 16,384 movers per step, and 186,616 of 1,048,576
  on an H100 at 16,384 worlds; most of them find no spot in 8 tries: 7% of tries succeed);
* ``goal``: the goal placer (offset ``collision_offset``) re-placing ``--goal-fraction`` (default 0.004: 46-66 of
  16,384 per step on the CPU) of the goals among the others.

Every row but ``grid`` uses ``search="world"`` (the default on CUDA up to 160 movers per world). State
(``--state``): ``random`` (default: every mover placed by the env's reset placer, the movers to place drawn at
random) or ``env`` (the env's own respawn requests after ``--env-steps`` fused steps of ``seek_goals``: the real
pattern, at the price of compiling the fused step). Times: the median of 5 batches of ``--calls`` calls, per call,
launched one by one (wall clock: the host's launch cost is in it, about 0.4 ms a call on the H100 machine, so small
requests measure the host; the env's step replays the same launches as one CUDA graph). A CUDA graph of the call
alone (``torch.cuda.graph``) was tried on the H100 on 2026-12-07 and its capture was invalidated
(``cudaErrorStreamCaptureInvalidated``): not debugged, removed; ``benchmarks/swarm.py`` times the env's graph step.

    python benchmarks/swarm_place.py --device cuda:0 --json benchmarks/results/swarm_place_gpu.json   # 16,384 worlds
    python benchmarks/swarm_place.py --device cpu                                                   # smoke: 32 worlds
"""

from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from common import batched_ms, finish, start_run, sync_device  # noqa: E402

from magwarp.swarm.placement import SCAN_SHAPES  # noqa: E402

#: the rounds' shapes compared (None: the default)
LANES = (None, 1, 2, 4, 8, 16, 32)


def _requests(worlds: int, movers: int, device: str, args) -> list[tuple[str, object, object, object]]:
    """(name, placer, start positions, mask) of each request."""
    import torch

    from magwarp.swarm import SwarmConfig
    from magwarp.swarm.placement import Placer
    from swarm import _layout, seek_goals

    cfg = SwarmConfig()
    if args.state == "env":
        from magwarp.swarm import SwarmEnv

        env = SwarmEnv(worlds, num_movers=movers, layout=_layout(movers), device=device, seed=0, check_inputs=False,
                       fused=True, graph=False)
        for _ in range(args.env_steps):
            env.step(seek_goals(env))
        out = [("respawn", env.respawn_placer, env.sim.pos[..., :2].contiguous().clone(),
                env._want_respawn.clone())]
        out.append(("goal", env.placer, env.goals.contiguous().clone(), env._want_goal.clone()))
        return out
    lay, mover = _layout(movers), cfg.make_mover()
    start = Placer(lay, movers, worlds, mover=mover, offset=cfg.collision_offset, device=device, seed=0).sample()
    gen = torch.Generator(device=start.device).manual_seed(0)
    out = []
    for name, offset, frac, seed in (("respawn", cfg.collision_offset + 0.5 * cfg.respawn_clearance,
                                      args.respawn_fraction, 1), ("goal", cfg.collision_offset, args.goal_fraction, 0)):
        placer = Placer(lay, movers, worlds, mover=mover, offset=offset, device=device, seed=seed)
        mask = torch.rand((worlds, movers), generator=gen, device=start.device) < frac
        out.append((name, placer, start.clone(), mask))
    return out


def bench(worlds: int, movers: int, device: str, calls: int, variants, args) -> list[dict]:
    """One row per request and variant ``(name, search, lanes, scan)``; the first variant is the reference."""
    import torch
    import warp as wp

    rows = []
    for name, placer, start, mask in _requests(worlds, movers, device, args):
        calls0, default, search, shape = placer._calls, placer.lanes, placer.search, placer.scan
        ref = base = None
        for label, place_search, lanes, scan in variants:
            placer.search = place_search
            try:
                placer.lanes = lanes
            except ValueError as exc:  # e.g. lanes > 1 on a CPU without cpu blocks
                print(f"  skip lanes={lanes}: {exc}", flush=True)
                continue
            placer.scan = scan
            xy = start.clone()

            def place():
                placer._calls = calls0  # the same random streams every call
                xy.copy_(start)
                return placer.place_device(xy, mask, rounds=2, hold=True)

            ms = batched_ms(place, device, calls, warmup=2)
            todo = wp.to_torch(place()).clone()
            sync_device(device)
            got = (xy.clone(), todo)
            if ref is None:
                ref, base = got, ms
            match = bool(torch.equal(got[0], ref[0]) and torch.equal(got[1], ref[1]))
            asked = int(mask.sum())
            left = int((todo != 0)[mask].sum())
            row = {"device": device, "worlds": worlds, "movers": movers, "state": args.state, "request": name,
                   "search": placer.search, "variant": label, "lanes": "default" if lanes is None else lanes,
                   "scan": scan, "ms": ms, "asked": asked, "left": left, "match": match,
                   "speedup": base / ms}
            rows.append(row)
            print(f"  {device} {worlds} x {movers} {name}: {label}: {ms:.4f} ms/call ({asked} asked, {left} left), "
                  f"x{row['speedup']:.2f}, match {match}", flush=True)
        placer.lanes, placer._calls, placer.search, placer.scan = default, calls0, search, shape
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default=None, help="cuda:0 or cpu (default: cuda:0 if present, else cpu)")
    p.add_argument("--worlds", type=int, default=None, help="worlds (default 16384 on CUDA, 32 on the CPU)")
    p.add_argument("--movers", type=int, nargs="+", default=[64, 100], help="movers per world (default 64 100)")
    p.add_argument("--lanes", default=None, help="comma-separated lane counts after the two one-thread shapes "
                   "(default 1,2,4,8,16,32; '' for none)")
    p.add_argument("--calls", type=int, default=None, help="calls per timed batch (default 20 on CUDA, 2 on the CPU)")
    p.add_argument("--state", choices=("random", "env"), default="random")
    p.add_argument("--env-steps", type=int, default=30, help="fused env steps before the env state is taken")
    p.add_argument("--respawn-fraction", type=float, default=0.18)
    p.add_argument("--goal-fraction", type=float, default=0.004)
    p.add_argument("--json", default=None, help="write the rows here")
    args = p.parse_args(argv)
    info, devices = start_run(args.device)
    device = devices[-1]
    cuda = device.startswith("cuda")
    if not cuda:
        import warp as wp

        wp.config.enable_cpu_blocks = True  # the lanes' votes by blocks (the GPU's warp votes' logic)
    worlds = args.worlds or (16384 if cuda else 32)
    calls = args.calls or (20 if cuda else 2)
    lanes_list = LANES[1:] if args.lanes is None else tuple(int(v) for v in args.lanes.split(",") if v)
    variants = [(shape, "world", None, shape) for shape in SCAN_SHAPES]
    variants += [(f"lanes {n}", "world", n, "serial") for n in lanes_list] + [("grid", "grid", None, "serial")]
    rows = []
    for movers in args.movers:
        rows += bench(worlds, movers, device, calls, variants, args)
    bad = [r for r in rows if not r["match"]]
    if bad:
        print(f"MISMATCH: {len(bad)} row(s) placed other spots than the serial shape", flush=True)
    code = finish(rows, ["device", "worlds", "movers", "request", "variant", ("ms", "ms/call"), "asked", "left",
                         "speedup", "match"], info, args.json)
    return code or int(bool(bad))


if __name__ == "__main__":
    raise SystemExit(main())
