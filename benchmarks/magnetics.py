"""The magnetic model's speed and accuracy: wrench-matrix and commutation evaluations per second, the fast model's
error against the exact model, and the exact model against magpylib (CPU) for the same wrenches, in one run.

Per device and mover count (movers at random poses over an 8 x 8-tile layout, 3-5 mm gaps, any yaw):
* ``gamma``: the coils + the wrench matrix Gamma(q) of every mover: the wrench-table model (``table``, one launch:
  :mod:`magwarp.magnetics.table`) at ``--sizes``, the field-table quadrature model (``fast``) at ``--fast-sizes``,
  the exact model at ``--exact-sizes``; then w = Gamma i (not for ``table``: the commutation delivers it);
* ``commutation``: least-loss currents for a hover-and-accelerate wrench per mover, given Gamma;
* ``cycle``: both (one control cycle: for ``table``, the issue's <= 2 ms at 1M movers on the GPU); ``fused_cycle``
  (``table`` only): the same cycle in one launch, one block of threads per mover (:mod:`magwarp.magnetics.cycle`,
  the pre-cycle hook's cycle), with its largest current difference from the two launches; ``thread_*_cycle``
  (``table`` only): the one-thread-per-mover cycle (:mod:`magwarp.magnetics.thread_cycle`, what the in-step drive
  runs) in float32 / float64 arithmetic, with or without writing coil ids and columns, with its largest current
  difference from the block cycle (all movers, and those neither regularised) and its share of equal flags;
* ``table_variant`` (``--table-variants``): smaller wrench tables (to fit a GPU's L2): their size, the one-thread
  cycle's time at the largest size and their error against the exact model;
* ``sim``: one 40-cycle step of the B0 layout (3 movers per world) with the ideal model and with
  ``force_model="magnetic"`` (:class:`magwarp.magnetics.drive.MagneticDrive`) in each of ``--drive-variants`` (in the
  step kernels in float64 / float32, or the pre-cycle hook; the first is reported as ``magnetic``), and each one's
  share of the ideal speed; ``env``: the same for the ``magwarp/TrajectoryPlanningB0-v0`` env's env-steps/s (the
  issue's >= 25%);
* ``fast_cycle`` (``--fast-cycle-sizes``): the block cycle beside the fast cycle (:mod:`magwarp.magnetics.fast_cycle`:
  a few lanes per mover, the no-saturation answer first) and its variants, with their current differences;
* ``sweep``: the shipped B0 policy's success rate and copper energy per goal with the ideal model and with the
  magnetic model as the coil current limit falls (``--limits``; ``magwarp eval`` with ``force_model``).
Also: the table and fast models' largest column error as a share of the peak force and torque against the exact
model, over random poses in the hover range and any yaw, level and tilted (``--accuracy-poses``); the copper loss
of hovering with the footprint's coils against every coil within the 1e-4 radius (``footprint`` rows); and
magpylib's ``getFT`` on the CPU for the same currents and poses as the exact model (``--magpylib-movers``): its time
per mover, the ratio, and how far the two wrenches differ.

    python benchmarks/magnetics.py --device cpu --json benchmarks/results/magnetics_cpu.json   # CPU
    python benchmarks/magnetics.py --device cpu --sizes 10,100 --cpu-sim-worlds 2 --env-envs 2 --json /tmp/m.json
    python benchmarks/magnetics.py --device cuda:0 --json benchmarks/results/magnetics_gpu.json   # the GPU run
    python benchmarks/magnetics.py --device cuda:0 --accuracy-poses 8 --magpylib-movers 0 --limits '' \
        --fast-sizes '' --exact-sizes '' --table-variants default,yaw24,gap25_55,yaw24_gap25_55 --per-cycle \
        --env-steps 10 --json benchmarks/results/magnetics_cycle_gpu.json   # the control cycle's variants (#17)
    python benchmarks/magnetics.py --device cuda:0 --fast-cycle-only --fast-cycle-sizes 1000,100000,1000000 \
        --json benchmarks/results/magnetics_fast_cycle_gpu.json   # the block cycle beside the fast cycle (#17)
"""

from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import numpy as np  # noqa: E402
import warp as wp  # noqa: E402

from common import finish, provenance, start_run, time_call, write_json  # noqa: E402

GAP = (0.003, 0.005)


def random_poses(rng, n: int, tiles: int, bottom: float) -> np.ndarray:
    ext = 0.24 * tiles
    return np.c_[rng.uniform(0.1, ext - 0.1, (n, 2)), rng.uniform(*GAP, n) - bottom,
                 rng.uniform(-0.01, 0.01, (n, 2)), rng.uniform(-np.pi, np.pi, n)]


def wanted_wrench(rng, n: int, mass: float = 1.24) -> np.ndarray:
    """Hover plus a random planar acceleration up to 5 m/s^2 and small torques."""
    acc = rng.uniform(-5.0, 5.0, (n, 2))
    return np.c_[mass * acc, np.full(n, mass * 9.81), rng.uniform(-0.02, 0.02, (n, 3))]


def time_model(model, com, poses: np.ndarray, wrench: np.ndarray, repeats: int, block_dims=()) -> dict:
    """Milliseconds per call of the Gamma evaluation, the commutation and both, for all movers at once: the table
    model's coils + columns (one launch), or another model's active coils, Gamma and w = Gamma i; for the table
    model also the one-launch cycle, with the commutation's threads per mover and each of ``block_dims``."""
    from magwarp.magnetics.exact import vec6d

    dev = model.device
    pos, quat = model.as_arrays(poses)
    if hasattr(model, "columns"):  # the wrench-table model
        ids, gamma, count = model.columns(pos, quat)

        def gamma_eval():
            model.columns(pos, quat, ids, gamma, count)
    else:
        ids, count = model.active_coils(pos)
        gamma = model.wrench_matrix(pos, quat, ids)
        w_out = model.wrench(gamma, wp.zeros(ids.shape, dtype=wp.float64, device=dev))

        def gamma_eval():
            model.active_coils(pos, ids, count)
            model.wrench_matrix(pos, quat, ids, gamma)
            model.wrench(gamma, res.currents, w_out)
    w_in = wp.array(wrench, dtype=vec6d, device=dev)
    res = com.solve(gamma, ids, count, w_in)

    def commutate():
        com.solve(gamma, ids, count, w_in, res)

    def cycle():
        gamma_eval()
        commutate()

    calls = [("gamma", gamma_eval), ("commutation", commutate), ("cycle", cycle)]
    thread_res = {}
    if hasattr(model, "columns"):  # the same cycle in one launch (magwarp.magnetics.cycle)
        from magwarp.magnetics.commutation import CommutationResult
        from magwarp.magnetics.cycle import ControlCycle

        from magwarp.magnetics.commutation import Commutation

        f_res = CommutationResult.zeros(*ids.shape, dev)
        f_ids, f_gamma, f_count = wp.empty_like(ids), wp.empty_like(gamma), wp.empty_like(count)
        for b in [None, *block_dims]:
            c = com if b is None else Commutation(com.coilset, com.options, dev, block_dim=b)
            fused = ControlCycle(model, c)
            calls.append(("fused_cycle" if b is None else f"fused_cycle_b{b}",
                          lambda f=fused: f.run(pos, quat, w_in, f_ids, f_gamma, f_count, f_res)))
        calls += thread_calls(model, com, pos, quat, w_in, ids.shape, thread_res)
    sync = lambda: wp.synchronize_device(dev)  # noqa: E731
    out = {}
    for name, fn in calls:
        out[f"{name}_ms"] = time_call(fn, repeats, warmup=1, sync=sync)[2]
    if hasattr(model, "columns"):  # the one-launch cycle gives the two launches' answer, and one thread per mover's
        calls[3][1]()
        for name, r in thread_res.items():  # the one-thread cycles against the block cycle (float64)
            diff = np.abs(r.currents.numpy() - f_res.currents.numpy()).max(axis=1)
            same = r.flags.numpy() == f_res.flags.numpy()
            regd = ((r.flags.numpy() | f_res.flags.numpy()) & 1) != 0
            out[f"{name}_max_current_diff_a"] = float(diff.max())
            out[f"{name}_max_current_diff_unregularised_a"] = float(diff[~regd].max()) if (~regd).any() else 0.0
            out[f"{name}_same_flags_share"] = float(same.mean())
        # one thread per mover on the CPU: the block sums against a plain loop (on a CPU: the same kernel)
        cpu = [wp.clone(a, device="cpu") for a in (gamma, ids, count, w_in)]
        one = Commutation(com.coilset, com.options, "cpu", block_dim=1).solve(*cpu)
        for key, r in (("fused", res), ("one_thread", one)):
            out[f"{key}_max_current_diff_a"] = float(np.abs(f_res.currents.numpy() - r.currents.numpy()).max())
            out[f"{key}_same_flags"] = bool(np.array_equal(f_res.flags.numpy(), r.flags.numpy()))
    flags = res.flags.numpy()
    out.update(active_coils_mean=float(count.numpy().mean()), saturated_movers=int((res.saturated.numpy() != 0)
               .any(axis=1).sum()), flagged_movers=int((flags != 0).sum()),
               loss_w_mean=float(res.loss.numpy().mean()), slots=int(ids.shape[1]))
    return out


#: The one-thread cycles timed beside the block cycle: (name, precision, write coil ids, write columns).
THREAD_VARIANTS = [("thread_f32", "float32", False, False), ("thread_f64", "float64", False, False),
                   ("thread_f64_ids", "float64", True, False), ("thread_f32_cols", "float32", True, True)]


def thread_calls(model, com, pos, quat, w_in, shape, results: dict) -> list:
    """``(name, call)`` of every one-thread cycle variant (:mod:`magwarp.magnetics.thread_cycle`); ``results`` gets
    each variant's :class:`CommutationResult`."""
    from magwarp.magnetics.commutation import CommutationResult, vec6f
    from magwarp.magnetics.thread_cycle import ThreadCycle

    dev = model.device
    calls = []
    count = wp.empty(shape[0], dtype=wp.int32, device=dev)
    for name, precision, with_ids, with_gamma in THREAD_VARIANTS:
        res = results[name] = CommutationResult.zeros(*shape, dev)
        cyc = ThreadCycle(model, com, precision)
        t_ids = wp.empty(shape, dtype=wp.int32, device=dev) if with_ids else None
        t_gamma = wp.empty(shape, dtype=vec6f, device=dev) if with_gamma else None
        calls.append((f"{name}_cycle", lambda c=cyc, r=res, i=t_ids, g=t_gamma: c.run(pos, quat, w_in, r, count, i,
                                                                                        g)))
    return calls


def speed_rows(args, device: str, params, spec) -> list[dict]:
    from magwarp.layout import Layout
    from magwarp.magnetics.commutation import Commutation
    from magwarp.magnetics.exact import ExactModel
    from magwarp.magnetics.fast import FastModel
    from magwarp.magnetics.table import TableModel

    layout = Layout.grid(args.tiles, args.tiles)
    gpu = device.startswith("cuda")
    t0 = time.perf_counter()
    table = TableModel(layout, params, args.table_spec, device=device)
    table_build_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    fast = FastModel(layout, params, spec, device=device)
    build_s = time.perf_counter() - t0
    exact = ExactModel(layout, params, device=device)
    com = Commutation(fast.coilset, device=device)
    rng = np.random.default_rng(0)
    bottom = float(params.magnets.bounds[0, 2])
    rows = []
    plan = [("table", table, n) for n in (args.sizes if gpu else args.cpu_sizes)]
    plan += [("fast", fast, n) for n in (args.fast_sizes if gpu else args.cpu_fast_sizes)]
    plan += [("exact", exact, n) for n in (args.exact_sizes if gpu else args.cpu_exact_sizes)]
    for name, model, n in plan:
        poses = random_poses(rng, n, args.tiles, bottom)
        res = time_model(model, com, poses, wanted_wrench(rng, n), args.repeats,
                         args.block_dims if gpu and name == "table" else ())
        row = {"device": device, "model": name, "movers": n, **res,
               "gamma_per_s": n / (res["gamma_ms"] * 1e-3), "commutation_per_s": n / (res["commutation_ms"] * 1e-3),
               "cycle_per_s": n / (res["cycle_ms"] * 1e-3)}
        fused = ""
        if "fused_cycle_ms" in res:
            row["fused_cycle_per_s"] = n / (res["fused_cycle_ms"] * 1e-3)
            fused = (f"  fused cycle {res['fused_cycle_ms']:.3f} ms (block_dim {com.block_dim}; max current diff "
                     f"{res['fused_max_current_diff_a']:.1e} A, same flags {res['fused_same_flags']}; against one "
                     f"thread per mover on the CPU {res['one_thread_max_current_diff_a']:.1e} A, same flags "
                     f"{res['one_thread_same_flags']})")
            for b in (args.block_dims if gpu else ()):
                fused += f", block_dim {b}: {res[f'fused_cycle_b{b}_ms']:.3f} ms"
            for t in THREAD_VARIANTS:
                row[f"{t[0]}_cycle_per_s"] = n / (res[f"{t[0]}_cycle_ms"] * 1e-3)
                fused += (f"\n      one thread per mover {t[0]}: {res[f'{t[0]}_cycle_ms']:.3f} ms (max current diff "
                          f"{res[f'{t[0]}_max_current_diff_a']:.1e} A, unregularised movers "
                          f"{res[f'{t[0]}_max_current_diff_unregularised_a']:.1e} A, same flags "
                          f"{res[f'{t[0]}_same_flags_share']:.2%})")
        if name == "fast":
            row.update(table_mb=fast.table_bytes / 1e6, table_build_s=build_s)
        if name == "table":
            row.update(table_mb=table.table_bytes / 1e6, table_build_s=table_build_s)
        rows.append(row)
        print(f"  {device:7s} {name:5s} movers={n:>8}  gamma {res['gamma_ms']:.3f} ms  commutation "
              f"{res['commutation_ms']:.3f} ms  cycle {res['cycle_ms']:.3f} ms{fused}", flush=True)
    return rows


#: Smaller wrench tables (``--table-variants``), to fit a GPU's L2 cache (50 MB on an H100): fewer yaw samples, fewer
#: heights (2.5-5.5 mm: 4 heights of 1 mm instead of 5 over 2-6 mm), both.
TABLE_VARIANTS = {"default": {}, "yaw24": {"yaw_steps": 24}, "gap25_55": {"gap": (0.0025, 0.0055)},
                  "yaw24_gap25_55": {"yaw_steps": 24, "gap": (0.0025, 0.0055)},
                  "yaw16": {"yaw_steps": 16}}


def table_variant_rows(args, device: str, params) -> list[dict]:
    """Per table variant: its size, the one-thread cycles' time at the largest mover count (float32 and float64
    arithmetic, no columns written) and, with ``--accuracy-poses``, its largest column error against the exact model
    (level poses over its gaps, any yaw)."""
    from dataclasses import replace

    from magwarp.layout import Layout
    from magwarp.magnetics.commutation import Commutation, CommutationResult
    from magwarp.magnetics.exact import ExactModel, vec6d
    from magwarp.magnetics.table import TableModel
    from magwarp.magnetics.thread_cycle import ThreadCycle

    gpu = device.startswith("cuda")
    n = (args.sizes if gpu else args.cpu_sizes)[-1]
    layout = Layout.grid(args.tiles, args.tiles)
    bottom = float(params.magnets.bounds[0, 2])
    rows = []
    for name in args.table_variants:
        spec = replace(args.table_spec, **TABLE_VARIANTS[name])
        t0 = time.perf_counter()
        table = TableModel(layout, params, spec, device=device)
        row = {"device": device, "table_variant": name, "table_spec": repr(spec), "table_mb": table.table_bytes / 1e6,
               "table_build_s": time.perf_counter() - t0, "movers": n}
        com = Commutation(table.coilset, device=device)
        rng = np.random.default_rng(0)
        pos, quat = table.as_arrays(random_poses(rng, n, args.tiles, bottom))
        w_in = wp.array(wanted_wrench(rng, n), dtype=vec6d, device=device)
        res = CommutationResult.zeros(n, table.max_active, device)
        for precision in ("float32", "float64"):
            cyc = ThreadCycle(table, com, precision)
            row[f"thread_{precision}_cycle_ms"] = time_call(lambda c=cyc: c.run(pos, quat, w_in, res), args.repeats,
                                                            warmup=1, sync=lambda: wp.synchronize_device(device))[2]
        if args.accuracy_poses > 0:
            small = TableModel(Layout.grid(4, 4), params, spec, device=device)
            exact = ExactModel(Layout.grid(4, 4), params, device=device)
            row.update(table_accuracy(small, exact, spec, params, args.accuracy_poses, 0.0,
                                      np.random.default_rng(5)))
        rows.append(row)
        print(f"  table {name}: {row['table_mb']:.1f} MB, one-thread cycle of {n} movers float32 "
              f"{row['thread_float32_cycle_ms']:.3f} ms, float64 {row['thread_float64_cycle_ms']:.3f} ms"
              + (f", force error {row['force_error_share']:.3%}, torque error {row['torque_error_share']:.3%}"
                 if "force_error_share" in row else ""), flush=True)
    return rows


#: The fast cycle's variants timed beside the block cycle (``--fast-cycle-sizes``): (name, FastCycle options, write
#: coil ids and columns). ``fast`` is the default (16 lanes on a GPU, the straight-line first kernel); ``fast_loop``
#: runs the general mover stopped after its first solve in the first kernel (the default until 2026-12-07).
FAST_VARIANTS = [("fast", {}, False), ("fast_ids_cols", {}, True), ("fast_loop", {"straight": False}, False),
                 ("fast_l8", {"lanes": 8}, False), ("fast_l32", {"lanes": 32}, False),
                 ("fast_r128", {"max_registers": 128}, False), ("fast_rb64", {"rest_block": 64}, False),
                 ("fast_rb32", {"rest_block": 32}, False), ("fast_rb16", {"rest_block": 16}, False)]


def fast_cycle_rows(args, device: str, params) -> list[dict]:
    """The block cycle (:class:`~magwarp.magnetics.cycle.ControlCycle`, one block of 32 threads per mover, coil ids
    and columns written) beside the fast cycle (:class:`~magwarp.magnetics.fast_cycle.FastCycle`: 8 lanes per mover,
    the fast path, then the active-set steps of the movers it left) and its variants, at each of
    ``--fast-cycle-sizes`` movers (the speed rows' poses and wrenches): ms per cycle, the largest current difference
    from the block cycle (all movers, unregularised ones), equal saturations and flags, the movers sent on to the
    active-set steps. Every kernel is compiled first, in parallel."""
    from magwarp.layout import Layout
    from magwarp.magnetics.commutation import Commutation, CommutationResult, vec6f
    from magwarp.magnetics.cycle import ControlCycle
    from magwarp.magnetics.exact import vec6d
    from magwarp.magnetics.fast_cycle import FastCycle
    from magwarp.magnetics.table import TableModel

    gpu = device.startswith("cuda")
    table = TableModel(Layout.grid(args.tiles, args.tiles), params, args.table_spec, device=device)
    com = Commutation(table.coilset, device=device)
    variants = FAST_VARIANTS if gpu else [v for v in FAST_VARIANTS if not v[1]]
    if args.fast_variants:
        unknown = sorted(set(args.fast_variants) - {v[0] for v in FAST_VARIANTS})
        if unknown:
            raise SystemExit(f"unknown --fast-variants {unknown}; known: {[v[0] for v in FAST_VARIANTS]}")
        variants = [v for v in variants if v[0] in args.fast_variants or v[0] == "fast"]
    cycles = {name: FastCycle(table, com, **opts) for name, opts, _ in variants}
    block = ControlCycle(table, com)
    from magwarp.magnetics.cycle import cycle_kernel

    kernels = [cycle_kernel] + [k for c in cycles.values() for k in ((c.first_kernel, c.rest_kernel) if c.split
                                                                      else (c.kernel,))]
    t0 = time.perf_counter()
    wp.force_load(device, modules=list({id(k.module): k.module for k in kernels}.values()), max_workers=8)
    print(f"  fast cycle: kernels compiled in {time.perf_counter() - t0:.1f} s", flush=True)
    bottom = float(params.magnets.bounds[0, 2])
    rows = []
    sync = lambda: wp.synchronize_device(device)  # noqa: E731
    for n in args.fast_cycle_sizes:
        rng = np.random.default_rng(0)
        pos, quat = table.as_arrays(random_poses(rng, n, args.tiles, bottom))
        w_in = wp.array(wanted_wrench(rng, n), dtype=vec6d, device=device)
        slots = table.max_active
        ids, count = wp.empty((n, slots), dtype=wp.int32, device=device), wp.empty(n, dtype=wp.int32, device=device)
        gamma = wp.empty((n, slots), dtype=vec6f, device=device)
        ref = CommutationResult.zeros(n, slots, device)
        row = {"device": device, "movers": n, "slots": slots, "gpu_lanes": cycles["fast"].lanes}
        row["block_cycle_ms"] = time_call(lambda: block.run(pos, quat, w_in, ids, gamma, count, ref), args.repeats,
                                          warmup=1, sync=sync)[2]
        flags = ref.flags.numpy()
        regd = (flags & 1) != 0
        row.update(saturated_movers=int(ref.saturated.numpy().any(axis=1).sum()), regularised_movers=int(regd.sum()))
        for name, _, with_cols in variants:
            cyc, res = cycles[name], CommutationResult.zeros(n, slots, device)
            f_ids = wp.empty_like(ids) if with_cols else None
            f_gamma = wp.empty_like(gamma) if with_cols else None
            row[f"{name}_ms"] = time_call(lambda c=cyc, r=res, i=f_ids, g=f_gamma: c.run(pos, quat, w_in, r, count, i,
                                                                                          g), args.repeats, warmup=1,
                                          sync=sync)[2]
            diff = np.abs(res.currents.numpy() - ref.currents.numpy()).max(axis=1)
            row[f"{name}_max_current_diff_a"] = float(diff.max())
            row[f"{name}_max_current_diff_unregularised_a"] = float(diff[~regd].max()) if (~regd).any() else 0.0
            row[f"{name}_same_flags"] = bool(np.array_equal(res.flags.numpy(), flags))
            row[f"{name}_same_saturated"] = bool(np.array_equal(res.saturated.numpy(), ref.saturated.numpy()))
            if cyc.split:
                row[f"{name}_rest_movers"] = cyc.rest_movers
        row["fast_speedup"] = row["block_cycle_ms"] / row["fast_ms"]
        rows.append(row)
        print(f"  {device} fast cycle, {n} movers: block {row['block_cycle_ms']:.3f} ms, "
              + ", ".join(f"{v[0]} {row[f'{v[0]}_ms']:.3f} ms" for v in variants)
              + f" (x{row['fast_speedup']:.1f}; max current diff {row['fast_max_current_diff_a']:.1e} A, unregularised "
              f"{row['fast_max_current_diff_unregularised_a']:.1e} A, same flags {row['fast_same_flags']}, same "
              f"saturations {row['fast_same_saturated']}; {row.get('fast_rest_movers', '-')} movers to the active-set "
              f"steps, {row['saturated_movers']} saturated, {row['regularised_movers']} regularised)", flush=True)
    print("\n  | movers | block cycle ms | " + " | ".join(f"{v[0]} ms" for v in variants) + " | speedup |")
    print("  |---" * (len(variants) + 3) + "|")
    for r in rows:
        print(f"  | {r['movers']:,} | {r['block_cycle_ms']:.3f} | "
              + " | ".join(f"{r[f'{v[0]}_ms']:.3f}" for v in variants) + f" | {r['fast_speedup']:.1f}x |")
    return rows


def table_accuracy(table, exact, spec, params, n: int, tilt: float, rng) -> dict:
    """Largest |Gamma_table - Gamma_exact| as a share of the peak column force and torque over ``n`` random poses
    (drawn from ``rng``) at the table's gaps, tilted up to ``tilt``, any yaw."""
    lo, hi = spec.gap
    poses = np.c_[rng.uniform(0.25, 0.71, (n, 2)), rng.uniform(lo, hi, n) - float(params.magnets.bounds[0, 2]),
                  rng.uniform(-tilt, tilt, (n, 2)), rng.uniform(-np.pi, np.pi, n)]
    ids, _, gt = table.evaluate(poses)
    pos, quat = exact.as_arrays(poses)
    ge = exact.wrench_matrix(pos, quat, wp.array(ids, dtype=wp.int32, device=exact.device)).numpy()
    pf, pt = np.linalg.norm(ge[..., :3], axis=-1).max(), np.linalg.norm(ge[..., 3:], axis=-1).max()
    return {"poses": n, "max_tilt_rad": tilt, "force_error_share": float(np.abs(gt - ge)[..., :3].max() / pf),
            "torque_error_share": float(np.abs(gt - ge)[..., 3:].max() / pt), "peak_force_n_per_a": float(pf),
            "peak_torque_nm_per_a": float(pt)}


def accuracy_rows(args, device: str, params, spec) -> list[dict]:
    """Largest |Gamma_model - Gamma_exact| as a share of the peak column force and torque, over random poses: the
    wrench-table model (level, and tilted by up to 2 mrad) and the field-table model (tilts up to 0.02 rad)."""
    from magwarp.layout import Layout
    from magwarp.magnetics.exact import ExactModel
    from magwarp.magnetics.table import TableModel

    layout = Layout.grid(4, 4)
    exact, table = ExactModel(layout, params, device=device), TableModel(layout, params, args.table_spec,
                                                                          device=device)
    rows = [accuracy_row(args, device, params, spec)]
    rng = np.random.default_rng(3)
    n = args.accuracy_poses
    for tilt in (0.0, 0.002):
        ts = args.table_spec
        row = {"device": device, "model": "table", "gap_range_m": list(ts.gap),
               **table_accuracy(table, exact, ts, params, n, tilt, rng), "out_of_range": table.out_of_range,
               "table_mb": table.table_bytes / 1e6, "table_step_m": ts.step, "table_z_step_m": ts.z_step,
               "table_yaw_steps": ts.yaw_steps, "footprint_m": ts.footprint}
        rows.append(row)
        print(f"  table vs exact over {n} poses (tilt <= {tilt} rad): force error {row['force_error_share']:.3%}, "
              f"torque error {row['torque_error_share']:.3%} of the peak column", flush=True)
    return rows


def footprint_rows(args, device: str, params) -> list[dict]:
    """Copper loss of hovering (least-loss, no limits) with the footprint's coils and with every coil within the
    1e-4 radius, at random level poses (float64 least squares on the exact model's columns)."""
    from magwarp.layout import Layout
    from magwarp.magnetics import reference as ref
    from magwarp.magnetics.exact import ExactModel

    layout = Layout.grid(4, 4)
    exact = ExactModel(layout, params, device=device)
    rng = np.random.default_rng(4)
    n = args.accuracy_poses
    poses = np.c_[rng.uniform(0.3, 0.66, (n, 2)), rng.uniform(*GAP, n) - float(params.magnets.bounds[0, 2]),
                  np.zeros((n, 2)), rng.uniform(-np.pi, np.pi, n)]
    ids, _, g = exact.evaluate(poses)
    hover = np.array([0.0, 0.0, 1.24 * 9.81, 0.0, 0.0, 0.0])
    r = exact.coilset.resistance[0]
    fp = args.table_spec.footprint
    ratios, counts = [], []
    for m in range(n):
        act = ids[m] >= 0
        near = np.isin(ids[m], ref.active_coils(exact.coilset, poses[m:m + 1, :2], fp)[0]) & act
        loss = [r * np.sum(np.linalg.lstsq(g[m][sel].T, hover, rcond=None)[0] ** 2) for sel in (near, act)]
        ratios.append(loss[0] / loss[1])
        counts.append(int(near.sum()))
    row = {"device": device, "poses": n, "footprint_m": fp, "active_radius_m": exact.active_radius,
           "footprint_coils_mean": float(np.mean(counts)), "radius_coils_mean": float((ids >= 0).sum(1).mean()),
           "hover_loss_ratio_max": float(np.max(ratios)), "hover_loss_ratio_mean": float(np.mean(ratios))}
    print(f"  footprint {fp} m ({row['footprint_coils_mean']:.1f} coils) vs radius {exact.active_radius:.3f} m "
          f"({row['radius_coils_mean']:.1f} coils): hover loss x{row['hover_loss_ratio_mean']:.4f} mean, "
          f"x{row['hover_loss_ratio_max']:.4f} max", flush=True)
    return [row]


def accuracy_row(args, device: str, params, spec) -> dict:
    """Largest |Gamma_fast - Gamma_exact| as a share of the peak column force and torque, over random poses."""
    from magwarp.layout import Layout
    from magwarp.magnetics.exact import ExactModel
    from magwarp.magnetics.fast import FastModel

    layout = Layout.grid(4, 4)
    exact, fast = ExactModel(layout, params, device=device), FastModel(layout, params, spec, device=device)
    rng = np.random.default_rng(1)
    n = args.accuracy_poses
    lo, hi = spec.gap
    poses = np.c_[rng.uniform(0.25, 0.71, (n, 2)), rng.uniform(lo, hi, n) - float(params.magnets.bounds[0, 2]),
                  rng.uniform(-0.02, 0.02, (n, 2)), rng.uniform(-np.pi, np.pi, n)]
    _, _, ge = exact.evaluate(poses)
    _, _, gf = fast.evaluate(poses)
    pf, pt = np.linalg.norm(ge[..., :3], axis=-1).max(), np.linalg.norm(ge[..., 3:], axis=-1).max()
    row = {"device": device, "model": "fast", "poses": n, "gap_range_m": list(spec.gap), "max_tilt_rad": 0.02,
           "force_error_share": float(np.abs(gf - ge)[..., :3].max() / pf),
           "torque_error_share": float(np.abs(gf - ge)[..., 3:].max() / pt),
           "peak_force_n_per_a": float(pf), "peak_torque_nm_per_a": float(pt), "out_of_range": fast.out_of_range,
           "table_mb": fast.table_bytes / 1e6, "table_step_m": spec.step, "table_z_step_m": spec.z_step,
           "table_margin_m": spec.margin}
    print(f"  fast vs exact over {n} poses: force error {row['force_error_share']:.3%}, torque error "
          f"{row['torque_error_share']:.3%} of the peak column", flush=True)
    return row


def magpylib_rows(args, device: str, params) -> list[dict]:
    """The exact model (``device``) and magpylib's getFT (CPU) for the same poses and currents."""
    import magpylib as magpy
    from scipy.spatial.transform import Rotation

    from magwarp.layout import Layout
    from magwarp.magnetics import reference as ref
    from magwarp.magnetics.exact import ExactModel

    layout = Layout.grid(args.tiles, args.tiles)
    exact = ExactModel(layout, params, device=device)
    rng = np.random.default_rng(2)
    n_gpu = max(args.magpylib_movers, (args.exact_sizes if device.startswith("cuda") else args.cpu_exact_sizes)[-1])
    poses = random_poses(rng, n_gpu, args.tiles, float(params.magnets.bounds[0, 2]))
    pos, quat = exact.as_arrays(poses)
    ids, count = exact.active_coils(pos)
    currents = rng.uniform(-3.0, 3.0, ids.shape) * (ids.numpy() >= 0)
    cur = wp.array(currents, dtype=wp.float64, device=exact.device)

    def run_exact():
        exact.active_coils(pos, ids, count)
        g = exact.wrench_matrix(pos, quat, ids)
        return exact.wrench(g, cur)

    w_exact = run_exact().numpy()
    ms, _, _ = time_call(run_exact, 2, warmup=0, sync=lambda: wp.synchronize_device(exact.device))
    exact_s_per_mover = ms * 1e-3 / n_gpu
    cs = exact.coilset
    ids_np = ids.numpy()
    rows = []
    for m in range(args.magpylib_movers):
        rot = Rotation.from_matrix(ref.rotation(poses[m])[0])
        coll = magpy.Collection(*[magpy.magnet.Cuboid(polarization=j, dimension=s, position=c) for c, s, j in
                                  zip(params.magnets.centers, params.magnets.sizes, params.magnets.polarizations)])
        coll.rotate(rot, anchor=0).move(poses[m, :3])
        lines = [magpy.current.Polyline(current=cs.seg_weight[s] * currents[m, j], vertices=[cs.seg_a[s], cs.seg_b[s]])
                 for j, k in enumerate(ids_np[m]) if k >= 0 for s in range(cs.seg_start[k], cs.seg_start[k + 1])]
        t0 = time.perf_counter()
        ft = np.asarray(magpy.getFT(coll, lines, pivot=poses[m, :3], meshing=args.meshing)).sum(axis=1)
        mp_s = time.perf_counter() - t0
        w_mp = -ft.ravel()
        row = {"device": device, "mover": m, "active_coils": int(count.numpy()[m]), "polylines": len(lines),
               "meshing": args.meshing, "magpylib_cpu_s": mp_s, "exact_s_per_mover": exact_s_per_mover,
               "exact_movers_in_batch": n_gpu, "speedup": mp_s / exact_s_per_mover,
               "force_rel_diff": float(np.linalg.norm(w_mp[:3] - w_exact[m, :3]) / np.linalg.norm(w_exact[m, :3])),
               "torque_rel_diff": float(np.linalg.norm(w_mp[3:] - w_exact[m, 3:]) / np.linalg.norm(w_exact[m, 3:]))}
        rows.append(row)
        print(f"  magpylib (CPU) {mp_s:.2f} s/mover vs exact ({device}) {exact_s_per_mover * 1e3:.3f} ms/mover: "
              f"{row['speedup']:.0f}x; wrench differs by {row['force_rel_diff']:.2e} (force), "
              f"{row['torque_rel_diff']:.2e} (torque)", flush=True)
    return rows


def sim_rows(args, device: str, params, spec) -> list[dict]:
    """One 40-cycle step of the B0 layout (3 movers per world) with the ideal model and with the magnetic drive."""
    import torch

    from magwarp.layout import benchmark_layout
    from magwarp.sim import Simulator

    layout, movers = benchmark_layout("B0")
    rows = []
    for worlds in (args.sim_worlds if device.startswith("cuda") else args.cpu_sim_worlds):
        out = {"device": device, "worlds": worlds, "movers_per_world": movers, "cycles": 40}
        per_cycle = [f"{v}_per_cycle" for v in args.drive_variants if v.startswith("in_step") and args.per_cycle]
        for name in ("ideal", *args.drive_variants, *per_cycle):
            model = drive_model(args, params, name.removesuffix("_per_cycle"))
            # _per_cycle: the per-cycle kernels (one thread per mover and cycle, 2 launches a cycle) instead of the
            # fused one-thread-per-world kernel
            sim = Simulator(layout, movers, worlds, device=device, stop_on_collision=False, check_inputs=False,
                            force_model=model, **({"fused_max_movers": 0} if name.endswith("_per_cycle") else {}))
            gen = torch.Generator(device=sim.torch_device).manual_seed(0)
            cmd = torch.rand((worlds, movers, 2), generator=gen, device=sim.torch_device) * 2.0 - 1.0
            sim.set_command(cmd)
            ms, _, _ = time_call(lambda: sim.step(40), args.repeats, warmup=1,
                                 sync=lambda: wp.synchronize_device(device))  # noqa: B023
            out[f"{name}_step_ms"] = ms
        variants = [*args.drive_variants, *per_cycle]
        variants_share(out, variants, lambda v: out["ideal_step_ms"] / out[f"{v}_step_ms"])
        rows.append(out)
        print(f"  {device:7s} B0 x {worlds:>6} worlds, 40 cycles: ideal {out['ideal_step_ms']:.3f} ms, magnetic "
              + ", ".join(f"{v} {out[f'{v}_step_ms']:.3f} ms ({out[f'{v}_share_of_ideal_speed']:.1%})"
                          for v in variants), flush=True)
    return rows


#: The magnetic drive's variants (``--drive-variants``): inside the step kernels in float64 or float32
#: arithmetic (:class:`magwarp.magnetics.drive.MagneticDrive`, ``in_step=True``), or the float64 pre-cycle hook.
DRIVE_VARIANTS = {"in_step_f64": {"in_step": True, "precision": "float64"},
                  "in_step_f32": {"in_step": True, "precision": "float32"}, "hook": {"in_step": False}}


def drive_model(args, params, name: str):
    """The force model of a row: None (``ideal``) or the magnetic model of drive variant ``name``."""
    from magwarp.magnetics.drive import MagneticModel

    return None if name == "ideal" else MagneticModel(params, args.table_spec, **DRIVE_VARIANTS[name])


def variants_share(out: dict, variants, share) -> None:
    """Each drive variant's share of the ideal speed; ``magnetic_*``: the first variant's (the default drive)."""
    for v in variants:
        out[f"{v}_share_of_ideal_speed"] = share(v)
    first = variants[0]
    out["magnetic_variant"] = first
    for key in [k for k in out if k.startswith(first + "_")]:
        out["magnetic" + key[len(first):]] = out[key]


def env_rows(args, device: str, params) -> list[dict]:
    """env-steps/s of ``magwarp/TrajectoryPlanningB0-v0`` (random actions) with the ideal and the magnetic model."""
    from env_throughput import raw_env_row

    rows = []
    for n in (args.env_envs if device.startswith("cuda") else args.cpu_env_envs):
        out = {"device": device, "env": "magwarp/TrajectoryPlanningB0-v0", "num_envs": n}
        for name in ("ideal", *args.drive_variants):
            try:
                res = raw_env_row(out["env"], n, device, args.env_steps, force_model=drive_model(args, params, name))
            except Exception as e:  # noqa: BLE001 - a variant that fails is a result; the others still run
                print(f"  {device:7s} B0 env x {n:>6}: {name} failed: {type(e).__name__}: {str(e)[:300]}", flush=True)
                res = {"step_ms": float("nan"), "env_steps_per_s": float("nan"), "path": f"failed: {type(e).__name__}"}
            out[f"{name}_step_ms"] = res["step_ms"]
            out[f"{name}_env_steps_per_s"] = res["env_steps_per_s"]
            out[f"{name}_path"] = res.get("path")
        variants_share(out, args.drive_variants,
                       lambda v: out[f"{v}_env_steps_per_s"] / out["ideal_env_steps_per_s"])
        rows.append(out)
        print(f"  {device:7s} B0 env x {n:>6}: ideal {out['ideal_env_steps_per_s']:.4g} env-steps/s, magnetic "
              + ", ".join(f"{v} {out[f'{v}_env_steps_per_s']:.4g} ({out[f'{v}_share_of_ideal_speed']:.1%}, "
                          f"{out[f'{v}_path']})" for v in args.drive_variants), flush=True)
    return rows


def sweep_rows(args, device: str, params) -> list[dict]:
    """The shipped B0 policy (``--sweep-policy``) evaluated with the ideal model and with the magnetic model at
    falling coil current limits (``--limits``, A): success rate and copper energy per goal."""
    from dataclasses import replace

    from magwarp.evaluate import evaluate
    from magwarp.magnetics.drive import MagneticModel

    rows = []
    for limit in [None, *args.limits]:
        kwargs = {}
        if limit is not None:
            coils = replace(params.coils, coil=replace(params.coils.coil, current_limit=float(limit)))
            kwargs = {"force_model": MagneticModel(replace(params, coils=coils), args.table_spec)}
        res = evaluate("TrajectoryPlanningB0", args.sweep_policy, args.sweep_episodes, args.sweep_repeats,
                       device=device, steps=args.sweep_steps, progress=False, env_kwargs=kwargs)
        r = {row.key: row for row in res.rows}
        row = {"device": device, "policy": args.sweep_policy, "model": "ideal" if limit is None else "magnetic",
               "current_limit_a": limit, "episodes": args.sweep_episodes, "repeats": args.sweep_repeats,
               "steps": args.sweep_steps, "success_rate": r["success_rate"].mean,
               "success_rate_std": r["success_rate"].std, "goals_per_repeat": r["success_rate"].n,
               "copper_energy_j_per_goal": r["copper_energy_j_per_goal"].mean if limit is not None else None,
               "copper_power_w": r["copper_power_w"].mean if limit is not None else None}
        rows.append(row)
        print(f"  B0 {args.sweep_policy} {row['model']} limit {limit} A: success {row['success_rate']:.2f}%, "
              f"{row['goals_per_repeat']:.0f} goals, {row['copper_energy_j_per_goal'] or 0:.1f} J/goal", flush=True)
    return rows


def floats(text: str) -> list[float]:
    return [float(s) for s in text.split(",") if s]


def names(text: str) -> list[str]:
    out = [s for s in text.split(",") if s]
    unknown = [s for s in out if s not in DRIVE_VARIANTS]
    if unknown or not out:
        raise argparse.ArgumentTypeError(f"drive variants must be some of {sorted(DRIVE_VARIANTS)}, got {text!r}")
    return out


def sizes(text: str) -> list[int]:
    return [int(float(s)) for s in text.split(",") if s]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default=None, help="cpu or cuda:0 (default: cpu, and cuda:0 when present)")
    parser.add_argument("--sizes", type=sizes, default=sizes("1000,100000,1000000"), help="GPU movers, table model")
    parser.add_argument("--block-dims", type=sizes, default=sizes(""),
                        help="GPU: more threads per mover (1 to 36) to time the one-launch cycle with, beside the "
                             "default 32 (below 32: partial warps, not yet run on a GPU)")
    parser.add_argument("--cpu-sizes", type=sizes, default=sizes("100,1000"), help="CPU movers, table model")
    parser.add_argument("--fast-sizes", type=sizes, default=sizes("1000,100000"), help="GPU movers, fast model")
    parser.add_argument("--cpu-fast-sizes", type=sizes, default=sizes("100"), help="CPU movers, fast model")
    parser.add_argument("--exact-sizes", type=sizes, default=sizes("100,1000"), help="GPU mover counts, exact model")
    parser.add_argument("--cpu-exact-sizes", type=sizes, default=sizes("4"), help="CPU mover counts, exact model")
    parser.add_argument("--sim-worlds", type=sizes, default=sizes("4096,65536"), help="GPU B0 worlds, sim step")
    parser.add_argument("--cpu-sim-worlds", type=sizes, default=sizes("4"), help="CPU B0 worlds, sim step")
    parser.add_argument("--env-envs", type=sizes, default=sizes("4096,65536"), help="GPU B0 envs, env step")
    parser.add_argument("--cpu-env-envs", type=sizes, default=sizes("4"), help="CPU B0 envs, env step")
    parser.add_argument("--env-steps", type=int, default=20, help="env steps timed per row")
    parser.add_argument("--drive-variants", type=names, default=names("hook,in_step_f64,in_step_f32"),
                        help=f"magnetic drives of the sim and env rows (the first is reported as 'magnetic'): "
                             f"{', '.join(DRIVE_VARIANTS)}")
    parser.add_argument("--per-cycle", action="store_true",
                        help="sim rows: also each in-step drive on the per-cycle kernels (one thread per mover)")
    parser.add_argument("--tiles", type=int, default=8, help="the layout is tiles x tiles")
    parser.add_argument("--table-variants", type=lambda t: [s for s in t.split(",") if s], default=[],
                        help=f"wrench tables to time the one-thread cycle with at the largest size (and check "
                             f"against the exact model): some of {', '.join(TABLE_VARIANTS)}")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--accuracy-poses", type=int, default=8, help="0 skips the accuracy and footprint checks")
    parser.add_argument("--magpylib-movers", type=int, default=1, help="0 skips the magpylib comparison")
    parser.add_argument("--meshing", type=int, default=100, help="magpylib getFT points per polyline")
    parser.add_argument("--limits", type=floats, default=floats("7,5,3,2"),
                        help="coil current limits (A) of the B0 policy sweep ('' skips it)")
    parser.add_argument("--sweep-policy", default="pretrained:b0_ppo")
    parser.add_argument("--sweep-episodes", type=int, default=None, help="worlds per repeat (GPU 1024, CPU 8)")
    parser.add_argument("--sweep-repeats", type=int, default=None, help="repeats (GPU 10, CPU 1)")
    parser.add_argument("--sweep-steps", type=int, default=250, help="env steps per world (250: 10 s)")
    parser.add_argument("--fast-cycle-sizes", type=sizes, default=sizes(""),
                        help="movers: the block cycle beside the fast cycle (magwarp/magnetics/fast_cycle.py)")
    parser.add_argument("--fast-cycle-only", action="store_true", help="only the --fast-cycle-sizes rows")
    parser.add_argument("--fast-variants", type=lambda t: [v for v in t.split(",") if v], default=[],
                        help="the fast cycle's variants beside the default one (default: all of FAST_VARIANTS)")
    parser.add_argument("--json", default=None, help="default: benchmarks/results/magnetics_<cpu|gpu>.json")
    args = parser.parse_args(argv)

    from magwarp.magnetics.fast import FieldTableSpec
    from magwarp.magnetics.geometry import MagneticParams
    from magwarp.magnetics.table import WrenchTableSpec

    info, devices = start_run(args.device)
    wp.init()
    params, spec = MagneticParams(), FieldTableSpec()
    args.table_spec = WrenchTableSpec()
    unknown = [v for v in args.table_variants if v not in TABLE_VARIANTS]
    if unknown:
        parser.error(f"unknown --table-variants {unknown}; known: {sorted(TABLE_VARIANTS)}")
    speed, accuracy, footprint, magpylib, sim, env, tables, fast = [], [], [], [], [], [], [], []
    if args.fast_cycle_only:
        args.accuracy_poses = args.magpylib_movers = 0
        args.limits = []
    for device in devices:
        if args.fast_cycle_sizes:
            fast += fast_cycle_rows(args, device, params)
        if args.fast_cycle_only:
            continue
        speed += speed_rows(args, device, params, spec)
        if args.table_variants:
            tables += table_variant_rows(args, device, params)
        sim += sim_rows(args, device, params, spec)
        env += env_rows(args, device, params)
    if args.accuracy_poses > 0:
        accuracy += accuracy_rows(args, devices[-1], params, spec)
        footprint += footprint_rows(args, devices[-1], params)
    if args.magpylib_movers > 0:
        magpylib += magpylib_rows(args, devices[-1], params)
    sweep = []
    if args.limits:
        gpu = devices[-1].startswith("cuda")
        args.sweep_episodes = args.sweep_episodes or (1024 if gpu else 8)
        args.sweep_repeats = args.sweep_repeats or (10 if gpu else 1)
        sweep = sweep_rows(args, devices[-1], params)
    print()
    gpu = any(d.startswith("cuda") for d in devices)
    path = args.json or os.path.join(os.path.dirname(os.path.abspath(__file__)), "results",
                                     f"magnetics_{'gpu' if gpu else 'cpu'}.json")
    options = {k: v for k, v in vars(args).items() if k != "table_spec"}
    rows = ([{"kind": "speed", **r} for r in speed] + [{"kind": "sim", **r} for r in sim]
            + [{"kind": "env", **r} for r in env] + [{"kind": "table_variant", **r} for r in tables]
            + [{"kind": "accuracy", **r} for r in accuracy]
            + [{"kind": "footprint", **r} for r in footprint] + [{"kind": "magpylib", **r} for r in magpylib]
            + [{"kind": "sweep", **r} for r in sweep] + [{"kind": "fast_cycle", **r} for r in fast]
            + [{"kind": "options", **options, "table_spec": repr(args.table_spec)}])
    finish([r for r in rows if r["kind"] != "options"],
           ["kind", "device", "model", "movers", "worlds", "num_envs", ("gamma_ms", "Gamma ms"),
            ("commutation_ms", "commutation ms"), ("cycle_ms", "cycle ms"),
            ("fused_cycle_ms", "fused cycle ms"), ("block_cycle_ms", "block cycle ms"), ("fast_ms", "fast cycle ms"),
            ("thread_f32_cycle_ms", "1-thread f32 ms"),
            ("thread_f64_cycle_ms", "1-thread f64 ms"), "table_variant", ("table_mb", "table MB"),
            ("thread_float32_cycle_ms", "variant f32 ms"), ("active_coils_mean", "coils/mover"),
            ("ideal_step_ms", "ideal ms/step"), ("magnetic_step_ms", "magnetic ms/step"),
            ("magnetic_share_of_ideal_speed", "magnetic/ideal speed"), ("hook_step_ms", "hook ms/step"),
            ("hook_share_of_ideal_speed", "hook/ideal speed"), ("max_tilt_rad", "tilt"),
            ("force_error_share", "force err/peak"), ("torque_error_share", "torque err/peak"),
            ("hover_loss_ratio_mean", "footprint loss ratio"), ("speedup", "exact vs magpylib"),
            ("current_limit_a", "limit A"), ("success_rate", "success %"),
            ("copper_energy_j_per_goal", "J/goal")],
           info, None)
    write_json(path, [{**r, **provenance(info)} for r in rows])
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
