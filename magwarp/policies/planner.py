"""A scripted, collision-aware goal-seeking planner for trajectory planning (a baseline, no learning).

Every env step each mover picks its next velocity from a small fixed set of candidates reachable within the held
step (the preferred change, braking, coasting and rings of velocity changes up to ``a_max`` times the step), scored
like a sampling-based reciprocal velocity obstacle: squared distance to a preferred velocity plus a penalty that
grows as the time to collision with another mover (each taking half the avoidance) falls below a horizon.

* Preferred velocity: toward the goal on a braking profile. On layouts with holes, toward the first waypoint of the
  shortest path through a visibility graph whose nodes sit just off the convex corners of the holes (on the centre
  line of one-tile passages); corner-to-corner distances are precomputed once. A mover lying across the straight way
  is passed tangentially, with it on the left (right-hand traffic: two movers meeting head-on pick consistent sides)
  unless that side is walled off.
* Hard safety (a "brake-safe" invariant): a candidate is allowed only if its plan -- the held step, then braking at
  ``a_max`` along a straight line, sampled every ~20 ms on the 1 ms cycle grid -- keeps the footprint off every edge
  of the tiles (an exact distance-to-edge field) and, against every other mover, off that mover's braking plan and
  off the plan chosen by any mover of higher priority. Movers choose in parallel (``rounds`` refinements); a mover
  whose choice still meets a higher-priority choice brakes. Braking is therefore always allowed and every pair of
  final plans is checked, so a world that starts at rest does not collide (up to the time sampling and the
  integration rounding, which ``buffer`` and ``wall_buffer`` cover). Boxes are checked as their circumscribed
  circles.
* Priority: movers nearer to their goal first; a mover stuck for long first of all.
* Deadlock breaking: a mover that made no progress toward its goal for ``stuck_steps`` steps may leave for a short
  escape (``escape_steps``) to a random free point away from the other movers.

Everything is batched torch on the env's device: no Python loop over worlds or movers (only fixed small loops over
choice rounds and the two coordinates). Written for acceleration control; with ``learn_jerk`` the chosen acceleration
is tracked by a jerk command (no safety guarantee then).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Protocol

import numpy as np
import torch
import torch.nn.functional as F

from magwarp._vectors import clip_norm

if TYPE_CHECKING:
    from magwarp.layout import Layout
    from magwarp.sim import Simulator


class PlannedEnv(Protocol):
    """What the planner reads of a batched trajectory-planning env (structurally: the planner imports no env module,
    so that envs -> policies stays one way; :class:`~magwarp.envs.trajectory.TrajectoryPlanningEnv` is one)."""

    sim: Simulator
    layout: Layout
    device: torch.device
    num_envs: int
    num_movers: int
    num_cycles: int
    learn_jerk: bool
    goals: torch.Tensor
    num_steps: torch.Tensor
    last_goal_step: torch.Tensor


class GoalSeekingPlanner:
    """``planner(obs) -> action`` for a :class:`~magwarp.envs.trajectory.TrajectoryPlanningEnv` (any
    :class:`PlannedEnv`; batched, torch in and out).

    Args:
        env: the batched env (the planner reads layout, limits, collision sizes and the exact state from it).
        cruise_speed: top planning speed (m/s); brake: deceleration (m/s^2) of the speed profile toward a goal.
        buffer: extra distance (m) kept between two movers' collision shapes, on top of the safety margin.
        horizon: time horizon (s) of the time-to-collision penalty; sidestep: its weight ((m/s)^2 at contact).
        leader_share: kept for compatibility (unused).
        wall_resolution: grid step (m) of the precomputed distance-to-edge field.
        arrive_speed: speed (m/s) the profile still allows ``slack`` (m) from the goal (a goal counts as reached
            anywhere within ``threshold_pos``, so there is no need to stop on it).
        rounds: parallel refinements of the choices per step.
        detour_margin: clearance (m) added to two collision shapes when passing a mover tangentially.
        ttc_margin: clearance (m) added to two collision shapes in the time-to-collision penalty.
        wall_buffer: extra distance (m) kept between a collision shape and the edges of the tiles.
        stuck_steps, escape_steps: deadlock breaking (see the module docstring); idle_steps: escape only in worlds
            where no goal was reached for this many steps.
        ring: number of velocity-change directions at full, half, quarter, ... change.
        seed: seed of the escape sampling.
    """

    def __init__(self, env: PlannedEnv, cruise_speed: float = 2.0, brake: float = 6.0,
                 buffer: float = 0.006, horizon: float = 0.3, sidestep: float = 2.0, leader_share: float = 0.35,
                 wall_resolution: float = 0.005, arrive_speed: float = 0.5, rounds: int = 1,
                 detour_margin: float = 0.03, ttc_margin: float = 0.01, wall_buffer: float = 0.003,
                 stuck_steps: int = 10, escape_steps: int = 5, idle_steps: int = 0, slack: float = 0.06,
                 ring: tuple[int, ...] = (12, 6, 6), seed: int = 0):
        self.env = env
        self.sim = env.sim
        self.device = env.device
        lim = self.sim.model.limits
        self.dt = float(lim.dt)
        self.T = env.num_cycles * self.dt  # the action is held for one env step
        self.a_max = float(lim.a_max)
        self.v_max = float(lim.v_max)
        self.j_max = float(lim.j_max)
        self.cruise = min(float(cruise_speed), self.v_max)
        self.brake = float(brake)
        self.buffer = float(buffer)
        self.wall_buffer = float(wall_buffer)
        self.horizon = float(horizon)
        self.w_ttc = float(sidestep)
        self.leader_share = leader_share
        self.arrive = float(arrive_speed)
        self.rounds = int(rounds)
        self.detour_margin = float(detour_margin)
        self.ttc_margin = float(ttc_margin)
        self.stuck_steps = int(stuck_steps)
        self.escape_steps = int(escape_steps)
        self.idle_steps = int(idle_steps)
        self.slack = float(slack)
        mover = self.sim.mover
        if mover.collision_shape == "circle":
            r = float(self.sim._radii_np.max())
            self.reach_m = r + mover.margin
            self.reach_w = r + mover.wall_margin
        else:  # boxes may turn: their circumscribed circle
            half = self.sim._half_np.max(axis=0)
            self.reach_m = float(np.linalg.norm(half + mover.margin))
            self.reach_w = float(np.linalg.norm(half + mover.wall_margin))
        self._build_times()
        self._build_candidates(ring)
        self._build_wall_field(wall_resolution)
        self._build_waypoints()
        n, m = env.num_envs, env.num_movers
        self._stuck = torch.zeros(n, m, device=self.device)
        self._best = torch.full((n, m), float("inf"), device=self.device)
        self._goal_prev = torch.zeros(n, m, 2, device=self.device)
        self._esc_target = torch.zeros(n, m, 2, device=self.device)
        self._esc_left = torch.zeros(n, m, dtype=torch.int64, device=self.device)
        self._gen = torch.Generator(device=self.device)
        self._gen.manual_seed(int(seed))

    # ------------------------------------------------------------------ precomputation
    def _build_times(self) -> None:
        """Sample times (s) of a plan: the held step, then braking until a stop from ``v_max`` (~20 ms apart)."""
        T, dt = self.T, self.dt
        n1 = max(1, math.ceil(T / 0.02 - 1e-9))
        t1 = [T * (k + 1) / n1 for k in range(n1)]
        steps_b = math.ceil(self.v_max / (self.a_max * T) - 1e-9) + 1
        tb = steps_b * T
        n2 = max(1, math.ceil(tb / 0.02 - 1e-9))
        t2 = [T + tb * (k + 1) / n2 for k in range(n2)]
        t = torch.tensor(t1 + t2, dtype=torch.float32, device=self.device)
        self.times = torch.round(t / dt) * dt  # on the cycle grid: the integration formulas below are exact there

    def _build_candidates(self, ring) -> None:
        """Velocity changes (fraction of ``a_max * T``) tried besides the preferred one and braking: coasting, then
        ``ring[k]`` evenly spread directions at 1, 1/2, 1/4, ... of the largest change (alternate rings turned)."""
        parts = [torch.zeros(1, 2)]
        for k, count in enumerate(ring):
            if count <= 0:
                continue
            ang = (torch.arange(count, dtype=torch.float32) + 0.5 * (k % 2)) * (2 * math.pi / count)
            parts.append(torch.stack([torch.cos(ang), torch.sin(ang)], dim=-1) * 0.5 ** k)
        self._dv = torch.cat(parts).to(self.device)  # (K0, 2)

    def _build_wall_field(self, res: float) -> None:
        """Exact distance (m) from grid points to the nearest point off the tiles (holes and outside), for sampling."""
        lay = self.env.layout
        ext = lay.extent
        ts = lay.tile.size
        pad = 4
        nx, ny = int(math.ceil(ext[0] / res)) + 2 * pad + 1, int(math.ceil(ext[1] / res)) + 2 * pad + 1
        xs = (np.arange(nx) - pad) * res
        ys = (np.arange(ny) - pad) * res
        X, Y = np.meshgrid(xs, ys, indexing="ij")
        d = np.minimum(np.minimum(X, Y), np.minimum(ext[0] - X, ext[1] - Y))  # to the outside (<0 outside)
        holes = np.argwhere(lay.tiles == 0)
        for i, j in holes:
            lo = np.array([i * ts, j * ts])
            dx = np.maximum(np.maximum(lo[0] - X, X - lo[0] - ts), 0.0)
            dy = np.maximum(np.maximum(lo[1] - Y, Y - lo[1] - ts), 0.0)
            d = np.minimum(d, np.hypot(dx, dy))
        self._field = torch.tensor(d, dtype=torch.float32, device=self.device)[None, None]
        self._f_lo = (xs[0], ys[0])
        self._f_span = (xs[-1] - xs[0], ys[-1] - ys[0])
        self._holes = holes

    def _wall_dist(self, xy: torch.Tensor) -> torch.Tensor:
        """Distance to the nearest off-tile point for points ``(..., 2)`` (bilinear in the field; border: clamped)."""
        shape = xy.shape[:-1]
        flat = xy.reshape(1, -1, 1, 2)
        gx = (flat[..., 0] - self._f_lo[0]) / self._f_span[0] * 2 - 1
        gy = (flat[..., 1] - self._f_lo[1]) / self._f_span[1] * 2 - 1
        grid = torch.stack([gy, gx], dim=-1)  # grid_sample: last dim (x) indexes W = our y
        out = F.grid_sample(self._field, grid, mode="bilinear", align_corners=True, padding_mode="border")
        return out.reshape(shape)

    def _build_waypoints(self) -> None:
        """Waypoints off the convex corners of the holes and their shortest corner-to-corner path lengths."""
        lay = self.env.layout
        self.has_holes = bool((lay.tiles == 0).any())
        self._wp = torch.zeros(0, 2, device=self.device)
        if not self.has_holes:
            return
        tiles = lay.tiles
        nx, ny = tiles.shape
        ts = lay.tile.size

        def present(i, j):
            return 0 <= i < nx and 0 <= j < ny and tiles[i, j] == 1

        clear = self.reach_w + self.wall_buffer + 0.01
        need = self.reach_w + self.wall_buffer + 0.002
        offs = np.linspace(clear, self.reach_w, 7)
        cx, cy = np.meshgrid(offs, offs, indexing="ij")
        order = np.argsort(-(cx + cy).ravel(), kind="stable")  # widest around the corner first
        cx, cy = cx.ravel()[order], cy.ravel()[order]
        pts = []
        for vi in range(nx + 1):
            for vj in range(ny + 1):
                for sx in (-1, 1):
                    for sy in (-1, 1):
                        # quadrant tiles around vertex (vi, vj): toward (sx, sy) present, the opposite one absent
                        qi, qj = vi + (0 if sx > 0 else -1), vj + (0 if sy > 0 else -1)
                        oi, oj = vi + (-1 if sx > 0 else 0), vj + (-1 if sy > 0 else 0)
                        ai, aj = vi + (0 if sx > 0 else -1), vj + (-1 if sy > 0 else 0)
                        bi, bj = vi + (-1 if sx > 0 else 0), vj + (0 if sy > 0 else -1)
                        if present(qi, qj) and not present(oi, oj) and present(ai, aj) and present(bi, bj):
                            pts.append(np.stack([vi * ts + sx * cx, vj * ts + sy * cy], axis=-1))
        if not pts:
            self.has_holes = False
            return
        # per corner: the offset nearest the corner that still leaves room (narrow passages: their centre line)
        opts = torch.tensor(np.stack(pts), dtype=torch.float32, device=self.device)  # (P, O, 2)
        fits = self._wall_dist(opts) >= need
        first = torch.where(fits, torch.arange(opts.shape[1], device=self.device), opts.shape[1]).amin(dim=1)
        keep = first < opts.shape[1]
        wp_ = opts[keep, first[keep].clamp(max=opts.shape[1] - 1)]
        if len(wp_) == 0:
            self.has_holes = False
            return
        self._wp = wp_
        c = len(wp_)
        vis = self._visible(wp_.view(c, 1, 2).expand(c, c, 2), wp_.view(1, c, 2).expand(c, c, 2))
        d = (wp_.view(c, 1, 2) - wp_.view(1, c, 2)).norm(dim=-1)
        d = torch.where(vis, d, torch.full_like(d, float("inf"))).cpu().numpy().astype(np.float64)
        np.fill_diagonal(d, 0.0)
        for k in range(c):  # Floyd-Warshall, once
            d = np.minimum(d, d[:, k:k + 1] + d[k:k + 1, :])
        self._wp_dist = torch.tensor(d, dtype=torch.float32, device=self.device)

    def _visible(self, a: torch.Tensor, b: torch.Tensor, samples: int = 24) -> torch.Tensor:
        """Whether the straight segment a -> b keeps the footprint off the walls (sampled), for ``(..., 2)``."""
        s = torch.linspace(0.0, 1.0, samples, device=self.device).view(*([1] * (a.dim() - 1)), samples, 1)
        pts = a.unsqueeze(-2) + (b - a).unsqueeze(-2) * s
        return (self._wall_dist(pts) >= self.reach_w + 0.5 * self.wall_buffer).all(dim=-1)

    # ------------------------------------------------------------------ per step
    def _preferred(self, pos: torch.Tensor, goal: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Preferred velocity (N, M, 2) and remaining path length (N, M)."""
        to_goal = goal - pos
        direct = to_goal.norm(dim=-1)
        target, length = goal, direct
        if self.has_holes:
            wp_, c = self._wp, len(self._wp)
            n, m, _ = pos.shape
            inf = torch.tensor(float("inf"), device=self.device)
            see_goal = self._visible(pos, goal)
            P = pos.unsqueeze(2).expand(n, m, c, 2)
            G = goal.unsqueeze(2).expand(n, m, c, 2)
            W = wp_.view(1, 1, c, 2).expand(n, m, c, 2)
            from_pos = torch.where(self._visible(P, W), (W - P).norm(dim=-1), inf)  # (N, M, C)
            to_goal_c = torch.where(self._visible(W, G), (G - W).norm(dim=-1), inf)
            # length via first waypoint c1 and last waypoint c2: |p - c1| + D[c1, c2] + |c2 - g|
            via = (self._wp_dist.view(1, 1, c, c) + to_goal_c.unsqueeze(2)).amin(dim=-1)  # from c1 to goal
            total = from_pos + via
            best, first = total.min(dim=-1)
            use_wp = ~see_goal & torch.isfinite(best)
            target = torch.where(use_wp.unsqueeze(-1), wp_[first], goal)
            length = torch.where(use_wp, best, direct)
        d = target - pos
        dn = d.norm(dim=-1, keepdim=True).clamp_min(1e-6)
        e = self._detour(pos, d / dn, dn.squeeze(-1))
        rest = (length - self.slack).clamp_min(0.0)
        speed = torch.sqrt(self.arrive ** 2 + 2 * self.brake * rest).clamp(max=self.cruise).unsqueeze(-1)
        speed = torch.minimum(speed, length.unsqueeze(-1) / self.T)  # no overshoot of the goal in one step
        return e * speed, length

    def _detour(self, pos, e, dist):
        """Heading (N, M, 2) that passes the nearest mover lying across the straight way to the target tangentially:
        with it on the left (right-hand traffic, so two movers meeting head-on pick consistent sides) unless it
        lies to the right of the way or that side is walled off."""
        n, m, _ = pos.shape
        q = pos.unsqueeze(1) - pos.unsqueeze(2)  # (N, i, j, 2) = p_j - p_i
        left = torch.stack([-e[..., 1], e[..., 0]], dim=-1)
        along = (q * e.unsqueeze(2)).sum(-1)
        perp = (q * left.unsqueeze(2)).sum(-1)
        rc = 2 * self.reach_m + self.detour_margin
        eye = torch.eye(m, dtype=torch.bool, device=pos.device)
        block = (along > 0) & (along < dist.unsqueeze(-1)) & (perp.abs() < rc) & ~eye
        key = torch.where(block, along, torch.full_like(along, float("inf")))
        jn = key.argmin(dim=-1, keepdim=True)  # nearest blocker
        any_block = block.any(-1)
        qj = q.gather(2, jn.unsqueeze(-1).expand(n, m, 1, 2)).squeeze(2)
        pj = pos + qj
        pp = perp.gather(2, jn).squeeze(-1)
        # side: +1 passes with the blocker on our right (we go left), -1 with it on our left (we go right)
        side = torch.where(pp < -0.02, torch.ones_like(pp), -torch.ones_like(pp))
        need = self.reach_w + self.wall_buffer
        ok_side = self._wall_dist(pj + left * (side * rc).unsqueeze(-1)) >= need
        ok_other = self._wall_dist(pj - left * (side * rc).unsqueeze(-1)) >= need
        side = torch.where(ok_side | ~ok_other, side, -side)
        use = any_block & (ok_side | ok_other)
        qn = qj.norm(dim=-1).clamp_min(1e-6)
        th = torch.asin((rc / qn).clamp(max=1.0)) * side
        qh = qj / qn.unsqueeze(-1)
        c, s_ = torch.cos(th).unsqueeze(-1), torch.sin(th).unsqueeze(-1)
        rot = torch.cat([qh[..., :1] * c - qh[..., 1:] * s_, qh[..., :1] * s_ + qh[..., 1:] * c], dim=-1)
        return torch.where(use.unsqueeze(-1), rot, e)

    def _trajectories(self, pos, vel, cand):
        """Plan positions at ``self.times``, x and y apart, each (N, M, K, S): reach velocity ``cand`` (N, M, K, 2)
        over the held step, then brake at ``a_max`` along a straight line (the braking candidate's own rule)."""
        T, dt, ab = self.T, self.dt, self.a_max
        tt = self.times.view(1, 1, 1, -1)
        tin = tt.clamp(max=T)
        q_in = 0.5 * tin * (tin + dt) / T  # semi-implicit Euler, exact on the cycle grid
        q_1 = 0.5 * (T + dt)
        s1 = cand.norm(dim=-1, keepdim=True)  # (N, M, K, 1)
        nfull = torch.floor(s1 / (ab * T) + 1e-6)
        tk = nfull * T
        sk = (s1 - ab * tk).clamp_min(0.0)
        tau = (tt - T).clamp_min(0.0)
        t_a = torch.minimum(tau, tk)
        t_b = (tau - tk).clamp(0.0, T)
        d = s1 * t_a - 0.5 * ab * t_a * (t_a + dt) + sk * t_b - 0.5 * (sk / T) * t_b * (t_b + dt)  # (N, M, K, S)
        d_over_s = d / s1.clamp_min(1e-9)
        inside = tt <= T
        out = []
        for c in range(2):
            p0 = pos[..., c].unsqueeze(-1).unsqueeze(-1)
            v0 = vel[..., c].unsqueeze(-1).unsqueeze(-1)
            v1 = cand[..., c].unsqueeze(-1)
            p_in = p0 + v0 * tin + (v1 - v0) * q_in
            p_out = p0 + v0 * T + (v1 - v0) * q_1 + v1 * d_over_s
            out.append(torch.where(inside, p_in, p_out))
        return out

    def _ttc_penalty(self, pos, vel, cand):
        """Time-to-collision penalty (N, M, K) of candidate velocities against every other mover (reciprocal)."""
        n, m, k, _ = cand.shape
        rel_p = pos.unsqueeze(2) - pos.unsqueeze(1)  # (N, i, j, 2): p_j - p_i negated below
        rel_p = -rel_p  # p_j - p_i
        # reciprocal: i takes half the avoidance, so test 2 v' - v_i against v_j
        vr = 2 * cand.unsqueeze(3) - vel.unsqueeze(2).unsqueeze(2) - vel.unsqueeze(1).unsqueeze(2)  # (N,i,K,j,2)
        p = rel_p.unsqueeze(2)  # (N,i,1,j,2)
        R = 2 * self.reach_m + self.ttc_margin
        b = (p * vr).sum(-1)
        vv = (vr * vr).sum(-1).clamp_min(1e-9)
        pp = (p * p).sum(-1)
        disc = b * b - vv * (pp - R * R)
        ttc = (b - torch.sqrt(disc.clamp_min(0.0))) / vv
        hit = (disc > 0) & (b > 0)
        inside = pp < R * R
        ttc = torch.where(inside, torch.zeros_like(ttc), ttc)
        hit = hit | (inside & (b > 0))
        pen = torch.where(hit & (ttc < self.horizon), (self.horizon - ttc) / self.horizon, torch.zeros_like(ttc))
        eye = torch.eye(m, dtype=torch.bool, device=self.device).view(1, m, 1, m)
        pen = pen.masked_fill(eye, 0.0)
        return pen.sum(-1)

    @staticmethod
    def _pair_clearance(tx, ty, ox, oy):
        """min over time of squared centre distance (N, i, K, j): candidate plans (N, i, K, S) of i (x and y apart)
        vs one plan (N, j, S) of each j."""
        dx = tx.unsqueeze(3) - ox.unsqueeze(1).unsqueeze(1)  # (N, i, K, j, S)
        dy = ty.unsqueeze(3) - oy.unsqueeze(1).unsqueeze(1)
        return torch.addcmul(dx * dx, dy, dy).amin(-1)

    def _bookkeeping(self, pos, goal, length, esc) -> None:
        """Count steps without progress toward the goal; a mover stuck for ``stuck_steps`` may leave for a short
        escape to a random free point (deadlock breaking), and one stuck for long gets priority."""
        new_goal = (goal - self._goal_prev).abs().sum(-1) > 0  # reached, or the world was reset
        self._goal_prev = goal.clone()
        inf = torch.full_like(self._best, float("inf"))
        best = torch.where(new_goal | esc, inf, self._best)
        better = length < best - 0.01
        self._best = torch.where(esc, inf, torch.where(better, length, best))
        stuck = torch.where(better | new_goal | esc, torch.zeros_like(self._stuck), self._stuck + 1)
        arrived = (pos - self._esc_target).norm(dim=-1) < 0.03
        left = torch.where(esc & ~arrived & ~new_goal, self._esc_left - 1, torch.zeros_like(self._esc_left))
        coin = torch.rand(stuck.shape, generator=self._gen, device=self.device) < 0.5
        idle = (self.env.num_steps - self.env.last_goal_step).unsqueeze(-1) >= self.idle_steps  # world: no goal lately
        trigger = (left <= 0) & ~esc & (stuck >= self.stuck_steps) & coin & idle
        n, m, _ = pos.shape
        k = 8
        ang = torch.rand(n, m, k, generator=self._gen, device=self.device) * (2 * math.pi)
        rad = 0.15 + 0.2 * torch.rand(n, m, k, generator=self._gen, device=self.device)
        pts = pos.unsqueeze(2) + rad.unsqueeze(-1) * torch.stack([torch.cos(ang), torch.sin(ang)], dim=-1)
        free = self._wall_dist(pts) >= self.reach_w + self.wall_buffer + 0.01
        if self.has_holes:
            free = free & self._visible(pos.unsqueeze(2).expand_as(pts), pts)
        others = (pts.unsqueeze(3) - pos.unsqueeze(1).unsqueeze(1)).norm(dim=-1)  # (N, i, K, j)
        eye = torch.eye(m, dtype=torch.bool, device=self.device).view(1, m, 1, m)
        room = others.masked_fill(eye, float("inf")).amin(-1)
        room = torch.where(free, room, torch.full_like(room, -1.0))
        score, pick = room.max(dim=-1)
        trigger = trigger & (score > 0)
        target = pts.gather(2, pick.view(n, m, 1, 1).expand(n, m, 1, 2)).squeeze(2)
        self._esc_target = torch.where(trigger.unsqueeze(-1), target, self._esc_target)
        self._esc_left = torch.where(trigger, torch.full_like(left, self.escape_steps), left)
        self._stuck = torch.where(trigger, torch.zeros_like(stuck), stuck)

    def __call__(self, obs=None) -> torch.Tensor:
        sim, env = self.sim, self.env
        pos = sim.pos[..., :2]
        vel = sim.vel[..., :2]
        vel = torch.where(vel.abs() < 1e-12, torch.zeros_like(vel), vel)  # denormals (braked to rest) are slow
        n, m, _ = pos.shape
        dev = pos.device
        T = self.T
        goal = env.goals

        esc = self._esc_left > 0
        v_pref, length = self._preferred(pos, torch.where(esc.unsqueeze(-1), self._esc_target, goal))

        # Candidates: preferred, brake, coast and a fixed ring of velocity changes.
        dvm = self.a_max * T
        ideal = v_pref - vel
        ideal = ideal * (dvm / ideal.norm(dim=-1, keepdim=True).clamp_min(dvm))
        brake = -vel * (dvm / vel.norm(dim=-1, keepdim=True).clamp_min(dvm))
        dv = torch.cat([brake.unsqueeze(2), ideal.unsqueeze(2), (self._dv * dvm).view(1, 1, -1, 2).expand(n, m, -1, 2)],
                       dim=2)
        cand = vel.unsqueeze(2) + dv
        cand = clip_norm(cand, self.v_max * 0.999)

        tx, ty = self._trajectories(pos, vel, cand)  # (N, M, K, S) each
        S = tx.shape[-1]
        wall_ok = self._wall_dist(torch.stack([tx, ty], dim=-1)).amin(-1) >= self.reach_w + self.wall_buffer  # (N, M, K)
        rr = (2 * self.reach_m + self.buffer) ** 2
        eye = torch.eye(m, dtype=torch.bool, device=dev).view(1, m, 1, m)
        vs_brake = (self._pair_clearance(tx, ty, tx[:, :, 0], ty[:, :, 0]) >= rr) | eye  # (N, i, K, j)
        base_ok = wall_ok & vs_brake.all(-1)

        cost = ((cand - v_pref.unsqueeze(2)) ** 2).sum(-1) + self.w_ttc * self._ttc_penalty(pos, vel, cand)

        # Priority: nearer to the goal first; long-stuck movers first of all.
        score = length - 10.0 * (self._stuck > 25).float()
        rank = score.argsort(dim=1).argsort(dim=1)  # 0 = highest priority
        lower = (rank.unsqueeze(1) < rank.unsqueeze(2)).view(n, m, 1, m) & ~eye  # [i, j]: j has priority over i
        free = ~lower

        big = torch.tensor(1e9, device=dev)

        def pick(ok):
            ch = torch.where(ok, cost, cost + big).argmin(dim=2)  # (N, M)
            idx = ch.view(n, m, 1, 1).expand(n, m, 1, S)
            return ch, tx.gather(2, idx).squeeze(2), ty.gather(2, idx).squeeze(2)

        choice, cx, cy = pick(base_ok)
        for _ in range(self.rounds):
            ok = base_ok & ((self._pair_clearance(tx, ty, cx, cy) >= rr) | free).all(-1)
            choice, cx, cy = pick(ok)
        # Final fix: a choice that meets a higher-priority final choice becomes braking (always allowed).
        final_ok = ((self._pair_clearance(cx.unsqueeze(2), cy.unsqueeze(2), cx, cy) >= rr) | free).all(-1).squeeze(2)
        choice = torch.where(final_ok, choice, torch.zeros_like(choice))
        v_new = cand.gather(2, choice.view(n, m, 1, 1).expand(n, m, 1, 2)).squeeze(2)

        self._bookkeeping(pos, goal, length, esc)
        acc = (v_new - vel) / T
        acc = clip_norm(acc, self.a_max)
        if env.learn_jerk:
            jerk = (acc - sim.acc[..., :2]) / self.T  # the acceleration reaches the choice by the step end
            acc = clip_norm(jerk, self.j_max)
        return acc.reshape(env.num_envs, -1)
