"""ORCA's incremental 2-D linear program as one Warp kernel, a thread per mover (:func:`solve_lines`), and the
planner's half-planes as another (:func:`build_lines`).

The same program as :func:`magwarp.swarm.planner.solve_lines_torch` (its reference): the velocity closest to the
preferred one within a speed circle that satisfies every half-plane, the constraints added one by one; a violated one
moves the velocity to the best point of its line within the earlier ones, and an infeasible one (no such point)
keeps the velocity and clears ``ok`` (``skip``: and is dropped for the later lines). The torch form runs
O(lines^2) tensor operations over every mover (about 4,000 small ones per planner call with 8 neighbours and 8 rays);
here each thread runs its own lines in a loop. float32, with the same operations in the same order per mover.
:func:`build_lines` writes the planner's lines themselves (walls, braking shield, ORCA: its greedy path), so the two
steps are two launches. On this project's 2-core CPU (16 worlds of 1,024 movers, 8 rays and 8 neighbours: 16 lines
per mover): 14.2 ms for both launches against 49.0 ms for the torch lines and their solve
(``benchmarks/results/swarm_planner_cost_lines_s44_cpu.json``).
"""

from __future__ import annotations

import warp as wp

from magwarp.kernels.dynamics import clip_norm2
from magwarp.kernels.options import MODULE_OPTIONS

wp.set_module_options({"enable_backward": False, **MODULE_OPTIONS})


@wp.func
def det2(a: wp.vec2, b: wp.vec2) -> float:
    return a[0] * b[1] - a[1] * b[0]


@wp.kernel
def solve_lines(
    # Model:
    max_speed: float,
    skip: int,  # 1: a line that leaves no room with the earlier ones is dropped for the later ones
    # State in:
    points: wp.array2d(dtype=wp.vec2),  # [rows, L]: a point of each line
    directions: wp.array2d(dtype=wp.vec2),  # [rows, L]: allowed v satisfy det(direction, point - v) <= 0
    live_in: wp.array2d(dtype=wp.bool),
    v_pref: wp.array(dtype=wp.vec2),
    # Scratch:
    live: wp.array2d(dtype=wp.bool),  # the lines kept (``skip``)
    # State out:
    v_out: wp.array(dtype=wp.vec2),
    ok_out: wp.array(dtype=wp.bool),
):
    i = wp.tid()
    pref = v_pref[i]
    v = clip_norm2(pref, max_speed)
    ok = bool(True)
    L = points.shape[1]
    for a in range(L):
        live[i, a] = live_in[i, a]
    for a in range(L):
        p_a = points[i, a]
        d_a = directions[i, a]
        live_a = live[i, a]
        violated = live_a and det2(d_a, p_a - v) > 0.0
        # the part of line a inside the speed circle ...
        dot = wp.dot(p_a, d_a)
        disc = dot * dot + max_speed * max_speed - wp.dot(p_a, p_a)
        feasible = disc >= 0.0
        root = wp.sqrt(wp.max(disc, 0.0))
        t_lo = -dot - root
        t_hi = -dot + root
        # ... and inside the earlier half-planes
        for b in range(a):
            if not live[i, b]:
                continue
            d_b = directions[i, b]
            den = det2(d_a, d_b)
            num = det2(d_b, p_a - points[i, b])
            if wp.abs(den) <= 1.0e-6:  # parallel
                if num < 0.0:
                    feasible = False
                continue
            t = num / den
            if den >= 0.0:
                t_hi = wp.min(t_hi, t)
            else:
                t_lo = wp.max(t_lo, t)
        feasible = feasible and t_lo <= t_hi
        if violated:
            if feasible:
                t = wp.dot(pref - p_a, d_a)
                v = p_a + wp.min(wp.max(t, t_lo), t_hi) * d_a
            else:
                ok = False
                if skip != 0:
                    live[i, a] = False
    v_out[i] = v
    ok_out[i] = ok


@wp.struct
class LineParams:
    """The planner's constants for :func:`build_lines` (:class:`magwarp.swarm.SwarmPlanner`'s names)."""

    step: float  # s: the held command's step (T)
    horizon: float  # s: ORCA's time horizon
    separate: float  # s: pairs inside the radius leave it within this
    safe: float  # m: the safe distance (the pair's reach and the buffer)
    contact: float  # m: the collision distance of two centres
    margin: float  # m
    yield_share: float  # the lower-indexed mover's share is 1 - yield_share
    shield: float  # the braking shield's share of a_max (0: no shield lines)
    a_max: float
    a_brake: float
    wall_reach: float  # m


@wp.func
def stop_speed(room: float, closing: float, decel: float, step: float) -> float:
    """:func:`magwarp.swarm.planner.stop_speed`, one value."""
    left = room - 0.5 * step * closing
    root = wp.sqrt(0.25 * step * step + 2.0 * wp.max(left, 0.0) / decel)
    if left >= 0.0:
        return decel * (root - 0.5 * step)
    return 2.0 * left / step


@wp.kernel
def build_lines(
    # Model:
    p: LineParams,
    rays: wp.array(dtype=wp.vec2),
    num_movers: int,
    # State in:
    vel: wp.array(dtype=wp.vec2),
    rel_pos: wp.array2d(dtype=wp.vec2),  # [rows, k]: neighbours relative to the mover (p_j - p_i)
    rel_vel: wp.array2d(dtype=wp.vec2),  # v_j - v_i
    mask: wp.array2d(dtype=wp.bool),
    index: wp.array2d(dtype=wp.int32),
    walls: wp.array2d(dtype=float),  # [rows, R]: distance to the first point off the tiles along each ray
    # State out ([rows, R + (k if shield) + k]: the wall lines, the shield lines, the ORCA lines):
    points: wp.array2d(dtype=wp.vec2),
    directions: wp.array2d(dtype=wp.vec2),
    live: wp.array2d(dtype=wp.bool),
):
    """The half-planes of :meth:`magwarp.swarm.SwarmPlanner._wall_lines` and ``_neighbour_lines`` for one mover, in
    the planner's order of urgency, into the rows :func:`solve_lines` reads."""
    i = wp.tid()
    v0 = vel[i]
    T = p.step
    R = rays.shape[0]
    k = rel_pos.shape[1]
    # walls: no faster towards the wall than stopping before it allows
    for r in range(R):
        ray = rays[r]
        room = wp.max(walls[i, r] - p.wall_reach, 0.0)
        limit = wp.max(stop_speed(room, wp.dot(v0, ray), p.a_brake, T), 0.0)
        points[i, r] = limit * ray
        directions[i, r] = wp.vec2(-ray[1], ray[0])
        live[i, r] = True
    base = R
    if p.shield > 0.0:  # the braking shield: the closing speed at the step's end from which both can still stop
        for s in range(k):
            rp = rel_pos[i, s]
            d0 = wp.max(wp.length(rp), 1.0e-6)
            nrm = rp / d0
            c0 = -wp.dot(rel_vel[i, s], nrm)
            c_max = stop_speed(d0 - p.contact - p.margin, c0, 2.0 * p.shield * p.a_max, T)
            lim = wp.dot(v0, nrm) + 0.5 * (c_max - c0)
            points[i, base + s] = lim * nrm
            directions[i, base + s] = wp.vec2(-nrm[1], nrm[0])
            live[i, base + s] = mask[i, s]
        base = base + k
    own = i % num_movers
    floor = p.contact + 2.0 * p.margin
    inv_h = 1.0 / p.horizon
    for s in range(k):
        # ORCA from the positions half a step ahead, for the relative velocity v_i - v_j
        rv = -rel_vel[i, s]
        rp = rel_pos[i, s] - 0.5 * T * rv
        gap = wp.length(rp)
        radius = wp.min(p.safe, wp.max(0.98 * gap, floor))
        dist_sq = wp.dot(rp, rp)
        r_sq = radius * radius
        w = rv - inv_h * rp
        w_sq = wp.max(wp.dot(w, w), 1.0e-12)
        dot1 = wp.dot(w, rp)
        w_len = wp.sqrt(w_sq)
        unit_w = w / w_len
        direction = wp.vec2(0.0)
        u = wp.vec2(0.0)
        if dot1 < 0.0 and dot1 * dot1 > r_sq * w_sq:  # the cutoff circle
            direction = wp.vec2(unit_w[1], -unit_w[0])
            u = (radius * inv_h - w_len) * unit_w
        else:  # a leg
            leg = wp.sqrt(wp.max(dist_sq - r_sq, 0.0))
            x = rp[0]
            y = rp[1]
            dir_leg = -wp.vec2(x * leg + y * radius, -x * radius + y * leg)
            if det2(rp, w) > 0.0:
                dir_leg = wp.vec2(x * leg - y * radius, x * radius + y * leg)
            dir_leg = dir_leg / wp.max(dist_sq, 1.0e-12)
            direction = dir_leg
            u = wp.dot(rv, dir_leg) * dir_leg - rv
        if dist_sq <= r_sq:  # already closer than the radius: leave within ``separate``
            wc = rv - rp / p.separate
            wc_len = wp.max(wp.length(wc), 1.0e-9)
            unit_c = wc / wc_len
            direction = wp.vec2(unit_c[1], -unit_c[0])
            u = (radius / p.separate - wc_len) * unit_c
        share = 1.0 - p.yield_share
        if index[i, s] < own:
            share = p.yield_share
        points[i, base + s] = v0 + share * u
        directions[i, base + s] = direction
        live[i, base + s] = mask[i, s]
