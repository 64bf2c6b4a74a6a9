"""The fused swarm step: every control cycle of a step in one kernel, with per-mover collision stops.

The per-cycle path (:mod:`magwarp.kernels.step` with the grid broad phase, then
:func:`magwarp.kernels.swarm.stop_collided` as a cycle hook) launches three or four kernels per cycle over all
movers. Here one launch runs the whole step, with the same semantics:

* each cycle every mover advances (:func:`~magwarp.kernels.step.make_advance_kernel`'s ``advance_pose``, the same
  force model, limits and float64 x/y law), is checked against the walls and against the other movers (its partner is
  the lowest colliding index), and a mover flagged in the cycle stops for good: its x/y velocity, acceleration and
  command are zeroed after the cycle (z and attitude stay under the impedance hold), as the stop hook does;
* outputs as the per-cycle path leaves them: the last cycle's ``flags``, ``partner``, ``wall``, ``world_pairs``,
  ``world_walls`` and ``pair_list``; ``flags_any`` and ``halted`` over the step; ``cycles``; the ``stopped`` marks;
* the simulator's NaN guard (``guard``): the record :func:`~magwarp.kernels.guard.flag_nonfinite` would write after
  the step, from the movers' final state while it is in registers (one pass over every mover's pose and velocity
  less per step: 85 MB at 16,384 worlds of 100 movers).

Mover-mover checks use candidate lists built at the step's start: the movers within the pair's reach plus twice the
``travel`` budget (the farthest a mover can go in the step at the speed cap). A guard keeps this exact for any force
model: every cycle each mover checks that it is still within ``travel`` of its start, and in a cycle where any mover
of the world is not, every mover of that world checks every other. A mover with more than ``MAX_CANDIDATES``
candidates checks every other mover too.

Two launch shapes of one kernel (:func:`make_step_kernel`) with the same arithmetic:

* tiled (CUDA): one world per thread block (or several: ``worlds``), one thread per mover, its state in registers
  for the whole step; each cycle the world's positions and headings are exchanged through shared memory: by default
  with one ``__syncthreads_or`` a cycle over two buffers (:func:`share_poses`, ``native``; the movers' collision
  sizes are then read from shared memory too, :func:`share_sizes`), or through a Warp tile and a tile reduction for
  the travel guard (about four block barriers a cycle; also the shape the CPU tests run on Warp's cooperative CPU
  blocks);
* per world (CPU, where a tile block is one thread wide): one thread per world, looping over its movers, the state in
  memory.

Only the respawn rule (``stop_on_collision`` off) is fused: MagBotSim's rule stops a whole world, which the per-cycle
path does.
"""

from __future__ import annotations

import functools
from typing import Any

import warp as wp

from magwarp.kernels.collision import (add_pair, collision_flags, hits_wall_cs, model_row, movers_collide_cs,
                                       shape_heading, world_collision)
from magwarp.kernels.dynamics import sync_planar64
from magwarp.kernels.guard import flag_world, state_finite
from magwarp.kernels.options import MODULE_OPTIONS
from magwarp.kernels.step import NoActuator, make_advance_kernel
from magwarp.types import SHAPE_CIRCLE, Body, Collision, Impedance, Limits, Planar64, make_pose

wp.set_module_options({"enable_backward": False, **MODULE_OPTIONS})

MAX_CANDIDATES = 16  # candidate slots per mover; more: the mover checks every other one
MAX_BLOCK = 256  # the most movers per world the tiled kernel holds (a block of 256 threads leaves each 255 registers)
CANDIDATE_SLACK = 1.0e-3  # m: room for float32 rounding in the candidate distance test

Candidates = wp.types.vector(length=MAX_CANDIDATES, dtype=wp.int32)

# The CUDA exchange of the tiled step (one block barrier a cycle): a block's poses of this cycle in one of two shared
# buffers (by the cycle's parity), written by each lane without a barrier, then one ``__syncthreads_or`` that both
# publishes them and tells every lane whether any lane's flag is set. A buffer is written again two cycles later,
# after the next cycle's barrier, which no lane passes before every lane has read it. ``op`` 0: write ``v`` at
# ``lane`` of buffer ``buf``, then the barrier (returns ``(any flag, 0, 0, 0)``); ``op`` 1: entry ``lane`` of buffer
# ``buf``. One function, so that both ops see the same (function-scope) shared array.
@wp.func_native("""
#if defined(__CUDA_ARCH__)
    __shared__ float share_poses[2 * SHARE_BLOCK * 4];
    float* e = share_poses + (buf * SHARE_BLOCK + lane) * 4;
    if (op == 0) {
        e[0] = v.c[0]; e[1] = v.c[1]; e[2] = v.c[2]; e[3] = v.c[3];
        const int any = __syncthreads_or(flag);
        return wp::vec4(any != 0 ? 1.0f : 0.0f, 0.0f, 0.0f, 0.0f);
    }
    return wp::vec4(e[0], e[1], e[2], e[3]);
#else
    return v;
#endif
""".replace("SHARE_BLOCK", str(MAX_BLOCK)))
def share_poses(op: int, buf: int, lane: int, v: wp.vec4, flag: int) -> wp.vec4:
    """The CUDA exchange of the tiled step's poses (see above; blocks of at most :data:`MAX_BLOCK` threads)."""
    ...


@wp.func
def bounding_radius(col: Collision, r: float, half: wp.vec2) -> float:
    """Radius of a circle about the mover centre that holds its collision shape grown by the safety margin."""
    if col.shape == SHAPE_CIRCLE:
        return r + col.margin
    return wp.length(half + wp.vec2(col.margin, col.margin))


# The movers' collision sizes (radius, half x, half y, bounding radius) in shared memory for the native exchange,
# written once a step by each lane before the block's first barrier (the start positions' tile) and read by every lane
# after it (one 16-byte load): the candidate search and the partner checks then read no model row per candidate, and
# the search takes each partner's bounding radius as its owner computed it. ``op`` 0: write ``v`` at ``lane``;
# ``op`` 1: entry ``lane``.
@wp.func_native("""
#if defined(__CUDA_ARCH__)
    __shared__ __align__(16) float4 share_sizes[SHARE_BLOCK];
    if (op == 0) {
        share_sizes[lane] = make_float4(v.c[0], v.c[1], v.c[2], v.c[3]);
        return v;
    }
    const float4 e = share_sizes[lane];
    return wp::vec4(e.x, e.y, e.z, e.w);
#else
    return v;
#endif
""".replace("SHARE_BLOCK", str(MAX_BLOCK)))
def share_sizes(op: int, lane: int, v: wp.vec4) -> wp.vec4:
    """The CUDA shared copy of the tiled step's collision sizes (see above; blocks of at most :data:`MAX_BLOCK`)."""
    ...


@functools.cache
def make_size_of(native: bool = False):
    """``size_of(col, radius, half_size, wr, wh, base, j)``: mover ``j``'s collision radius, half sizes and bounding
    radius (:func:`bounding_radius`) as a vec4, from the model's rows or, ``native``, from :func:`share_sizes` (its
    world's entries from lane ``base``)."""

    @wp.func
    def size_of(col: Collision, radius: wp.array2d(dtype=float), half_size: wp.array2d(dtype=wp.vec2), wr: int,
                wh: int, base: int, j: int) -> wp.vec4:
        if wp.static(native):
            return share_sizes(1, base + j, wp.vec4())
        else:
            h = half_size[wh, j]
            r = radius[wr, j]
            return wp.vec4(r, h[0], h[1], bounding_radius(col, r, h))

    return size_of


@wp.func
def is_candidate(d0: wp.vec2, bi: float, bj: float, travel: float) -> bool:
    """Can two movers whose step-start centres differ by ``d0`` (bounding radii ``bi``, ``bj``:
    :func:`bounding_radius`) collide in the step while each stays within ``travel`` of its start?"""
    reach = bi + bj + 2.0 * travel + CANDIDATE_SLACK
    return wp.dot(d0, d0) <= reach * reach


@wp.func
def stop_after(f: int, stopped: int, vel: wp.vec3, acc: wp.vec2, cmd: wp.vec2):
    """The stop rule of :func:`magwarp.kernels.swarm.stop_collided` on one mover's values: a mover flagged in this
    cycle is stopped for good; a stopped mover's x/y velocity, acceleration and command are zero."""
    s = stopped
    if f != 0:
        s = 1
    if s != 0:
        return s, wp.vec3(0.0, 0.0, vel[2]), wp.vec2(0.0), wp.vec2(0.0)
    return s, vel, acc, cmd


@wp.func
def moved_far(p: wp.vec3, start: wp.vec2, travel: float) -> int:
    """1 where a mover is more than ``travel`` from its step-start centre (its candidate list may then miss)."""
    d = wp.vec2(p[0] - start[0], p[1] - start[1])
    if wp.dot(d, d) > travel * travel:
        return 1
    return 0


@functools.cache
def make_find_candidates(native: bool = False):
    """:func:`find_candidates` with the partners' sizes from :func:`make_size_of` (``native``: shared memory)."""
    size_of = make_size_of(native)

    @wp.func
    def find_candidates(
        starts: Any, base: int, m: int, num_movers: int, col: Collision, radius: wp.array2d(dtype=float),
        half_size: wp.array2d(dtype=wp.vec2), wr: int, wh: int, travel: float, r: float, h: wp.vec2,
    ):
        """Mover ``m``'s candidates in ascending order (``starts[base + j]``: the step-start x/y of mover ``j``, from
        a tile, where its world's entries start at ``base``, or an array row; ``r``, ``h``: mover ``m``'s own sizes)
        and their count (more than ``MAX_CANDIDATES``: the list is incomplete)."""
        cand = Candidates()
        count = int(0)
        start = starts[base + m]
        bm = bounding_radius(col, r, h)
        for j in range(num_movers):
            if j != m:
                sj = size_of(col, radius, half_size, wr, wh, base, j)
                if is_candidate(start - starts[base + j], bm, sj[3], travel):
                    if count < MAX_CANDIDATES:
                        cand[count] = j
                    count += 1
        return cand, count

    return find_candidates


@functools.cache
def make_lowest_partner(native: bool = False):
    """:func:`lowest_partner` reading the poses from an array row or a tile (``movers[j]``) or, ``native``, from the
    CUDA exchange's buffer ``movers`` (an int: :func:`share_poses`), with the partners' sizes from
    :func:`make_size_of`."""
    size_of = make_size_of(native)

    @wp.func
    def pose_of(movers: Any, j: int) -> wp.vec4:
        if wp.static(native):
            return share_poses(1, movers, j, wp.vec4(), 0)
        else:
            return movers[j]

    @wp.func
    def lowest_partner(
        movers: Any, base: int, cand: Any, count: int, every: bool, m: int, num_movers: int, col: Collision,
        radius: wp.array2d(dtype=float), half_size: wp.array2d(dtype=wp.vec2), wr: int, wh: int, r: float,
        h: wp.vec2, record: bool, w: int, world_pairs: wp.array(dtype=wp.int32), pair_list: wp.array2d(dtype=wp.vec2i),
    ) -> int:
        """The lowest index colliding with mover ``m`` this cycle, -1 if none (``movers``: x, y and heading (cos, sin)
        of each mover, its world's from entry ``base``, see :func:`pose_of`): among its ``count`` candidates ``cand``,
        or among every mover (``every``); ``r``, ``h``: mover ``m``'s own sizes. ``record``: list the pairs (from
        their lower index) and count them, as the last cycle does."""
        q = pose_of(movers, base + m)
        p = wp.vec2(q[0], q[1])
        hd = wp.vec2(q[2], q[3])
        partner = int(-1)
        num = count
        if every:
            num = num_movers
        for k in range(num):
            j = k
            if not every:
                j = cand[k]
            if j != m:
                o = pose_of(movers, base + j)
                d = wp.vec2(p[0] - o[0], p[1] - o[1])
                sj = size_of(col, radius, half_size, wr, wh, base, j)
                if movers_collide_cs(col, d, hd, r, h, wp.vec2(o[2], o[3]), sj[0], wp.vec2(sj[1], sj[2])):
                    if partner < 0:  # in ascending order: the first hit is the lowest index
                        partner = j
                    if record:
                        if j > m:
                            add_pair(w, m, j, world_pairs, pair_list)
                    else:
                        break
        return partner

    return lowest_partner


@functools.cache
def _mover_cycle(force_fn, latency: bool, nominal: bool):
    """One mover's cycle from values (the advance of :func:`~magwarp.kernels.step.make_advance_kernel`'s
    ``advance_mover`` and its wall check): returns the new pose, acceleration, float64 x/y state and wall flag."""
    advance_pose = make_advance_kernel(force_fn, latency, nominal)[2]

    @wp.func
    def mover_cycle(
        pos: wp.vec3, quat: wp.quat, vel: wp.vec3, omega: wp.vec3, acc: wp.vec2, planar: Planar64, u: wp.vec2,
        b: Body, target_pos: wp.vec3, target_quat: wp.quat, aux: wp.array(dtype=float), lim: Limits,
        imp: Impedance, col: Collision, tiles: wp.array2d(dtype=wp.int32), r: float, half: wp.vec2,
    ):
        p = make_pose(pos, quat, vel, omega)
        xy0 = sync_planar64(planar, pos, vel, acc)
        # no actuator: the fused swarm step declines while one is set (FusedSwarmStep.applies)
        n, a, xy = advance_pose(p, xy0, u, b, target_pos, target_quat, aux, lim, imp, NoActuator(), 0, 0, 0)
        hit = int(0)
        if hits_wall_cs(tiles, col, wp.vec2(n.pos[0], n.pos[1]), shape_heading(col, n.quat), r, half):
            hit = 1
        return n, a, xy, hit

    return mover_cycle


@functools.cache
def make_step_kernel(force_fn, latency: bool, nominal: bool, block_dim: int, max_registers: int = 0,
                     native: bool = False, worlds: int = 1):
    """The fused swarm step for ``force_fn``. ``block_dim`` > 0: the CUDA shape,
    ``wp.launch_tiled(kernel, dim=num_worlds, block_dim=block_dim)`` with ``block_dim`` >= the movers per world; lanes
    past the last mover mirror it (same work, no writes) so that every lane reaches every tile operation.
    ``block_dim`` 0: the CPU shape, one thread per world (``dim=num_worlds``), the state in memory, the same
    candidate and partner functions; ``start_xy`` (vec2), ``snap`` (vec4), ``cand_list`` (:data:`Candidates`) and
    ``cand_count`` (int32), all ``[W, M]``, are its scratch. ``max_registers`` > 0 (CUDA): a cap on the registers per
    thread (``__maxnreg__``; more blocks per SM, maybe spills; the same arithmetic), 0: the compiler's choice.
    ``native`` (CUDA, tiled): each cycle's poses and the travel guard go through :func:`share_poses` (one block
    barrier a cycle) instead of a Warp tile and a tile reduction (about four barriers); the same arithmetic.
    ``worlds`` (tiled): worlds per block, ``block_dim >= worlds * movers``, launched as ``dim=ceil(num_worlds /
    worlds)``: lane ``l`` is mover ``l % M`` of the block's world ``l // M``; lanes past ``worlds * M`` and the lanes
    of worlds past the last one mirror a mover (the same work, no writes). The travel guard is then the block's: a
    mover past its budget makes every world of its block check every pair (the same results, more work)."""
    if native and int(block_dim) > MAX_BLOCK:
        raise ValueError(f"the native exchange holds blocks of at most {MAX_BLOCK} threads, got {block_dim}")
    K = int(worlds)
    if K < 1 or (int(block_dim) > 0 and K > int(block_dim)):
        raise ValueError(f"worlds per block must be in 1..block_dim={block_dim}, got {worlds!r}")
    mover_cycle = _mover_cycle(force_fn, latency, nominal)
    NATIVE = bool(native) and int(block_dim) > 0
    lowest_partner = make_lowest_partner(NATIVE)  # (NATIVE: the other shapes' calls are static branches not taken)
    find_candidates = make_find_candidates(NATIVE)
    TILED = int(block_dim) > 0
    BLOCK = max(int(block_dim), 1)
    options = {**MODULE_OPTIONS, "block_dim": BLOCK} if TILED else MODULE_OPTIONS

    caps = {"cuda_max_registers": int(max_registers)} if int(max_registers) > 0 else {}

    @wp.kernel(module="unique", enable_backward=False, module_options=options, **caps)
    def swarm_step(
        num_cycles: int,
        travel: float,  # m: the candidate lists' travel budget
        # Model:
        lim: Limits,
        imp: Impedance,
        col_shared: Collision,
        tiles: wp.array2d(dtype=wp.int32),
        body: wp.array2d(dtype=Body),
        radius: wp.array2d(dtype=float),
        half_size: wp.array2d(dtype=wp.vec2),
        margins: wp.array(dtype=wp.vec2),
        # State in:
        delay: wp.array(dtype=wp.int32),  # latency only: per-world delay (cycles)
        target_pos: wp.array2d(dtype=wp.vec3),
        target_quat: wp.array2d(dtype=wp.quat),
        force_aux: wp.array3d(dtype=float),
        # State out:
        cmd: wp.array2d(dtype=wp.vec2),
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
        stopped: wp.array2d(dtype=wp.int32),
        # The NaN guard (guard 1: a world with a non-finite mover after the step gets the step's number, once):
        guard: int,
        steps: wp.array(dtype=wp.int32),
        nonfinite_step: wp.array(dtype=wp.int32),
        # Scratch of the per-world shape (placeholders for the tiled one):
        start_xy: wp.array2d(dtype=wp.vec2),  # the step-start x/y
        snap: wp.array2d(dtype=wp.vec4),  # this cycle's x, y and heading (cos, sin)
        cand_list: wp.array2d(dtype=Candidates),
        cand_count: wp.array2d(dtype=wp.int32),
    ):
        if wp.static(TILED):
            blk, lane = wp.tid()
            M = pos.shape[1]
            slot = wp.min(lane // M, K - 1)  # the block's world of this lane (lanes past K * M: the last one's)
            first = slot * M  # the world's first lane: its entries in the shared buffers
            w_raw = blk * K + slot
            w = wp.min(w_raw, pos.shape[0] - 1)  # worlds past the last one mirror it
            m = wp.min(lane - first, M - 1)
            live = lane < K * M and w_raw < pos.shape[0]
            col = world_collision(col_shared, margins, w)
            wr = model_row(radius.shape[0], w)
            wh = model_row(half_size.shape[0], w)
            b = body[model_row(body.shape[0], w), m]
            r = radius[wr, m]
            h = half_size[wh, m]
            P = pos[w, m]
            Q = quat[w, m]
            V = vel[w, m]
            Om = omega[w, m]
            A = acc[w, m]
            XY = planar[w, m]
            U = cmd[w, m]
            S = stopped[w, m]
            TP = target_pos[w, m]
            TQ = target_quat[w, m]
            held = int(0)
            Up = wp.vec2(0.0)
            if wp.static(latency):
                held = delay[w]
                Up = prev_cmd[w, m]
            if live and m == 0:  # per-step accumulators (ordered before the adds below by the tiles' barriers)
                world_pairs[w] = 0
                world_walls[w] = 0
                halted[w] = 0
                cycles[w] = num_cycles
            # Candidate lists from the step-start positions.
            start = wp.vec2(P[0], P[1])
            # Shared tiles (one entry per lane), each lane writing its own entry (tile_assign synchronises the block
            # after writing); each lane then reads any entry.
            starts = wp.tile_zeros(shape=BLOCK, dtype=wp.vec2, storage="shared")
            if wp.static(not NATIVE):
                movers = wp.tile_zeros(shape=BLOCK, dtype=wp.vec4, storage="shared")
            if wp.static(NATIVE):  # the sizes, published by the starts' barrier below
                share_sizes(0, lane, wp.vec4(r, h[0], h[1], bounding_radius(col, r, h)))
            wp.tile_assign(starts, wp.tile(start, preserve_type=True))
            cand, count = find_candidates(starts, first, m, M, col, radius, half_size, wr, wh, travel, r, h)
            F = int(0)
            Fa = int(0)
            Wl = int(0)
            Pr = int(-1)
            last = num_cycles - 1
            for c in range(num_cycles):
                u = U
                if wp.static(latency):
                    if c < held:
                        u = Up
                n, a, xy, hit = mover_cycle(P, Q, V, Om, A, XY, u, b, TP, TQ, force_aux[w, m], lim, imp, col, tiles, r,
                                            h)
                P = n.pos
                Q = n.quat
                V = n.vel
                Om = n.omega
                A = a
                XY = xy
                Wl = hit
                hd = shape_heading(col, Q)
                # Whether any mover left its travel budget, and the world's positions and headings of this cycle: one
                # barrier (native, see share_poses) or, with tiles, the reduction then the tile. With tiles the order
                # matters: tile_assign writes without a barrier first, and the reduction's result (a shared tile
                # written with a barrier before, from the second cycle on) holds every lane there until all have read
                # the last cycle's entries.
                if wp.static(NATIVE):
                    buf = c % 2
                    any_far = share_poses(0, buf, lane, wp.vec4(P[0], P[1], hd[0], hd[1]), moved_far(P, start, travel))
                    every = any_far[0] != 0.0 or count > MAX_CANDIDATES
                    Pr = lowest_partner(buf, first, cand, count, every, m, M, col, radius, half_size, wr, wh, r, h,
                                        c == last and live, w, world_pairs, pair_list)
                else:
                    far = wp.tile_max(wp.tile(moved_far(P, start, travel)))
                    wp.tile_assign(movers, wp.tile(wp.vec4(P[0], P[1], hd[0], hd[1]), preserve_type=True))
                    every = far[0] != 0 or count > MAX_CANDIDATES
                    Pr = lowest_partner(movers, first, cand, count, every, m, M, col, radius, half_size, wr, wh, r, h,
                                        c == last and live, w, world_pairs, pair_list)
                F = collision_flags(Pr, Wl)
                Fa = Fa | F
                S, V, A, U = stop_after(F, S, V, A, U)
            if live:
                if Wl != 0:
                    wp.atomic_add(world_walls, w, 1)
                if Fa != 0:
                    halted[w] = 1
                pos[w, m] = P
                quat[w, m] = Q
                vel[w, m] = V
                omega[w, m] = Om
                acc[w, m] = A
                planar[w, m] = XY
                cmd[w, m] = U
                wall[w, m] = Wl
                flags[w, m] = F
                flags_any[w, m] = Fa
                partner[w, m] = Pr
                stopped[w, m] = S
                if wp.static(latency):  # the next step's previous command
                    prev_cmd[w, m] = U
                if guard != 0 and not state_finite(P, Q, V, Om):
                    flag_world(steps, nonfinite_step, w)
        else:
            w = wp.tid()
            M = pos.shape[1]
            col = world_collision(col_shared, margins, w)
            wr = model_row(radius.shape[0], w)
            wh = model_row(half_size.shape[0], w)
            wb = model_row(body.shape[0], w)
            world_pairs[w] = 0
            world_walls[w] = 0
            halted[w] = 0
            cycles[w] = num_cycles
            for m in range(M):
                start_xy[w, m] = wp.vec2(pos[w, m][0], pos[w, m][1])
                flags_any[w, m] = 0
            for m in range(M):
                cm, nm = find_candidates(start_xy[w], 0, m, M, col, radius, half_size, wr, wh, travel, radius[wr, m],
                                         half_size[wh, m])
                cand_list[w, m] = cm
                cand_count[w, m] = nm
            last = num_cycles - 1
            for c in range(num_cycles):
                far = int(0)
                for m in range(M):
                    u = cmd[w, m]
                    if wp.static(latency):
                        if c < delay[w]:
                            u = prev_cmd[w, m]
                    n, a, xy, hit = mover_cycle(pos[w, m], quat[w, m], vel[w, m], omega[w, m], acc[w, m], planar[w, m],
                                                u, body[wb, m], target_pos[w, m], target_quat[w, m], force_aux[w, m],
                                                lim, imp, col, tiles, radius[wr, m], half_size[wh, m])
                    pos[w, m] = n.pos
                    quat[w, m] = n.quat
                    vel[w, m] = n.vel
                    omega[w, m] = n.omega
                    acc[w, m] = a
                    planar[w, m] = xy
                    wall[w, m] = hit
                    hd = shape_heading(col, n.quat)
                    snap[w, m] = wp.vec4(n.pos[0], n.pos[1], hd[0], hd[1])
                    far = wp.max(far, moved_far(n.pos, start_xy[w, m], travel))
                for m in range(M):
                    every = far != 0 or cand_count[w, m] > MAX_CANDIDATES
                    pr = lowest_partner(snap[w], 0, cand_list[w, m], cand_count[w, m], every, m, M, col, radius,
                                        half_size, wr, wh, radius[wr, m], half_size[wh, m], c == last, w,
                                        world_pairs, pair_list)
                    f = collision_flags(pr, wall[w, m])
                    flags[w, m] = f
                    flags_any[w, m] = flags_any[w, m] | f
                    partner[w, m] = pr
                    s, v, a, u = stop_after(f, stopped[w, m], vel[w, m], acc[w, m], cmd[w, m])
                    stopped[w, m] = s
                    vel[w, m] = v
                    acc[w, m] = a
                    cmd[w, m] = u
            for m in range(M):
                if wall[w, m] != 0:
                    world_walls[w] = world_walls[w] + 1
                if flags_any[w, m] != 0:
                    halted[w] = 1
                if wp.static(latency):  # the next step's previous command
                    prev_cmd[w, m] = cmd[w, m]
                if guard != 0 and not state_finite(pos[w, m], quat[w, m], vel[w, m], omega[w, m]):
                    flag_world(steps, nonfinite_step, w)

    return swarm_step
