"""A scripted, decentralised planner for the swarm env: ORCA (optimal reciprocal collision avoidance) on the
local view, with a braking shield for the 40 ms command hold, then a provably collision-free safety filter.

Each mover looks only at what its observation holds (its goal, the ``k`` nearest movers within the observation
radius, the wall rays), so a step costs O(k) per mover, on the device, for any swarm size. Per mover:

1. *preferred velocity*: towards the goal at ``cruise`` speed, slowing so that it can stop on the goal
   (``sqrt(2 a_brake d)``); with ``traffic="lanes"`` (``"auto"``, the default: on layouts without holes at least
   :data:`AUTO_LANES_TILES` tiles a side) along a Manhattan grid of one-way lanes every ``lane_pitch`` tiles instead
   (:class:`~magwarp.swarm.traffic.LaneField`: no head-on meetings, flows cross at right angles, routes keep off
   the middle; 1024 movers on 64 x 64 tiles reached 95.1% / 94.8% of their first goals in 40 s, seeds 0 / 1,
   against 56% straight at the goals, where the crowd packed in the middle);
2. *reciprocal avoidance*: every neighbour gives one half-plane of allowed velocities, the ORCA line of van den
   Berg et al. (2011) for a time horizon ``horizon`` and the safe distance (both collision shapes' reach, the safety
   margin and a ``buffer``). The command is an acceleration held for the whole env step, so the velocity changes
   linearly within it: the lines are drawn from the positions half a step ahead (where the new velocity in effect
   starts). Pairs already inside the safe distance use 0.98 x their gap as the radius, but never less than
   ``2 margin`` above contact (no creep into contact; below that they separate within ``separate`` s). The mover of
   lower index takes ``1 - yield_share`` of the avoidance and the other ``yield_share``;
3. *braking shield*: per neighbour, the closing speed at the end of the step may be no more than the one from
   which both movers, braking at ``shield * a_max``, stop ``margin`` short of contact (:func:`stop_speed`, counting
   the closing during the held step); each mover takes half of the change. This is what keeps a crowd collision
   free when the ORCA lines leave no room;
4. *walls*: every wall ray gives a half-plane too: no faster towards the wall than stopping before it allows (the
   same held-then-braked rule at ``a_brake``);
5. the new velocity is the one closest to the preferred one, within ``cruise``, that satisfies the half-planes
   (ORCA's incremental 2-D linear program, :func:`solve_lines`: a Warp kernel, a thread per mover running its
   O((k + rays)^2) steps), taken in order of urgency: walls, shield, then the neighbours nearest first; a line that
   leaves no room with the earlier ones is dropped (``greedy``, the default), so a crowd keeps the most urgent
   constraints and keeps moving instead of braking into a jam. ``greedy=False`` is the plain program with fallbacks
   (every line; else lines relaxed by ``relax`` x their slack; else shield and walls alone; else brake to
   ``brake_factor`` of the velocity); ``reachable`` solves within the velocities one step of ``a_max`` reaches.
   The command is the acceleration that reaches the new velocity within one env step, within ``a_max``.

6. *safety filter* (``safe=True``, the default; :mod:`magwarp.swarm.safety`): the velocity is replaced by the
   nearest one of a few candidates that keeps every mover's committed braking path apart from every other's by
   separating planes, and off the cells around it that hold no tile; braking always qualifies. This makes the
   planner provably collision-free (with movers, holes and edges, on any layout) whatever the steps above chose;
   they only steer. ``commit_brake``
   (x ``a_max``) is the committed braking, ``safe_margin`` (m) the extra distance kept;
7. *deadlock escape* (``patience`` steps, with the filter): a mover held still away from its goal for ``patience``
   steps wants to go to its right (every mover the same side, so head-on pairs pass) for ``patience`` steps,
   skipping steps 2-5 (which held it), the filter still applied.

Quality (``benchmarks/swarm.py`` planner rows, :class:`~magwarp.swarm.SwarmMetrics`): the share of movers that
reached their first goal (the one drawn at reset) within 40 s while the goals stream, the time by which 95% had
(t95), makespan, goals reached, collided movers per 1000 goals and deadlocked movers at the end.
"""

from __future__ import annotations

import math

import torch
import warp as wp

from magwarp._checks import warp_device
from magwarp.swarm.env import SwarmEnv
from magwarp.swarm.placement import on_torch_stream
from magwarp.swarm.observations import ray_directions
from magwarp._vectors import clip_norm
from magwarp.swarm.safety import (COMMIT_BRAKE, SAFE_K, SAFE_MARGIN, SAFE_SPEED, build_safety,
                                  collision_distances, vec2_array)
from magwarp.swarm.traffic import LaneField, lanes_fit

__all__ = ["SwarmPlanner", "TRAFFIC", "orca_lines", "solve_lines", "solve_lines_torch", "stop_speed"]

TRAFFIC = ("auto", "lanes", "free")
#: ``traffic="auto"`` takes the lanes on layouts without holes at least this many tiles a side (on smaller ones the
#: crowd does not pack and straight paths are shorter: 64 movers on 16 x 16 tiles reached fewer goals in 4 s on lanes)
AUTO_LANES_TILES = 32


def _det(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def orca_lines(rel_pos: torch.Tensor, rel_vel: torch.Tensor, radius: float | torch.Tensor, horizon: float,
               step: float) -> tuple[torch.Tensor, torch.Tensor]:
    """ORCA for relative positions ``p_j - p_i`` and relative velocities ``v_i - v_j`` (``[..., 2]``): the
    direction of each line and the full velocity change ``u`` that leaves the velocity obstacle (the caller takes
    its share of ``u``). Allowed velocities ``v`` satisfy ``det(direction, point - v) <= 0`` with
    ``point = v_i + share * u``."""
    dist_sq = (rel_pos * rel_pos).sum(-1)
    r_sq = radius * radius
    inv_h = 1.0 / horizon
    # no collision yet: the velocity obstacle truncated at the horizon
    w = rel_vel - inv_h * rel_pos
    w_sq = (w * w).sum(-1).clamp_min(1e-12)
    dot1 = (w * rel_pos).sum(-1)
    cutoff = (dot1 < 0) & (dot1 * dot1 > r_sq * w_sq)
    w_len = w_sq.sqrt()
    unit_w = w / w_len[..., None]
    dir_cut = torch.stack([unit_w[..., 1], -unit_w[..., 0]], -1)
    u_cut = (radius * inv_h - w_len)[..., None] * unit_w
    leg = (dist_sq - r_sq).clamp_min(0.0).sqrt()
    x, y = rel_pos[..., 0], rel_pos[..., 1]
    left = torch.stack([x * leg - y * radius, x * radius + y * leg], -1)
    right = -torch.stack([x * leg + y * radius, -x * radius + y * leg], -1)
    dir_leg = torch.where((_det(rel_pos, w) > 0)[..., None], left, right) / dist_sq.clamp_min(1e-12)[..., None]
    u_leg = (rel_vel * dir_leg).sum(-1, keepdim=True) * dir_leg - rel_vel
    direction = torch.where(cutoff[..., None], dir_cut, dir_leg)
    u = torch.where(cutoff[..., None], u_cut, u_leg)
    # already closer than the radius: leave within one step
    wc = rel_vel - rel_pos / step
    wc_len = wc.norm(dim=-1).clamp_min(1e-9)
    unit_c = wc / wc_len[..., None]
    inside = (dist_sq <= r_sq)[..., None]
    direction = torch.where(inside, torch.stack([unit_c[..., 1], -unit_c[..., 0]], -1), direction)
    u = torch.where(inside, (radius / step - wc_len)[..., None] * unit_c, u)
    return direction, u


def solve_lines(lines: list, v_pref: torch.Tensor, max_speed: float,
                skip: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """The velocity closest to ``v_pref`` within speed ``max_speed`` that satisfies every half-plane of ``lines``
    (``(point, direction, live)`` triples, each ``[..., 2]``, ``[..., 2]``, ``[...]``): ORCA's incremental 2-D linear
    program (constraints added one by one; when the new one is violated, the best point on its line that keeps the
    earlier ones). Where the lines have no common point, the last feasible velocity is kept and ``ok`` is false
    (``skip``: and that line is dropped for the later ones). float32 inputs: one Warp launch, a thread per mover
    (:func:`magwarp.kernels.orca.solve_lines`); else :func:`solve_lines_torch`, its reference."""
    if not lines or v_pref.dtype != torch.float32 or any(p.dtype != torch.float32 or d.dtype != torch.float32
                                                         for p, d, _ in lines):
        return solve_lines_torch(lines, v_pref, max_speed, skip)
    lead = v_pref.shape[:-1]
    shape = (*lead, 2)
    points = torch.stack([p.expand(shape) for p, _, _ in lines], -2).reshape(-1, len(lines), 2)
    directions = torch.stack([d.expand(shape) for _, d, _ in lines], -2).reshape(-1, len(lines), 2)
    live = torch.stack([lv.expand(lead).to(torch.bool) for _, _, lv in lines], -1).reshape(-1, len(lines))
    v, ok = _solve_rows(points, directions, live, v_pref.reshape(-1, 2), max_speed, skip)
    return v.reshape(shape), ok.reshape(lead)


def _solve_rows(points: torch.Tensor, directions: torch.Tensor, live: torch.Tensor, v_pref: torch.Tensor,
                max_speed: float, skip: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """One launch of :func:`magwarp.kernels.orca.solve_lines` over ``rows`` movers: ``points`` and ``directions``
    ``[rows, L, 2]``, ``live`` ``[rows, L]`` bool, ``v_pref`` ``[rows, 2]`` (float32, on one device); returns the
    velocities ``[rows, 2]`` and ``ok`` ``[rows]``."""
    from magwarp.kernels import orca

    rows, dev = points.shape[0], points.device
    v = torch.empty(rows, 2, device=dev)
    ok = torch.empty(rows, dtype=torch.bool, device=dev)
    wdev = warp_device(dev)
    with on_torch_stream(wdev):
        wp.launch(orca.solve_lines, dim=rows, device=wdev,
                  inputs=[float(max_speed), int(bool(skip)), vec2_array(points), vec2_array(directions),
                          wp.from_torch(live.contiguous()), vec2_array(v_pref), wp.from_torch(torch.empty_like(live))],
                  outputs=[vec2_array(v), wp.from_torch(ok)])
    return v, ok


def solve_lines_torch(lines: list, v_pref: torch.Tensor, max_speed: float,
                      skip: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`solve_lines` in torch ops (the kernel's reference; any float dtype): O(len(lines)^2) tensor operations,
    each over every mover at once."""
    v = clip_norm(v_pref, max_speed)
    ok = torch.ones(v.shape[:-1], dtype=torch.bool, device=v.device)
    lines = list(lines)
    for i, (p_i, d_i, live_i) in enumerate(lines):
        violated = live_i & (_det(d_i, p_i - v) > 0)
        # the part of line i inside the speed circle ...
        dot = (p_i * d_i).sum(-1)
        disc = dot * dot + max_speed * max_speed - (p_i * p_i).sum(-1)
        feasible = disc >= 0
        root = disc.clamp_min(0.0).sqrt()
        t_lo, t_hi = -dot - root, -dot + root
        # ... and inside the earlier half-planes
        for p_j, d_j, live_j in lines[:i]:
            den = _det(d_i, d_j)
            num = _det(d_j, p_i - p_j)
            parallel = den.abs() <= 1e-6
            feasible = feasible & ~(live_j & parallel & (num < 0))
            t = num / torch.where(parallel, torch.ones_like(den), den)
            cut = live_j & ~parallel
            t_hi = torch.where(cut & (den >= 0), torch.minimum(t_hi, t), t_hi)
            t_lo = torch.where(cut & (den < 0), torch.maximum(t_lo, t), t_lo)
        feasible = feasible & (t_lo <= t_hi)
        t = ((v_pref - p_i) * d_i).sum(-1)
        best = p_i + torch.minimum(torch.maximum(t, t_lo), t_hi)[..., None] * d_i
        take = violated & feasible
        v = torch.where(take[..., None], best, v)
        ok = ok & ~(violated & ~feasible)
        if skip:  # an infeasible line is dropped: the later lines need not keep it
            lines[i] = (p_i, d_i, live_i & ~(violated & ~feasible))
    return v, ok


def stop_speed(room: torch.Tensor, closing: torch.Tensor, decel: float, step: float) -> torch.Tensor:
    """The fastest closing speed ``c`` at the end of a step from which the gap can still be closed no further than
    ``room`` (m): the speed changes linearly within the step, from ``closing`` to ``c``, then brakes at ``decel``:
    ``room - step (closing + c) / 2 - c^2 / (2 decel) >= 0``. Where ``room`` is already spent (< 0) the result is
    the opening speed that gives it back within one step."""
    left = room - 0.5 * step * closing
    root = torch.sqrt((0.25 * step * step + 2.0 * left.clamp_min(0.0) / decel))
    return torch.where(left >= 0, decel * (root - 0.5 * step), 2.0 * left / step)


class SwarmPlanner:
    """``action = SwarmPlanner(env)()``: x/y accelerations ``[num_envs, num_movers, 2]`` for a :class:`SwarmEnv`
    (acceleration control). See the module docstring for the rule and its parameters (``orca=False``: no steps
    2-5, the preferred velocity goes straight to the safety filter). With ``safe=True`` the filter finds its own
    ``safe_k`` nearest movers within ``safety.reach_radius`` (0.65 m at the default cruise of 1.5 m/s).
    Defaults with ``safe=True``: ``cruise=1.5``, ``buffer=0.02``, ``shield=0`` (the filter keeps the movers apart);
    with ``safe=False``: ``cruise=1.0``, ``buffer=0.06``, ``shield=0.4``. ``kernels`` (default True): the half-planes
    (greedy), the linear program and the safety filter run as Warp kernels, a thread per mover
    (:mod:`magwarp.kernels.orca`, :mod:`magwarp.kernels.safety`); False: their torch forms (the kernels' references;
    the same rule, slower)."""

    def __init__(self, env: SwarmEnv, *, cruise: float | None = None, a_brake: float = 4.0, horizon: float = 2.0,
                 buffer: float | None = None, yield_share: float = 0.5, shield: float | None = None,
                 margin: float = 0.005, greedy: bool = True, brake_factor: float = 0.5, separate: float = 0.3,
                 relax: float = 0.0, reachable: bool = False, orca: bool = True, safe: bool = True, patience: int = 5,
                 commit_brake: float = COMMIT_BRAKE, safe_margin: float = SAFE_MARGIN, safe_k: int = SAFE_K,
                 traffic: str = "auto", lane_pitch: int = 4, kernels: bool = True):
        # defaults by mode: with the safety filter the steering may be bolder (measured on 64 movers at 25%, 2 seeds,
        # before the filter's slack sharing: 68 / 81 goals in 4 s against 45 / 64 with the unfiltered planner's
        # settings, none colliding)
        cruise = (SAFE_SPEED if safe else 1.0) if cruise is None else cruise
        buffer = (0.02 if safe else 0.06) if buffer is None else buffer
        shield = (0.0 if safe else 0.4) if shield is None else shield
        if env.learn_jerk:
            raise ValueError("SwarmPlanner commands accelerations: build the env with learn_jerk=False")
        for name, value in (("cruise", cruise), ("a_brake", a_brake), ("horizon", horizon)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")
        for name, value, hi in (("yield_share", yield_share, 1.0), ("brake_factor", brake_factor, 1.0),
                                ("shield", shield, 1.0)):
            if not 0.0 <= value <= hi:
                raise ValueError(f"{name} must be in [0, {hi}], got {value!r}")
        for name, value in (("relax", relax), ("margin", margin), ("buffer", buffer)):
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a number >= 0, got {value!r}")
        self.env = env
        self.orca = bool(orca)
        self.cruise, self.a_brake, self.horizon = float(cruise), float(a_brake), float(horizon)
        self.yield_share, self.brake_factor = float(yield_share), float(brake_factor)
        self.shield, self.margin, self.greedy = float(shield), float(margin), bool(greedy)
        self.relax, self.reachable = float(relax), bool(reachable)
        self.kernels = bool(kernels)
        self._line_params = None  # the line kernel's constants, made on first use
        sim = env.sim
        # the simulator's collision distance, and how close a centre may come to a wall (goals may lie this close to
        # a wall: no buffer)
        self.contact, self.wall_reach = collision_distances(sim)
        self.safe = self.contact + float(buffer)
        self.a_max = float(env.config.a_max)
        self.step_time = env.num_cycles * float(sim.model.limits.dt)
        self.separate = max(float(separate), self.step_time)
        dev = env.device
        self.safety = None
        if safe:
            # the filter and its own neighbour search: the safe_k nearest within the reach radius (the env's shield
            # builds the same, :func:`~magwarp.swarm.safety.build_safety`)
            self.safety, self.near = build_safety(env, v_cap=self.cruise, commit_brake=commit_brake,
                                                  margin=safe_margin, k=safe_k)
            self.safety.kernel = self.kernels
        self.rays = torch.as_tensor(ray_directions(max(env.local.num_rays, 1)), dtype=torch.float32, device=dev)
        self.index = torch.arange(env.num_movers, device=dev).view(1, -1, 1)
        if isinstance(patience, bool) or not isinstance(patience, int) or patience < 0:
            raise ValueError(f"patience must be an integer >= 0 (steps), got {patience!r}")
        self.patience = patience
        self.stuck = torch.zeros(env.num_envs, env.num_movers, dtype=torch.int32, device=dev)
        if traffic not in TRAFFIC:
            raise ValueError(f"traffic must be one of {TRAFFIC}, got {traffic!r}")
        if traffic == "auto":
            fits = lanes_fit(env.layout, lane_pitch) and min(env.layout.shape) >= AUTO_LANES_TILES
            traffic = "lanes" if fits else "free"
        #: the traffic rule in use ("lanes": :class:`~magwarp.swarm.traffic.LaneField`; "free": straight at the goal)
        self.traffic = traffic
        self.lanes = LaneField(env.layout, self.cruise, pitch=lane_pitch, a_brake=self.a_brake) \
            if traffic == "lanes" else None

    def reset(self, mask: torch.Tensor | None = None) -> None:
        """Forget the deadlock counter (the planner's only state between calls) of the worlds in ``mask`` (bool
        ``[num_envs]``), of the movers in ``mask`` (bool ``[num_envs, num_movers]``), or of every mover (None): what
        a fresh planner has, for worlds or movers that start anew (a reset, a respawn). In place, no host sync."""
        if mask is None:
            self.stuck.zero_()
            return
        shape = tuple(self.stuck.shape)
        if mask.dtype != torch.bool or tuple(mask.shape) not in (shape, shape[:1]):
            raise ValueError(f"mask must be a bool tensor of shape {shape[:1]} (worlds) or {shape} (movers), got "
                             f"{mask.dtype} {tuple(mask.shape)}")
        self.stuck.masked_fill_(mask if mask.dim() == 2 else mask[:, None], 0)

    def _neighbour_lines(self, vel: torch.Tensor) -> tuple[list, list, list]:
        """ORCA lines, their slack (for ``relax``) and the braking-shield lines of the ``k`` neighbours."""
        local, T = self.env.local, self.step_time
        # the command is held for the step and the velocity changes linearly within it: from the middle of the
        # step on, the mover travels at its new velocity as if it had started there
        rel_pos = local.rel_pos + (0.5 * T) * local.rel_vel
        gap = rel_pos.norm(dim=-1)
        # pairs already inside the safe distance use (almost) their gap as the radius, down to ``margin`` above
        # contact (below it they separate, within ``separate`` s): they may not close it further
        floor = self.contact + 2.0 * self.margin
        radius = torch.minimum(torch.full_like(gap, self.safe), (0.98 * gap).clamp_min(floor))
        direction, u = orca_lines(rel_pos, -local.rel_vel, radius, self.horizon, self.separate)
        share = torch.where(local.index < self.index, self.yield_share, 1.0 - self.yield_share)
        point = vel[..., None, :] + share[..., None] * u
        k, mask = local.k, local.mask
        lines = [(point[..., s, :], direction[..., s, :], mask[..., s]) for s in range(k)]
        slack = [(gap[..., s] - floor).clamp_min(0.0) for s in range(k)]
        shield = []
        if self.shield > 0:
            # braking shield: after this step the pair can still stop ``margin`` short of contact, both braking at
            # ``shield * a_max``; each mover takes half of the change: v_i . n <= v_i0 . n + (c_max - c0) / 2
            d0 = local.rel_pos.norm(dim=-1).clamp_min(1e-6)
            nrm = local.rel_pos / d0[..., None]
            c0 = -(local.rel_vel * nrm).sum(-1)
            c_max = stop_speed(d0 - self.contact - self.margin, c0, 2.0 * self.shield * self.a_max, T)
            lim = (vel[..., None, :] * nrm).sum(-1) + 0.5 * (c_max - c0)
            sdir = torch.stack([-nrm[..., 1], nrm[..., 0]], -1)  # det(sdir, lim n - v) <= 0 <=> v . n <= lim
            spoint = lim[..., None] * nrm
            shield = [(spoint[..., s, :], sdir[..., s, :], mask[..., s]) for s in range(k)]
        return lines, slack, shield

    def _wall_lines(self, vel: torch.Tensor) -> tuple[list, list]:
        """One line per wall ray: ``v . ray <= c`` with ``c`` the fastest approach that can still stop before the
        wall (the speed changing linearly within the step, then braking at ``a_brake``)."""
        local = self.env.local
        room = (local.walls - self.wall_reach).clamp_min(0.0)
        approach = (vel[..., None, :] * self.rays[: local.num_rays]).sum(-1)
        limit = stop_speed(room, approach, self.a_brake, self.step_time).clamp_min(0.0)
        live = torch.ones_like(room[..., 0], dtype=torch.bool)
        lines, slack = [], []
        for r in range(local.num_rays):
            ray = self.rays[r]
            normal_dir = torch.stack([-ray[1], ray[0]]).expand_as(vel)  # det(dir, point - v) <= 0 <=> v.ray <= lim
            lines.append((limit[..., r, None] * ray, normal_dir, live))
            slack.append(room[..., r])
        return lines, slack

    def _greedy_kernels(self, vel: torch.Tensor, v_pref: torch.Tensor) -> torch.Tensor:
        """Steps 2 and 3 (greedy) as two Warp launches: :func:`magwarp.kernels.orca.build_lines` writes every mover's
        wall, shield and ORCA lines (:meth:`_wall_lines`, :meth:`_neighbour_lines`), :func:`~magwarp.kernels.orca.
        solve_lines` solves them; the torch path's numbers but for rounding."""
        from magwarp.kernels import orca as korca

        local, dev = self.env.local, vel.device
        lead = vel.shape[:-1]
        rows, k, R = vel[..., 0].numel(), local.k, local.num_rays
        L = R + (k if self.shield > 0 else 0) + k
        if self._line_params is None:
            p = korca.LineParams()
            p.step, p.horizon, p.separate, p.safe = self.step_time, self.horizon, self.separate, self.safe
            p.contact, p.margin, p.yield_share, p.shield = self.contact, self.margin, self.yield_share, self.shield
            p.a_max, p.a_brake, p.wall_reach = self.a_max, self.a_brake, self.wall_reach
            self._line_params = (p, vec2_array(self.rays[:R]), warp_device(dev))
        p, rays, wdev = self._line_params
        points = torch.empty(rows, L, 2, device=dev)
        directions = torch.empty(rows, L, 2, device=dev)
        live = torch.empty(rows, L, dtype=torch.bool, device=dev)
        with on_torch_stream(wdev):
            wp.launch(korca.build_lines, dim=rows, device=wdev,
                      inputs=[p, rays, self.env.num_movers, vec2_array(vel, rows),
                              vec2_array(local.rel_pos, rows, k), vec2_array(local.rel_vel, rows, k),
                              wp.from_torch(local.mask.reshape(rows, k).contiguous()),
                              wp.from_torch(local.index.reshape(rows, k).contiguous()),
                              wp.from_torch(local.walls.reshape(rows, R).contiguous())],
                      outputs=[vec2_array(points), vec2_array(directions), wp.from_torch(live)])
        v, _ = _solve_rows(points, directions, live, v_pref.reshape(rows, 2), self.cruise, True)
        return v.reshape(*lead, 2)

    def _solve(self, lines: list, v_pref: torch.Tensor, vel: torch.Tensor, skip: bool = False):
        solve = solve_lines if self.kernels else solve_lines_torch
        if self.reachable:  # among the velocities reachable within one step (a disc around the velocity)
            dv, ok = solve([(p - vel, d, live) for p, d, live in lines], v_pref - vel, self.a_max * self.step_time,
                           skip=skip)
            return vel + dv, ok
        return solve(lines, v_pref, self.cruise, skip=skip)

    def __call__(self, obs=None) -> torch.Tensor:
        env, sim = self.env, self.env.sim
        pos, vel = sim.pos[..., :2], sim.vel[..., :2]
        local = env.local
        # 1. preferred velocity: arrive at the goal
        err = env.goals - pos
        dist = err.norm(dim=-1, keepdim=True).clamp_min(1e-6)
        speed = torch.minimum(torch.full_like(dist, self.cruise), torch.sqrt(2.0 * self.a_brake * dist))
        v_pref = err / dist * speed
        if self.lanes is not None:  # traffic rules: along the one-way lanes
            v_pref = self.lanes(pos, env.goals)
        if self.safety is not None and self.patience > 0:
            # deadlock breaking: a mover held still away from its goal for ``patience`` steps steps aside to its
            # right (every mover the same side: two movers head-on pass each other) for ``patience`` steps
            slow = (vel.norm(dim=-1) < 0.05) & (dist[..., 0] > self.env.config.threshold_pos)
            # in place: the counter a recorded CUDA graph reads and updates (SwarmResidualEnv plans inside its step)
            stuck = torch.where(slow | (self.stuck >= self.patience), self.stuck + 1, 0)
            self.stuck.copy_(torch.where(stuck >= 2 * self.patience, 0, stuck))
            escape = (self.stuck >= self.patience)[..., None]
            right = torch.stack([v_pref[..., 1], -v_pref[..., 0]], -1)
        # 2. lines: walls, the braking shield, the neighbours' ORCA lines (nearest first)
        fused = self.orca and self.greedy and self.kernels and not self.reachable and local.k + local.num_rays > 0
        if not fused:
            orca, slack, shield = self._neighbour_lines(vel) if local.k > 0 else ([], [], [])
            walls, wall_slack = self._wall_lines(vel) if local.num_rays > 0 else ([], [])
        if self.orca is False:
            v = v_pref
        elif fused:  # steps 2 and 3 in two launches: every line built on the device, then the program
            v = self._greedy_kernels(vel, v_pref)
        elif self.greedy:
            # 3. a line that leaves no room with the earlier ones is dropped: the most urgent ones are kept
            v, _ = self._solve(walls + shield + orca, v_pref, vel, skip=True)
        else:
            # 3'. every line, else (``relax``) lines missed by up to ``relax`` x their slack, else the shield and
            # walls alone, else brake
            lines = shield + orca + walls
            slack = [torch.zeros_like(p[..., 0]) for p, _, _ in shield] + slack + wall_slack
            v, ok = self._solve(lines, v_pref, vel)
            if self.relax > 0:
                loose = [(p + (self.relax * sl)[..., None] * torch.stack([d[..., 1], -d[..., 0]], -1), d, live)
                         for (p, d, live), sl in zip(lines, slack)]
                v2, ok2 = self._solve(loose, v_pref, vel)
                v = torch.where((~ok & ok2)[..., None], v2, v)
                ok = ok | ok2
            if shield:
                v3, ok3 = self._solve(shield + walls, v_pref, vel)
                v = torch.where((~ok & ok3)[..., None], v3, v)
                ok = ok | ok3
            v = torch.where(ok[..., None], v, vel * self.brake_factor)
        if self.safety is not None:
            if self.patience > 0:  # escaping movers skip the avoidance rule (it held them still): the filter only
                v = torch.where(escape, right, v)
            # 3''. the safety filter: the safe velocity nearest to the chosen one (provably collision-free)
            near = self.near
            near.compute(sim.state.pos, sim.state.vel)
            v = self.safety(vel, v, near.rel_pos, near.rel_vel, near.mask, pos)
        # 4. the acceleration that reaches v within one env step, within the limit
        return clip_norm((v - vel) / self.step_time, self.a_max)
