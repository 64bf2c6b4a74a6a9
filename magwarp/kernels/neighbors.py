"""Local observation kernels for large swarms: k nearest movers within a radius, and distances to the walls.

:func:`make_observation_kernel` fills each mover's observation row in one pass:

* its own state (velocity, goal relative to it, acceleration, carrying flag; each part optional);
* the ``k`` nearest other movers of its world within ``radius`` (ordered by distance, ties by index; relative x, y,
  vx, vy and a mask per slot), found by scanning the neighbouring cells of a uniform grid whose lists the
  simulator's own :func:`~magwarp.kernels.collision.bin_movers` builds. The candidates are kept sorted in
  registers, so the work per mover is the movers in its neighbouring cells, not the world's;
* for each of a few ray directions, the distance from its centre to the first point off the tiles (a hole or the
  layout's edge), capped at ``max_range``, by stepping tile by tile along the ray (at most ``max_range / tile_size``
  steps per ray: :func:`ray_to_wall`).

It writes the rows straight into the caller's ``[W, M, D]`` array (no copies), the neighbours' indices beside them,
and a per-world flag for any non-finite entry.
"""

from __future__ import annotations

import functools

import warp as wp

from magwarp.kernels.collision import cell_coords
from magwarp.kernels.options import MODULE_OPTIONS
from magwarp.types import Grid

wp.set_module_options({"enable_backward": False, **MODULE_OPTIONS})

BIG = 1.0e30


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


#: parts of the mover's own state that :func:`make_observation_kernel` writes first (bit flags)
OWN_STATE = 1  # x/y velocity, then the goal relative to the mover (4 columns)
OWN_ACC = 2  # x/y acceleration (2 columns, after the state)
OWN_CARRY = 4  # carrying flag (1 column, last)


@functools.cache
def make_observation_kernel(k: int, num_rays: int, own: int):
    """The fused observation kernel for fixed ``k``, ``num_rays`` and own-state parts ``own`` (bits of
    :data:`OWN_STATE`, :data:`OWN_ACC`, :data:`OWN_CARRY`). Row of a mover: its own state, then per neighbour slot
    (relative x, y, relative vx, vy, mask; nearest first, ties by the lower index; zeros in padded slots), then
    ``num_rays`` wall distances (:func:`ray_to_wall` along ``dirs``)."""
    K, R = int(k), int(num_rays)
    KK = max(K, 1)
    Dists = wp.types.vector(length=KK, dtype=wp.float32)
    Ids = wp.types.vector(length=KK, dtype=wp.int32)
    WITH_STATE, WITH_ACC, WITH_CARRY = bool(own & OWN_STATE), bool(own & OWN_ACC), bool(own & OWN_CARRY)
    BASE = 4 * int(WITH_STATE) + 2 * int(WITH_ACC) + int(WITH_CARRY)

    @wp.kernel(module="unique", enable_backward=False, module_options=MODULE_OPTIONS)
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
        w, m = wp.tid()
        p = pos[w, m]
        v = vel[w, m]
        finite = bool(True)
        if wp.static(WITH_STATE):
            g = goals[w, m]
            row4 = wp.vec4(v[0], v[1], g[0] - p[0], g[1] - p[1])
            for e in range(4):
                out[w, m, e] = row4[e]
                finite = finite and wp.isfinite(row4[e])
        if wp.static(WITH_ACC):
            a = acc[w, m]
            out[w, m, 4] = a[0]
            out[w, m, 5] = a[1]
            finite = finite and wp.isfinite(a[0]) and wp.isfinite(a[1])
        if wp.static(WITH_CARRY):
            cv = float(0.0)
            if carrying[w, m]:
                cv = 1.0
            out[w, m, BASE - 1] = cv
        if wp.static(K > 0):
            r2 = radius * radius
            D = Dists()
            I = Ids()
            for s in range(KK):
                D[s] = BIG
                I[s] = -1
            c = cell_coords(grid, p)
            for dy in range(-reach, reach + 1):
                cy = c[1] + dy
                if cy < 0 or cy >= grid.ncy:
                    continue
                for dx in range(-reach, reach + 1):
                    cx = c[0] + dx
                    if cx < 0 or cx >= grid.ncx:
                        continue
                    j = head[(w * grid.ncy + cy) * grid.ncx + cx]
                    while j >= 0:
                        if j != m:
                            q = pos[w, j]
                            ex = q[0] - p[0]
                            ey = q[1] - p[1]
                            d2 = ex * ex + ey * ey
                            # keep (d2, j) if it beats the last kept one; ties by the lower index
                            if d2 <= r2 and (d2 < D[KK - 1] or (d2 == D[KK - 1] and j < I[KK - 1]) or I[KK - 1] < 0):
                                s = KK - 1
                                while s > 0 and (D[s - 1] > d2 or (D[s - 1] == d2 and I[s - 1] > j)):
                                    D[s] = D[s - 1]
                                    I[s] = I[s - 1]
                                    s -= 1
                                D[s] = d2
                                I[s] = j
                        j = next_in_cell[w, j]
            for s in range(KK):
                j = I[s]
                index[w, m, s] = j
                col = BASE + 5 * s
                slot = wp.vec4(0.0)
                flag = float(0.0)
                if j >= 0:
                    q = pos[w, j]
                    u = vel[w, j]
                    slot = wp.vec4(q[0] - p[0], q[1] - p[1], u[0] - v[0], u[1] - v[1])
                    flag = 1.0
                for e in range(4):
                    out[w, m, col + e] = slot[e]
                    finite = finite and wp.isfinite(slot[e])
                out[w, m, col + 4] = flag
        if wp.static(R > 0):
            p2 = wp.vec2(p[0], p[1])
            for r in range(R):
                d = ray_to_wall(tiles, tile_size, p2, dirs[r], max_range)
                out[w, m, BASE + 5 * K + r] = d
                finite = finite and wp.isfinite(d)
        if not finite:
            nonfinite[w] = 1

    return observe
