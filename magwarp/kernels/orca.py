"""ORCA's incremental 2-D linear program as one Warp kernel: a thread per mover (:func:`solve_lines`).

The same program as :func:`magwarp.swarm.planner.solve_lines_torch` (its reference): the velocity closest to the
preferred one within a speed circle that satisfies every half-plane, the constraints added one by one; a violated one
moves the velocity to the best point of its line within the earlier ones, and an infeasible one (no such point)
keeps the velocity and clears ``ok`` (``skip``: and is dropped for the later lines). The torch form runs
O(lines^2) tensor operations over every mover (about 4,000 small ones per planner call with 8 neighbours and 8 rays);
here each thread runs its own lines in a loop. float32, with the same operations in the same order per mover. On this
project's 2-core CPU (16 worlds of 1,024 movers, 8 rays and 24 lines per mover with the env's 8 neighbours): 11.5 ms
against 36.0 ms in torch, with the lines' stacking (``benchmarks/results/swarm_planner_cost_s44_cpu.json``).
"""

from __future__ import annotations

import warp as wp

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
    v = pref
    n = wp.length(pref)
    if n > max_speed:
        v = pref * (max_speed / wp.max(n, 1.0e-9))
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
