"""The fused small-world step with one thread per mover: several worlds per thread block, each world's positions and
headings exchanged through shared memory (Warp tiles) every cycle.

:func:`magwarp.kernels.step.make_register_kernel` runs a small world in one thread that holds every mover's state
(and, in the general variant, every mover's body row) in registers for all cycles of a step: on sm_90 it sits at the
255-register cap and spills, the more so with per-world rows and action latency. Here a thread holds one mover: its
state and its command; the general variant keeps the mover's (per-world) body row for the step in shared memory, a
column per lane (or in registers: ``rows``), the nominal one reads the one shared row every cycle, as the register
kernel does. Each cycle:

1. every live mover advances (:func:`~magwarp.kernels.step.make_advance_kernel`'s ``advance_pose``: the same force
   model, limits and float64 x/y law as the register kernel, called with the same arguments) and checks the walls;
2. it writes its x/y and shape heading into a shared tile; after the block's barrier it checks every other mover of
   its world (the pair ``(i, j)``, ``i < j``, evaluated as the register kernel does: offset ``p_i - p_j``, ``i``'s
   heading and sizes first), its partner being the lowest colliding index;
3. it writes its count of pairs with higher movers and its wall flag into a second shared tile; after the barrier
   every mover of the world knows the world's pair and wall counts (so whether the world stops) and where its own
   pairs go in the world's pair list (the register kernel's order: ``i`` ascending, then ``j``).

The results are those of the register kernel bit for bit (same arithmetic, same order), outputs included
(``flags``, ``flags_any``, ``partner``, ``wall``, ``world_pairs``, ``world_walls``, ``pair_list``, ``halted``,
``cycles``, ``stop_on_collision``, action latency). A world that stops (``stop_on_collision``) keeps its lanes in the
cycle loop, idle, since every lane must reach every barrier of its block. (Bit for bit on the CPU:
``tests/test_step_blocks.py``; on CUDA the two kernels are separate compilations of the same functions, which
``benchmarks/small_world_kernels.py`` compares.)

Launch: ``wp.launch_tiled(kernel, dim=[num_blocks(W, M, block_dim)], block_dim=block_dim)``: ``K = block_dim // M``
worlds per block, lane ``l`` is mover ``l % M`` of the block's world ``l // M``. Lanes past ``K * M`` and lanes of
worlds past the last one mirror a valid world's mover (the same work on the same inputs, their own tile entries,
no writes). No actuator (:class:`~magwarp.kernels.step.Actuator`): the simulator keeps the register kernel then.
On the CPU it needs Warp's cooperative CPU blocks (``wp.config.enable_cpu_blocks``).
"""

from __future__ import annotations

import functools

import warp as wp

from magwarp.kernels.collision import (collision_flags, hits_wall_cs, model_row, movers_collide_cs, shape_heading,
                                       world_collision)
from magwarp.kernels.dynamics import sync_planar64
from magwarp.kernels.options import MODULE_OPTIONS
from magwarp.kernels.params import BodyF32, BodyF64, body_f32, body_f64, row_body
from magwarp.kernels.step import NoActuator, make_advance_kernel
from magwarp.types import Body, Collision, Impedance, Limits, Planar64, make_pose

wp.set_module_options({"enable_backward": False, **MODULE_OPTIONS})


def worlds_per_block(num_movers: int, block_dim: int) -> int:
    """Worlds of ``num_movers`` movers one block of ``block_dim`` threads holds."""
    if num_movers < 1 or block_dim < num_movers:
        raise ValueError(f"a block of {block_dim} threads cannot hold a world of {num_movers} movers")
    return block_dim // num_movers


def num_blocks(num_worlds: int, num_movers: int, block_dim: int) -> int:
    """Blocks of the launch for ``num_worlds`` worlds."""
    k = worlds_per_block(num_movers, block_dim)
    return (num_worlds + k - 1) // k


@functools.cache
def make_movers_kernel(force_fn, num_movers: int, latency: bool = False, nominal: bool = False,
                       block_dim: int = 96, max_registers: int = 0, rows: str = "shared"):
    """The one-thread-per-mover fused step for ``force_fn``, specialised for ``num_movers`` and ``block_dim`` (see the
    module docstring). Same arguments as :func:`~magwarp.kernels.step.make_register_kernel`'s kernel (``act`` a
    :class:`~magwarp.kernels.step.NoActuator`), ``latency`` and ``nominal`` as there. ``max_registers`` > 0 caps the
    registers per thread on CUDA (``__maxnreg__``: more blocks per SM, spilling what does not fit). ``rows``: where
    the general variant keeps each mover's body row for the step, ``"registers"`` or ``"shared"`` (shared memory, one
    column per lane, read every cycle: about 20 registers fewer; the nominal variant reads the one shared row from
    memory every cycle either way)."""
    if rows not in ("registers", "shared"):
        raise ValueError(f"rows must be 'registers' or 'shared', got {rows!r}")
    if not 1 <= int(num_movers) <= 31:  # a mover's colliding partners above it are an int32 bit mask
        raise ValueError(f"the movers kernel takes worlds of 1 to 31 movers, got {num_movers!r}")
    shared_rows = bool(rows == "shared" and not nominal)
    M = int(num_movers)
    B = int(block_dim)
    K = worlds_per_block(M, B)
    advance_pose = make_advance_kernel(force_fn, latency, nominal)[2]
    caps = {"cuda_max_registers": int(max_registers)} if max_registers > 0 else {}

    @wp.kernel(module="unique", enable_backward=False, module_options={**MODULE_OPTIONS, "block_dim": B}, **caps)
    def fused_movers(
        num_cycles: int,
        # Model:
        lim: Limits,
        imp: Impedance,
        col_shared: Collision,
        tiles: wp.array2d(dtype=wp.int32),
        body: wp.array2d(dtype=Body),
        radius: wp.array2d(dtype=float),
        half_size: wp.array2d(dtype=wp.vec2),
        margins: wp.array(dtype=wp.vec2),
        act: NoActuator,  # never read (no actuator in this shape)
        # State in:
        cmd: wp.array2d(dtype=wp.vec2),
        delay: wp.array(dtype=wp.int32),  # latency only: per-world delay (cycles)
        target_pos: wp.array2d(dtype=wp.vec3),
        target_quat: wp.array2d(dtype=wp.quat),
        force_aux: wp.array3d(dtype=float),
        # State out:
        prev_cmd: wp.array2d(dtype=wp.vec2),  # latency only: the previous step's command, then this step's
        pos: wp.array2d(dtype=wp.vec3),
        quat: wp.array2d(dtype=wp.quat),
        vel: wp.array2d(dtype=wp.vec3),
        omega: wp.array2d(dtype=wp.vec3),
        acc: wp.array2d(dtype=wp.vec2),
        planar: wp.array2d(dtype=Planar64),
        wall: wp.array2d(dtype=wp.int32),
        flags: wp.array2d(dtype=wp.int32),
        flags_any: wp.array2d(dtype=wp.int32),
        partner: wp.array2d(dtype=wp.int32),
        world_pairs: wp.array(dtype=wp.int32),
        world_walls: wp.array(dtype=wp.int32),
        halted: wp.array(dtype=wp.int32),
        cycles: wp.array(dtype=wp.int32),
        pair_list: wp.array2d(dtype=wp.vec2i),
    ):
        blk, lane = wp.tid()
        m = lane % M
        slot = wp.min(lane // M, K - 1)  # lanes past K * M mirror the block's last world
        first = slot * M  # the tile entry of the world's mover 0
        w_raw = blk * K + slot
        w = wp.min(w_raw, pos.shape[0] - 1)  # worlds past the last one mirror it
        live = lane < K * M and w_raw < pos.shape[0]
        col = world_collision(col_shared, margins, w)
        wb = model_row(body.shape[0], w)
        b = body[wb, m]  # kept by the general variant (see rows); the nominal one reads the shared row each cycle
        r = radius[model_row(radius.shape[0], w), m]
        h = half_size[model_row(half_size.shape[0], w), m]
        P = pos[w, m]
        Q = quat[w, m]
        V = vel[w, m]
        Om = omega[w, m]
        A = acc[w, m]
        XY = sync_planar64(planar[w, m], P, V, A)
        TP = target_pos[w, m]
        TQ = target_quat[w, m]
        # The acting command: the step's or, with latency, the previous step's during the world's first ``held``
        # cycles, the step's from cycle ``held`` on (as the register kernel loads them).
        U = cmd[w, m]
        held = int(0)
        if wp.static(latency):
            held = delay[w]
            if held > 0:
                U = prev_cmd[w, m]
        Wl = wall[w, m]
        F = flags[w, m]
        Fa = int(0)  # per-step accumulators start here: fused steps need no begin_step launch
        Pr = partner[w, m]
        pairs = world_pairs[w]
        walls = world_walls[w]
        stopped = int(0)
        done = int(0)
        # Shared tiles, one entry per lane, each lane writing its own (tile_assign writes, then synchronises the
        # block): the sizes once, then per cycle the poses (x, y, heading) and the (pairs above, wall) counts. Two
        # barriers a cycle keep a lane from overwriting an entry that another lane has yet to read.
        sizes = wp.tile_zeros(shape=B, dtype=wp.vec3, storage="shared")
        poses = wp.tile_zeros(shape=B, dtype=wp.vec4, storage="shared")
        counts = wp.tile_zeros(shape=B, dtype=wp.int32, storage="shared")
        wp.tile_assign(sizes, wp.tile(wp.vec3(r, h[0], h[1]), preserve_type=True))
        if wp.static(shared_rows):  # the body rows, a column per lane (conflict-free reads)
            rows32 = wp.tile_zeros(shape=(20, B), dtype=wp.float32, storage="shared")
            rows64 = wp.tile_zeros(shape=(4, B), dtype=wp.float64, storage="shared")
            wp.tile_assign(rows32, wp.tile(body_f32(b)))
            wp.tile_assign(rows64, wp.tile(body_f64(b)))
        for c in range(num_cycles):
            active = col.stop_on_collision == 0 or stopped == 0  # the same in every lane of a world
            hd = wp.vec2(1.0, 0.0)  # the shape's heading (cos, sin); a stopped world's lanes read no tile entries
            if active:
                if wp.static(latency):
                    if c == held and c > 0:
                        U = cmd[w, m]
                if wp.static(nominal):
                    b = body[wb, m]
                if wp.static(shared_rows):
                    f32 = BodyF32()
                    for k in range(20):
                        f32[k] = rows32[k, lane]
                    f64 = BodyF64()
                    for k in range(4):
                        f64[k] = rows64[k, lane]
                    b = row_body(f32, f64)
                n, a, xy = advance_pose(make_pose(P, Q, V, Om), XY, U, b, TP, TQ, force_aux[w, m], lim, imp, act, w,
                                        m, int(c == num_cycles - 1))
                P = n.pos
                Q = n.quat
                V = n.vel
                Om = n.omega
                A = a
                XY = xy
                hd = shape_heading(col, Q)
                hit = int(0)
                if hits_wall_cs(tiles, col, wp.vec2(P[0], P[1]), hd, r, h):
                    hit = 1
                Wl = hit
                done += 1
            wp.tile_assign(poses, wp.tile(wp.vec4(P[0], P[1], hd[0], hd[1]), preserve_type=True))
            above = int(0)  # colliding movers above this one: bit j set for mover j
            num_above = int(0)
            if active:
                Pr = int(-1)
                # Dynamic loops over the world's movers (not unrolled): unrolled, the compiler keeps every partner's
                # entries live at once (about 30 registers more for 3 movers, 40 for 8, on sm_90).
                for i in range(first, first + M):
                    j = i - first
                    if j != m:
                        o = poses[i]
                        s = sizes[i]
                        # the pair (lower index, higher index) as the register kernel evaluates it, through one call
                        # for every lane (a branch per order would run both orders in turn in a warp)
                        lo = j < m
                        oh = wp.vec2(o[2], o[3])
                        oz = wp.vec2(s[1], s[2])
                        d = wp.vec2(P[0] - o[0], P[1] - o[1])
                        if lo:
                            d = wp.vec2(o[0] - P[0], o[1] - P[1])
                        hit_j = movers_collide_cs(col, d, wp.where(lo, oh, hd), wp.where(lo, s[0], r),
                                                  wp.where(lo, oz, h), wp.where(lo, hd, oh), wp.where(lo, r, s[0]),
                                                  wp.where(lo, h, oz))
                        if hit_j:
                            if Pr < 0:  # ascending: the first hit is the lowest index
                                Pr = j
                            if j > m:
                                above = above | (1 << j)
                                num_above += 1
                F = collision_flags(Pr, Wl)
                Fa = Fa | F
            wp.tile_assign(counts, wp.tile(2 * num_above + wp.where(Wl != 0, 1, 0), preserve_type=True))
            if active:
                pairs = int(0)
                walls = int(0)
                k = int(0)  # this mover's first entry in the world's pair list
                for i in range(first, first + M):
                    e = counts[i]
                    pairs += e >> 1
                    walls += e & 1
                    if i - first < m:
                        k += e >> 1
                if live and above != 0:
                    for j in range(m + 1, M):
                        if (above >> j) & 1 != 0:
                            if k < pair_list.shape[1]:
                                pair_list[w, k] = wp.vec2i(m, j)
                            k += 1
                if pairs > 0 or walls > 0:
                    stopped = 1
        if live:
            pos[w, m] = P
            quat[w, m] = Q
            vel[w, m] = V
            omega[w, m] = Om
            acc[w, m] = A
            planar[w, m] = XY
            wall[w, m] = Wl
            flags[w, m] = F
            flags_any[w, m] = Fa
            partner[w, m] = Pr
            if wp.static(latency):  # the next step's previous command
                prev_cmd[w, m] = cmd[w, m]
            if m == 0:
                world_pairs[w] = pairs
                world_walls[w] = walls
                halted[w] = stopped
                cycles[w] = done

    return fused_movers
