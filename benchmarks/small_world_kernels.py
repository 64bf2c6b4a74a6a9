"""The fused small-world step's two launch shapes side by side: the physics of one B0 env step (the simulator's step
alone: 40 control cycles, its CUDA graph replayed) per variant and kernel setting, and whether each setting's results
equal the register kernel's bit for bit.

    python benchmarks/small_world_kernels.py                                   # cpu smoke check (cooperative blocks)
    python benchmarks/small_world_kernels.py --device cuda:0 --num-envs 16384,65536 --blocks 96 --maxregs 168,0 \\
        --json small_world_kernels_gpu.json

Kernels (:data:`magwarp.kernels.options.SMALL_WORLD_KERNEL`): ``registers`` (one thread per world, the whole world in
registers: :func:`magwarp.kernels.step.make_register_kernel`) and ``movers`` (one thread per mover, several worlds a
block: :mod:`magwarp.kernels.step_blocks`) for each ``--blocks`` x ``--maxregs`` x ``--rows`` setting. Variants:
``nominal`` (body rows as built), ``general`` (per-world body rows and collision sizes: what domain randomisation
switches to) and ``general+latency`` (plus action latency, per-world delays of 0..5 cycles). The worlds are the B0
env's (its layout, movers and reset starts, seed 0), stepped with random accelerations (the same for every setting);
``equal`` compares every output (poses, velocities, float64 x/y state, flags, partners, walls, pair counts and lists,
halted, cycles) with the register kernel's after ``--check-steps`` steps, ``max_pos_diff`` the largest position
difference (m).
Targets (#24): the movers kernel's ``general+latency`` no slower than the register kernel's ``nominal``, and its
``nominal`` no slower than the register kernel's.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from common import finish, start_run  # noqa: E402

OUTPUTS = ("pos", "quat", "vel", "omega", "acc", "planar", "flags", "flags_any", "partner", "wall", "world_pairs",
           "world_walls", "halted", "cycles", "pair_list")
VARIANTS = ("nominal", "general", "general+latency")
CYCLES = 40


def make_sim(device: str, num_envs: int, variant: str, kernel: str, block: int, maxreg: int, rows: str):
    """The B0 env's simulator (reset with seed 0) under one kernel setting and variant."""
    import numpy as np
    import torch

    from magwarp.envs.trajectory import TrajectoryPlanningEnv
    from magwarp.kernels import options as kernel_options

    kernel_options.SMALL_WORLD_KERNEL, kernel_options.SMALL_WORLD_BLOCK = kernel, block
    kernel_options.SMALL_WORLD_MAXREG, kernel_options.SMALL_WORLD_ROWS = maxreg, rows
    env = TrajectoryPlanningEnv(num_envs, device=device, seed=0, check_inputs=False)
    env.reset(seed=0)
    sim = env.sim
    if variant != "nominal":
        sim.commit_mover_params()  # per-world body rows (the configured values: same physics, general kernel)
        sim.make_per_world("radius", "half_size", "margins")
    if variant == "general+latency":
        delays = np.random.default_rng(1).integers(0, 6, num_envs)
        sim.set_latency(torch.as_tensor(delays, dtype=torch.int32, device=sim.torch_device), bound=5)
    want = block if kernel == "movers" else 0
    if sim._movers_block != want:
        raise RuntimeError(f"{kernel} (block {block}) did not take on {device}: movers block {sim._movers_block}")
    return env, sim


def commands(sim, steps: int):
    import torch

    gen = torch.Generator(device=sim.torch_device).manual_seed(0)
    shape = (sim.num_worlds, sim.num_movers, 2)
    return [(torch.rand(shape, device=sim.torch_device, generator=gen) * 2 - 1) * 10.0 for _ in range(steps)]


def time_steps(sim, cmds, reps: int) -> float:
    """Microseconds per step of ``CYCLES`` cycles (the simulator's recorded graph), commands set outside the timing."""
    import torch

    cuda = sim.device.is_cuda
    total = 0.0
    for i in range(reps):
        sim.set_command(cmds[i % len(cmds)])
        if cuda:
            start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
            start.record()
            sim.step(CYCLES)
            end.record()
            end.synchronize()
            total += start.elapsed_time(end) * 1e3
        else:
            t0 = time.perf_counter()
            sim.step(CYCLES)
            total += (time.perf_counter() - t0) * 1e6
    return total / reps


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default="cpu", help="cpu (cooperative CPU blocks: a smoke check) or cuda:N")
    p.add_argument("--num-envs", default=None, help="comma-separated sizes (default: 64 on CPU, 16384,65536 on GPU)")
    p.add_argument("--blocks", default="96", help="comma-separated threads per block of the movers kernel")
    p.add_argument("--maxregs", default="168", help="comma-separated register caps of the movers kernel (0: none)")
    p.add_argument("--rows", default="shared", help="comma-separated: where the movers kernel's general variant keeps "
                   "the body rows (shared, registers)")
    p.add_argument("--variants", default=",".join(VARIANTS))
    p.add_argument("--reps", type=int, default=None, help="timed steps (default: 5 on CPU, 50 on GPU)")
    p.add_argument("--check-steps", type=int, default=5)
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    import numpy as np
    import warp as wp

    info, _ = start_run(args.device)
    cuda = args.device.startswith("cuda")
    if not cuda:
        wp.config.enable_cpu_blocks = True  # the movers kernel's shape on the CPU (Warp's cooperative blocks)
    sizes = [int(s) for s in args.num_envs.split(",")] if args.num_envs else ([16384, 65536] if cuda else [64])
    reps = args.reps or (50 if cuda else 5)
    settings = [("registers", 0, 0, "-")] + [("movers", int(b), int(r), where) for b in args.blocks.split(",")
                                             for r in args.maxregs.split(",") for where in args.rows.split(",")]
    variants = [v for v in args.variants.split(",") if v]
    unknown = sorted(set(variants) - set(VARIANTS))
    if unknown:
        p.error(f"--variants: unknown {unknown} (known: {', '.join(VARIANTS)})")
    rows = []
    for n in sizes:
        for variant in variants:
            reference = None
            for kernel, block, maxreg, where in settings:
                if where == "registers" and variant == "nominal" and ("movers", block, maxreg, "shared") in settings:
                    continue  # the nominal variant holds no rows: the same kernel
                env, sim = make_sim(args.device, n, variant, kernel, block, maxreg, where)
                cmds = commands(sim, max(args.check_steps, 8))
                for cmd in cmds[:args.check_steps]:  # the agreement check (also loads the kernels, records the graph)
                    sim.set_command(cmd)
                    sim.step(CYCLES)
                out = {k: getattr(sim.state, k).numpy().copy() for k in OUTPUTS}  # (CPU arrays: views)
                if reference is None:
                    reference = out
                equal = all(out[k].tobytes() == reference[k].tobytes() for k in OUTPUTS)
                differ = [k for k in OUTPUTS if out[k].tobytes() != reference[k].tobytes()]
                pos_diff = float(np.abs(out["pos"] - reference["pos"]).max())
                halted = int(out["halted"].sum())
                us = time_steps(sim, cmds, reps)
                rows.append({"device": args.device, "num_envs": n, "variant": variant, "kernel": kernel,
                             "block": block or None, "maxreg": maxreg or None, "rows": where, "us_per_step": us,
                             "equal": equal,
                             "differs": ",".join(differ), "max_pos_diff": pos_diff, "halted_worlds": halted,
                             "movers_block": sim._movers_block})
                print(f"  {args.device} n={n} {variant} {kernel} block={block} maxreg={maxreg} rows={where}: "
                      f"{us:.1f} us/step, "
                      f"equal={equal}{' (' + ','.join(differ) + ')' if differ else ''}, max pos diff {pos_diff:.3g},"
                      f" halted {halted}", flush=True)
                del env, sim
    columns = ["device", "num_envs", "variant", "kernel", "block", "maxreg", "rows", ("us_per_step", "us/step"),
               "equal",
               ("max_pos_diff", "max |dpos| m"), ("halted_worlds", "halted")]
    return finish(rows, columns, info, args.json)


if __name__ == "__main__":
    raise SystemExit(main())
