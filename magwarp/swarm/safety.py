"""A provably collision-free safety filter for swarms of acceleration-commanded movers (the last stage of
:class:`~magwarp.swarm.SwarmPlanner`): committed braking paths kept apart by separating planes.

Why the planner collided before (``benchmarks/swarm.py`` on an H100: 205 / 1,015 / 1,122 collided movers per 1000
goals at 256 / 1024 / 4096 movers). Measured on the CPU at 256 movers (32 x 32 tiles, 120 steps, ``safe=False``):
15 mover and 3 wall collisions; 12 of the 15 movers had their command saturated at ``a_max`` (the program's velocity
was out of one step's reach, so the clipped command broke every promise made for it); no colliding partner was
missing from the neighbour lists (the search radius was not the cause); half of the pairs closed faster than 0.5
m/s, the others grazed (the braking shield only bounded the closing speed along the *current* centre line, which
turns within a step for movers sliding past each other, and assumed both brake head-on at ``shield * a_max``). The
greedy program also dropped shield lines it could not meet together with the walls and the earlier lines (three or
more movers around one), and the wall rays saw no hole corners between them. Above all nothing carried a promise
from one step to the next: a crowd could reach states from which no command avoided contact. This filter keeps one
invariant instead, and every command it gives is within one step's reach.

**The invariant.** Every mover has a *committed path*: if it brakes from now on (each 40 ms step an acceleration of
``a_brake`` against its velocity, held; the last step exactly to rest) it stays on the segment ``S = [p, p + v^
D(|v|)]`` with ``D(s) = s^2 / (2 a_brake) + s T / 2`` (``T``: the step). Invariant: the committed paths of every
pair of movers are at least ``contact + margin`` apart (``contact``: the simulator's collision distance).

**The step rule.** For a pair ``(i, j)`` the closest points ``q_i``, ``q_j`` of their segments give a separating
direction ``n`` (from ``q_i`` to ``q_j``) and a gap ``g``; each mover keeps its whole *new* committed path (the held
step, then braking from the new velocity ``v1``) within its share ``w_i (g - contact - margin)`` beyond its own
closest point along ``n``:

    (p - q_i).n + T/2 max(v0.n, 0) + max(v1.n, 0) (T + dt/2 + |v1| / (2 a_brake)) <= w_i (g - contact - margin)

with ``w_i = (max(v0_i.n, 0) + f) / (max(v0_i.n, 0) + max(-v0_j.n, 0) + 2 f)`` (``f`` = 0.2 m/s): the pair's slack
split by how fast each mover heads into it now, which both compute alike (``w_i + w_j = 1``), so that a follower
may close up on a leader moving away (at 1024 movers, 12 s: 502 goals against 405 with equal halves). A share is
never below ``w_min = f / (v + 2 f)`` (``v``: the speed cap)

(the left side bounds the held step's projection for the simulator's semi-implicit cycles of ``dt``, and the braking
segment's; a right side below 0 counts as 0: a pair placed closer than ``contact + margin`` may part, not close).
The two movers decide alone, and their new paths stay on their own sides of the same plane: the pair stays
``contact + margin`` apart at every instant, and the new committed paths (the tails of the new paths) keep the
invariant. *Recursive feasibility*: braking (``v1 = v0 - a_brake T v0^``, or rest) satisfies every such constraint
(its new path lies inside the old segment, which lies behind ``q_i``), so a safe velocity always exists. Walls: every
cell off the tiles (a hole, or beyond the layout's edge) near the mover is a square obstacle; the closest points of
the committed segment and the square give the same kind of constraint, with the whole gap less ``wall_reach`` for
the mover (the square does not move): no path comes within ``wall_reach`` of a hole or an edge, on any layout.

**Neighbours.** Paths are at most ``L = (T + dt/2) v + D(v)`` long, so movers farther apart than ``R = contact +
margin + 2 L`` (``v``: the speed cap) cannot meet within a step; the local view must see at least that far
(the planner searches that far). A mover whose ``k`` neighbour slots are all taken, the farthest at ``d_k <= R``,
may miss a mover ``j`` (at ``d >= d_k``): its new path then keeps within ``w_min (d_k - D(|v0|) - D(v) - contact -
margin)`` of it, which lies inside its share towards any such ``j`` (whether ``j`` sees it and keeps to its own
share, or misses it too and keeps to its own ball). Braking stays allowed (its path lies in the old segment).

**The choice.** Among candidates ``v_b + a (w - v_b)`` (``v_b``: braking; ``w``: the wanted velocity and turns of it
by +-45 and +-90 degrees, within one step's reach; ``a`` in 1, 3/4, 1/2, 1/4) and ``v_b`` itself, the safe one
closest to the wanted velocity. One Warp kernel, a thread per mover (:mod:`magwarp.kernels.safety`; the torch
form, :meth:`SafetyFilter.choose_torch`: O(k) tensor operations per mover), no host synchronisation.
"""

from __future__ import annotations

import math

import numpy as np
import torch
import warp as wp

from magwarp._checks import warp_device
from magwarp.kernels.safety import TOUCH_GAP
from magwarp.swarm.placement import on_torch_stream

__all__ = ["SafetyFilter", "build_safety", "collision_distances", "segment_closest_points", "stop_length",
           "SAFE_SPEED", "COMMIT_BRAKE", "SAFE_MARGIN", "SAFE_K"]

#: the defaults of the planner's filter (:class:`~magwarp.swarm.SwarmPlanner` with ``safe=True``: its ``cruise``,
#: ``commit_brake``, ``safe_margin``, ``safe_k``), which the env's shield (``SwarmConfig.shield``) uses too: the speed
#: cap ``v_cap`` (m/s), the committed braking (x ``a_max``), the extra distance kept (m), the neighbour slots
SAFE_SPEED = 1.5
COMMIT_BRAKE = 0.95
SAFE_MARGIN = 0.002
SAFE_K = 24


def stop_length(speed: torch.Tensor | float, a_brake: float, step: float):
    """``D(s) = s^2 / (2 a_brake) + s T / 2``: an upper bound of the distance a mover at speed ``s`` travels braking
    step by step (``a_brake`` held for each step of ``T``; the last step to rest), which nests: one braking step plus
    ``D`` of the speed left is at most ``D(s)``."""
    return speed * speed / (2.0 * a_brake) + 0.5 * step * speed


def _dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return (a * b).sum(-1)


def segment_closest_points(p1: torch.Tensor, d1: torch.Tensor, p2: torch.Tensor, d2: torch.Tensor,
                           eps: float = 1e-12) -> tuple[torch.Tensor, torch.Tensor]:
    """The parameters ``s, t`` in [0, 1] of the closest points ``p1 + s d1`` and ``p2 + t d2`` of two segments
    (``[..., 2]`` each; degenerate segments are points). Batched form of the classic clamped solution."""
    r = p1 - p2
    a, e, f = _dot(d1, d1), _dot(d2, d2), _dot(d2, r)
    c, b = _dot(d1, r), _dot(d1, d2)
    a_ok, e_ok = a > eps, e > eps
    safe_a = torch.where(a_ok, a, torch.ones_like(a))
    safe_e = torch.where(e_ok, e, torch.ones_like(e))
    denom = a * e - b * b
    s = torch.where(denom > eps * (a * e + eps), ((b * f - c * e) / torch.where(denom > 0, denom, 1.0)), 0.0)
    s = s.clamp(0.0, 1.0)
    t = (b * s + f) / safe_e
    s = torch.where(t < 0, (-c / safe_a).clamp(0.0, 1.0), torch.where(t > 1, ((b - c) / safe_a).clamp(0.0, 1.0), s))
    t = t.clamp(0.0, 1.0)
    # degenerate cases: a point against a segment, or two points
    s = torch.where(e_ok, s, (-c / safe_a).clamp(0.0, 1.0))
    t = torch.where(e_ok, t, torch.zeros_like(t))
    t = torch.where(a_ok, t, (f / safe_e).clamp(0.0, 1.0))
    s = torch.where(a_ok, s, torch.zeros_like(s))
    return s, t


def vec2_array(t: torch.Tensor, *shape: int) -> wp.array:
    """A float32 torch tensor as a Warp vec2 array, reshaped to ``[*shape, 2]`` first where ``shape`` is given
    (contiguous: a copy where it was not). What the filter's and the planner's kernel launches take."""
    if shape:
        t = t.reshape(*shape, 2)
    return wp.from_torch(t.contiguous(), dtype=wp.vec2)


def collision_distances(sim) -> tuple[float, float]:
    """``(contact, wall_reach)`` (m) of a :class:`~magwarp.sim.Simulator`'s movers: the collision distance between two
    centres (both shapes' reach, with the collision margin) and the closest a centre may come to the edge of the tiles
    (the reach and the wall margin). A box counts as the circle around it; per-mover sizes as the largest."""
    col = sim.model.collision
    reach = float(sim._radii_np.max()) if col.shape == 0 else float(math.hypot(*sim._half_np.max(axis=0)))
    return 2.0 * (reach + float(col.margin)), reach + float(col.wall_margin)


def build_safety(env, *, v_cap: float = SAFE_SPEED, commit_brake: float = COMMIT_BRAKE, margin: float = SAFE_MARGIN,
                 k: int = SAFE_K, what: tuple[str, str, str, str] = ("cruise", "commit_brake", "safe_margin", "safe_k")
                 ):
    """The safety filter of a :class:`~magwarp.swarm.SwarmEnv` ``env`` (acceleration control; its simulator, layout,
    ``a_max`` and step) and its own neighbour view: ``(SafetyFilter, LocalObservations)``, the view holding the ``k``
    nearest movers within the filter's :attr:`~SafetyFilter.reach_radius` (no rays: the filter finds the cells off
    the tiles itself). What :class:`~magwarp.swarm.SwarmPlanner` (``safe=True``) and the env's shield both build.
    ``v_cap``: the speed cap (at most the simulator's ``v_max``: a speed capped by the simulator would leave the
    committed path), ``commit_brake`` (in (0, 1], x ``a_max``): the committed braking, ``margin`` (m): the extra
    distance kept. ``what``: the caller's names of these four options, for the error messages."""
    from magwarp.swarm.observations import LocalObservations

    sim = env.sim
    n_cap, n_brake, n_margin, n_k = what
    v_max = float(sim.model.limits.v_max)
    if not (math.isfinite(v_cap) and 0 < v_cap <= v_max):
        raise ValueError(f"{n_cap} ({v_cap!r}) must be a positive speed at most the movers' v_max ({v_max}) with the "
                         f"safety filter (a speed capped by the simulator would leave the committed path)")
    if not 0.0 < commit_brake <= 1.0:
        raise ValueError(f"{n_brake} must be in (0, 1], got {commit_brake!r}")
    if not (math.isfinite(margin) and margin >= 0):
        raise ValueError(f"{n_margin} must be a number >= 0 (m), got {margin!r}")
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
        raise ValueError(f"{n_k} must be an integer >= 1, got {k!r}")
    contact, wall_reach = collision_distances(sim)
    a_max = float(env.config.a_max)
    dt = float(sim.model.limits.dt)
    safety = SafetyFilter(contact=contact, wall_reach=wall_reach, a_max=a_max, step=env.num_cycles * dt, dt=dt,
                          a_brake=commit_brake * a_max, margin=margin, v_cap=float(v_cap), tiles=env.layout.tiles,
                          tile_size=float(env.layout.tile.size), device=env.device)
    # the filter's own neighbour search: the k nearest within the reach radius (a list full of movers within reach
    # restricts the mover to a small ball: 8 slots were full for most movers of a dense crowd)
    near = LocalObservations(env.layout, env.num_envs, env.num_movers, k=int(k), radius=safety.reach_radius,
                             num_rays=0, device=sim.device)
    return safety, near


class SafetyFilter:
    """The velocity filter of the module docstring for movers of collision distance ``contact`` (m) whose centres
    must stay ``wall_reach`` (m) from the edge of the tiles, acceleration limit ``a_max`` held for steps of
    ``step`` s made of cycles of ``dt`` s; ``a_brake`` (<= ``a_max``) is the committed braking, ``margin`` (m)
    the extra distance kept (float rounding), ``v_cap`` the largest speed any mover will have (for the neighbour
    radius :attr:`reach_radius`)."""

    TURNS = (0.0, math.pi / 4, -math.pi / 4, math.pi / 2, -math.pi / 2)
    SHARE_FLOOR = 0.2  # m/s: a mover at rest still gets a share of a pair's slack
    FRACTIONS = (1.0, 0.75, 0.5, 0.25)

    def __init__(self, *, contact: float, wall_reach: float, a_max: float, step: float, dt: float, a_brake: float,
                 margin: float, v_cap: float, tiles=None, tile_size: float = 0.24, device=None,
                 kernel: bool = True):
        for name, value in (("contact", contact), ("a_max", a_max), ("step", step), ("a_brake", a_brake),
                            ("v_cap", v_cap)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")
        for name, value in (("wall_reach", wall_reach), ("dt", dt), ("margin", margin)):
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a number >= 0, got {value!r}")
        if a_brake > a_max:
            raise ValueError(f"a_brake ({a_brake}) must be at most a_max ({a_max}): braking must be reachable")
        self.contact, self.wall_reach, self.a_max = float(contact), float(wall_reach), float(a_max)
        self.step, self.dt, self.a_brake, self.margin = float(step), float(dt), float(a_brake), float(margin)
        self.v_cap = float(v_cap)
        #: the farthest a committed path reaches from its mover
        self.path_reach = (self.step + 0.5 * self.dt) * self.v_cap + stop_length(self.v_cap, self.a_brake, self.step)
        #: movers farther apart than this cannot meet within a step (the local view must see this far)
        self.reach_radius = self.contact + self.margin + 2.0 * self.path_reach
        self.stop_cap = stop_length(self.v_cap, self.a_brake, self.step)  # the longest committed segment
        self.share_min = self.SHARE_FLOOR / (self.v_cap + 2.0 * self.SHARE_FLOOR)  # the least share of a pair's slack
        # walls: the cells off the tiles (holes, and beyond the edges) near a mover are square obstacles
        self.tiles = None
        if tiles is not None:
            if not (math.isfinite(tile_size) and tile_size > 0):
                raise ValueError(f"tile_size must be a positive number, got {tile_size!r}")
            self.tile_size = float(tile_size)
            self.tiles = torch.as_tensor(np.array(tiles, dtype=bool), device=device)
            # every cell that a path (reach path_reach) can come within wall_reach + margin of
            c = math.ceil((self.wall_reach + self.margin + self.path_reach) / self.tile_size)
            r = torch.arange(-c, c + 1, device=device)
            self.cell_offsets = torch.stack(torch.meshgrid(r, r, indexing="ij"), -1).reshape(-1, 2)
        turns = torch.tensor(self.TURNS, dtype=torch.float32, device=device)
        c, s = turns.cos(), turns.sin()
        self.rot = torch.stack([torch.stack([c, -s], -1), torch.stack([s, c], -1)], -2)  # [R, 2, 2]
        self.fractions = torch.tensor(self.FRACTIONS, dtype=torch.float32, device=device)
        #: choose with the Warp kernel (:func:`magwarp.kernels.safety.safe_choice`: a thread per mover) where the
        #: inputs are float32, else (or False) with the torch form below, its reference
        self.kernel = bool(kernel)
        self._kernel_inputs: dict = {}

    def _gain(self, v1: torch.Tensor) -> torch.Tensor:
        """``T + dt/2 + |v1| / (2 a_brake)``: the factor of ``max(v1.n, 0)`` in the path bound."""
        return self.step + 0.5 * self.dt + v1.norm(dim=-1) / (2.0 * self.a_brake)

    def wall_constraints(self, pos: torch.Tensor, vel: torch.Tensor, seg: torch.Tensor
                         ) -> tuple[torch.Tensor, torch.Tensor]:
        """``normals`` ``[..., C, 2]`` and ``base`` ``[..., C]`` of the cells off the tiles around each mover at
        ``pos`` (absolute), whose committed segment is ``seg``: the separating plane between the segment and each
        such square (the closest points of a segment and a box: an endpoint against the box, or a corner against
        the segment), with the whole ``gap - wall_reach - margin`` for the mover (walls do not move)."""
        size, (nx, ny) = self.tile_size, self.tiles.shape
        cell = torch.floor(pos / size).long()[..., None, :] + self.cell_offsets  # [..., C, 2]
        inside = (cell[..., 0] >= 0) & (cell[..., 0] < nx) & (cell[..., 1] >= 0) & (cell[..., 1] < ny)
        flat = cell[..., 0].clamp(0, nx - 1) * ny + cell[..., 1].clamp(0, ny - 1)
        obstacle = ~(inside & self.tiles.reshape(-1)[flat])
        lo = cell.to(pos.dtype) * size
        hi = lo + size
        a = pos[..., None, :].expand_as(lo)
        d = seg[..., None, :].expand_as(lo)
        b = a + d
        corners = torch.stack([lo, torch.stack([hi[..., 0], lo[..., 1]], -1), torch.stack([lo[..., 0], hi[..., 1]], -1),
                               hi], -2)  # [..., C, 4, 2]
        t = (_dot(corners - a[..., None, :], d[..., None, :]) / _dot(d, d).clamp_min(1e-12)[..., None]).clamp(0, 1)
        on_seg = a[..., None, :] + t[..., None] * d[..., None, :]
        q_seg = torch.cat([a[..., None, :], b[..., None, :], on_seg], -2)  # [..., C, 6, 2]
        q_box = torch.cat([torch.maximum(torch.minimum(a, hi), lo)[..., None, :],
                           torch.maximum(torch.minimum(b, hi), lo)[..., None, :], corners], -2)
        dist = (q_box - q_seg).norm(dim=-1)
        best = dist.argmin(-1, keepdim=True)
        pick = lambda x: x.gather(-2, best[..., None].expand(*best.shape, 2)).squeeze(-2)  # noqa: E731
        q_i, q_o = pick(q_seg), pick(q_box)
        gap = dist.gather(-1, best).squeeze(-1)
        centre = 0.5 * (lo + hi) - a
        n = torch.where((gap > TOUCH_GAP)[..., None], (q_o - q_i) / gap.clamp_min(1e-12)[..., None],
                        centre / centre.norm(dim=-1, keepdim=True).clamp_min(1e-12))
        budget = (gap - self.wall_reach - self.margin).clamp_min(0.0)
        base = _dot(a - q_i, n) + 0.5 * self.step * _dot(vel[..., None, :], n).clamp_min(0.0) - budget
        return n, torch.where(obstacle, base, -math.inf)

    def constraints(self, vel: torch.Tensor, rel_pos: torch.Tensor, rel_vel: torch.Tensor, mask: torch.Tensor,
                    pos: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Per mover, its constraints ``base + max(v1.n, 0) gain(v1) <= 0``: ``normals`` ``[..., C, 2]``,
        ``base`` ``[..., C]`` (inactive constraints: ``-inf``), and ``ball`` ``[...]``: the largest
        :meth:`path_reach_of` its new path may have (``inf`` unless its neighbour list is crowded)."""
        T = self.step
        speed = vel.norm(dim=-1, keepdim=True)
        unit = vel / speed.clamp_min(1e-12)
        seg_i = unit * stop_length(speed, self.a_brake, T)  # [..., 2]
        vel_j = vel[..., None, :] + rel_vel
        speed_j = vel_j.norm(dim=-1, keepdim=True)
        seg_j = vel_j / speed_j.clamp_min(1e-12) * stop_length(speed_j, self.a_brake, T)
        seg_i_k = seg_i[..., None, :].expand_as(seg_j)
        s, t = segment_closest_points(torch.zeros_like(rel_pos), seg_i_k, rel_pos, seg_j)
        q_i = s[..., None] * seg_i_k
        q_j = rel_pos + t[..., None] * seg_j
        sep = q_j - q_i
        gap = sep.norm(dim=-1)
        # touching or crossing paths (the invariant was broken from outside, e.g. a respawn; closest points nearer
        # than TOUCH_GAP, where their difference is rounding): the centre line as the normal
        centre = rel_pos / rel_pos.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        n = torch.where((gap > TOUCH_GAP)[..., None], sep / gap.clamp_min(1e-12)[..., None], centre)
        v0n = _dot(vel[..., None, :], n)
        # the pair's slack, shared in proportion to how fast each heads into it now (both movers compute the same
        # split: a follower may close up on a leader moving away); a pair closer than contact + margin (e.g. placed
        # so) gets none: no closer than now, moving apart stays allowed
        toward_i = v0n.clamp_min(0.0) + self.SHARE_FLOOR
        toward_j = (-_dot(vel_j, n)).clamp_min(0.0) + self.SHARE_FLOOR
        budget = (gap - self.contact - self.margin).clamp_min(0.0) * (toward_i / (toward_i + toward_j))
        base = -_dot(q_i, n) + 0.5 * T * v0n.clamp_min(0.0) - budget
        base = torch.where(mask, base, -math.inf)
        # a full neighbour list whose farthest entry (at d_k) is within reach: a mover within reach may be unseen
        # (no nearer than d_k); the new path then stays within a ball that no unseen mover's half can reach
        ball = torch.full(vel.shape[:-1], math.inf, device=vel.device)
        if mask.shape[-1] > 0:
            d_k = rel_pos.norm(dim=-1).masked_fill(~mask, 0.0).amax(-1)
            crowded = mask.all(-1) & (d_k <= self.reach_radius)
            room = self.share_min * (d_k - stop_length(speed[..., 0], self.a_brake, T) - self.stop_cap
                                     - self.contact - self.margin)
            ball = torch.where(crowded, room, ball)
        if pos is not None and self.tiles is not None:
            wn, wbase = self.wall_constraints(pos, vel, seg_i)
            n = torch.cat([n, wn], -2)
            base = torch.cat([base, wbase], -1)
        return n, base, ball

    def path_reach_of(self, vel: torch.Tensor, cand: torch.Tensor) -> torch.Tensor:
        """``[..., K]``: how far from the mover the new path (held step, then braking) of each candidate ``[..., K,
        2]`` may reach: ``T/2 |v0| + |v1| (T + dt/2 + |v1| / (2 a_brake))``."""
        return 0.5 * self.step * vel.norm(dim=-1, keepdim=True) + cand.norm(dim=-1) * self._gain(cand)

    def braking(self, vel: torch.Tensor) -> torch.Tensor:
        """The committed braking's velocity after one step: ``a_brake`` against the velocity, or rest."""
        speed = vel.norm(dim=-1, keepdim=True)
        return vel * (1.0 - self.a_brake * self.step / speed.clamp_min(1e-12)).clamp_min(0.0)

    def candidates(self, vel: torch.Tensor, wanted: torch.Tensor) -> torch.Tensor:
        """``[..., K, 2]``: braking first, then the wanted velocity (at most ``v_cap`` fast) and its turns at each
        fraction of the way from braking (every one within one step's reach of ``vel``)."""
        v_b = self.braking(vel)
        speed = wanted.norm(dim=-1, keepdim=True)  # no faster than v_cap (the reach of paths assumes it)
        wanted = torch.where(speed > self.v_cap, wanted * (self.v_cap / speed.clamp_min(1e-12)), wanted)
        turned = torch.einsum("rab,...b->...ra", self.rot.to(vel.device), wanted)  # [..., R, 2]
        dv = turned - vel[..., None, :]
        reach = self.a_max * self.step * (1.0 - 1e-5)
        norm = dv.norm(dim=-1, keepdim=True)
        w = vel[..., None, :] + torch.where(norm > reach, dv * (reach / norm.clamp_min(1e-12)), dv)
        f = self.fractions.to(vel.device)[:, None, None]  # [F, 1, 1]
        mix = v_b[..., None, None, :] + f * (w[..., None, :, :] - v_b[..., None, None, :])  # [..., F, R, 2]
        return torch.cat([v_b[..., None, :], mix.flatten(-3, -2)], -2)

    def violation(self, cand: torch.Tensor, normals: torch.Tensor, base: torch.Tensor) -> torch.Tensor:
        """``[..., K]``: the largest constraint value of each candidate (safe where <= 0)."""
        v1n = torch.einsum("...ka,...ca->...kc", cand, normals)
        g = base[..., None, :] + v1n.clamp_min(0.0) * self._gain(cand)[..., None]
        return g.amax(-1) if g.shape[-1] else torch.full(cand.shape[:-1], -math.inf, device=cand.device)

    def __call__(self, vel: torch.Tensor, wanted: torch.Tensor, rel_pos: torch.Tensor, rel_vel: torch.Tensor,
                 mask: torch.Tensor, pos: torch.Tensor | None = None) -> torch.Tensor:
        """The safe velocity for the end of the step ``[..., 2]`` closest to ``wanted`` among the candidates
        (braking where no other is safe)."""
        return self.choose(vel, wanted, rel_pos, rel_vel, mask, pos)[0]

    def choose(self, vel: torch.Tensor, wanted: torch.Tensor, rel_pos: torch.Tensor, rel_vel: torch.Tensor,
               mask: torch.Tensor, pos: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`__call__`'s safe velocity and ``[...]`` bool: where ``wanted`` itself passes, i.e. it is no faster
        than ``v_cap`` and its candidate (the first after braking: ``wanted``, moved within one step's reach of
        ``vel``, which is ``a_max T (1 - 1e-5)``) is safe; there the safe velocity is at least as close to ``wanted``
        as that candidate. With :attr:`kernel` (the default) and float32 inputs one Warp launch
        (:func:`magwarp.kernels.safety.safe_choice`), else :meth:`choose_torch`."""
        if self.kernel and all(t.dtype == torch.float32 for t in (vel, wanted, rel_pos, rel_vel)) and (
                pos is None or pos.dtype == torch.float32):
            return self._choose_kernel(vel, wanted, rel_pos, rel_vel, mask, pos)
        return self.choose_torch(vel, wanted, rel_pos, rel_vel, mask, pos)

    def _kernel_model(self, device: torch.device, walls: bool) -> tuple:
        """The kernel's parameters (with or without the walls), tiles, cell offsets, turns and fractions on
        ``device`` (made once per device and walls)."""
        key = (str(device), bool(walls))
        if key not in self._kernel_inputs:
            from magwarp.kernels.safety import SafetyParams

            p = SafetyParams()
            for name in ("contact", "wall_reach", "a_max", "step", "dt", "a_brake", "margin", "v_cap", "reach_radius",
                         "stop_cap", "share_min"):
                setattr(p, name, float(getattr(self, name)))
            p.share_floor = float(self.SHARE_FLOOR)
            p.tile_size = float(getattr(self, "tile_size", 1.0))
            p.walls = int(walls)
            wdev = warp_device(device)
            tiles = self.tiles if self.tiles is not None else torch.zeros(1, 1, dtype=torch.bool)
            offsets = self.cell_offsets if self.tiles is not None else torch.zeros(0, 2, dtype=torch.int64)
            self._kernel_inputs[key] = (
                p, wp.from_torch(tiles.to(device=device, dtype=torch.int32).contiguous()),
                wp.from_torch(offsets.to(device=device, dtype=torch.int32).contiguous(), dtype=wp.vec2i),
                wp.from_torch(self.rot.to(device).contiguous(), dtype=wp.mat22),
                wp.from_torch(self.fractions.to(device).contiguous()), wdev)
        return self._kernel_inputs[key]

    def _choose_kernel(self, vel, wanted, rel_pos, rel_vel, mask, pos):
        from magwarp.kernels.safety import safe_choice

        lead, k, dev = vel.shape[:-1], rel_pos.shape[-2], vel.device
        rows = vel[..., 0].numel()
        walls = pos is not None and self.tiles is not None
        p, tiles, offsets, rot, fractions, wdev = self._kernel_model(dev, walls)
        cells = offsets.shape[0] if walls else 0

        # the scratch holds a block of movers at a time (12 bytes per constraint, 8 per turn: within chunk_bytes)
        block = max(1, min(rows, self.chunk_bytes // (12 * (k + cells) + 8 * self.rot.shape[0])))
        normals = torch.empty(block, k + cells, 2, device=dev)
        bases = torch.empty(block, k + cells, device=dev)
        turned = torch.empty(block, self.rot.shape[0], 2, device=dev)
        safe = torch.empty(rows, 2, device=dev)
        passes = torch.empty(rows, dtype=torch.bool, device=dev)
        pos_rows = vec2_array(pos, rows) if walls else wp.empty(0, dtype=wp.vec2, device=wdev)
        inputs = [p, tiles, offsets, rot, fractions, vec2_array(vel, rows), vec2_array(wanted, rows),
                  vec2_array(rel_pos, rows, k), vec2_array(rel_vel, rows, k),
                  wp.from_torch(mask.reshape(rows, k).to(torch.bool).contiguous()), pos_rows]
        scratch = [wp.from_torch(normals, dtype=wp.vec2), wp.from_torch(bases), wp.from_torch(turned, dtype=wp.vec2)]
        outputs = [wp.from_torch(safe, dtype=wp.vec2), wp.from_torch(passes, dtype=wp.bool)]
        with on_torch_stream(wdev):
            for row0 in range(0, rows, block):
                wp.launch(safe_choice, dim=min(block, rows - row0), inputs=[*inputs, row0, *scratch],
                          outputs=outputs, device=wdev)
        return safe.reshape(*lead, 2), passes.reshape(lead)

    def choose_torch(self, vel: torch.Tensor, wanted: torch.Tensor, rel_pos: torch.Tensor, rel_vel: torch.Tensor,
                     mask: torch.Tensor, pos: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`choose` in torch ops (the kernel's reference; any float dtype).

        The candidates' constraint values are a ``[..., K, C]`` tensor (K candidates, C neighbour and wall
        constraints; about 4 KB per mover): for more movers than fit :attr:`chunk_bytes` (16,384 worlds of 256
        movers asked 16 GiB) the movers are taken a block at a time, with the same results (each mover's choice
        reads its own rows only)."""
        rows = vel[..., 0].numel()
        walls = self.cell_offsets.shape[0] if pos is not None and self.tiles is not None else 0
        per_row = 4 * self.num_candidates * (rel_pos.shape[-2] + walls)
        block = max(1, self.chunk_bytes // max(per_row, 1))
        if rows <= block:
            return self._choose(vel, wanted, rel_pos, rel_vel, mask, pos)
        lead = vel.shape[:-1]
        flat = [t.reshape(rows, *t.shape[len(lead):]) if t is not None else None
                for t in (vel, wanted, rel_pos, rel_vel, mask, pos)]
        parts = [self._choose(*(t[i:i + block] if t is not None else None for t in flat))
                 for i in range(0, rows, block)]
        safe = torch.cat([p[0] for p in parts]).reshape(*lead, 2)
        return safe, torch.cat([p[1] for p in parts]).reshape(lead)

    #: the largest ``[..., K, C]`` constraint tensor (bytes) :meth:`choose_torch` makes at once, and the largest
    #: scratch of the kernel's launches (a block of movers per launch)
    chunk_bytes = 1 << 31

    @property
    def num_candidates(self) -> int:
        """K: braking, then the wanted velocity's turns at each fraction of the way (:meth:`candidates`)."""
        return 1 + self.fractions.numel() * self.rot.shape[0]

    def _choose(self, vel, wanted, rel_pos, rel_vel, mask, pos):
        normals, base, ball = self.constraints(vel, rel_pos, rel_vel, mask, pos)
        cand = self.candidates(vel, wanted)
        bad = (self.violation(cand, normals, base) > 0) | (self.path_reach_of(vel, cand) > ball[..., None])
        bad[..., 0] = False  # braking is always safe (recursive feasibility)
        cost = ((cand - wanted[..., None, :]) ** 2).sum(-1).masked_fill(bad, math.inf)
        best = cost.argmin(-1, keepdim=True)
        passes = ~bad[..., 1] & (wanted.norm(dim=-1) <= self.v_cap)
        return cand.gather(-2, best[..., None].expand(*best.shape, 2)).squeeze(-2), passes
