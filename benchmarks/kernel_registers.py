"""Registers and stack per thread of the fused small-world step kernels, compiled ahead of time for a GPU arch (no GPU
needed: Warp's NVRTC writes the cubin), read from the cubin's ``.nv.info`` attributes (EIATTR_REGCOUNT, 0x2f;
EIATTR_MIN_STACK_SIZE, 0x12: the per-thread stack frame, spills included).

    python benchmarks/kernel_registers.py                        # sm_90, 3 movers, both shapes, three variants
    python benchmarks/kernel_registers.py --arch 90 --movers 3,8 --json kernel_registers.json
    python benchmarks/kernel_registers.py --randomize            # the randomisation firing kernels instead
    python benchmarks/kernel_registers.py --swarm                # the swarm env's step kernels (#18), register caps
    python benchmarks/kernel_registers.py --swarm --swarm-step-only --swarm-caps 128,96 --swarm-blocks 64,128,160
    python benchmarks/kernel_registers.py --place                # the placement rounds (default and lane shapes)

Shapes: ``registers`` (:func:`magwarp.kernels.step.make_register_kernel`, one thread per world, the register-row
variant given by ``--register-rows``) and ``movers`` (:func:`magwarp.kernels.step_blocks.make_movers_kernel`, one
thread per mover, ``--block`` threads per block, ``--maxregs`` register caps, ``--rows``; setting "block/cap/rows").
Variants: ``nominal`` (the body rows as built), ``general``
(per-world rows: domain randomisation) and ``general+latency`` (with action latency).
"""

from __future__ import annotations

import argparse
import os
import re
import struct
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from common import finish, start_run  # noqa: E402

ATTR_REGCOUNT = 0x2F
ATTR_MIN_STACK_SIZE = 0x12


def _sections(blob: bytes) -> list[tuple[str, int, int]]:
    """(name, offset, size) of every section of an ELF64 file."""
    shoff, = struct.unpack_from("<Q", blob, 0x28)
    shentsize, shnum, shstrndx = struct.unpack_from("<HHH", blob, 0x3A)
    hdrs = [struct.unpack_from("<IIQQQQIIQQ", blob, shoff + i * shentsize) for i in range(shnum)]
    strings = hdrs[shstrndx][4]

    def name(o: int) -> str:
        return blob[strings + o:blob.index(b"\0", strings + o)].decode()

    return [(name(h[0]), h[4], h[5]) for h in hdrs]


def _symbols(blob: bytes, sections: list[tuple[str, int, int]]) -> list[str]:
    """The names of the ELF symbol table's entries, by index."""
    table = {name: (off, size) for name, off, size in sections}
    (sym_off, sym_size), (str_off, _) = table[".symtab"], table[".strtab"]
    names = []
    for o in range(sym_off, sym_off + sym_size, 24):
        st_name, = struct.unpack_from("<I", blob, o)
        names.append(blob[str_off + st_name:blob.index(b"\0", str_off + st_name)].decode())
    return names


def cubin_attributes(path: str) -> dict[str, dict[str, int]]:
    """Per function symbol with a register count: ``registers`` and ``stack`` (bytes per thread), from the
    ``.nv.info`` sections' (symbol index, value) attributes."""
    blob = open(path, "rb").read()
    sections = _sections(blob)
    symbols = _symbols(blob, sections)
    out: dict[str, dict[str, int]] = {}
    for name, off, size in sections:
        if not name.startswith(".nv.info"):
            continue
        o, end = off, off + size
        while o < end:
            fmt, attr = blob[o], blob[o + 1]
            if fmt == 4:  # EIFMT_SVAL: a 16-bit size, then the data
                n, = struct.unpack_from("<H", blob, o + 2)
                if attr in (ATTR_REGCOUNT, ATTR_MIN_STACK_SIZE) and n == 8:
                    sym, value = struct.unpack_from("<II", blob, o + 4)
                    out.setdefault(symbols[sym], {})["registers" if attr == ATTR_REGCOUNT else "stack"] = value
                o += 4 + n
            elif fmt == 3:  # EIFMT_HVAL
                o += 4
            elif fmt == 2:  # EIFMT_BVAL
                o += 3
            else:
                o += 2
    return {k: v for k, v in out.items() if "registers" in v}


def kernel_figures(kernel, arch: int) -> dict[str, int]:
    """Registers and stack per thread of ``kernel`` compiled for ``sm_<arch>``."""
    import warp as wp

    with tempfile.TemporaryDirectory() as tmp:
        paths = wp.compile_aot_module(kernel.module, arch=arch, module_dir=tmp, use_ptx=False)
        cubins = [str(p) for p in paths if str(p).endswith(".cubin")]
        if not cubins:
            raise RuntimeError(f"no cubin written for {kernel.key} (got {[str(p) for p in paths]})")
        entry = re.compile(rf"{re.escape(kernel.key)}_[0-9a-f]+_cuda_kernel_forward")  # not another key's prefix
        found = {k: v for c in cubins for k, v in cubin_attributes(c).items() if entry.fullmatch(k)}
    if len(found) != 1:
        raise RuntimeError(f"expected one {kernel.key} entry in the cubin, found {sorted(found)}")
    return next(iter(found.values()))


def ptx_barriers(kernel, arch: int) -> int:
    """``bar.sync`` / ``barrier.sync`` instructions in the PTX of ``kernel``'s module for ``sm_<arch>`` (block
    barriers as written, before ptxas; a barrier in a loop counts once)."""
    import warp as wp

    with tempfile.TemporaryDirectory() as tmp:
        paths = wp.compile_aot_module(kernel.module, arch=arch, module_dir=tmp, use_ptx=True)
        ptx = "".join(open(p).read() for p in map(str, paths) if p.endswith(".ptx"))
    return len(re.findall(r"\b(?:bar|barrier)\.sync\b", ptx))


def randomize_figures(arch: int, json_path: str | None) -> int:
    """Registers and stack of the randomisation firing kernel (:func:`magwarp.kernels.randomize.fire_terms`, the one
    kernel benchmarks/fire_cost.py's candidates launch): it does not depend on the mover count."""
    from magwarp.kernels import randomize as krand

    info, _ = start_run("cpu")
    results = []
    for kernel in (krand.fire_terms,):
        fig = kernel_figures(kernel, arch)
        results.append({"arch": f"sm_{arch}", "kernel": kernel.key, **fig})
        print(f"  sm_{arch} {kernel.key}: {fig.get('registers')} registers, {fig.get('stack')} B stack", flush=True)
    return finish(results, ["arch", "kernel", "registers", ("stack", "stack B/thread")], info, json_path)


def place_rows(arch: int) -> list[dict]:
    """Registers and stack of the placement rounds' kernels: the default shape, lean and grid-stride
    (:func:`magwarp.kernels.placement.strided`: the launches capped by ``Placer.blocks``), and the lane shape
    (:func:`magwarp.kernels.placement.make_lane_kernels`) at 64, 100 and 256 movers per world."""
    from magwarp.kernels import placement as kpl

    rows = [{"kernel": k.key, "cap": 0, **kernel_figures(k, arch)}
            for base in (kpl.begin_todo, kpl.propose, kpl.resolve) for k in (base, kpl.strided(base))]
    for movers in (64, 100, 256):
        for lanes in kpl.LANE_CHOICES:
            per_lane = -(-movers // lanes)
            for k in kpl.make_lane_kernels(lanes, per_lane, False, per_lane <= kpl.MAX_PER_LANE):
                rows.append({"kernel": f"{k.key}/{movers}m/{lanes}l", "cap": 0, **kernel_figures(k, arch)})
    return rows


def place_figures(arch: int, json_path: str | None) -> int:
    """The placement rounds' kernels alone (:func:`place_rows`)."""
    info, _ = start_run("cpu")
    rows = place_rows(arch)
    for r in rows:
        r["arch"] = f"sm_{arch}"
        print(f"  sm_{arch} {r['kernel']}: {r.get('registers')} registers, {r.get('stack')} B stack", flush=True)
    return finish(rows, ["arch", "kernel", "registers", ("stack", "stack B/thread")], info, json_path)


def swarm_figures(arch: int, caps: list[int], json_path: str | None, blocks=(64, 128, 256), latencies=(False, True),
                  with_others: bool = True) -> int:
    """Registers and stack of the swarm env's step kernels (#18): the fused step (tiled shape, 64/128/256 threads per
    block, without and with latency, under each register cap; 0: none), the staged observation kernel (with the
    merge and the closed-form rays, with its PTX block barriers) and the placement rounds."""
    from magwarp.kernels import neighbors as knb
    from magwarp.kernels import swarm_step as kss
    from magwarp.swarm import SwarmEnv

    info, _ = start_run("cpu")
    sim = SwarmEnv(1, num_movers=8, device="cpu", seed=0, check_inputs=False).sim
    rows = []
    for block in blocks:
        for latency in latencies:
            for cap in caps:  # the CUDA default's native exchange (one barrier a cycle)
                k = kss.make_step_kernel(sim._force_model, latency, sim._nominal_body, block, cap, native=True)
                rows.append({"kernel": f"swarm_step/{block}" + ("+latency" if latency else ""), "cap": cap,
                             **kernel_figures(k, arch)})
        if not with_others:
            continue
        rows.append({"kernel": f"observe_staged/{block}", "cap": 0,
                     **kernel_figures(knb.make_observation_kernel(8, 8, knb.OWN_STATE, "world", block, True, True),
                                      arch)})
        k = knb.make_observation_kernel(8, 8, knb.OWN_STATE, "world", block, True, True, True, True)
        rows.append({"kernel": f"observe_staged_merge_rect/{block}", "cap": 0, **kernel_figures(k, arch),
                     "bar_sync": ptx_barriers(k, arch)})
    if with_others:
        rows += place_rows(arch)
    for r in rows:
        r["arch"] = f"sm_{arch}"
        bars = f", {r['bar_sync']} bar.sync" if "bar_sync" in r else ""
        print(f"  sm_{arch} {r['kernel']} cap {r['cap']}: {r.get('registers')} registers, {r.get('stack')} B stack"
              f"{bars}", flush=True)
    return finish(rows, ["arch", "kernel", "cap", "registers", ("stack", "stack B/thread"), "bar_sync"], info,
                  json_path)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--arch", type=int, default=90)
    p.add_argument("--movers", default="3", help="comma-separated mover counts")
    p.add_argument("--block", default="96", help="comma-separated threads per block of the movers shape")
    p.add_argument("--maxregs", default="0,168", help="comma-separated register caps of the movers shape (0: none)")
    p.add_argument("--rows", default="shared,registers", help="comma-separated: the movers shape's body rows")
    p.add_argument("--register-rows", default=None, help="the register kernel's rows (default: the library's)")
    p.add_argument("--randomize", action="store_true",
                   help="the domain-randomisation firing kernel (magwarp.kernels.randomize) instead of the step's")
    p.add_argument("--place", action="store_true", help="the placement rounds' kernels only (default and lane shapes)")
    p.add_argument("--swarm", action="store_true", help="the swarm env's step kernels instead (#18), under the "
                   "register caps of --swarm-caps")
    p.add_argument("--swarm-caps", default="0,128,112,96", help="comma-separated register caps of the swarm step")
    p.add_argument("--swarm-blocks", default="64,128,256", help="comma-separated threads per block of the swarm step")
    p.add_argument("--swarm-step-only", action="store_true", help="--swarm: the step kernel without latency only "
                   "(no observation or placement kernels)")
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    if args.randomize:
        return randomize_figures(args.arch, args.json)
    if args.place:
        return place_figures(args.arch, args.json)
    if args.swarm:
        return swarm_figures(args.arch, [int(c) for c in args.swarm_caps.split(",")], args.json,
                             blocks=[int(b) for b in args.swarm_blocks.split(",")],
                             latencies=(False,) if args.swarm_step_only else (False, True),
                             with_others=not args.swarm_step_only)
    from magwarp.kernels import options as kernel_options
    from magwarp.kernels import step as kstep
    from magwarp.kernels import step_blocks
    from magwarp.kernels.impedance import default_force

    rows = args.register_rows or kernel_options.REGISTER_ROWS
    info, _ = start_run("cpu")
    variants = {"nominal": (False, True), "general": (False, False), "general+latency": (True, False)}
    results = []
    for m in (int(s) for s in args.movers.split(",")):
        for variant, (latency, nominal) in variants.items():
            kernels = [("registers", rows, kstep.make_register_kernel(default_force, m, latency, nominal, rows))]
            kernels += [("movers", f"{b}/{r}/{rows}", step_blocks.make_movers_kernel(default_force, m, latency,
                                                                                     nominal, int(b), int(r), rows))
                        for b in args.block.split(",") for r in args.maxregs.split(",")
                        for rows in (args.rows.split(",") if not nominal else ["shared"])]
            for shape, setting, kernel in kernels:
                fig = kernel_figures(kernel, args.arch)
                row = {"arch": f"sm_{args.arch}", "num_movers": m, "shape": shape, "setting": setting,
                       "variant": variant, **fig}
                print(f"  sm_{args.arch} M={m} {shape} ({setting}) {variant}: {fig.get('registers')} registers, "
                      f"{fig.get('stack')} B stack", flush=True)
                results.append(row)
    columns = ["arch", "num_movers", "shape", "setting", "variant", "registers", ("stack", "stack B/thread")]
    return finish(results, columns, info, args.json)


if __name__ == "__main__":
    raise SystemExit(main())
