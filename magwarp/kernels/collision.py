"""Geometric collision detection with safety margins: mover-mover (circle or oriented box) and mover-wall.

Movers never touch physically (all such contacts are excluded), so collisions are detected, reported per mover and
per world, and (optionally) stop the world for the rest of the step, as a real system stops on a lag error.

Broad phase for large worlds: movers are binned into a uniform grid of cells at least one interaction distance
wide, one block of cells per world, with per-cell linked lists built by ``atomic_exch`` (no sort and no scan, so it
is capturable in a graph on CPU and GPU). Each mover then scans the 3x3 neighbouring cells. Positions outside the
layout are clamped into the border cells, which never separates two nearby movers.
"""

import warp as wp

from magwarp.kernels.options import MODULE_OPTIONS
from magwarp.types import COLLIDE_MOVER, COLLIDE_WALL, SHAPE_CIRCLE, Collision, Grid

# Forward simulation only: skipping adjoint code halves the (cold) compile time.
wp.set_module_options({"enable_backward": False, **MODULE_OPTIONS})


@wp.func
def yaw_of(q: wp.quat) -> float:
    """Heading of a (near-level) mover: the angle of its body x axis in the world x/y plane."""
    ax = wp.quat_rotate(q, wp.vec3(1.0, 0.0, 0.0))
    return wp.atan2(ax[1], ax[0])


@wp.func
def free_joint_xy_yaw(qpos: wp.array2d(dtype=float), w: int, qa: int):
    """x, y and heading of a body on a MuJoCo free joint at qpos address ``qa`` (quaternion stored w, x, y, z)."""
    q = wp.quat(qpos[w, qa + 4], qpos[w, qa + 5], qpos[w, qa + 6], qpos[w, qa + 3])
    return wp.vec2(qpos[w, qa], qpos[w, qa + 1]), yaw_of(q)


@wp.func
def shape_yaw(col: Collision, q: wp.quat) -> float:
    """Heading when the collision shape depends on it (boxes); circles skip the trigonometry."""
    if col.shape == SHAPE_CIRCLE:
        return 0.0
    return yaw_of(q)


@wp.func
def heading_of(q: wp.quat) -> wp.vec2:
    """(cos, sin) of a mover's heading straight from its orientation: no trigonometric call in the hot loops."""
    ax = wp.quat_rotate(q, wp.vec3(1.0, 0.0, 0.0))
    v = wp.vec2(ax[0], ax[1])
    n = wp.length(v)
    if n > 0.0:
        return v / n
    return wp.vec2(1.0, 0.0)


@wp.func
def shape_heading(col: Collision, q: wp.quat) -> wp.vec2:
    """The heading when the collision shape depends on it (boxes); circles skip the work."""
    if col.shape == SHAPE_CIRCLE:
        return wp.vec2(1.0, 0.0)
    return heading_of(q)


@wp.func
def box_extent(axis: wp.vec2, c: float, s: float, half: wp.vec2) -> float:
    """Half length of the projection onto ``axis`` of a box with half sizes ``half`` rotated by (c, s)."""
    return half[0] * wp.abs(axis[0] * c + axis[1] * s) + half[1] * wp.abs(-axis[0] * s + axis[1] * c)


@wp.func
def boxes_overlap_cs(d: wp.vec2, ha: wp.vec2, half_a: wp.vec2, hb: wp.vec2, half_b: wp.vec2) -> bool:
    """Separating-axis test for two rectangles (headings ``ha``, ``hb`` as (cos, sin)) whose centres differ by
    ``d``; touching counts as overlap."""
    ca = ha[0]
    sa = ha[1]
    cb = hb[0]
    sb = hb[1]
    for k in range(4):
        axis = wp.vec2(ca, sa)
        if k == 1:
            axis = wp.vec2(-sa, ca)
        elif k == 2:
            axis = wp.vec2(cb, sb)
        elif k == 3:
            axis = wp.vec2(-sb, cb)
        dist = wp.abs(wp.dot(d, axis))
        if dist > box_extent(axis, ca, sa, half_a) + box_extent(axis, cb, sb, half_b):
            return False
    return True


@wp.func
def boxes_overlap(d: wp.vec2, yaw_a: float, half_a: wp.vec2, yaw_b: float, half_b: wp.vec2) -> bool:
    """:func:`boxes_overlap_cs` with headings given as angles."""
    return boxes_overlap_cs(d, wp.vec2(wp.cos(yaw_a), wp.sin(yaw_a)), half_a, wp.vec2(wp.cos(yaw_b), wp.sin(yaw_b)), half_b)


@wp.func
def movers_collide_cs(
    col: Collision, d: wp.vec2, ha: wp.vec2, r_a: float, half_a: wp.vec2, hb: wp.vec2, r_b: float, half_b: wp.vec2
) -> bool:
    """Do two movers (centre offset ``d``, headings as (cos, sin)) collide once both shapes are grown by the safety
    margin?"""
    if col.shape == SHAPE_CIRCLE:
        reach = r_a + r_b + 2.0 * col.margin
        return wp.dot(d, d) <= reach * reach  # squared: no square root in the hottest test
    m = wp.vec2(col.margin, col.margin)
    return boxes_overlap_cs(d, ha, half_a + m, hb, half_b + m)


@wp.func
def movers_collide(
    col: Collision, d: wp.vec2, yaw_a: float, r_a: float, half_a: wp.vec2, yaw_b: float, r_b: float, half_b: wp.vec2
) -> bool:
    """:func:`movers_collide_cs` with headings given as angles."""
    return movers_collide_cs(col, d, wp.vec2(wp.cos(yaw_a), wp.sin(yaw_a)), r_a, half_a,
                             wp.vec2(wp.cos(yaw_b), wp.sin(yaw_b)), r_b, half_b)


@wp.func
def footprint_hits_square(shape: int, p: wp.vec2, h: wp.vec2, radius: float, half: wp.vec2, lo: wp.vec2, size: float) -> bool:
    """Does the footprint (heading ``h`` as (cos, sin)) overlap the square ``[lo, lo + size]`` with positive area?
    (Touching is not a hit.)"""
    if shape == SHAPE_CIRCLE:
        nearest = wp.vec2(wp.clamp(p[0], lo[0], lo[0] + size), wp.clamp(p[1], lo[1], lo[1] + size))
        return wp.length(p - nearest) < radius
    hs = 0.5 * size
    d = p - (lo + wp.vec2(hs, hs))
    c = h[0]
    s = h[1]
    for k in range(4):
        axis = wp.vec2(1.0, 0.0)
        if k == 1:
            axis = wp.vec2(0.0, 1.0)
        elif k == 2:
            axis = wp.vec2(c, s)
        elif k == 3:
            axis = wp.vec2(-s, c)
        if wp.abs(wp.dot(d, axis)) >= box_extent(axis, c, s, half) + hs * (wp.abs(axis[0]) + wp.abs(axis[1])):
            return False
    return True


@wp.func
def hits_wall(tiles: wp.array2d(dtype=wp.int32), col: Collision, p: wp.vec2, yaw: float, radius: float, half: wp.vec2) -> bool:
    """:func:`hits_wall_cs` with the heading given as an angle."""
    return hits_wall_cs(tiles, col, p, wp.vec2(wp.cos(yaw), wp.sin(yaw)), radius, half)


@wp.func
def hits_wall_cs(tiles: wp.array2d(dtype=wp.int32), col: Collision, p: wp.vec2, h: wp.vec2, radius: float,
                 half: wp.vec2) -> bool:
    """Does the footprint (heading ``h`` as (cos, sin)) grown by the wall margin overlap a missing tile or leave
    the grid?"""
    r = radius + col.wall_margin
    hh = half + wp.vec2(col.wall_margin, col.wall_margin)
    reach = r
    if col.shape != SHAPE_CIRCLE:
        reach = wp.length(hh)
    if col.full_rect == 1:
        # Every tile present: the footprint leaves the tiles exactly when its bounding box leaves the rectangle (a
        # box's extreme corner then lies outside). Same answer as the per-cell test below, in four comparisons.
        ex = r
        ey = r
        if col.shape != SHAPE_CIRCLE:
            c = wp.abs(h[0])
            s = wp.abs(h[1])
            ex = hh[0] * c + hh[1] * s
            ey = hh[0] * s + hh[1] * c
        return p[0] - ex < 0.0 or p[1] - ey < 0.0 or p[0] + ex > col.extent[0] or p[1] + ey > col.extent[1]
    size = col.tile_size
    i0 = int(wp.floor((p[0] - reach) / size))
    i1 = int(wp.floor((p[0] + reach) / size))
    j0 = int(wp.floor((p[1] - reach) / size))
    j1 = int(wp.floor((p[1] + reach) / size))
    nx = tiles.shape[0]
    ny = tiles.shape[1]
    for i in range(i0, i1 + 1):
        for j in range(j0, j1 + 1):
            present = False
            if i >= 0 and i < nx and j >= 0 and j < ny:
                present = tiles[i, j] == 1
            if not present:
                if footprint_hits_square(col.shape, p, h, r, hh, wp.vec2(float(i) * size, float(j) * size), size):
                    return True
    return False


@wp.func
def cell_coords(grid: Grid, p: wp.vec3) -> wp.vec2i:
    cx = wp.clamp(int(wp.floor(p[0] / grid.cell_size)), 0, grid.ncx - 1)
    cy = wp.clamp(int(wp.floor(p[1] / grid.cell_size)), 0, grid.ncy - 1)
    return wp.vec2i(cx, cy)


@wp.kernel
def clear_cells(head: wp.array(dtype=wp.int32), world_pairs: wp.array(dtype=wp.int32), world_walls: wp.array(dtype=wp.int32)):
    """Empty every cell list and zero the per-world counters (one launch: launches dominate small steps)."""
    i = wp.tid()
    if i < head.shape[0]:
        head[i] = -1
    if i < world_pairs.shape[0]:
        world_pairs[i] = 0
        world_walls[i] = 0


@wp.func
def push_to_cell(w: int, m: int, grid: Grid, pos: wp.array2d(dtype=wp.vec3), head: wp.array(dtype=wp.int32),
                 next_in_cell: wp.array2d(dtype=wp.int32)):
    """Push mover ``m`` onto its cell's linked list (lists hold mover indices within the world)."""
    c = cell_coords(grid, pos[w, m])
    cell = (w * grid.ncy + c[1]) * grid.ncx + c[0]
    next_in_cell[w, m] = wp.atomic_exch(head, cell, m)


@wp.kernel
def bin_movers(
    # Model:
    grid: Grid,
    # State in:
    pos: wp.array2d(dtype=wp.vec3),
    # State out:
    head: wp.array(dtype=wp.int32),
    next_in_cell: wp.array2d(dtype=wp.int32),
):
    """Bin every mover (used where no integration kernel does it on the way, e.g. :meth:`check_collisions`)."""
    w, m = wp.tid()
    push_to_cell(w, m, grid, pos, head, next_in_cell)


@wp.func
def model_row(rows: int, w: int) -> int:
    """The row of world ``w`` in a model array of ``rows`` rows: its own when the array is per world, else the one
    shared row (a model array stays shared until domain randomisation makes it per world, as mujoco-warp's do)."""
    if rows == 1:
        return 0
    return w


@wp.func
def world_collision(col: Collision, margins: wp.array(dtype=wp.vec2), w: int) -> Collision:
    """``col`` with world ``w``'s margins (``margins[w]`` = (mover-mover margin, wall margin); per world so that domain
    randomisation can change them on the device)."""
    mw = margins[model_row(margins.shape[0], w)]
    out = Collision()
    out.shape = col.shape
    out.margin = mw[0]
    out.wall_margin = mw[1]
    out.tile_size = col.tile_size
    out.stop_on_collision = col.stop_on_collision
    out.full_rect = col.full_rect
    out.extent = col.extent
    return out


@wp.func
def add_pair(w: int, i: int, j: int, world_pairs: wp.array(dtype=wp.int32), pair_list: wp.array2d(dtype=wp.vec2i)):
    """Count a colliding pair (found by its lower index ``i``) and list it while the world's list has room."""
    k = wp.atomic_add(world_pairs, w, 1)
    if k < pair_list.shape[1]:
        pair_list[w, k] = wp.vec2i(i, j)


@wp.func
def visit_pair(
    col: Collision,
    w: int,
    m: int,
    j: int,
    p: wp.vec3,
    hd: wp.vec2,
    pos: wp.array2d(dtype=wp.vec3),
    quat: wp.array2d(dtype=wp.quat),
    radius: wp.array2d(dtype=float),
    half_size: wp.array2d(dtype=wp.vec2),
    partner: int,
    world_pairs: wp.array(dtype=wp.int32),
    pair_list: wp.array2d(dtype=wp.vec2i),
) -> int:
    """Narrow phase of mover ``m`` against candidate ``j``: returns the updated partner (the lowest colliding
    index) and lists the pair once, from its lower index."""
    if j == m:
        return partner
    q = pos[w, j]
    d = wp.vec2(p[0] - q[0], p[1] - q[1])
    wr = model_row(radius.shape[0], w)
    wh = model_row(half_size.shape[0], w)
    if not movers_collide_cs(col, d, hd, radius[wr, m], half_size[wh, m], shape_heading(col, quat[w, j]), radius[wr, j],
                             half_size[wh, j]):
        return partner
    if j > m:
        add_pair(w, m, j, world_pairs, pair_list)
    if partner < 0 or j < partner:
        return j
    return partner


@wp.func
def collision_flags(partner: int, wall: int) -> int:
    """One mover's collision bits in a cycle: :data:`~magwarp.types.COLLIDE_MOVER` when it has a colliding partner
    (``partner >= 0``), :data:`~magwarp.types.COLLIDE_WALL` when its footprint left the tiles (``wall != 0``)."""
    f = int(0)
    if partner >= 0:
        f = f | COLLIDE_MOVER
    if wall != 0:
        f = f | COLLIDE_WALL
    return f


@wp.func
def record_collisions(
    w: int,
    m: int,
    partner: int,
    wall: wp.array2d(dtype=wp.int32),
    flags: wp.array2d(dtype=wp.int32),
    flags_any: wp.array2d(dtype=wp.int32),
    partner_out: wp.array2d(dtype=wp.int32),
    world_pairs: wp.array(dtype=wp.int32),
    world_walls: wp.array(dtype=wp.int32),
    halted: wp.array(dtype=wp.int32),
):
    """Write one mover's collision outputs; each thread writes only its own mover plus per-world counters."""
    f = collision_flags(partner, wall[w, m])
    if wall[w, m] != 0:
        wp.atomic_add(world_walls, w, 1)
    flags[w, m] = f
    flags_any[w, m] = flags_any[w, m] | f
    partner_out[w, m] = partner
    if f != 0:
        halted[w] = 1


@wp.kernel
def clear_world_counters(world_pairs: wp.array(dtype=wp.int32), world_walls: wp.array(dtype=wp.int32)):
    w = wp.tid()
    world_pairs[w] = 0
    world_walls[w] = 0


@wp.kernel
def detect_collisions_grid(
    # Model:
    col_shared: Collision,
    grid: Grid,
    radius: wp.array2d(dtype=float),
    half_size: wp.array2d(dtype=wp.vec2),
    margins: wp.array(dtype=wp.vec2),
    # State in:
    pos: wp.array2d(dtype=wp.vec3),
    quat: wp.array2d(dtype=wp.quat),
    wall: wp.array2d(dtype=wp.int32),
    head: wp.array(dtype=wp.int32),
    next_in_cell: wp.array2d(dtype=wp.int32),
    # State out:
    flags: wp.array2d(dtype=wp.int32),
    flags_any: wp.array2d(dtype=wp.int32),
    partner_out: wp.array2d(dtype=wp.int32),
    world_pairs: wp.array(dtype=wp.int32),
    world_walls: wp.array(dtype=wp.int32),
    halted: wp.array(dtype=wp.int32),
    pair_list: wp.array2d(dtype=wp.vec2i),
):
    """Mover-mover narrow phase over the 3x3 neighbouring cells, then the mover's flags."""
    w, m = wp.tid()
    col = world_collision(col_shared, margins, w)
    p = pos[w, m]
    hd = shape_heading(col, quat[w, m])
    c = cell_coords(grid, p)
    partner = int(-1)
    for dy in range(-1, 2):
        cy = c[1] + dy
        if cy < 0 or cy >= grid.ncy:
            continue
        for dx in range(-1, 2):
            cx = c[0] + dx
            if cx < 0 or cx >= grid.ncx:
                continue
            j = head[(w * grid.ncy + cy) * grid.ncx + cx]
            while j >= 0:
                partner = visit_pair(col, w, m, j, p, hd, pos, quat, radius, half_size, partner, world_pairs, pair_list)
                j = next_in_cell[w, j]
    record_collisions(w, m, partner, wall, flags, flags_any, partner_out, world_pairs, world_walls, halted)


@wp.kernel
def detect_collisions_brute(
    # Model:
    col_shared: Collision,
    radius: wp.array2d(dtype=float),
    half_size: wp.array2d(dtype=wp.vec2),
    margins: wp.array(dtype=wp.vec2),
    # State in:
    pos: wp.array2d(dtype=wp.vec3),
    quat: wp.array2d(dtype=wp.quat),
    wall: wp.array2d(dtype=wp.int32),
    # State out:
    flags: wp.array2d(dtype=wp.int32),
    flags_any: wp.array2d(dtype=wp.int32),
    partner_out: wp.array2d(dtype=wp.int32),
    world_pairs: wp.array(dtype=wp.int32),
    world_walls: wp.array(dtype=wp.int32),
    halted: wp.array(dtype=wp.int32),
    pair_list: wp.array2d(dtype=wp.vec2i),
):
    """Mover-mover check against every other mover of the world: the fast choice for small worlds."""
    w, m = wp.tid()
    col = world_collision(col_shared, margins, w)
    p = pos[w, m]
    hd = shape_heading(col, quat[w, m])
    partner = int(-1)
    for j in range(pos.shape[1]):
        partner = visit_pair(col, w, m, j, p, hd, pos, quat, radius, half_size, partner, world_pairs, pair_list)
    record_collisions(w, m, partner, wall, flags, flags_any, partner_out, world_pairs, world_walls, halted)


@wp.kernel
def footprints_on_tiles(
    # Model:
    tiles: wp.array2d(dtype=wp.int32),
    col: Collision,
    radius: float,
    half: wp.vec2,
    extra: float,
    # State in:
    xy: wp.array(dtype=wp.vec2),
    # State out:
    valid: wp.array(dtype=wp.int32),
):
    """1 where an axis-aligned footprint at ``xy``, grown by ``extra`` on top of the wall margin, is fully on tiles.

    Used to sample start poses and goals with exactly the rule the simulator applies every cycle.
    """
    i = wp.tid()
    ok = int(1)
    if hits_wall_cs(tiles, col, xy[i], wp.vec2(1.0, 0.0), radius + extra, half + wp.vec2(extra, extra)):
        ok = 0
    valid[i] = ok


@wp.kernel
def detect_walls(
    # Model:
    tiles: wp.array2d(dtype=wp.int32),
    col_shared: Collision,
    radius: wp.array2d(dtype=float),
    half_size: wp.array2d(dtype=wp.vec2),
    margins: wp.array(dtype=wp.vec2),
    # State in:
    pos: wp.array2d(dtype=wp.vec3),
    quat: wp.array2d(dtype=wp.quat),
    # State out:
    wall: wp.array2d(dtype=wp.int32),
):
    """Wall flags of the current poses, without integrating (start-pose validation, queries)."""
    w, m = wp.tid()
    col = world_collision(col_shared, margins, w)
    p = pos[w, m]
    hit = int(0)
    if hits_wall_cs(tiles, col, wp.vec2(p[0], p[1]), shape_heading(col, quat[w, m]),
                    radius[model_row(radius.shape[0], w), m], half_size[model_row(half_size.shape[0], w), m]):
        hit = 1
    wall[w, m] = hit


# ---------------------------------------------------------------------------------------------- batched queries
# The public queries of :mod:`magwarp.collision`: poses (x, y, yaw) with per-pose sizes, the same shape tests as the
# simulator's step (``movers_collide_cs``, ``hits_wall_cs``), plus the signed clearance between two movers.


@wp.func
def point_box_distance(q: wp.vec2, c: wp.vec2, h: wp.vec2, half: wp.vec2) -> float:
    """Distance from point ``q`` to the rectangle centred at ``c`` (heading ``h`` as (cos, sin)); 0 inside."""
    d = q - c
    lx = wp.abs(d[0] * h[0] + d[1] * h[1]) - half[0]
    ly = wp.abs(-d[0] * h[1] + d[1] * h[0]) - half[1]
    return wp.length(wp.vec2(wp.max(lx, 0.0), wp.max(ly, 0.0)))


@wp.func
def corners_to_box(ca: wp.vec2, ha: wp.vec2, half_a: wp.vec2, cb: wp.vec2, hb: wp.vec2, half_b: wp.vec2) -> float:
    """Smallest distance from a corner of rectangle a to rectangle b."""
    ex = wp.vec2(ha[0], ha[1]) * half_a[0]
    ey = wp.vec2(-ha[1], ha[0]) * half_a[1]
    best = point_box_distance(ca + ex + ey, cb, hb, half_b)
    best = wp.min(best, point_box_distance(ca + ex - ey, cb, hb, half_b))
    best = wp.min(best, point_box_distance(ca - ex + ey, cb, hb, half_b))
    return wp.min(best, point_box_distance(ca - ex - ey, cb, hb, half_b))


@wp.func
def movers_clearance_cs(
    col: Collision, d: wp.vec2, ha: wp.vec2, r_a: float, half_a: wp.vec2, hb: wp.vec2, r_b: float, half_b: wp.vec2
) -> float:
    """Signed clearance of two movers (centre offset ``d = p_a - p_b``) once both shapes are grown by the safety
    margin: the gap between them (> 0), 0 at contact, minus the penetration depth when they overlap (< 0)."""
    if col.shape == SHAPE_CIRCLE:
        return wp.length(d) - (r_a + r_b + 2.0 * col.margin)
    m = wp.vec2(col.margin, col.margin)
    return boxes_clearance(d, ha, half_a + m, hb, half_b + m)


@wp.func
def boxes_clearance(d: wp.vec2, ha: wp.vec2, ga: wp.vec2, hb: wp.vec2, gb: wp.vec2) -> float:
    """Signed distance of two rectangles (centre offset ``d = c_a - c_b``, headings as (cos, sin), half sizes ``ga``,
    ``gb``): the gap apart, minus the penetration depth (the shortest push apart) when they overlap."""
    # Largest separation over the four candidate axes: the penetration depth (negated) when they overlap.
    sep = float(-1.0e30)
    for k in range(4):
        axis = wp.vec2(ha[0], ha[1])
        if k == 1:
            axis = wp.vec2(-ha[1], ha[0])
        elif k == 2:
            axis = wp.vec2(hb[0], hb[1])
        elif k == 3:
            axis = wp.vec2(-hb[1], hb[0])
        reach = box_extent(axis, ha[0], ha[1], ga) + box_extent(axis, hb[0], hb[1], gb)
        sep = wp.max(sep, wp.abs(wp.dot(d, axis)) - reach)
    if sep <= 0.0:
        return sep
    # Apart: the distance between two convex polygons is attained at a corner of one of them.
    zero = wp.vec2(0.0, 0.0)
    return wp.min(corners_to_box(d, ha, ga, zero, hb, gb), corners_to_box(zero, hb, gb, d, ha, ga))


@wp.func
def wall_clearance_cs(tiles: wp.array2d(dtype=wp.int32), col: Collision, p: wp.vec2, h: wp.vec2, radius: float,
                      half: wp.vec2) -> float:
    """Signed clearance of a footprint (grown by the wall margin) to the area without tiles (holes and outside the
    layout): the gap (> 0), 0 at contact, < 0 where it overlaps. Exact up to one tile size; larger gaps read as one
    tile size (missing tiles are only searched within a tile of the footprint)."""
    r = radius + col.wall_margin
    hh = half + wp.vec2(col.wall_margin, col.wall_margin)
    size = col.tile_size
    ex = r
    ey = r
    reach = r
    if col.shape != SHAPE_CIRCLE:
        ex = hh[0] * wp.abs(h[0]) + hh[1] * wp.abs(h[1])
        ey = hh[0] * wp.abs(h[1]) + hh[1] * wp.abs(h[0])
        reach = wp.length(hh)
    nx = tiles.shape[0]
    ny = tiles.shape[1]
    # Outside the layout: four half planes (exact for a circle and for a rectangle's extreme corner).
    best = wp.min(wp.min(p[0] - ex, p[1] - ey), wp.min(float(nx) * size - p[0] - ex, float(ny) * size - p[1] - ey))
    best = wp.min(best, size)
    if col.full_rect == 1:
        return best
    i0 = wp.max(int(wp.floor((p[0] - reach - size) / size)), 0)
    i1 = wp.min(int(wp.floor((p[0] + reach + size) / size)), nx - 1)
    j0 = wp.max(int(wp.floor((p[1] - reach - size) / size)), 0)
    j1 = wp.min(int(wp.floor((p[1] + reach + size) / size)), ny - 1)
    hs = 0.5 * size
    for i in range(i0, i1 + 1):
        for j in range(j0, j1 + 1):
            if tiles[i, j] != 1:
                c = wp.vec2((float(i) + 0.5) * size, (float(j) + 0.5) * size)
                if col.shape == SHAPE_CIRCLE:
                    q = p - c
                    out = wp.vec2(wp.max(wp.abs(q[0]) - hs, 0.0), wp.max(wp.abs(q[1]) - hs, 0.0))
                    inside = wp.min(hs - wp.abs(q[0]), hs - wp.abs(q[1]))
                    sd = wp.length(out)
                    if inside > 0.0:
                        sd = -inside
                    best = wp.min(best, sd - r)
                else:
                    best = wp.min(best, boxes_clearance(p - c, h, hh, wp.vec2(1.0, 0.0), wp.vec2(hs, hs)))
    return best


@wp.func
def heading_of_yaw(yaw: float) -> wp.vec2:
    return wp.vec2(wp.cos(yaw), wp.sin(yaw))


@wp.kernel
def query_poses(
    # Model:
    tiles: wp.array2d(dtype=wp.int32),
    col: Collision,
    # In:
    poses: wp.array2d(dtype=wp.vec3),
    radius: wp.array2d(dtype=float),
    half_size: wp.array2d(dtype=wp.vec2),
    # Out:
    hit: wp.array3d(dtype=wp.bool),
    clearance: wp.array3d(dtype=float),
    valid: wp.array2d(dtype=wp.bool),
    wall_clearance: wp.array2d(dtype=float),
):
    """Mover ``i`` of configuration ``b``: against every ``j > i`` (both entries of the symmetric pair outputs written
    once), and against the walls: on the tiles (MagBotSim's ``qpos_is_valid``) and its signed wall clearance."""
    b, i = wp.tid()
    pi = poses[b, i]
    xy = wp.vec2(pi[0], pi[1])
    hi = heading_of_yaw(pi[2])
    valid[b, i] = not hits_wall_cs(tiles, col, xy, hi, radius[b, i], half_size[b, i])
    wall_clearance[b, i] = wall_clearance_cs(tiles, col, xy, hi, radius[b, i], half_size[b, i])
    hit[b, i, i] = False
    clearance[b, i, i] = wp.inf
    for j in range(i + 1, poses.shape[1]):
        pj = poses[b, j]
        hj = heading_of_yaw(pj[2])
        d = wp.vec2(pi[0] - pj[0], pi[1] - pj[1])
        h = movers_collide_cs(col, d, hi, radius[b, i], half_size[b, i], hj, radius[b, j], half_size[b, j])
        c = movers_clearance_cs(col, d, hi, radius[b, i], half_size[b, i], hj, radius[b, j], half_size[b, j])
        hit[b, i, j] = h
        hit[b, j, i] = h
        clearance[b, i, j] = c
        clearance[b, j, i] = c


@wp.kernel
def query_movers(
    # In:
    hit: wp.array3d(dtype=wp.bool),
    clearance: wp.array3d(dtype=float),
    # Out:
    mover_hit: wp.array2d(dtype=wp.bool),
    mover_clearance: wp.array2d(dtype=float),
):
    """Per mover: does it collide with any other, and its smallest pair clearance (+inf alone)."""
    b, i = wp.tid()
    h = bool(False)
    c = float(wp.inf)
    for j in range(hit.shape[2]):
        h = h or hit[b, i, j]
        c = wp.min(c, clearance[b, i, j])
    mover_hit[b, i] = h
    mover_clearance[b, i] = c
