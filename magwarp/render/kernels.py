"""The top-down drawing kernel: one thread per pixel of a mosaic of worlds, one launch per frame.

Each thread finds its mosaic cell (one world) and its pixel centre in world metres from per-row/per-column lookup
tables, starts from the static layer (tiles, grid lines, hatched holes, drawn once by ``draw_background``), then
paints layer by layer, bottom to top: static obstacles, object goal areas, mover-to-goal lines, objects, each
mover's safety zone (collision shape grown by the margin) and footprint, and finally goals. Painting per pixel in
a fixed order means no atomics and no sorting, and the whole frame is a single kernel launch.

Per-world inputs may have a leading size of 1: they are then shared by every world (e.g. static obstacles).
"""

from __future__ import annotations

import warp as wp

from magwarp.render import colors

# Forward-only drawing: no adjoints (faster compile); -O3 helps the per-pixel loops on CPU.
wp.set_module_options({"enable_backward": False, "optimization_level": 3})

# Indices into the fixed-colour table (see magwarp.render.colors, packed by topdown.py).
C_BACKGROUND = wp.constant(0)
C_TILE = wp.constant(1)
C_TILE_LINE = wp.constant(2)
C_HOLE = wp.constant(3)
C_HOLE_HATCH = wp.constant(4)
C_OBSTACLE = wp.constant(5)
C_OBSTACLE_EDGE = wp.constant(6)
C_OBJECT = wp.constant(7)
C_OBJECT_EDGE = wp.constant(8)
C_OBJECT_GOAL = wp.constant(9)
C_COLLISION = wp.constant(10)
C_HEADING = wp.constant(11)
C_GOAL_RING = wp.constant(12)
NUM_FIXED_COLORS = 13

SHAPE_CIRCLE = wp.constant(0)
SHAPE_BOX = wp.constant(1)

# Up to BAND_MOVERS movers per world, each pixel row keeps a bit mask of the movers it can touch (the "row band",
# at most 31 bits); above it, movers and goals are first sorted into per-tile bins of up to BIN_CAPACITY items, and a
# pixel tests only the bins around it. Measured crossover on CPU: bins win from about 12-16 movers per world.
BAND_MOVERS = 16
BIN_CAPACITY = 8

# Style bits.
DRAW_GRID = wp.constant(1)
DRAW_SAFETY_ZONE = wp.constant(2)
DRAW_HEADING = wp.constant(4)
DRAW_GOAL_LINES = wp.constant(8)

# Blend factors, from the palette module so legends and tests agree with the kernel.
SAFETY_ZONE_ALPHA = wp.constant(colors.SAFETY_ZONE_ALPHA)
GOAL_LINE_ALPHA = wp.constant(colors.GOAL_LINE_ALPHA)
OBJECT_GOAL_ALPHA = wp.constant(colors.OBJECT_GOAL_ALPHA)
COLLIDED_ZONE_ALPHA = wp.constant(colors.COLLIDED_ZONE_ALPHA)


@wp.func
def blend(base: wp.vec3, over: wp.vec3, alpha: float) -> wp.vec3:
    return base + (over - base) * alpha


@wp.func
def to_body(d: wp.vec2, c: float, s: float) -> wp.vec2:
    """A world-frame offset expressed in the frame of a body with yaw (cos, sin) = (c, s)."""
    return wp.vec2(c * d[0] + s * d[1], -s * d[0] + c * d[1])


@wp.func
def box_sdf(q: wp.vec2, half: wp.vec2) -> float:
    """Signed distance from body-frame point q to an axis-aligned box of half sizes ``half`` (negative inside)."""
    dx = wp.abs(q[0]) - half[0]
    dy = wp.abs(q[1]) - half[1]
    outside = wp.sqrt(wp.max(dx, 0.0) * wp.max(dx, 0.0) + wp.max(dy, 0.0) * wp.max(dy, 0.0))
    return outside + wp.min(wp.max(dx, dy), 0.0)


@wp.func
def part_sdf(q: wp.vec2, part: wp.vec4) -> float:
    """Signed distance to one object part (cx, cy, hx, hy) in the object frame; hy <= 0 marks a disc of radius hx."""
    d = wp.vec2(q[0] - part[0], q[1] - part[1])
    if part[3] <= 0.0:
        return wp.length(d) - part[2]
    return box_sdf(d, wp.vec2(part[2], part[3]))


@wp.func
def object_sdf(p: wp.vec2, pose_x: float, pose_y: float, pose_yaw: float, parts: wp.array2d[wp.vec4], o: int) -> float:
    """Signed distance (min over parts, i.e. the union) from world point p to object o at the given pose."""
    q = to_body(wp.vec2(p[0] - pose_x, p[1] - pose_y), wp.cos(pose_yaw), wp.sin(pose_yaw))
    best = float(1.0e9)
    for k in range(parts.shape[1]):
        best = wp.min(best, part_sdf(q, parts[o, k]))
    return best


@wp.func
def mover_heading(rot: wp.array3d[wp.float32], w: int, m: int) -> wp.vec2:
    """(cos yaw, sin yaw) from a yaw array (last dim 1) or a quaternion (x, y, z, w) array (last dim 4).

    For quaternions it is the body x axis projected on the floor, normalised: no trigonometry per pixel, which
    matters because every pixel near a mover needs it."""
    if rot.shape[2] == 1:
        yaw = rot[w, m, 0]
        return wp.vec2(wp.cos(yaw), wp.sin(yaw))
    x = rot[w, m, 0]
    y = rot[w, m, 1]
    z = rot[w, m, 2]
    qw = rot[w, m, 3]
    c = 1.0 - 2.0 * (y * y + z * z)
    s = 2.0 * (qw * z + x * y)
    n = wp.sqrt(c * c + s * s)
    if n < 1.0e-12:
        return wp.vec2(1.0, 0.0)
    return wp.vec2(c / n, s / n)


@wp.func
def segment_distance(p: wp.vec2, a: wp.vec2, b: wp.vec2) -> float:
    ab = b - a
    denom = wp.dot(ab, ab)
    t = float(0.0)
    if denom > 0.0:
        t = wp.clamp(wp.dot(p - a, ab) / denom, 0.0, 1.0)
    return wp.length(p - (a + ab * t))


@wp.func
def shared(index: int, arr_len: int) -> int:
    """Index into a per-world array that may be shared (leading size 1) by all worlds."""
    return wp.min(index, arr_len - 1)


@wp.func
def near(p: wp.vec2, cx: float, cy: float, radius: float) -> bool:
    dx = p[0] - cx
    dy = p[1] - cy
    return wp.abs(dx) <= radius and wp.abs(dy) <= radius and dx * dx + dy * dy <= radius * radius


@wp.func
def paint_mover(
    color: wp.vec3,
    p: wp.vec2,
    px: float,
    m: int,
    wm: int,
    wr: int,
    wf: int,
    wrad: int,
    whs: int,
    pos: wp.array3d[wp.float32],
    rot: wp.array3d[wp.float32],
    flags: wp.array2d[wp.int32],
    radii: wp.array2d[wp.float32],
    half_sizes: wp.array3d[wp.float32],
    mover_colors: wp.array[wp.vec3],
    fixed_colors: wp.array[wp.vec3],
    shape_kind: int,
    footprint_half: wp.vec2,
    margin: float,
    reject_radius: float,
    style: int,
    ws: int,
    state: wp.array2d[wp.int32],
    state_colors: wp.array[wp.vec3],
    min_dot: float,
) -> wp.vec3:
    """Paint mover m over ``color`` at point p: its safety zone (collision shape + margin), footprint, heading.

    With per-mover states (``state`` has one column per mover) the mover takes its state's colour instead of its
    index colour. A footprint narrower than a few pixels is drawn as a plain square of at least ``min_dot`` (m)
    half width, without rim or heading (which would hide it)."""
    # Cheap reject: outside a square/circle that holds everything drawn for any mover.
    dx = p[0] - pos[wm, m, 0]
    if wp.abs(dx) > reject_radius:
        return color
    dy = p[1] - pos[wm, m, 1]
    if wp.abs(dy) > reject_radius or dx * dx + dy * dy > reject_radius * reject_radius:
        return color
    out = color
    dm = wp.vec2(dx, dy)
    cs = mover_heading(rot, wr, m)
    q = to_body(dm, cs[0], cs[1])
    mc = mover_colors[m % mover_colors.shape[0]]
    if state.shape[1] == pos.shape[1]:
        mc = state_colors[wp.clamp(state[ws, m], 0, state_colors.shape[0] - 1)]
    # A collided mover keeps its own colour (so you can tell which one it is) inside a red halo: its safety zone
    # turns red, more opaque, with a thicker rim.
    zc = mc
    zone_alpha = float(SAFETY_ZONE_ALPHA)
    rim = 1.5 * px
    collided = False
    if flags.shape[1] == pos.shape[1]:
        if flags[wf, m] != 0:
            collided = True
            zc = fixed_colors[C_COLLISION]
            zone_alpha = COLLIDED_ZONE_ALPHA
            rim = 2.5 * px
    if (style & DRAW_SAFETY_ZONE) or collided:
        zone = wp.length(dm) - (radii[wrad, m] + margin)
        if shape_kind == SHAPE_BOX:
            zone = box_sdf(q, wp.vec2(half_sizes[whs, m, 0] + margin, half_sizes[whs, m, 1] + margin))
        if zone <= 0.0:
            out = blend(out, zc, zone_alpha)
            if zone > -rim:
                out = zc
    small = footprint_half[0] < 3.0 * px or footprint_half[1] < 3.0 * px
    if small:
        if wp.abs(dx) <= wp.max(min_dot, footprint_half[0]) and wp.abs(dy) <= wp.max(min_dot, footprint_half[1]):
            out = mc
        return out
    foot = box_sdf(q, footprint_half)
    if foot <= 0.0:
        out = mc
        if foot > -1.0 * px:
            out = mc * 0.6  # darker rim separates touching movers
        if style & DRAW_HEADING:
            if q[0] >= 0.0 and q[0] <= footprint_half[0] - 1.5 * px and wp.abs(q[1]) <= 0.75 * px:
                out = fixed_colors[C_HEADING]
    return out


@wp.func
def paint_goal(
    color: wp.vec3,
    p: wp.vec2,
    px: float,
    m: int,
    wgl: int,
    goals: wp.array3d[wp.float32],
    goal_radius: float,
    mover_colors: wp.array[wp.vec3],
    fixed_colors: wp.array[wp.vec3],
) -> wp.vec3:
    """Paint mover m's goal: a disc in the mover's colour with a dark ring (still visible under its own mover)."""
    gx = p[0] - goals[wgl, m, 0]
    gy = p[1] - goals[wgl, m, 1]
    if wp.abs(gx) > goal_radius or wp.abs(gy) > goal_radius:
        return color
    dist = wp.sqrt(gx * gx + gy * gy)
    if dist > goal_radius:
        return color
    if dist > goal_radius - 1.0 * px:
        return fixed_colors[C_GOAL_RING]
    return mover_colors[m % mover_colors.shape[0]]


@wp.kernel
def bin_movers(
    # Model:
    cell_worlds: wp.array[wp.int32],
    tile_size: float,
    # State in:
    pos: wp.array3d[wp.float32],
    goals: wp.array3d[wp.float32],
    # State out:
    bin_count: wp.array3d[wp.int32],
    bin_items: wp.array4d[wp.int32],
    goal_count: wp.array3d[wp.int32],
    goal_items: wp.array4d[wp.int32],
    bin_overflow: wp.array[wp.int32],
):
    """Sort the movers (and goals) of each shown world into per-tile bins, so that for big swarms a pixel only
    tests the movers near it. Bins hold a few items (a tile fits about 4 non-overlapping movers); a full bin marks
    the cell, which then falls back to testing every mover (correct, only slower)."""
    c, m = wp.tid()
    w = cell_worlds[c]
    wm = shared(w, pos.shape[0])
    i = wp.clamp(int(wp.floor(pos[wm, m, 0] / tile_size)), 0, bin_count.shape[1] - 1)
    j = wp.clamp(int(wp.floor(pos[wm, m, 1] / tile_size)), 0, bin_count.shape[2] - 1)
    slot = wp.atomic_add(bin_count, c, i, j, 1)
    if slot < bin_items.shape[3]:
        bin_items[c, i, j, slot] = m
    else:
        bin_overflow[c] = 1
    if goals.shape[1] == pos.shape[1]:
        wg = shared(w, goals.shape[0])
        gi = wp.clamp(int(wp.floor(goals[wg, m, 0] / tile_size)), 0, goal_count.shape[1] - 1)
        gj = wp.clamp(int(wp.floor(goals[wg, m, 1] / tile_size)), 0, goal_count.shape[2] - 1)
        gslot = wp.atomic_add(goal_count, c, gi, gj, 1)
        if gslot < goal_items.shape[3]:
            goal_items[c, gi, gj, gslot] = m
        else:
            bin_overflow[c] = 1


@wp.kernel
def draw_background(
    # Model:
    tiles: wp.array2d[wp.int32],
    tile_size: float,
    px_per_m: float,
    num_cells: int,
    cols: int,
    row_cell: wp.array[wp.int32],
    col_cell: wp.array[wp.int32],
    row_local: wp.array[wp.int32],
    col_local: wp.array[wp.int32],
    row_y: wp.array[wp.float32],
    col_x: wp.array[wp.float32],
    fixed_colors: wp.array[wp.vec3],
    style: int,
    # State out:
    background: wp.array3d[wp.uint8],
):
    """The static layer (separators, tiles, grid lines, hatched holes), drawn once when the renderer is built."""
    row, col = wp.tid()
    color = fixed_colors[C_BACKGROUND]
    rc = row_cell[row]
    cc = col_cell[col]
    if rc >= 0 and cc >= 0 and rc * cols + cc < num_cells:
        x = col_x[col]
        y = row_y[row]
        px = 1.0 / px_per_m
        ti = int(wp.floor(x / tile_size))
        tj = int(wp.floor(y / tile_size))
        present = 0
        if ti >= 0 and tj >= 0 and ti < tiles.shape[0] and tj < tiles.shape[1]:
            present = tiles[ti, tj]
        if present != 0:
            color = fixed_colors[C_TILE]
            if style & DRAW_GRID:
                # A pixel-wide line at every tile edge: distance to the nearest multiple of the tile size.
                ex = wp.abs(x - wp.round(x / tile_size) * tile_size)
                ey = wp.abs(y - wp.round(y / tile_size) * tile_size)
                if wp.min(ex, ey) < 0.75 * px:
                    color = fixed_colors[C_TILE_LINE]
        else:
            color = fixed_colors[C_HOLE]
            if (row_local[row] + col_local[col]) % 8 < 2:  # diagonal hatch: reads as "no floor here"
                color = fixed_colors[C_HOLE_HATCH]
    background[row, col, 0] = wp.uint8(int(color[0] + 0.5))
    background[row, col, 1] = wp.uint8(int(color[1] + 0.5))
    background[row, col, 2] = wp.uint8(int(color[2] + 0.5))


@wp.kernel
def draw_topdown(
    # Model: mosaic geometry (per-row / per-column lookup tables, so no divisions per pixel)
    background: wp.array3d[wp.uint8],
    num_cells: int,
    cols: int,
    row_cell: wp.array[wp.int32],
    col_cell: wp.array[wp.int32],
    row_y: wp.array[wp.float32],
    col_x: wp.array[wp.float32],
    px_per_m: float,
    cell_worlds: wp.array[wp.int32],
    run_length: int,
    # Model: shapes and style
    shape_kind: int,
    footprint_half: wp.vec2,
    margin: float,
    reject_radius: float,
    radii: wp.array2d[wp.float32],
    half_sizes: wp.array3d[wp.float32],
    object_parts: wp.array2d[wp.vec4],
    object_shape: wp.array2d[wp.int32],
    fixed_colors: wp.array[wp.vec3],
    mover_colors: wp.array[wp.vec3],
    goal_radius: float,
    style: int,
    tile_size: float,
    bin_reach: int,
    state_colors: wp.array[wp.vec3],
    min_dot: float,
    # State in:
    pos: wp.array3d[wp.float32],
    rot: wp.array3d[wp.float32],
    flags: wp.array2d[wp.int32],
    goals: wp.array3d[wp.float32],
    object_poses: wp.array3d[wp.float32],
    object_goals: wp.array3d[wp.float32],
    obstacles: wp.array3d[wp.float32],
    state: wp.array2d[wp.int32],
    bin_count: wp.array3d[wp.int32],
    bin_items: wp.array4d[wp.int32],
    goal_count: wp.array3d[wp.int32],
    goal_items: wp.array4d[wp.int32],
    bin_overflow: wp.array[wp.int32],
    # State out:
    image: wp.array3d[wp.uint8],
):
    row, chunk = wp.tid()
    # Each thread draws a run of `run_length` pixels of one row: 1 on GPUs (one thread per pixel); longer runs on
    # CPUs, where every thread call copies the kernel's arguments and that copy would dominate a cheap pixel.
    col_start = chunk * run_length
    col_end = wp.min(col_start + run_length, image.shape[1])
    rc = row_cell[row]
    px = 1.0 / px_per_m
    y = row_y[row]
    num_movers = pos.shape[1]
    has_goals = goals.shape[1] == num_movers and num_movers > 0
    static_only = obstacles.shape[1] == 0 and object_goals.shape[1] == 0 and object_poses.shape[1] == 0
    # Row band: bit m is set when this row can touch mover m, its goal or its goal line. Computed once per cell
    # along the run; most rows of a cell meet few movers, so most mover tests are skipped (movers >= 31: tested).
    last_cell = int(-1)
    band = int(0)
    for col in range(col_start, col_end):
        cc = col_cell[col]
        cell = rc * cols + cc
        if rc < 0 or cc < 0 or cell >= num_cells:  # separator: copy the static layer
            image[row, col, 0] = background[row, col, 0]
            image[row, col, 1] = background[row, col, 1]
            image[row, col, 2] = background[row, col, 2]
            continue
        w = cell_worlds[cell]
        if cell != last_cell:
            last_cell = cell
            band = int(0)
            wb = shared(w, pos.shape[0])
            wbg = shared(w, goals.shape[0])
            for m in range(wp.min(num_movers, 31)):
                lo = pos[wb, m, 1] - reject_radius
                hi = pos[wb, m, 1] + reject_radius
                if has_goals:
                    lo = wp.min(lo, goals[wbg, m, 1] - goal_radius - px)
                    hi = wp.max(hi, goals[wbg, m, 1] + goal_radius + px)
                if y >= lo and y <= hi:
                    band = band | (1 << m)
        if band == 0 and static_only and num_movers <= 31:  # nothing dynamic on this pixel's row
            image[row, col, 0] = background[row, col, 0]
            image[row, col, 1] = background[row, col, 1]
            image[row, col, 2] = background[row, col, 2]
            continue
        color = wp.vec3(float(background[row, col, 0]), float(background[row, col, 1]), float(background[row, col, 2]))
        # Pixel centre in world metres (image rows grow downwards, world y upwards: the tables already flip it).
        p = wp.vec2(col_x[col], y)

        # --- static obstacles: oriented rectangles (cx, cy, hx, hy, yaw)
        wo = shared(w, obstacles.shape[0])
        for k in range(obstacles.shape[1]):
            yaw = obstacles[wo, k, 4]
            q = to_body(wp.vec2(p[0] - obstacles[wo, k, 0], p[1] - obstacles[wo, k, 1]), wp.cos(yaw), wp.sin(yaw))
            d = box_sdf(q, wp.vec2(obstacles[wo, k, 2], obstacles[wo, k, 3]))
            if d <= 0.0:
                color = fixed_colors[C_OBSTACLE]
                if d > -1.5 * px:
                    color = fixed_colors[C_OBSTACLE_EDGE]

        # --- object goal poses: translucent green silhouettes of the objects
        wg = shared(w, object_goals.shape[0])
        ws = shared(w, object_shape.shape[0])
        for o in range(object_goals.shape[1]):
            d = object_sdf(p, object_goals[wg, o, 0], object_goals[wg, o, 1], object_goals[wg, o, 2], object_parts,
                           object_shape[ws, o])
            if d <= 0.0:
                color = blend(color, fixed_colors[C_OBJECT_GOAL], OBJECT_GOAL_ALPHA)
                if d > -1.5 * px:
                    color = fixed_colors[C_OBJECT_GOAL]

        wm = shared(w, pos.shape[0])
        wr = shared(w, rot.shape[0])
        wgl = shared(w, goals.shape[0])

        # --- thin translucent lines from each mover to its goal (which goal is whose)
        if has_goals and (style & DRAW_GOAL_LINES) and bin_count.shape[0] == 0:
            for m in range(num_movers):
                if m < 31 and ((band >> m) & 1) == 0:
                    continue
                ax = pos[wm, m, 0]
                ay = pos[wm, m, 1]
                bx = goals[wgl, m, 0]
                by = goals[wgl, m, 1]
                # Cheap reject with the segment's bounding box before the exact distance.
                if p[0] < wp.min(ax, bx) - px or p[0] > wp.max(ax, bx) + px:
                    continue
                if p[1] < wp.min(ay, by) - px or p[1] > wp.max(ay, by) + px:
                    continue
                if segment_distance(p, wp.vec2(ax, ay), wp.vec2(bx, by)) < 0.6 * px:
                    color = blend(color, mover_colors[m % mover_colors.shape[0]], GOAL_LINE_ALPHA)

        # --- objects: opaque union of parts with a dark rim
        wob = shared(w, object_poses.shape[0])
        for o in range(object_poses.shape[1]):
            d = object_sdf(p, object_poses[wob, o, 0], object_poses[wob, o, 1], object_poses[wob, o, 2], object_parts,
                           object_shape[ws, o])
            if d <= 0.0:
                color = fixed_colors[C_OBJECT]
                if d > -1.5 * px:
                    color = fixed_colors[C_OBJECT_EDGE]

        # --- movers (safety zone, footprint, heading), then goals on top. Few movers: every mover of the row band;
        # many: only those binned in the 3 x 3 (or wider) tiles around the pixel (see bin_movers).
        wf = shared(w, flags.shape[0])
        wrad = shared(w, radii.shape[0])
        whs = shared(w, half_sizes.shape[0])
        wst = shared(w, state.shape[0])
        use_bins = int(0)
        if bin_count.shape[0] > 0:
            if bin_overflow[cell] == 0:
                use_bins = int(1)
        if use_bins == 1:
            ti = wp.clamp(int(wp.floor(p[0] / tile_size)), 0, bin_count.shape[1] - 1)
            tj = wp.clamp(int(wp.floor(p[1] / tile_size)), 0, bin_count.shape[2] - 1)
            for bi in range(wp.max(ti - bin_reach, 0), wp.min(ti + bin_reach + 1, bin_count.shape[1])):
                for bj in range(wp.max(tj - bin_reach, 0), wp.min(tj + bin_reach + 1, bin_count.shape[2])):
                    for k in range(wp.min(bin_count[cell, bi, bj], bin_items.shape[3])):
                        m = bin_items[cell, bi, bj, k]
                        # The cheap reject inline: the call (which copies its array arguments) only near a mover.
                        if near(p, pos[wm, m, 0], pos[wm, m, 1], reject_radius):
                            color = paint_mover(color, p, px, m, wm, wr, wf, wrad, whs, pos, rot, flags, radii,
                                                half_sizes, mover_colors, fixed_colors, shape_kind, footprint_half,
                                                margin, reject_radius, style, wst, state, state_colors, min_dot)
            if has_goals:
                for bi in range(wp.max(ti - 1, 0), wp.min(ti + 2, bin_count.shape[1])):
                    for bj in range(wp.max(tj - 1, 0), wp.min(tj + 2, bin_count.shape[2])):
                        for k in range(wp.min(goal_count[cell, bi, bj], goal_items.shape[3])):
                            color = paint_goal(color, p, px, goal_items[cell, bi, bj, k], wgl, goals, goal_radius,
                                               mover_colors, fixed_colors)
        else:
            for m in range(num_movers):
                if m < 31 and ((band >> m) & 1) == 0:
                    continue
                if not near(p, pos[wm, m, 0], pos[wm, m, 1], reject_radius):
                    continue
                color = paint_mover(color, p, px, m, wm, wr, wf, wrad, whs, pos, rot, flags, radii, half_sizes,
                                    mover_colors, fixed_colors, shape_kind, footprint_half, margin, reject_radius,
                                    style, wst, state, state_colors, min_dot)
            if has_goals:
                for m in range(num_movers):
                    if m < 31 and ((band >> m) & 1) == 0:
                        continue
                    color = paint_goal(color, p, px, m, wgl, goals, goal_radius, mover_colors, fixed_colors)

        image[row, col, 0] = wp.uint8(int(color[0] + 0.5))
        image[row, col, 1] = wp.uint8(int(color[1] + 0.5))
        image[row, col, 2] = wp.uint8(int(color[2] + 0.5))
