"""Compilation options shared by the simulator's step and collision kernels.

``MAGWARP_KERNEL_OPTIONS`` (e.g. ``"fast_math=1,default_grid_stride=0"``) overrides them, read once at import: a
tuning knob for benchmarks (each setting is a separate kernel-cache entry), not an API.
"""

from __future__ import annotations

import os

# Chosen with benchmarks/gpu_explore.sh on an H200 (benchmarks/results/tuning/): fast math (approximate division,
# square root and trigonometry, denormals flushed; CUDA only, Warp's CPU build ignores it) took the 1000-mover box
# step from 31.9 to 22.3 us and 16384 worlds x 3 movers x 40 cycles from 109 to 66 us; lean launches (no grid-stride
# loop) shave another 1-3%. The kernels need neither IEEE-exact division nor denormals: their results are compared
# with float64 references under tolerances, and CPU and GPU builds agree within them.
# Trap: a launch capped with ``max_blocks`` needs a kernel compiled with the grid-stride loop. Warp refuses it for a
# lean kernel on CUDA only (the CPU ignores ``max_blocks``, so no CPU test sees it; every swarm placement on the GPU
# once failed so): compile such a kernel with ``grid_stride=True``, as :func:`magwarp.kernels.placement.strided`.
DEFAULT_OPTIONS: dict[str, bool] = {"fast_math": True, "default_grid_stride": False}


def _parse(text: str) -> dict[str, bool]:
    out: dict[str, bool] = {}
    for item in filter(None, (s.strip() for s in text.split(","))):
        key, sep, value = item.partition("=")
        if not sep or value not in ("0", "1"):
            raise ValueError(f"MAGWARP_KERNEL_OPTIONS entries must look like name=0 or name=1, got {item!r}")
        out[key.strip()] = value == "1"
    return out


def _env_choice(name: str, choices: tuple[str, ...], default: str) -> str:
    value = os.environ.get(name, default)
    if value not in choices:
        raise ValueError(f"{name} must be one of {', '.join(choices)}, got {value!r}")
    return value


def _env_int(name: str, default: int, lo: int, hi: int) -> int:
    text = os.environ.get(name, str(default))
    try:
        value = int(text)
    except ValueError:
        value = None
    if value is None or not lo <= value <= hi:
        raise ValueError(f"{name} must be an integer in {lo}..{hi}, got {text!r}")
    return value


MODULE_OPTIONS: dict[str, bool] = {**DEFAULT_OPTIONS, **_parse(os.environ.get("MAGWARP_KERNEL_OPTIONS", ""))}



def world_block_dim(num_movers: int) -> int:
    """Threads per block of a block-per-world kernel (one lane per mover): the movers rounded up to whole warps."""
    return max(32, -(-int(num_movers) // 32) * 32)


#: Which of a world's per-world rows the general fused register kernel
#: (:func:`magwarp.kernels.step.make_register_kernel`, domain randomisation) holds in registers for the whole step:
#: ``"all"`` (body rows and collision sizes), ``"f32"`` (the same less the body rows' float64 limits, read every
#: cycle), ``"sizes"`` (collision sizes only; body rows read every cycle) or ``"none"`` (every row read every cycle,
#: as the nominal kernel reads its one shared row). Registers save a memory read per cycle but can spill (the kernel
#: is at 255 registers on sm_90): ``MAGWARP_REGISTER_ROWS`` picks the variant, read once at import, a tuning knob for
#: benchmarks (``benchmarks/randomization.py --register-rows``), not an API.
REGISTER_ROWS_CHOICES = ("all", "f32", "sizes", "none")
# "f32" was the fastest in one H100 run of the four (B0, 65,536 envs, every planar term: +25% over no terms, against
# +32-36% for the others; benchmarks/results/randomization_rows_*_gpu.json; calls vary by about 5 points). A fifth,
# the body rows read every cycle from a transposed copy (one transaction per warp and field), measured +65% against
# f32's +37% (terms, 65,536 envs, randomization_parts_*_gpu.json, 2026-11-25) and was removed.
REGISTER_ROWS: str = os.environ.get("MAGWARP_REGISTER_ROWS", "f32")
if REGISTER_ROWS not in REGISTER_ROWS_CHOICES:
    raise ValueError(f"MAGWARP_REGISTER_ROWS must be one of {', '.join(REGISTER_ROWS_CHOICES)}, got {REGISTER_ROWS!r}")


#: The launch shape of the fused step for small worlds (up to :data:`magwarp.sim.REGISTER_MAX_MOVERS` movers) on CUDA:
#: ``"registers"`` (one thread per world, every mover's state in registers:
#: :func:`magwarp.kernels.step.make_register_kernel`) or ``"movers"`` (one thread per mover, several worlds per
#: block, poses exchanged through shared memory each cycle: :mod:`magwarp.kernels.step_blocks`; never with an
#: actuator). The same arithmetic: bit for bit on the CPU (Warp's cooperative blocks, the tests) and, on the H100, for
#: the general variants; the nominal one within 6e-8 m there (the compiler contracts a multiply-add differently).
#: ``"movers"`` is the default (CUDA; the CPU runs ``"registers"``): on the H100 at 65,536 B0 worlds, in the env's
#: step, it took 199.6 / 221.9 / 231.2 us without / with the planar terms / with terms and latency, against 199.3 /
#: 234.8 / 258.5 for ``"registers"`` (benchmarks/results/randomization_small_world_*_gpu.json, 2026-11-25).
#: ``MAGWARP_SMALL_WORLD_KERNEL`` picks it, ``MAGWARP_SMALL_WORLD_BLOCK``
#: the threads per block of the "movers" shape (``block_dim // num_movers`` worlds a block) and
#: ``MAGWARP_SMALL_WORLD_MAXREG`` its register cap per thread (0: none); read once at import, tuning knobs for
#: benchmarks (``benchmarks/randomization.py --small-world-kernel``, ``benchmarks/small_world_kernels.py``), not an
#: API. The cap's default, 168: uncapped, the kernel takes 167-170 registers on sm_90 for 3 movers
#: (``benchmarks/kernel_registers.py``), three blocks of 96 threads per SM; at 168, four blocks fit (65,536 registers /
#: (4 x 96)) and no variant spills: the general ones keep the per-world body rows in shared memory
#: (``MAGWARP_SMALL_WORLD_ROWS=shared``; ``registers``: 186-190 registers uncapped, 48-56 bytes of spills at 168).
SMALL_WORLD_KERNEL_CHOICES = ("registers", "movers")
SMALL_WORLD_KERNEL: str = _env_choice("MAGWARP_SMALL_WORLD_KERNEL", SMALL_WORLD_KERNEL_CHOICES, "movers")
SMALL_WORLD_BLOCK: int = _env_int("MAGWARP_SMALL_WORLD_BLOCK", 96, 1, 1024)
SMALL_WORLD_MAXREG: int = _env_int("MAGWARP_SMALL_WORLD_MAXREG", 168, 0, 255)  # 0: no cap
SMALL_WORLD_ROWS_CHOICES = ("shared", "registers")
SMALL_WORLD_ROWS: str = _env_choice("MAGWARP_SMALL_WORLD_ROWS", SMALL_WORLD_ROWS_CHOICES, "shared")

#: Whether the trajectory env's fused step (:mod:`magwarp.envs.trajectory_fused`, CUDA) runs two parts that the
#: step's next launches do not read on a second stream, as parallel branches of its CUDA graph: the torch draws of
#: the goals and starts beside the physics kernel, and the reset firing of the randomisation terms beside the
#: simulator's reset kernels and the observation kernel (``"on"``), or everything in order on one stream
#: (``"off"``). The same results either way. ``MAGWARP_STEP_BRANCHES``, read once at import: a tuning knob for
#: benchmarks (``benchmarks/rand_gaps.py``), not an API. On the H100 at 65,536 B0 worlds the env step took 0.275 /
#: 0.346 ms with them (no / full randomisation) against 0.286 / 0.362 without (rand_gaps_s37_branches_*_gpu.json).
STEP_BRANCHES: str = _env_choice("MAGWARP_STEP_BRANCHES", ("on", "off"), "on")

#: How the swarm placement's rounds with ``search="world"`` check a round's tries (:attr:`magwarp.swarm.Placer.scan`,
#: :data:`magwarp.swarm.placement.SCAN_SHAPES`) when the placer is not told: ``"device"`` (the device's default,
#: :data:`~magwarp.swarm.placement.SCAN_CUDA` / :data:`~magwarp.swarm.placement.SCAN_CPU`) or one shape for every
#: device. ``MAGWARP_PLACE_SCAN``, read once at import: a tuning knob for benchmarks (``benchmarks/swarm.py``), not an
#: API. The same spots whatever the shape.
PLACE_SCAN_CHOICES = ("device", "serial", "chunked")
PLACE_SCAN: str = _env_choice("MAGWARP_PLACE_SCAN", PLACE_SCAN_CHOICES, "device")
