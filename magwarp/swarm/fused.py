"""The swarm env's fused step: all control cycles of an env step, with the per-mover collision stops, in one launch.

:class:`FusedSwarmStep` is a simulator motion (:meth:`magwarp.sim.Simulator.set_motion`) for the respawn rule: on
CUDA one thread block per world with its movers' state in registers and their positions exchanged through shared
memory each cycle, on the CPU one thread per world (:mod:`magwarp.kernels.swarm_step`). Results match the per-cycle
path (the step kernels, then the stop hook after every cycle) bit for bit: same movers flagged in the same cycle,
same stops, same state.

It steps aside (the per-cycle path runs, the stop hook included) while the simulator has other cycle hooks (metrics,
a magnetic drive as a hook), which must run between cycles, or an in-step actuator (a magnetic drive with
``in_step=True``).
"""

from __future__ import annotations

from collections.abc import Callable

import os

import warp as wp

from magwarp.kernels import swarm_step as kss
from magwarp.kernels.options import world_block_dim

__all__ = ["FusedSwarmStep", "fused_applies", "guard_in_step", "launch_block", "max_registers", "MAX_FUSED_MOVERS"]

MAX_FUSED_MOVERS = kss.MAX_BLOCK
TRAVEL_SLACK = 1.01  # the travel budget's room over the speed cap's distance (rounding; the guard covers the rest)
#: the tiled (CUDA) kernel's register caps per thread: :func:`max_registers` takes :data:`LOW_REGISTERS` where it fits
#: more blocks of the launch's size on a multiprocessor (65,536 registers) than :data:`MAX_REGISTERS` and the block
#: holds one world, else :data:`MAX_REGISTERS`. The compiler's own choice for sm_90 is 128 registers and 64 B of stack
#: (the candidate list); at a cap of 96 the stack is 184 B (spills; ``python benchmarks/kernel_registers.py --swarm
#: --swarm-step-only``, the same at every block size), which pays where it adds a block: blocks of 64 threads 10 per SM
#: instead of 8, of 128 threads 5 instead of 4, of 160 4 instead of 3, but of 256 still 2. Blocks of several worlds
#: did not gain: 2 worlds of 100 movers in 224 threads, 3 blocks per SM at 96 against 2 at 128, took 3.71 ms against
#: 3.55 (``swarm_pack*_s43_gpu.json``; their travel guard is the block's). On the H200 at 16,384 worlds
#: (``benchmarks/results/swarm_cap*_s43_gpu.json``, 2026-12-07) the env step under the scripted planner / the seek
#: load took: 64 movers 1.693 / 2.214 ms at 96 against 1.704 / 2.264 at 128; 100 movers 3.371 / 4.296 against
#: 3.504 / 4.425 (80, 88, 104 and 112 registers: 3.50, 3.50, 3.61, 3.55); 160 movers 4.553 / 6.267 against 4.918 /
#: 6.627; 256 movers 8.342 / 11.23 against 7.966 / 10.74. The same arithmetic and results (the CUDA tests ran at
#: both). ``MAGWARP_SWARM_MAX_REGISTERS`` overrides both (0: no cap), for tuning.
MAX_REGISTERS = 128
LOW_REGISTERS = 96
_SM_REGISTERS = 65536


def max_registers(block_dim: int, worlds: int = 1) -> int:
    """The tiled kernel's register cap for blocks of ``block_dim`` threads holding ``worlds`` worlds (see
    :data:`MAX_REGISTERS`), or ``MAGWARP_SWARM_MAX_REGISTERS``."""
    value = os.environ.get("MAGWARP_SWARM_MAX_REGISTERS", "").strip()
    if value:
        if not value.isdigit() or not (int(value) == 0 or 16 <= int(value) <= 255):
            raise ValueError(f"MAGWARP_SWARM_MAX_REGISTERS must be 0 (no cap) or an integer in 16..255, got {value!r}")
        return int(value)
    b = max(int(block_dim), 1)
    more_blocks = _SM_REGISTERS // (LOW_REGISTERS * b) > _SM_REGISTERS // (MAX_REGISTERS * b)
    return LOW_REGISTERS if more_blocks and int(worlds) == 1 else MAX_REGISTERS


#: how the tiled (CUDA) kernel exchanges each cycle's poses: ``"native"`` (one ``__syncthreads_or`` a cycle over two
#: shared buffers, :func:`magwarp.kernels.swarm_step.share_poses`) or ``"tile"`` (a Warp tile and a tile reduction for
#: the travel guard: about four block barriers a cycle). The same arithmetic and results. On the H100 at 16,384
#: worlds the env step took 7-10% less with ``"native"`` under the seek load and 11-13% less with still movers, at
#: 64, 100 and 256 movers (``benchmarks/results/swarm_exchange_*_s40_gpu.json``, 2026-12-07): the kernel is
#: latency-bound at 25% occupancy (Nsight Compute, ``benchmarks/results/ncu/``), where every barrier idles its
#: block. ``MAGWARP_SWARM_EXCHANGE`` overrides it, for tuning.
EXCHANGE = "native"


def _env_choice(variable: str, default: str, choices: tuple[str, str]) -> str:
    """The environment variable ``variable`` if set (one of ``choices``, else an error naming it), else ``default``."""
    value = os.environ.get(variable, "").strip() or default
    if value not in choices:
        raise ValueError(f"{variable} must be {choices[0]!r} or {choices[1]!r}, got {value!r}")
    return value


def exchange() -> str:
    """The tiled kernel's pose exchange on CUDA (:data:`EXCHANGE`, or ``MAGWARP_SWARM_EXCHANGE``)."""
    return _env_choice("MAGWARP_SWARM_EXCHANGE", EXCHANGE, ("native", "tile"))


#: where the simulator's NaN guard checks the movers after a fused step: ``"fused"`` (the step kernel, from the final
#: state in registers: no separate pass over every mover's pose and velocity, which took 33 us of a 3.4 ms step at
#: 16,384 worlds of 100 movers on the H200, ``benchmarks/results/swarm_kernels_s43_gpu.json``) or ``"separate"`` (the
#: simulator's own check, :func:`magwarp.kernels.guard.flag_nonfinite`). The same record. ``MAGWARP_SWARM_GUARD``
#: overrides it, for measuring.
GUARD = "fused"


def guard_in_step() -> bool:
    """Whether the fused step writes the NaN guard's record itself (:data:`GUARD`, or ``MAGWARP_SWARM_GUARD``)."""
    return _env_choice("MAGWARP_SWARM_GUARD", GUARD, ("fused", "separate")) == "fused"


#: Worlds per thread block of the tiled kernel: ``1`` (a block per world), ``"auto"`` (:func:`pack_worlds`: as many
#: as waste the fewest lanes, e.g. 2 worlds of 100 movers in 7 warps instead of 8, or 2 of 16 in one warp instead of
#: two) or a count. The same results (the travel guard becomes the block's: more checks, the same flags). 1 is the
#: default: on the H100 at 16,384 worlds of 100 movers the env step took 3.565 ms with ``"auto"`` against 3.525 with 1
#: (at 128 registers an SM holds 2 blocks of 224 threads, 14 warps, against 4 of 128, 16 warps), and the same at 256
#: movers, where it packs nothing (``benchmarks/results/swarm_{sift,siftpack}_r*_s42_gpu.json``, 2026-12-07).
#: ``MAGWARP_SWARM_WORLDS`` overrides it, for tuning.
WORLDS_PER_BLOCK: int | str = 1


def pack_worlds(num_movers: int) -> int:
    """The worlds per block that waste the fewest warp lanes per world, within :data:`MAX_FUSED_MOVERS` threads (the
    smallest such count on a tie)."""
    m = int(num_movers)
    best, best_warps = 1, world_block_dim(m) // 32
    for k in range(2, MAX_FUSED_MOVERS // m + 1):
        warps = world_block_dim(k * m) // 32
        if warps * best < best_warps * k:  # warps / k < best_warps / best
            best, best_warps = k, warps
    return best


def worlds_per_block(num_movers: int) -> int:
    """The tiled kernel's worlds per block for worlds of ``num_movers`` (:data:`WORLDS_PER_BLOCK`, or
    ``MAGWARP_SWARM_WORLDS``)."""
    value = os.environ.get("MAGWARP_SWARM_WORLDS", "").strip() or str(WORLDS_PER_BLOCK)
    if value == "auto":
        return pack_worlds(num_movers)
    if not value.isdigit() or int(value) < 1:
        raise ValueError(f"MAGWARP_SWARM_WORLDS must be 'auto' or an integer >= 1, got {value!r}")
    k = int(value)
    if k * int(num_movers) > MAX_FUSED_MOVERS:
        raise ValueError(f"MAGWARP_SWARM_WORLDS={k} worlds of {num_movers} movers exceed the {MAX_FUSED_MOVERS} "
                         f"threads of a block")
    return k


def launch_block(num_movers: int) -> tuple[int, int, int]:
    """The tiled kernel's launch for worlds of ``num_movers``: worlds per block (:func:`worlds_per_block`), threads
    per block, and the register cap (:func:`max_registers`)."""
    k = worlds_per_block(num_movers)
    block = world_block_dim(k * int(num_movers))
    return k, block, max_registers(block, k)


def fused_applies(num_movers: int, on_collision: str) -> str | None:
    """None where the fused swarm step applies, else why not (for the error of an explicit ``fused=True``)."""
    if on_collision != "respawn":
        return f"on_collision={on_collision!r} stops whole worlds, which the per-cycle path does"
    if num_movers > MAX_FUSED_MOVERS:
        return f"num_movers={num_movers} exceeds the {MAX_FUSED_MOVERS} movers one thread block holds"
    return None


class FusedSwarmStep:
    """The fused motion of a swarm simulator whose movers stop where they collide. ``stopped``: the env's ``[W, M]``
    int32 stop marks (read and written by the step); ``stop_hook``: the env's per-cycle stop hook, the only cycle hook
    the fused step replaces. It writes the simulator's NaN guard record itself (``checks_nonfinite``, see
    :meth:`magwarp.sim.Simulator.set_motion`; :func:`guard_in_step`)."""

    @property
    def checks_nonfinite(self) -> bool:
        return guard_in_step()

    def __init__(self, sim, stopped: wp.array, stop_hook: Callable):
        if sim.model.collision.stop_on_collision != 0:
            raise ValueError("the fused swarm step needs stop_on_collision=False (movers stop, worlds go on)")
        if sim.num_movers > MAX_FUSED_MOVERS:
            raise ValueError(f"the fused swarm step holds at most {MAX_FUSED_MOVERS} movers per world, got "
                             f"{sim.num_movers}")
        self.stopped = stopped
        self.stop_hook = stop_hook
        W, M, dev = sim.num_worlds, sim.num_movers, sim.device
        # the launch shape: a block per world on CUDA; one thread per world on the CPU, where a tile block is one
        # thread wide unless warp.config.enable_cpu_blocks (cooperative fibers: the tests run the tiled shape there)
        self.tiled = dev.is_cuda
        shape = (1, 1) if dev.is_cuda else (W, M)  # scratch of the one-thread-per-world shape (CUDA: placeholders)
        self._scratch = [wp.zeros(shape, dtype=dtype, device=dev) for dtype in (wp.vec2, wp.vec4, kss.Candidates,
                                                                                 wp.int32)]

    def applies(self, sim) -> bool:
        """False while other cycle hooks must run between cycles, or an actuator (the in-step magnetic drive) runs in
        the step kernels, which this kernel does not call (then the per-cycle path runs)."""
        return not sim._pre_hooks and all(h == self.stop_hook for h in sim._hooks) and sim._actuator is None

    def travel(self, sim, num_cycles: int) -> float:
        """The candidate lists' travel budget (m): the distance at the shared speed cap over the step, with some room
        (a mover past it, e.g. with a per-world cap above the shared one, makes its world check every pair)."""
        lim = sim.model.limits
        return float(num_cycles * lim.dt64 * lim.v_max64 * TRAVEL_SLACK)

    def __call__(self, sim, num_cycles: int) -> bool:
        if not self.applies(sim):
            return False
        m, s, dev = sim.model, sim.state, sim.device
        latency = sim._latency_bound is not None
        args = [num_cycles, self.travel(sim, num_cycles), m.limits, m.impedance, m.collision, m.tiles, m.body,
                m.radius, m.half_size, m.margins, sim._delay, s.target_pos, s.target_quat, s.force_aux, s.cmd,
                sim._prev_cmd, s.pos, s.quat, s.vel, s.omega, s.acc, s.planar, s.wall, s.flags, s.flags_any,
                s.partner, s.world_pairs, s.world_walls, s.halted, s.cycles, s.pair_list, self.stopped,
                int(bool(sim.nan_guard) and guard_in_step()), sim._steps, sim._nonfinite]
        if self.tiled:
            if not dev.is_cuda and sim.num_movers != 1 and not wp.config.enable_cpu_blocks:
                raise ValueError(f"the tiled swarm step runs on the CPU only with warp.config.enable_cpu_blocks "
                                 f"(Warp's cooperative CPU blocks) or for worlds of one mover, got {sim.num_movers} "
                                 f"movers")
            k, block, cap = launch_block(sim.num_movers)
            kernel = kss.make_step_kernel(sim._force_model, latency, sim._nominal_body, block,
                                          cap if dev.is_cuda else 0,
                                          native=dev.is_cuda and exchange() == "native", worlds=k)
            wp.launch_tiled(kernel, dim=[-(-sim.num_worlds // k)], inputs=[*args, *self._scratch], block_dim=block,
                            device=dev)
        else:
            kernel = kss.make_step_kernel(sim._force_model, latency, sim._nominal_body, 0)
            wp.launch(kernel, dim=sim.num_worlds, inputs=[*args, *self._scratch], device=dev)
        return True
