"""The swarm safety filter's choice as one Warp kernel: a thread per mover (:func:`safe_choice`).

The same rule as :meth:`magwarp.swarm.safety.SafetyFilter.choose` (its torch form is this kernel's reference, and its
module docstring the rule's derivation): each mover's committed braking segment against each neighbour's (the closest
points of two segments, a separating direction and the pair's slack shared by how fast each heads into it), against
each cell off the tiles around it (the closest points of the segment and the square), and the crowded list's ball;
then the candidates (braking, and the wanted velocity's turns at each fraction of the way from braking), the first
safe one closest to the wanted velocity. In float32 like the torch form; the sums run in another order, so a
candidate at a constraint's boundary or two candidates at the same cost may be chosen differently
(``tests/test_swarm_safety.py`` compares both on random crowds).

The torch form builds ``[..., K, C]`` tensors (21 candidates by 24 neighbours and 25 cells per mover) and every cell's
six point pairs; here each thread loops over them, and skips the cells on the tiles at once. On this project's 2-core
CPU (torch on one thread, 16 worlds of 1,024 movers, the planner's filter): 11.5 ms against 268 ms in torch
(``python benchmarks/swarm_planner_cost.py --device cpu --movers 64 256 1024 --worlds 16``,
``benchmarks/results/swarm_planner_cost_lines_s44_cpu.json``, 2026-12-07).
"""

from __future__ import annotations

import warp as wp

from magwarp.kernels.options import MODULE_OPTIONS

wp.set_module_options({"enable_backward": False, **MODULE_OPTIONS})

INF = wp.constant(float("inf"))
#: m: closest points of two paths (or of a path and a cell) nearer than this take the centre line as their normal.
#: Below it the points' difference can be float32 rounding and its direction as good as random (the kernel and the
#: torch form would then choose from different constraints): positions of order 1 m round at about 1e-7 m, and paths
#: that cross at a shallow angle move their crossing point by that over the angle (3e-6 m at 1e-3 rad, seen)
TOUCH_GAP = 1.0e-5
_TOUCH_GAP = wp.constant(TOUCH_GAP)


@wp.struct
class SafetyParams:
    contact: float  # m: the collision distance of two centres
    wall_reach: float  # m: the closest a centre may come to the edge of the tiles
    a_max: float
    step: float  # s: T, an env step
    dt: float  # s: a control cycle
    a_brake: float  # the committed braking
    margin: float  # m: the extra distance kept
    v_cap: float  # the speed cap
    reach_radius: float  # m: movers farther apart cannot meet within a step
    stop_cap: float  # m: the longest committed segment
    share_min: float  # the least share of a pair's slack
    share_floor: float  # m/s: a mover at rest still gets a share
    tile_size: float
    walls: int  # 1: the cells off the tiles are obstacles (a position and the tiles were given)


@wp.func
def stop_length(speed: float, a_brake: float, step: float) -> float:
    return speed * speed / (2.0 * a_brake) + 0.5 * step * speed


@wp.func
def unit_or_zero(v: wp.vec2, n: float) -> wp.vec2:
    return v / wp.max(n, 1.0e-12)


@wp.func
def segment_params(p1: wp.vec2, d1: wp.vec2, p2: wp.vec2, d2: wp.vec2) -> wp.vec2:
    """``(s, t)`` in [0, 1] of the closest points ``p1 + s d1`` and ``p2 + t d2`` of two segments (degenerate segments
    are points): :func:`magwarp.swarm.safety.segment_closest_points`, one pair."""
    eps = 1.0e-12
    r = p1 - p2
    a = wp.dot(d1, d1)
    e = wp.dot(d2, d2)
    f = wp.dot(d2, r)
    c = wp.dot(d1, r)
    b = wp.dot(d1, d2)
    a_ok = a > eps
    e_ok = e > eps
    safe_a = wp.where(a_ok, a, 1.0)
    safe_e = wp.where(e_ok, e, 1.0)
    denom = a * e - b * b
    s = float(0.0)
    if denom > eps * (a * e + eps):
        s = (b * f - c * e) / wp.where(denom > 0.0, denom, 1.0)
    s = wp.clamp(s, 0.0, 1.0)
    t = (b * s + f) / safe_e
    if t < 0.0:
        s = wp.clamp(-c / safe_a, 0.0, 1.0)
    elif t > 1.0:
        s = wp.clamp((b - c) / safe_a, 0.0, 1.0)
    t = wp.clamp(t, 0.0, 1.0)
    if not e_ok:
        s = wp.clamp(-c / safe_a, 0.0, 1.0)
        t = 0.0
    if not a_ok:
        t = wp.clamp(f / safe_e, 0.0, 1.0)
        s = 0.0
    return wp.vec2(s, t)


@wp.func
def clamp_box(p: wp.vec2, lo: wp.vec2, hi: wp.vec2) -> wp.vec2:
    return wp.vec2(wp.max(wp.min(p[0], hi[0]), lo[0]), wp.max(wp.min(p[1], hi[1]), lo[1]))


@wp.func
def corner_on_segment(corner: wp.vec2, a: wp.vec2, d: wp.vec2, dd: float) -> wp.vec2:
    t = wp.clamp(wp.dot(corner - a, d) / wp.max(dd, 1.0e-12), 0.0, 1.0)
    return a + t * d


@wp.func
def gain(p: SafetyParams, v1: wp.vec2) -> float:
    """``T + dt/2 + |v1| / (2 a_brake)``: the factor of ``max(v1.n, 0)`` in the path bound."""
    return p.step + 0.5 * p.dt + wp.length(v1) / (2.0 * p.a_brake)


@wp.func
def candidate(p: SafetyParams, i: int, v_b: wp.vec2, w: wp.array(dtype=wp.vec2), fractions: wp.array(dtype=float),
              turns: int) -> wp.vec2:
    """Candidate ``i``: braking (0), then ``v_b + f (w_r - v_b)`` for fraction ``f`` and turn ``r`` (at
    ``1 + f R + r``)."""
    if i == 0:
        return v_b
    k = i - 1
    f = fractions[k // turns]
    return v_b + f * (w[k % turns] - v_b)


@wp.kernel
def safe_choice(
    # Model:
    p: SafetyParams,
    tiles: wp.array2d(dtype=wp.int32),
    cell_offsets: wp.array(dtype=wp.vec2i),
    rot: wp.array(dtype=wp.mat22),
    fractions: wp.array(dtype=float),
    # State in:
    vel: wp.array(dtype=wp.vec2),
    wanted: wp.array(dtype=wp.vec2),
    rel_pos: wp.array2d(dtype=wp.vec2),
    rel_vel: wp.array2d(dtype=wp.vec2),
    mask: wp.array2d(dtype=wp.bool),
    pos: wp.array(dtype=wp.vec2),
    row0: int,  # the first mover of this launch (thread i: mover row0 + i; scratch row i)
    # Scratch (per thread: its mover's constraints' normals and bases, its candidates' turned velocities):
    normals: wp.array2d(dtype=wp.vec2),
    bases: wp.array2d(dtype=float),
    turned: wp.array2d(dtype=wp.vec2),
    # State out:
    safe: wp.array(dtype=wp.vec2),
    passes: wp.array(dtype=wp.bool),
):
    """One mover: the safe velocity closest to ``wanted`` among the candidates (braking where no other is safe) and
    whether ``wanted``'s own candidate passes. ``pos`` with no rows: no walls."""
    i = wp.tid()  # scratch row
    row = row0 + i  # mover
    T = p.step
    v0 = vel[row]
    speed = wp.length(v0)
    seg_i = unit_or_zero(v0, speed) * stop_length(speed, p.a_brake, T)
    k = rel_pos.shape[1]
    count = int(0)
    # neighbours: the pair's separating plane and the mover's share of its slack
    all_live = bool(True)
    d_k = float(0.0)
    for s in range(k):
        live = mask[row, s]
        rp = rel_pos[row, s]
        if not live:
            all_live = False
            continue
        d_k = wp.max(d_k, wp.length(rp))
        vel_j = v0 + rel_vel[row, s]
        speed_j = wp.length(vel_j)
        seg_j = unit_or_zero(vel_j, speed_j) * stop_length(speed_j, p.a_brake, T)
        st = segment_params(wp.vec2(0.0), seg_i, rp, seg_j)
        q_i = st[0] * seg_i
        sep = rp + st[1] * seg_j - q_i
        gap = wp.length(sep)
        n = unit_or_zero(rp, wp.length(rp))
        if gap > _TOUCH_GAP:
            n = sep / wp.max(gap, 1.0e-12)
        v0n = wp.dot(v0, n)
        toward_i = wp.max(v0n, 0.0) + p.share_floor
        toward_j = wp.max(-wp.dot(vel_j, n), 0.0) + p.share_floor
        budget = wp.max(gap - p.contact - p.margin, 0.0) * (toward_i / (toward_i + toward_j))
        normals[i, count] = n
        bases[i, count] = -wp.dot(q_i, n) + 0.5 * T * wp.max(v0n, 0.0) - budget
        count += 1
    ball = float(INF)
    if k > 0 and all_live and d_k <= p.reach_radius:  # a full list within reach: a mover may be unseen
        ball = p.share_min * (d_k - stop_length(speed, p.a_brake, T) - p.stop_cap - p.contact - p.margin)
    # walls: every cell off the tiles around the mover is a square obstacle
    if p.walls != 0:
        a = pos[row]
        b = a + seg_i
        dd = wp.dot(seg_i, seg_i)
        size = p.tile_size
        cx = int(wp.floor(a[0] / size))
        cy = int(wp.floor(a[1] / size))
        for c in range(cell_offsets.shape[0]):
            ix = cx + cell_offsets[c][0]
            iy = cy + cell_offsets[c][1]
            if ix >= 0 and ix < tiles.shape[0] and iy >= 0 and iy < tiles.shape[1]:
                if tiles[ix, iy] != 0:
                    continue  # on the tiles: no obstacle
            lo = wp.vec2(float(ix) * size, float(iy) * size)
            hi = lo + wp.vec2(size, size)
            # the closest pair of the six: the segment's ends against the box, the box's corners against the
            # segment (the first of equal distances, as torch's argmin)
            q_i = a
            q_o = clamp_box(a, lo, hi)
            best_d = wp.length(q_o - q_i)
            qb = clamp_box(b, lo, hi)
            d = wp.length(qb - b)
            if d < best_d:
                best_d = d
                q_i = b
                q_o = qb
            for corner_index in range(4):
                corner = lo
                if corner_index == 1:
                    corner = wp.vec2(hi[0], lo[1])
                elif corner_index == 2:
                    corner = wp.vec2(lo[0], hi[1])
                elif corner_index == 3:
                    corner = hi
                qs = corner_on_segment(corner, a, seg_i, dd)
                d = wp.length(corner - qs)
                if d < best_d:
                    best_d = d
                    q_i = qs
                    q_o = corner
            gap = best_d
            centre = 0.5 * (lo + hi) - a
            n = unit_or_zero(centre, wp.length(centre))
            if gap > _TOUCH_GAP:
                n = (q_o - q_i) / wp.max(gap, 1.0e-12)
            budget = wp.max(gap - p.wall_reach - p.margin, 0.0)
            normals[i, count] = n
            bases[i, count] = wp.dot(a - q_i, n) + 0.5 * T * wp.max(wp.dot(v0, n), 0.0) - budget
            count += 1
    # candidates: braking, then the wanted velocity (no faster than v_cap) and its turns, each within one step's
    # reach of the velocity, at each fraction of the way from braking
    v_b = v0 * wp.max(1.0 - p.a_brake * T / wp.max(speed, 1.0e-12), 0.0)
    want = wanted[row]
    w_speed = wp.length(want)
    w_cap = want
    if w_speed > p.v_cap:
        w_cap = want * (p.v_cap / wp.max(w_speed, 1.0e-12))
    reach = p.a_max * T * (1.0 - 1.0e-5)
    R = rot.shape[0]
    for r in range(R):
        dv = rot[r] * w_cap - v0
        norm = wp.length(dv)
        if norm > reach:
            dv = dv * (reach / wp.max(norm, 1.0e-12))
        turned[i, r] = v0 + dv
    num = 1 + fractions.shape[0] * R
    reach_v0 = 0.5 * T * speed
    best = int(0)
    best_cost = float(INF)
    first_ok = bool(False)
    for j in range(num):
        cand = candidate(p, j, v_b, turned[i], fractions, R)
        g1 = gain(p, cand)
        bad = reach_v0 + wp.length(cand) * g1 > ball
        if count > 0:
            worst = float(-INF)
            for c in range(count):
                worst = wp.max(worst, bases[i, c] + wp.max(wp.dot(cand, normals[i, c]), 0.0) * g1)
            bad = bad or worst > 0.0
        if j == 0:
            bad = False  # braking is always safe (recursive feasibility)
        if j == 1:
            first_ok = not bad
        if not bad:
            cost = wp.length_sq(cand - want)
            if cost < best_cost:
                best_cost = cost
                best = j
    safe[row] = candidate(p, best, v_b, turned[i], fractions, R)
    passes[row] = first_ok and w_speed <= p.v_cap
