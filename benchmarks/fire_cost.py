"""Cost of the B0 env's reset firing alone (#24: ~30 us of the +29 % that full randomisation costs at 65,536 envs on an
H100): one :meth:`~magwarp.envs.planar_randomization.PlanarRandomizer.reset_in_step` (the launch the fused step's
graph holds) timed by itself, in us per firing, for masks of 0, 1, 6, 25 and 100 % of the worlds (random, fixed seed),
for each candidate way of firing and for diagnostic kernels that split the time into its parts.

    python benchmarks/fire_cost.py --device cuda:0 --json fire_cost_gpu.json     # 65,536 and 16,384 envs
    python benchmarks/fire_cost.py --device cpu --num-envs 512                     # smoke test (no graph)

The env: ``magwarp/TrajectoryPlanningB0-v0`` with benchmarks/randomization.py's ``full`` settings (3 movers, 8 reset
items per mover: 14 draws), built and reset with seed 0; its ``PlanarRandomizer`` (``env.randomizer``) fires.
Timing on CUDA: ``--graph-firings`` (20) firings captured in one CUDA graph (``wp.ScopedCapture``), replayed
``--replays`` times between two CUDA events, the median of ``--repeats`` such runs divided by the firings; on the CPU
the same firings timed eagerly (wall clock). The firings advance the counters (each draws new numbers: the cost is
the same).

Candidates (the ``PlanarRandomizer``'s launch of :func:`magwarp.kernels.randomize.fire_terms` over (world, mover)
threads): ``grid`` (Warp's 256 threads a block, the default until 2026-12-06), ``grid/bN`` (N threads a block;
``grid/b64`` is the default on CUDA since), ``grid/world`` (one thread per world, all its movers; the default block).
Before it is timed, each candidate is checked on the device against the default firing: from the same state, one
firing for the 1, 6 and 100 % masks must write the same bits (parameters, sizes, margins, body rows, counters):
column ``same_bits``. The compact (the masked worlds listed in the graph, then a dense grid over the list), split (the
list, then a thread per (world, item) drawing and one per (world, mover) packing), lean (row loaded first, stores
after the last draw) and register-capped (64) variants were measured on 2026-12-06 (an H100,
benchmarks/results/fire_cost_s34_gpu.json) and removed: at 65,536 envs and 6 % resetting, 24.4 (compact), 20.2
(compact, 64 a block), 30.9 (compact, lean), 22.9 (compact, an eighth of the grid), 25.5 (split), 64.2 (grid, lean)
and 23.0 (grid, 64 registers) us per firing against grid's 26.1 and grid/b64's 20.0.

Diagnostics (timing only, over the grid of (world, mover) threads with 256 a block, each a kernel of this script):
``d:empty`` (a launch of one thread: the graph's per-kernel floor), ``d:mask`` (read the mask, exit), ``d:counter``
(the masked threads advance their counter), ``d:pack`` (pack_mover and the counter, no draws), ``d:draws`` (the
draws, their sum stored once, no field written), ``d:draws_write`` (the draws and their writes, no packing).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from common import finish, start_run  # noqa: E402

import warp as wp  # noqa: E402

from magwarp.kernels import randomize as krand  # noqa: E402
from magwarp.kernels.params import MoverParams, pack_mover  # noqa: E402
from magwarp.types import Body  # noqa: E402

ENV_ID = "magwarp/TrajectoryPlanningB0-v0"
PCTS = (0, 1, 6, 25, 100)
CHECK_PCTS = (1, 6, 100)

#: candidate -> PlanarRandomizer attributes (``_per_thread`` "world": all of a world's targets in one thread)
CANDIDATES = {
    "grid": {"fire_block": 0},
    "grid/b128": {"fire_block": 128},
    "grid/b64": {"fire_block": 64},
    "grid/b32": {"fire_block": 32},
    "grid/world": {"_per_thread": "world"},
}
DIAGNOSTICS = ("d:empty", "d:mask", "d:counter", "d:pack", "d:draws", "d:draws_write")


@wp.kernel
def diag_empty(counter: wp.array2d(dtype=wp.int32)):
    pass


@wp.kernel
def diag_mask(mask: wp.array(dtype=wp.bool), never: int, counter: wp.array2d(dtype=wp.int32)):
    w, j = wp.tid()
    if mask[w] and j == never:  # never true (never = -1): the mask read is kept, nothing else done
        counter[w, 0] = 0


@wp.kernel
def diag_counter(mask: wp.array(dtype=wp.bool), counter: wp.array2d(dtype=wp.int32)):
    w, j = wp.tid()
    if not mask[w]:
        return
    counter[w, j] = counter[w, j] + 1


@wp.kernel
def diag_pack(mask: wp.array(dtype=wp.bool), params: MoverParams, counter: wp.array2d(dtype=wp.int32),
              body: wp.array2d(dtype=Body)):
    w, j = wp.tid()
    if not mask[w]:
        return
    if j < body.shape[1]:
        body[w, j] = pack_mover(params, w, j)
    counter[w, j] = counter[w, j] + 1


@wp.kernel
def diag_draws(mask: wp.array(dtype=wp.bool), items: wp.array(dtype=krand.Item), first: wp.array(dtype=wp.int32),
               key: wp.array(dtype=wp.int32), counter: wp.array2d(dtype=wp.int32),
               scratch: wp.array2d(dtype=wp.float64)):
    w, j = wp.tid()
    if not mask[w]:
        return
    count = counter[w, j]
    seed = krand.world_seed(key[0], count, w)
    acc = wp.float64(0.0)
    for q in range(first[j], first[j + 1]):
        v = krand.draw_item(items[q], seed)
        acc = acc + v[0] + v[1] + v[2]
    scratch[w, j] = acc
    counter[w, j] = count + 1


@wp.kernel
def diag_draws_write(mask: wp.array(dtype=wp.bool), items: wp.array(dtype=krand.Item),
                     first: wp.array(dtype=wp.int32), key: wp.array(dtype=wp.int32),
                     counter: wp.array2d(dtype=wp.int32), params: MoverParams, radius: wp.array2d(dtype=float),
                     half_size: wp.array2d(dtype=wp.vec2), margins: wp.array(dtype=wp.vec2)):
    w, j = wp.tid()
    if not mask[w]:
        return
    count = counter[w, j]
    seed = krand.world_seed(key[0], count, w)
    for q in range(first[j], first[j + 1]):  # (the reset list holds only winners)
        krand.fire_item(items[q], seed, w, params, radius, half_size, margins)
    counter[w, j] = count + 1


def make_env(device: str, num_envs: int):
    import gymnasium as gym

    import magwarp  # noqa: F401  (registers the ids)
    from randomization import ENVS

    env = gym.make_vec(ENV_ID, num_envs=num_envs, device=device, check_inputs=False, **ENVS[ENV_ID]["full"]).unwrapped
    env.reset(seed=0)
    return env


def apply(r, attrs: dict) -> dict:
    """Set a candidate's attributes on randomizer ``r``; returns the previous values (to restore)."""
    width = r._counter.shape[1]
    old = {k: getattr(r, k) for k in attrs}
    for k, v in attrs.items():
        setattr(r, k, width if v == "world" else v)
    return old


def diagnostic(r, name: str):
    """A function launching diagnostic ``name`` for a mask (on Warp's current stream)."""
    sim, dev = r.sim, r.sim.device
    W, width = r.num_worlds, r._counter.shape[1]
    m = sim.model
    params = sim.mover_param_struct(r._scale_inertia())
    counter, key = wp.from_torch(r._counter), wp.from_torch(r._key)
    items, first = r._items["reset"], r._first["reset"]
    scratch = wp.zeros((W, width), dtype=wp.float64, device=dev)

    def fire(mask_wp):
        if name == "d:empty":
            wp.launch(diag_empty, dim=1, device=dev, inputs=[counter])
        elif name == "d:mask":
            wp.launch(diag_mask, dim=(W, width), device=dev, inputs=[mask_wp, -1, counter])
        elif name == "d:counter":
            wp.launch(diag_counter, dim=(W, width), device=dev, inputs=[mask_wp, counter])
        elif name == "d:pack":
            wp.launch(diag_pack, dim=(W, width), device=dev, inputs=[mask_wp, params, counter, m.body])
        elif name == "d:draws":
            wp.launch(diag_draws, dim=(W, width), device=dev, inputs=[mask_wp, items, first, key, counter, scratch])
        elif name == "d:draws_write":
            wp.launch(diag_draws_write, dim=(W, width), device=dev,
                      inputs=[mask_wp, items, first, key, counter, params, m.radius, m.half_size, m.margins])
        else:
            raise ValueError(name)

    return fire


def time_us(fire, device: str, graph_firings: int, replays: int, repeats: int) -> float:
    """Median us per call of ``fire()`` (see the module doc)."""
    fire()  # loads the modules, warms the caches
    fire()
    wp.synchronize_device(device)
    runs = []
    if device.startswith("cuda"):
        with wp.ScopedCapture(device=device) as cap:
            for _ in range(graph_firings):
                fire()
        wp.capture_launch(cap.graph)
        wp.synchronize_device(device)
        for _ in range(repeats):
            start, end = wp.Event(device, enable_timing=True), wp.Event(device, enable_timing=True)
            wp.record_event(start)
            for _ in range(replays):
                wp.capture_launch(cap.graph)
            wp.record_event(end)
            wp.synchronize_event(end)
            runs.append(wp.get_event_elapsed_time(start, end) * 1e3 / (replays * graph_firings))
    else:
        for _ in range(repeats):
            t0 = time.perf_counter()
            for _ in range(graph_firings):
                fire()
            wp.synchronize_device(device)
            runs.append((time.perf_counter() - t0) * 1e6 / graph_firings)
    return statistics.median(runs)


def snapshot(env) -> list:
    """(array, copy) of everything a firing writes (to compare it bit for bit and to restore it)."""
    sim, r = env.sim, env.randomizer
    arrays = [sim.model.body, sim.model.radius, sim.model.half_size, sim.model.margins, wp.from_torch(r._counter)]
    arrays += [wp.from_torch(t) for t in sim.mover_params.values()]
    return [(a, wp.clone(a)) for a in arrays]


def restore(snap) -> None:
    for a, saved in snap:
        wp.copy(a, saved)


def state_bytes(snap) -> list[bytes]:
    """The arrays' current contents (body rows field by field: the struct's padding bytes are not compared)."""
    out = []
    for a, _ in snap:
        v = a.numpy()
        if v.dtype.names:
            out += [v[f].tobytes() for f in v.dtype.names]
        else:
            out.append(v.tobytes())
    return out


def same_bits(env, attrs: dict, masks: dict) -> bool:
    """One firing of the candidate (``attrs``) against one of the default, from the same state, for each mask."""
    r = env.randomizer
    snap = snapshot(env)
    ok = True
    for pct in CHECK_PCTS:
        r.reset_in_step(masks[pct])
        want = state_bytes(snap)
        restore(snap)
        old = apply(r, attrs)
        r.reset_in_step(masks[pct])
        apply(r, old)
        ok = ok and state_bytes(snap) == want
        restore(snap)
    return ok


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default="cuda:0", help="cuda:N or cpu (a smoke test)")
    p.add_argument("--num-envs", default="65536,16384", help="comma-separated sizes")
    p.add_argument("--variants", default=None,
                   help=f"comma-separated candidates and diagnostics (default: all: {', '.join(CANDIDATES)}, "
                        f"{', '.join(DIAGNOSTICS)})")
    p.add_argument("--graph-firings", type=int, default=20)
    p.add_argument("--replays", type=int, default=25)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    names = args.variants.split(",") if args.variants else [*CANDIDATES, *DIAGNOSTICS]
    unknown = [n for n in names if n not in CANDIDATES and n not in DIAGNOSTICS]
    if unknown:
        p.error(f"unknown variant(s) {', '.join(unknown)}")
    import torch

    info, _ = start_run(args.device)
    device = args.device
    rows = []
    for n in (int(s) for s in args.num_envs.split(",")):
        env = make_env(device, n)
        r = env.randomizer
        gen = torch.Generator(device=env.device).manual_seed(0)
        u = torch.rand(n, device=env.device, generator=gen)
        masks = {pct: (u < pct / 100.0) for pct in PCTS}
        masks[100] = torch.ones(n, dtype=torch.bool, device=env.device)
        print(f"  {device} num_envs={n}: masks of {', '.join(str(int(masks[p].sum())) for p in PCTS)} worlds; "
              f"{r._items['reset'].shape[0]} reset items over {r._counter.shape[1]} movers; per_thread "
              f"{r._per_thread}", flush=True)
        for name in names:
            row = {"device": device, "num_envs": n, "variant": name,
                   "kind": "candidate" if name in CANDIDATES else "diagnostic", "same_bits": None}
            if name in CANDIDATES:
                attrs = dict(CANDIDATES[name])
                row["same_bits"] = same_bits(env, attrs, masks)
                old = apply(r, attrs)
                try:
                    for pct in PCTS:
                        row[f"us_{pct}"] = time_us(lambda m=masks[pct]: r.reset_in_step(m), device,
                                                   args.graph_firings, args.replays, args.repeats)
                finally:
                    apply(r, old)
            else:
                fire = diagnostic(r, name)
                for pct in PCTS:
                    mask_wp = wp.from_torch(masks[pct], dtype=wp.bool)
                    row[f"us_{pct}"] = time_us(lambda m=mask_wp: fire(m), device, args.graph_firings, args.replays,
                                               args.repeats)
            rows.append(row)
            print(f"  {device} num_envs={n} {name}: " + ", ".join(f"{pct}% {row[f'us_{pct}']:.1f}" for pct in PCTS)
                  + " us" + ("" if row["same_bits"] is None else f"; same bits: {row['same_bits']}"), flush=True)
        del env
    bad = [r["variant"] for r in rows if r["same_bits"] is False]
    if bad:
        print(f"  DIFFERENT BITS: {', '.join(sorted(set(bad)))}", flush=True)
    columns = ["num_envs", "variant", "kind", *[(f"us_{p}", f"us @{p}%") for p in PCTS], "same_bits"]
    # the larger sizes last (a log's tail shows them): rows by num_envs, then as run
    finish(sorted(rows, key=lambda r: r["num_envs"]), columns, info, args.json)
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
