"""Local observation kernels for large swarms: k nearest movers within a radius, and distances to the walls.

:func:`make_observation_kernel` fills each mover's observation row in one pass:

* its own state (velocity, goal relative to it, acceleration, carrying flag; each part optional);
* the ``k`` nearest other movers of its world within ``radius`` (ordered by distance, ties by index; relative x, y,
  vx, vy and a mask per slot), found either by scanning the neighbouring cells of a uniform grid whose lists the
  simulator's own :func:`~magwarp.kernels.collision.bin_movers` builds (work per mover: the movers in its
  neighbouring cells, not the world's), or, for worlds of up to 256 movers on CUDA, with one thread block per world
  that loads its movers' positions and velocities into shared memory once and lets each lane scan them all (no grid
  to build, no linked lists to chase: every lane reads the same entry at once). The kept candidates sit in a
  sorted list walked by an unrolled compare-and-swap chain, so it stays in registers;
* for each of a few ray directions, the distance from its centre to the first point off the tiles (a hole or the
  layout's edge), capped at ``max_range``, by stepping tile by tile along the ray (at most ``max_range / tile_size``
  steps per ray: :func:`ray_to_wall`), or on a layout with every tile present in closed form, the same distances bit
  for bit (:func:`ray_to_rect`: no tile read).

It writes the rows straight into the caller's ``[W, M, D]`` array (no copies), the neighbours' indices beside them,
and a per-world flag for any non-finite entry.
"""

from __future__ import annotations

import functools
import os
from typing import Any

import warp as wp

from magwarp.kernels.collision import cell_coords
from magwarp.kernels.options import MODULE_OPTIONS
from magwarp.types import Grid

wp.set_module_options({"enable_backward": False, **MODULE_OPTIONS})

BIG = 1.0e30


# The lowest set bit's index of a non-zero word (the world search's sift walks a word of candidates by it).
@wp.func_native("""
#if defined(__CUDA_ARCH__)
    return __ffs((int)x) - 1;
#else
    return __builtin_ctz(x);
#endif
""")
def low_bit(x: wp.uint32) -> int:
    """Index of the lowest set bit of ``x`` (``x`` != 0)."""
    ...


@wp.kernel
def clear_heads(head: wp.array(dtype=wp.int32)):
    head[wp.tid()] = -1


@wp.func
def tile_present(tiles: wp.array2d(dtype=wp.int32), i: int, j: int) -> bool:
    if i < 0 or j < 0 or i >= tiles.shape[0] or j >= tiles.shape[1]:
        return False
    return tiles[i, j] == 1


@wp.func
def ray_to_wall(tiles: wp.array2d(dtype=wp.int32), size: float, p: wp.vec2, d: wp.vec2, max_range: float) -> float:
    """Distance along the unit direction ``d`` from ``p`` to the first point off the tiles, at most ``max_range``
    (grid traversal: one tile per step)."""
    i = int(wp.floor(p[0] / size))
    j = int(wp.floor(p[1] / size))
    if not tile_present(tiles, i, j):
        return 0.0
    step_i = int(0)
    step_j = int(0)
    t_x = float(BIG)
    t_y = float(BIG)
    dt_x = float(BIG)
    dt_y = float(BIG)
    if d[0] > 0.0:
        step_i = 1
        t_x = (float(i + 1) * size - p[0]) / d[0]
        dt_x = size / d[0]
    elif d[0] < 0.0:
        step_i = -1
        t_x = (float(i) * size - p[0]) / d[0]
        dt_x = -size / d[0]
    if d[1] > 0.0:
        step_j = 1
        t_y = (float(j + 1) * size - p[1]) / d[1]
        dt_y = size / d[1]
    elif d[1] < 0.0:
        step_j = -1
        t_y = (float(j) * size - p[1]) / d[1]
        dt_y = -size / d[1]
    t = float(0.0)
    while t < max_range:
        if t_x < t_y:
            t = t_x
            i += step_i
            t_x += dt_x
        else:
            t = t_y
            j += step_j
            t_y += dt_y
        if t >= max_range:
            break
        if not tile_present(tiles, i, j):
            return t
    return max_range


@wp.func
def axis_exit(p: float, d: float, i: int, n: int, size: float, max_range: float) -> float:
    """One axis of :func:`ray_to_rect`: the distance at which a ray from ``p`` (in tile ``i`` of ``n``) with direction
    component ``d`` crosses out of the rectangle, summed as the tile walk sums it (the first crossing, then one tile
    step per tile crossed) and stopped once past ``max_range``; BIG when ``d`` is 0."""
    t = float(BIG)
    dt = float(BIG)
    steps = int(0)  # tile steps along the axis before the step that leaves the rectangle
    if d > 0.0:
        t = (float(i + 1) * size - p) / d
        dt = size / d
        steps = n - 1 - i
    elif d < 0.0:
        t = (float(i) * size - p) / d
        dt = -size / d
        steps = i
    while steps > 0 and t < max_range:
        t += dt
        steps -= 1
    return t


@wp.func
def ray_to_rect(nx: int, ny: int, size: float, p: wp.vec2, d: wp.vec2, max_range: float) -> float:
    """:func:`ray_to_wall` on a layout with every tile of its ``nx`` x ``ny`` rectangle present, bit for bit: the
    walk leaves at its first crossing out of the rectangle, which is the earlier of the x and y exits, each the walk's
    own running sum (the first crossing plus one tile step per tile crossed: the same float additions in the same
    order), or ``max_range`` if that comes first. No tile is read, and each sum stops once past ``max_range``
    (the sums only grow), so a ray costs at most ``max_range / size`` additions per axis."""
    i = int(wp.floor(p[0] / size))
    j = int(wp.floor(p[1] / size))
    if i < 0 or j < 0 or i >= nx or j >= ny:
        return 0.0
    t_x = axis_exit(p[0], d[0], i, nx, size, max_range)
    t_y = axis_exit(p[1], d[1], j, ny, size, max_range)
    t = wp.min(t_x, t_y)
    if t >= max_range:
        return max_range
    return t


#: parts of the mover's own state that the observation kernels write first (bit flags)
OWN_STATE = 1  # x/y velocity, then the goal relative to the mover (4 columns)
OWN_ACC = 2  # x/y acceleration (2 columns, after the state)
OWN_CARRY = 4  # carrying flag (1 column, last)

#: how the observation kernels find the k nearest movers: the uniform grid's neighbouring cells, or every mover of
#: the world (a block per world on CUDA, the world's positions in shared memory)
SEARCHES = ("grid", "world")
#: the most movers per world the block-per-world kernel holds (one lane per mover)
MAX_WORLD_BLOCK = 256
#: the most movers per world for which the CPU scans the whole world by default (above it the grid is faster: at 64
#: worlds, world vs grid search 1.95 vs 2.1-2.4 ms with 64 movers, 3.2-3.3 vs 3.4 with 100, 10.3 vs 9.4 with 256)
MAX_WORLD_SCAN_CPU = 128
#: the world search's default limit on CUDA: every size the block-per-world kernel holds. On the H100 with the
#: branch-free slot merge and the closed-form rays (the CUDA defaults since 2026-12-06) it took 0.25 ms against the
#: grid's 1.11 ms at 16,384 worlds x 64 movers, 0.78 against 1.70 at 100 and 2.99 against 4.25 at 256, the same rows
#: (``python benchmarks/swarm.py --device cuda:0 --fused-sweep --fused-movers 256 --fused-worlds 16384``,
#: swarm_fused_s35_*_gpu.json); before the merge the grid won at 256 (7.13 against 4.28 ms, 2026-11-25).
WORLD_SEARCH_CUDA = MAX_WORLD_BLOCK
#: the world search's sift by default (:class:`magwarp.swarm.LocalObservations` ``sift``): on the H100 the
#: observation of 16,384 worlds took 0.52 ms against 0.80 without it at 100 movers and 1.27 against 2.99 at 256, the
#: same rows (``python benchmarks/swarm_obs.py --device cuda:0 --movers 100 256``, swarm_obs_sift_s42_gpu.json,
#: 2026-12-07); faster on the CPU too, up to the 128 movers it scans whole worlds for (swarm_obs_sift_cpu.json)
SIFT = True


def sift_default() -> bool:
    """:data:`SIFT`, or ``MAGWARP_OBS_SIFT`` (``0`` or ``1``) where set."""
    text = os.environ.get("MAGWARP_OBS_SIFT", "").strip()
    if text not in ("", "0", "1"):
        raise ValueError(f"MAGWARP_OBS_SIFT must be 0 or 1, got {text!r}")
    return SIFT if text == "" else text == "1"


@functools.cache
def _row_funcs(k: int, num_rays: int, own: int, search: str, unrolled: bool, merge: bool = False,
               rect: bool = False, sift: bool = False):
    """The pieces of a mover's observation row (see :func:`make_observation_kernel`): ``own_state``, ``nearest``
    (the k nearest within the radius, by ``search``), ``write_slots`` and ``write_rays``."""
    K, R = int(k), int(num_rays)
    KK = max(K, 1)
    Dists = wp.types.vector(length=KK, dtype=wp.float32)
    Ids = wp.types.vector(length=KK, dtype=wp.int32)
    WITH_STATE, WITH_ACC, WITH_CARRY = bool(own & OWN_STATE), bool(own & OWN_ACC), bool(own & OWN_CARRY)
    BASE = 4 * int(WITH_STATE) + 2 * int(WITH_ACC) + int(WITH_CARRY)
    GRID, UNROLLED = search == "grid", bool(unrolled)
    MERGE = bool(merge) and not GRID  # candidates come in index order: a branch-free merge (see nearest)
    SIFT = MERGE and bool(sift)  # only the candidates within the radius reach the merge (see nearest)
    RECT = bool(rect)

    @wp.func
    def merge_in(D: Any, I: Any, key: float, j: int):
        """Candidate ``(key, j)`` merged into the sorted slots with no branch (see :func:`nearest`); a NaN key
        changes nothing."""
        before = bool(False)  # the candidate goes before the slot above
        up_d = float(0.0)
        up_i = int(0)
        for s in range(wp.static(KK)):
            here = key < D[s]
            old_d = D[s]
            old_i = I[s]
            D[s] = wp.where(here, wp.where(before, up_d, key), old_d)
            I[s] = wp.where(here, wp.where(before, up_i, j), old_i)
            before = here
            up_d = old_d
            up_i = old_i
        return D, I

    @wp.func
    def own_state(
        w: int, m: int, p: wp.vec3, v: wp.vec3, acc: wp.array2d(dtype=wp.vec2), goals: wp.array2d(dtype=wp.vec2),
        carrying: wp.array2d(dtype=wp.bool), out: Any, row: int,
    ) -> bool:
        """Write the own-state columns into ``out[row]`` (the world's rows of the output, or a staging tile); False
        if one is not finite. Every write is unconditional (a staging tile's writes are block barriers)."""
        finite = bool(True)
        if wp.static(WITH_STATE):
            g = goals[w, m]
            row4 = wp.vec4(v[0], v[1], g[0] - p[0], g[1] - p[1])
            for e in range(4):
                out[row, e] = row4[e]
                finite = finite and wp.isfinite(row4[e])
        if wp.static(WITH_ACC):
            a = acc[w, m]
            out[row, 4] = a[0]
            out[row, 5] = a[1]
            finite = finite and wp.isfinite(a[0]) and wp.isfinite(a[1])
        if wp.static(WITH_CARRY):
            cv = float(0.0)
            if carrying[w, m]:
                cv = 1.0
            out[row, BASE - 1] = cv
        return finite

    @wp.func
    def nearest(
        rows: Any, w: int, m: int, num_movers: int, p: wp.vec3, r2: float, grid: Grid, reach: int,
        head: wp.array(dtype=wp.int32), next_in_cell: wp.array2d(dtype=wp.int32),
    ):
        """Distances squared and indices of mover ``m``'s k nearest others within the radius (nearest first, ties by
        the lower index; -1 past the last), ``rows[j]``: mover ``j``'s x, y first (an array row or a shared tile).
        Candidates: the movers of the grid's neighbouring cells, or (world search: one "cell" listing every mover)
        all of the world's."""
        D = Dists()
        I = Ids()
        if wp.static(MERGE):
            # the world's movers in index order, every candidate merged into the slots with no branch: a new one
            # has the highest index yet, so it goes after every kept one of an equal distance, before the first
            # of a greater one (strict <); a slot moves down one where the candidate goes before its upper
            # neighbour. Empty slots hold +inf, a rejected candidate (itself, outside the radius, not finite) a NaN
            # (no compare holds): the same slots as the chain while the radius squared is finite (checked by
            # LocalObservations), as every accepted distance then is.
            for s in range(KK):
                D[s] = wp.inf
                I[s] = -1
            if wp.static(SIFT):
                # A word of 32 candidates at a time: first the bits of those within the radius (a compare each),
                # then only those, lowest bit first (index order), through the merge. A warp merges as often as its
                # lane with the most such bits in the word, not once per candidate: about 13 movers lie within the
                # env's 1 m at 0.25 movers per tile. The same slots: a rejected candidate's merge changes nothing.
                base = int(0)
                while base < num_movers:
                    bits = wp.uint32(0)
                    for b in range(wp.min(32, num_movers - base)):
                        j = base + b
                        q = rows[j]
                        ex = q[0] - p[0]
                        ey = q[1] - p[1]
                        d2 = ex * ex + ey * ey
                        if d2 <= r2 and j != m:
                            bits = bits | (wp.uint32(1) << wp.uint32(b))
                    while bits != wp.uint32(0):
                        j = base + low_bit(bits)
                        bits = bits & (bits - wp.uint32(1))
                        q = rows[j]
                        ex = q[0] - p[0]
                        ey = q[1] - p[1]
                        D, I = merge_in(D, I, ex * ex + ey * ey, j)
                    base += 32
                return D, I
            nan = wp.nan
            for j in range(num_movers):
                q = rows[j]
                ex = q[0] - p[0]
                ey = q[1] - p[1]
                d2 = ex * ex + ey * ey
                D, I = merge_in(D, I, wp.where(d2 <= r2 and j != m, d2, nan), j)
            return D, I
        for s in range(KK):
            D[s] = BIG
            I[s] = -1
        c = cell_coords(grid, p)
        lo = -reach
        if wp.static(not GRID):
            lo = 0
        for dy in range(lo, -lo + 1):
            for dx in range(lo, -lo + 1):
                j = int(0)
                if wp.static(GRID):
                    cy = c[1] + dy
                    cx = c[0] + dx
                    if cy < 0 or cy >= grid.ncy or cx < 0 or cx >= grid.ncx:
                        continue
                    j = head[(w * grid.ncy + cy) * grid.ncx + cx]
                while j >= 0 and j < num_movers:
                    if j != m:
                        q = rows[j]
                        ex = q[0] - p[0]
                        ey = q[1] - p[1]
                        d2 = ex * ex + ey * ey
                        # keep (d2, j) if it beats the last kept one
                        if d2 <= r2 and (d2 < D[KK - 1] or (d2 == D[KK - 1] and j < I[KK - 1]) or I[KK - 1] < 0):
                            if wp.static(UNROLLED):
                                # constant indices (an unrolled compare-and-swap chain): the slots stay in registers
                                cd = d2
                                cj = j
                                for s in range(wp.static(KK)):
                                    if cj >= 0 and (I[s] < 0 or cd < D[s] or (cd == D[s] and cj < I[s])):
                                        td = D[s]
                                        tj = I[s]
                                        D[s] = cd
                                        I[s] = cj
                                        cd = td
                                        cj = tj
                            else:
                                # shifted from the back to its place (fewer steps; a CPU keeps the slots in cache)
                                s = KK - 1
                                while s > 0 and (D[s - 1] > d2 or (D[s - 1] == d2 and I[s - 1] > j)):
                                    D[s] = D[s - 1]
                                    I[s] = I[s - 1]
                                    s -= 1
                                D[s] = d2
                                I[s] = j
                    if wp.static(GRID):
                        j = next_in_cell[w, j]
                    else:
                        j += 1
        return D, I

    @wp.func
    def neighbour_slot(j: int, rows_pos: Any, rows_vel: Any, p: wp.vec3, v: wp.vec3):
        """Slot of neighbour ``j`` (-1: none): its x/y position and velocity relative to the mover, and its mask flag
        (zeros and 0 for none)."""
        slot = wp.vec4(0.0)
        flag = float(0.0)
        if j >= 0:
            q = rows_pos[j]
            u = rows_vel[j]
            slot = wp.vec4(q[0] - p[0], q[1] - p[1], u[0] - v[0], u[1] - v[1])
            flag = 1.0
        return slot, flag

    @wp.func
    def write_slots(
        w: int, m: int, p: wp.vec3, v: wp.vec3, I: Any, rows_pos: Any, rows_vel: Any,
        out: Any, index: Any, row: int,
    ) -> bool:
        """Write the neighbour slots of the indices ``I`` (``rows_pos[j]`` / ``rows_vel[j]``: mover ``j``'s x/y position
        and velocity first); False if one is not finite."""
        finite = bool(True)
        for s in range(KK):
            j = I[s]
            index[row, s] = j
            col = BASE + 5 * s
            slot, flag = neighbour_slot(j, rows_pos, rows_vel, p, v)
            for e in range(4):
                out[row, col + e] = slot[e]
                finite = finite and wp.isfinite(slot[e])
            out[row, col + 4] = flag
        return finite

    @wp.func
    def write_rays(
        w: int, m: int, p: wp.vec3, tiles: wp.array2d(dtype=wp.int32), tile_size: float,
        dirs: wp.array(dtype=wp.vec2), max_range: float, out: Any, row: int,
    ) -> bool:
        finite = bool(True)
        p2 = wp.vec2(p[0], p[1])
        for r in range(R):
            if wp.static(RECT):
                d = ray_to_rect(tiles.shape[0], tiles.shape[1], tile_size, p2, dirs[r], max_range)
            else:
                d = ray_to_wall(tiles, tile_size, p2, dirs[r], max_range)
            out[row, BASE + 5 * K + r] = d
            finite = finite and wp.isfinite(d)
        return finite

    return own_state, nearest, write_slots, write_rays, BASE + 5 * K + R


@functools.cache
def make_observation_kernel(k: int, num_rays: int, own: int, search: str = "grid", block_dim: int = 0,
                           unrolled: bool = True, staged: bool = False, merge: bool = False, rect: bool = False,
                           sift: bool = False):
    """The fused observation kernel for fixed ``k``, ``num_rays`` and own-state parts ``own`` (bits of
    :data:`OWN_STATE`, :data:`OWN_ACC`, :data:`OWN_CARRY`). Row of a mover: its own state, then per neighbour slot
    (relative x, y, relative vx, vy, mask; nearest first, ties by the lower index; zeros in padded slots), then
    ``num_rays`` wall distances (:func:`ray_to_wall` along ``dirs``).

    ``search`` (:data:`SEARCHES`) picks the candidates, with the same rows either way (the k nearest within the
    radius are a function of the positions alone):

    * ``"grid"``: the movers of the neighbouring cells of a uniform grid (``head`` / ``next_in_cell``, binned before
      by :func:`~magwarp.kernels.collision.bin_movers`), ``dim=(W, M)``: work per mover is its cells' movers;
    * ``"world"``: every mover of the world, no grid (``head`` / ``next_in_cell`` unused): for worlds of up to
      :data:`MAX_WORLD_BLOCK` movers. ``block_dim`` > 0: the CUDA shape,
      ``wp.launch_tiled(kernel, dim=W, block_dim=block_dim)`` with ``block_dim`` >= the movers per world: one
      block per world loads its movers' x/y positions and velocities into shared memory once and each lane scans
      them (lanes past the last mover mirror it and write nothing); ``block_dim`` 0: ``dim=(W, M)``, each thread
      scanning its world's rows of ``pos`` (the CPU shape). ``staged`` (block shape only): the block's rows are
      written into shared memory first (one barrier per column) and stored to ``out`` / ``index`` together, each
      lane writing consecutive addresses, instead of each lane writing its own row (addresses a row apart).

    ``unrolled``: how a candidate enters the sorted slots: an unrolled compare-and-swap chain (constant indices: the
    slots stay in registers on CUDA) or a shift from the back (fewer steps where the slots sit in a cache: the CPU);
    the same slots either way. ``merge`` (world search only; the grid ignores it): every candidate (they come in
    index order) is merged into the slots with no branch (a compare and two selects per slot), instead of a branch to
    the chain or shift taken by whichever lane keeps it (on CUDA nearly every candidate for some lane of a warp); the
    same slots while the radius squared is finite. ``sift`` (with ``merge``): only the candidates within the radius
    are merged, a word of 32 at a time (their bits first, then the set bits in index order); the same slots.

    ``rect``: the layout has every tile of its rectangle (``tiles`` all ones): the rays by :func:`ray_to_rect` (no
    tile read, no walk), the same distances bit for bit."""
    if search not in SEARCHES:
        raise ValueError(f"search must be one of {SEARCHES}, got {search!r}")
    K, R = int(k), int(num_rays)
    own_state, nearest, write_slots, write_rays, DIM = _row_funcs(K, R, int(own), search, bool(unrolled),
                                                                  bool(merge), bool(rect), bool(sift))
    KK = max(K, 1)
    TILED = search == "world" and int(block_dim) > 0
    STAGED = TILED and bool(staged)
    BLOCK = max(int(block_dim), 1)
    options = {**MODULE_OPTIONS, "block_dim": BLOCK} if TILED else MODULE_OPTIONS

    @wp.kernel(module="unique", enable_backward=False, module_options=options)
    def observe(
        # Model:
        grid: Grid,
        radius: float,
        reach: int,
        tiles: wp.array2d(dtype=wp.int32),
        tile_size: float,
        dirs: wp.array(dtype=wp.vec2),
        max_range: float,
        # State in:
        pos: wp.array2d(dtype=wp.vec3),
        vel: wp.array2d(dtype=wp.vec3),
        acc: wp.array2d(dtype=wp.vec2),
        goals: wp.array2d(dtype=wp.vec2),
        carrying: wp.array2d(dtype=wp.bool),
        head: wp.array(dtype=wp.int32),
        next_in_cell: wp.array2d(dtype=wp.int32),
        # State out:
        out: wp.array3d(dtype=wp.float32),
        index: wp.array3d(dtype=wp.int32),
        nonfinite: wp.array(dtype=wp.int32),
    ):
        """``out[w, m]``: the mover's observation row; ``index``: its neighbours (-1 in padded slots, whose
        columns are zeros); ``nonfinite[w]`` set to 1 where a row of world ``w`` holds a NaN or an infinity (it is
        only ever set: clear it before)."""
        live = bool(True)
        if wp.static(TILED):
            w, lane = wp.tid()
            M = pos.shape[1]
            live = lane < M
            m = wp.min(lane, M - 1)
        else:
            w, m = wp.tid()
            M = pos.shape[1]
        p = pos[w, m]
        v = vel[w, m]
        finite = bool(True)
        if wp.static(STAGED):
            # every lane (idle ones too: their rows fall past the world's and are not stored) writes its row into
            # the staging tiles, then the block stores them
            rows_out = wp.tile_zeros(shape=(BLOCK, DIM), dtype=wp.float32, storage="shared")
            rows_index = wp.tile_zeros(shape=(BLOCK, KK), dtype=wp.int32, storage="shared")
        if wp.static(K > 0):
            r2 = radius * radius
            if wp.static(TILED):
                # the world's x/y positions and velocities in shared memory, one entry per lane (tile_assign
                # synchronises the block after writing), then every lane scans them
                rows_pos = wp.tile_zeros(shape=BLOCK, dtype=wp.vec2, storage="shared")
                rows_vel = wp.tile_zeros(shape=BLOCK, dtype=wp.vec2, storage="shared")
                wp.tile_assign(rows_pos, wp.tile(wp.vec2(p[0], p[1]), preserve_type=True))
                wp.tile_assign(rows_vel, wp.tile(wp.vec2(v[0], v[1]), preserve_type=True))
                D, I = nearest(rows_pos, w, m, M, p, r2, grid, reach, head, next_in_cell)
                if wp.static(STAGED):
                    finite = write_slots(w, m, p, v, I, rows_pos, rows_vel, rows_out, rows_index, lane)
                elif live:
                    finite = write_slots(w, m, p, v, I, rows_pos, rows_vel, out[w], index[w], m)
            else:
                D, I = nearest(pos[w], w, m, M, p, r2, grid, reach, head, next_in_cell)
                finite = write_slots(w, m, p, v, I, pos[w], vel[w], out[w], index[w], m)
        if wp.static(STAGED):
            finite = own_state(w, m, p, v, acc, goals, carrying, rows_out, lane) and finite
            if wp.static(R > 0):
                finite = write_rays(w, m, p, tiles, tile_size, dirs, max_range, rows_out, lane) and finite
            wp.tile_store(out[w], rows_out)
            if wp.static(K > 0):
                wp.tile_store(index[w], rows_index)
        else:
            if not live:
                return
            finite = own_state(w, m, p, v, acc, goals, carrying, out[w], m) and finite
            if wp.static(R > 0):
                finite = write_rays(w, m, p, tiles, tile_size, dirs, max_range, out[w], m) and finite
        if live and not finite:
            nonfinite[w] = 1

    return observe
