"""A scripted contact-selecting push heuristic for the pushing tasks (a baseline, no learning).

Per world, mover 0 does the pushing (other movers hold still). Every env step it re-plans:

* **candidates**: push directions (a fixed fan of world directions plus the straight object-to-goal direction)
  times lateral offsets of the mover's line from the object's centre of area. For each, the mover's square
  footprint is swept along the direction into the object's parts (slab tests of mover corners against the rotated
  part rectangles and of part corners against the mover square): where it first touches gives the contact point,
  the contact normal and the mover's position at contact (the swept line behind it is free of the object);
* **prediction**: a quasi-static point push with an ellipsoidal limit surface (the object's centre of area and
  mean lever arm, Coulomb friction at the contact: sticking inside the friction cone, sliding on its edge) gives
  the object's twist per unit mover speed; its rate of decrease of the weighted pose error ``(dx, dy, rho*dyaw)``
  (yaw error modulo the shape's rotational symmetry; zero weight for position goals) scores the candidate;
* **choice**: the candidate with the smallest estimated time (way round the object to its staging point at cruise
  speed plus the pose error over its predicted rate at push speed) wins; the choice is kept unless another one is
  clearly faster (hysteresis against dithering);
* **motion**: on the swept line behind the contact (a narrow cone, which also counts the mover as pushing while it
  is a little past the predicted contact: the contact is soft) the mover pushes along it with a speed that brakes
  below the object's friction deceleration as the predicted remaining push shrinks, steering back onto the line;
  elsewhere it flies straight to a point on that line clear of the object, or goes around the object on a circle
  at a small clearance while the straight way would clip it (the shorter way unless it leaves the area);
* **obstacles** (``PushWithObstacles``): until it is past the walls the object is aimed at a point in front of the
  gap between them, then at one behind it (at a height where the mover pushing it fits through the gap, with the
  mover's wall gap, too), then at the goal; a candidate is dropped if its push would run the mover, or the object's
  predicted path, into a wall; the mover's speed toward each wall is capped to what can still brake before
  touching it, and that braking has priority in the acceleration;
* **settle**: once the goal is well inside the success threshold (position goals: the distance from the goal to
  where the object comes to rest if let go now; pose goals: the exact coverage), hold still: the episode is scored
  on its final state.

Contact distances use the exact support of the (rotated) object parts and of the mover's square footprint. Speeds
toward the sides of the safe rectangle (where the wall-collision shape stays on the tiles) are capped to what can
still brake, and that braking has priority in the acceleration (layouts with holes are only approximated by their
bounding rectangle). The desired velocity becomes an acceleration through a deadbeat velocity loop over one held
env step. Batched torch on the env's device, no Python loop over worlds (only small fixed loops over candidate
offsets).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import torch

from magwarp._vectors import clip_norm

__all__ = ["PushHeuristic"]

_INF = 1e9


def _outline(obj) -> dict:
    """Planar geometry of an object for pushing: parts ``rects [K, 4]`` (a cylinder as its bounding square), centre
    of area ``com``, squared mean lever arm ``c2`` (the limit surface's ratio m_max / f_max, uniform pressure), part
    corners ``verts [4K, 2]`` and the largest distance of the outline from the centre of area ``extent``."""
    if obj.shape == "cylinder":  # swept as its bounding square with the yaw held at zero
        rects = np.array([[0.0, 0.0, obj.radius, obj.radius]], np.float32)
    else:
        rects = np.asarray(obj.rects(), np.float32)
    area = 4 * rects[:, 2] * rects[:, 3]
    com = (rects[:, :2] * area[:, None]).sum(0) / area.sum()
    g = (np.arange(16) + 0.5) / 16 * 2 - 1
    gx, gy = np.meshgrid(g, g)
    pts = rects[:, None, :2] + np.stack([gx.ravel(), gy.ravel()], 1)[None] * rects[:, None, 2:]
    lever = (np.linalg.norm(pts - com, axis=-1).mean(1) * area).sum() / area.sum()
    corners = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]], np.float32)
    verts = (rects[:, None, :2] + corners[None] * rects[:, None, 2:]).reshape(-1, 2)
    extent = float(np.max(np.hypot(np.abs(rects[:, 0] - com[0]) + rects[:, 2],
                                   np.abs(rects[:, 1] - com[1]) + rects[:, 3])))
    return {"rects": rects, "com": com, "c2": float(lever) ** 2, "verts": verts, "extent": extent}


def _unit(v: torch.Tensor) -> torch.Tensor:
    return v / v.norm(dim=-1, keepdim=True).clamp_min(1e-9)


def _perp(v: torch.Tensor) -> torch.Tensor:
    return torch.stack([-v[..., 1], v[..., 0]], dim=-1)


def _cross(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _rot(c: torch.Tensor, s: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Rotate ``v [..., 2]`` by the angle with cosine ``c`` and sine ``s`` (broadcast against ``v[..., 0]``)."""
    return torch.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]], dim=-1)


def _slab(start: torch.Tensor, direction: torch.Tensor, half: torch.Tensor):
    """Entry time of rays ``start + t * direction`` into the boxes ``|x| <= half`` (per axis), and the entry axis.

    Returns ``(t_enter, axis)``; ``t_enter`` is ``_INF`` where the ray misses or starts inside."""
    small = direction.abs() < 1e-7
    safe = torch.where(small, torch.ones_like(direction), direction)
    t1 = (-half - start) / safe
    t2 = (half - start) / safe
    lo, hi = torch.minimum(t1, t2), torch.maximum(t1, t2)
    inside = start.abs() <= half
    lo = torch.where(small, torch.where(inside, torch.full_like(lo, -_INF), torch.full_like(lo, _INF)), lo)
    hi = torch.where(small, torch.where(inside, torch.full_like(hi, _INF), torch.full_like(hi, -_INF)), hi)
    enter, axis = lo.max(dim=-1)
    leave = hi.min(dim=-1).values
    hit = (enter <= leave) & (enter > 0.0)
    return torch.where(hit, enter, torch.full_like(enter, _INF)), axis


def _symmetry(rects: np.ndarray) -> float:
    """Smallest rotation (pi/2, pi or 2 pi) about the body origin that maps the union of rectangles onto itself
    (compared on a grid of points; the parts of a rotated shape need not be the same rectangles)."""
    ext = float(np.max(np.abs(rects[:, :2]) + rects[:, 2:])) * 1.1
    g = (np.arange(61) + 0.5) / 61 * 2 * ext - ext
    pts = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)

    def inside(p: np.ndarray) -> np.ndarray:
        return (np.abs(p[:, None] - rects[None, :, :2]) <= rects[None, :, 2:]).all(-1).any(-1)

    base = inside(pts)
    for angle in (math.pi / 2, math.pi):
        c, s = math.cos(angle), math.sin(angle)
        if np.mean(inside(pts @ np.array([[c, s], [-s, c]])) != base) < 1e-3:
            return angle
    return 2 * math.pi


class _Candidates(NamedTuple):
    """Candidate pushes per world ``[N, C, ...]`` (C: push directions times lateral offsets)."""

    d: torch.Tensor  # push direction (unit)
    m_c: torch.Tensor  # mover centre at contact
    m_pre: torch.Tensor  # staging point: the mover centre a clearance short of the contact
    point: torch.Tensor  # contact point
    normal: torch.Tensor  # contact normal into the object
    f: torch.Tensor  # predicted velocity of the object's centre of area per unit mover travel
    omega: torch.Tensor  # predicted yaw rate per unit mover travel
    amount: torch.Tensor  # mover travel that best reduces the weighted pose error
    residual: torch.Tensor  # weighted pose error that push leaves
    valid: torch.Tensor  # hits the object, reduces the error, and its staging point and push are clear (bool)


class PushHeuristic:
    """``policy(obs) -> action`` for a :class:`~magwarp.envs.push.PushEnv` (batched, torch in and out).

    Args:
        env: the batched push env (layout, object, mover sizes, limits and obstacles are read from it; with
            ``object_ranges`` each world's own object outline).
        cruise: top speed (m/s) while approaching; push_speed: top speed while pushing.
        push_brake: deceleration (m/s^2) planned while pushing (below the box's friction deceleration, ~6 m/s^2).
        approach_brake: deceleration (m/s^2) planned when arriving at points and before the sides of the area.
        clearance: gap (m) kept between mover and object while going around it.
        engage: fraction of the push speed the mover already has when it reaches the staging point.
        cone: lateral tolerance (per metre of gap) of the cone behind the contact in which it pushes.
        settle: the mover holds still once the object is within this fraction of the position threshold.
        stop_at: distance (m) short of the goal at which the planned push speed reaches zero.
        directions: number of world push directions in the candidate fan (plus the object-to-goal direction).
        offsets: number of lateral offsets of the push line per direction; spread: their half-range (m).
        yaw_scale: metres of position error one radian of yaw error weighs (pose goals).
        friction: mover-object friction coefficient assumed by the prediction.
        hold_coverage: pose goals: hold still once the coverage exceeds the success threshold by this much.
        switch: a new candidate replaces the kept one only if its estimated time is below this fraction of it.
        approach_speed: speed (m/s) assumed for the way round in the estimated time; residual_cost: its weight (s/m)
            of the pose error a candidate's push leaves undone.
        lateral_tol: lateral tolerance (m) of the push cone at the contact; overlap: how far (m) the mover may be past
            the predicted contact (the contact's softness) and still count as pushing. Default: 0.02 / 0.03 for
            position goals, 0.012 / 0.01 for pose goals (which need the exact contact).
        arrive_brake, orbit_brake: decelerations (m/s^2) planned when arriving at the staging point / going round.
        slide_decel: deceleration (m/s^2) assumed for the object sliding on its own (where it rests if let go).
        Obstacles: pass_margin: how far (m) past the walls the object is aimed before the goal; wall_gap: gap (m)
            the mover keeps to the walls; wall_band: extra band (m) of a wall's span in which that gap is kept;
            pass_slack: extra margin (m) of the object's passing height inside the band the mover fits through;
            path_checks: distances (m) along a candidate's push at which the mover (and, with ``object_check``,
            the object's predicted path) must be clear of the walls.
    """

    def __init__(self, env, cruise: float = 1.8, push_speed: float = 1.0, push_brake: float = 5.0,
                 approach_brake: float = 5.0, clearance: float = 0.008, engage: float = 0.5,
                 cone: float = 0.3, settle: float = 0.95, stop_at: float = 0.005, directions: int = 16,
                 offsets: int = 9, spread: float | None = None, yaw_scale: float = 0.08, friction: float = 0.5,
                 hold_coverage: float = 0.12, switch: float = 0.75, approach_speed: float = 1.0,
                 residual_cost: float = 20.0, lateral_tol: float | None = None, pass_margin: float = 0.03,
                 wall_gap: float = 0.01, overlap: float | None = None,
                 path_checks: tuple = (0.03, 0.07, 0.12, 0.18, 0.25), arrive_brake: float = 5.0,
                 orbit_brake: float = 5.0, slide_decel: float = 5.0, wall_band: float = 0.0,
                 pass_slack: float = 0.01, object_check: bool = True):
        self.env = env
        self.backend = env.backend
        self.cruise, self.push_speed = cruise, push_speed
        self.push_brake, self.approach_brake = push_brake, approach_brake
        self.clearance = clearance
        self.engage, self.cone, self.settle, self.stop_at = engage, cone, settle, stop_at
        self.yaw_scale, self.hold_coverage, self.switch = yaw_scale, hold_coverage, switch
        self.approach_speed, self.residual_cost = approach_speed, residual_cost
        self.mu = float(friction)
        self.path_checks = tuple(path_checks)
        self.pass_margin, self.wall_gap = pass_margin, wall_gap
        self.arrive_brake, self.orbit_brake, self.slide_decel = arrive_brake, orbit_brake, slide_decel
        self.wall_band, self.pass_slack = wall_band, pass_slack
        self.object_check = object_check
        c = self.backend.control
        self.latency = c.num_cycles * self.backend.dt  # one held env step
        self.a_max, self.v_max = c.a_max, c.v_max
        dev = self.device = env.device
        obj = env.object
        self.pose_goal = bool(getattr(env, "learn_pose", False))
        # position goals tolerate a looser push cone (pose goals need the exact contact)
        self.lateral_tol = (0.012 if self.pose_goal else 0.02) if lateral_tol is None else lateral_tol
        self.overlap = (0.01 if self.pose_goal else 0.03) if overlap is None else overlap
        g = _outline(obj)
        self._round, self._radius = obj.shape == "cylinder", float(obj.radius) if obj.shape == "cylinder" else 0.0
        rects, com = g["rects"], g["com"]
        self._parts = torch.as_tensor(rects, device=dev)  # (K, 4) cx, cy, hx, hy in the body frame
        self._com = torch.as_tensor(com, device=dev)
        self._c2 = g["c2"]
        self._period = 2 * math.pi if self._round else _symmetry(rects.astype(np.float64))
        corners = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]], np.float32)
        self._verts = torch.as_tensor(g["verts"], device=dev)  # part corners in the body frame (J, 2)
        # With object_ranges every world has its own outline: a bank per variant, gathered per world at each call
        # (extent and sweep reach stay the largest variant's: conservative margins).
        self._variants = None
        if getattr(env, "variants", None) is not None:
            outlines = [_outline(o) for o in env.variants.specs]
            self._variants = {
                "parts": torch.as_tensor(np.stack([o["rects"] for o in outlines]), device=dev),
                "com": torch.as_tensor(np.stack([o["com"] for o in outlines]), device=dev),
                "c2": torch.as_tensor(np.array([o["c2"] for o in outlines], np.float32), device=dev),
                "verts": torch.as_tensor(np.stack([o["verts"] for o in outlines]), device=dev),
            }
        self._mover_half = float(0.5 * env.mover.size[0])
        self._mover_corners = torch.as_tensor(corners * self._mover_half, device=dev)
        extent = g["extent"]
        self._extent = extent
        self._reach = extent + self._mover_half * math.sqrt(2) + 0.02  # sweep start distance
        spread = 0.9 * extent if spread is None else spread
        ang = torch.arange(directions, device=dev, dtype=torch.float32) * (2 * math.pi / directions)
        self._dirs = torch.stack([torch.cos(ang), torch.sin(ang)], -1)  # (D, 2) world directions
        self._offs = torch.linspace(-spread, spread, offsets, device=dev) if offsets > 1 else torch.zeros(1, device=dev)
        # Where the mover's wall-collision footprint stays on the tiles (full rectangles; others are approximated).
        reach = env.mover.bounding_radius(env.mover.wall_margin) + 0.01
        ext = np.asarray(env.layout.extent, np.float32)
        self._lo = torch.full((2,), reach, device=dev)
        self._hi = torch.as_tensor(ext - reach, device=dev)
        n = env.num_envs
        self._way = torch.zeros(n, 1, device=dev)  # per world: direction around the object (0: none)
        self._choice = torch.full((n,), -1, dtype=torch.long, device=dev)  # kept candidate (-1: none)
        self._obstacles = None
        obstacles = getattr(env, "obstacles", ())
        if obstacles:
            o = np.array([[ob.xy[0], ob.xy[1], ob.half_size[0], ob.half_size[1], ob.yaw] for ob in obstacles],
                         np.float32)
            self._obstacles = torch.as_tensor(o, device=dev)
            self._init_gap(o)

    # ------------------------------------------------------------------ geometry
    def _init_gap(self, o: np.ndarray) -> None:
        """The walls' x span (PushWithObstacles' two walls share it; it is the same in every obstacle mode)."""
        self._gap_x = (float(min(o[:, 0] - o[:, 2])), float(max(o[:, 0] + o[:, 2])))
        self._set_walls(torch.as_tensor(o, device=self.device)[None].expand(self.env.num_envs, -1, -1))

    def _set_walls(self, boxes: torch.Tensor) -> None:
        """Each world's walls from ``boxes [N, K, 5]`` (cx, cy, hx, hy, yaw; the env's ``obstacle_boxes``, which vary
        per world in its random and curriculum modes): the keep-out rectangles and the gap between the lowest
        two walls' facing edges, through which the object is aimed."""
        c, h = boxes[..., :2], boxes[..., 2:4]
        self._walls = torch.cat([c - h, c + h], -1)  # (N, K, 4) x0, y0, x1, y1 (yaw ignored)
        order = torch.argsort(boxes[..., 1], dim=-1)
        lower = torch.gather(boxes, 1, order[:, :1, None].expand(-1, 1, 5))[:, 0]
        upper = torch.gather(boxes, 1, order[:, 1:2, None].expand(-1, 1, 5))[:, 0]
        self._gap_y = (lower[:, 1] + lower[:, 3], upper[:, 1] - upper[:, 3])

    def _object_support(self, yaw: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
        """Extent of the object (yaw ``[N]``) along unit directions ``w`` ``[N, 2]`` from its centre of area."""
        if self._round:
            return torch.full(w.shape[:-1], self._radius, device=w.device)
        c, s = torch.cos(yaw)[:, None], torch.sin(yaw)[:, None]  # (N, 1)
        p = self._parts  # (K, 4), or (N, K, 4) per world
        px, py = p[..., 0] - self._com[..., 0:1], p[..., 1] - self._com[..., 1:2]
        cx = c * px - s * py  # part centres relative to the centre of area, world frame (N, K)
        cy = s * px + c * py
        wx, wy = w[:, 0:1], w[:, 1:2]
        along_x = (wx * c + wy * s).abs()  # |w . body x|
        along_y = (-wx * s + wy * c).abs()
        return (cx * wx + cy * wy + p[..., 2] * along_x + p[..., 3] * along_y).amax(dim=1)

    def _mover_support(self, w: torch.Tensor) -> torch.Tensor:
        return self._mover_half * (w[..., 0].abs() + w[..., 1].abs())

    def _clear(self, x: torch.Tensor, com: torch.Tensor, yaw: torch.Tensor, margin: float) -> torch.Tensor:
        """Mover centres ``x [N, 2]`` whose footprint is separated from the object by at least ``margin``
        (sufficient test: the support sum along the centre line)."""
        rel = x - com
        e = _unit(rel)
        need = self._object_support(yaw, e) + self._mover_support(e) + margin
        return rel.norm(dim=-1) >= need

    def _sweep(self, origin: torch.Tensor, yaw: torch.Tensor, start: torch.Tensor, d: torch.Tensor):
        """Sweep the mover square from centres ``start [N, C, 2]`` along unit ``d [N, C, 2]`` into the object (body
        origin ``origin [N, 2]``, ``yaw [N]``). Returns (travel ``[N, C]`` (``_INF``: miss), contact point and
        contact normal into the object ``[N, C, 2]``)."""
        c, s = torch.cos(yaw), torch.sin(yaw)
        p = self._parts if self._parts.dim() == 3 else self._parts[None]  # (N or 1, K, 4)
        vb = self._verts if self._verts.dim() == 3 else self._verts[None]
        # A: object corners entering the mover square (the mover moves +d, so in its frame the corners move -d).
        verts = origin[:, None] + _rot(c[:, None], s[:, None], vb)  # (N, J, 2)
        rel = verts[:, None] - start[:, :, None]  # (N, C, J, 2)
        ta, axa = _slab(rel, -d[:, :, None].expand_as(rel), torch.full_like(rel, self._mover_half))
        axis_a = torch.nn.functional.one_hot(axa, 2).to(d.dtype)
        na = axis_a * torch.sign(d[:, :, None])  # the mover face's outward normal
        pa = verts[:, None].expand_as(rel)
        # B: mover corners entering the object's parts (in each part's frame).
        centres = origin[:, None] + _rot(c[:, None], s[:, None], p[:, :, :2])  # (N, K, 2)
        q = start[:, :, None] + self._mover_corners  # (N, C, 4, 2)
        z = q[:, :, :, None] - centres[:, None, None]  # (N, C, 4, K, 2)
        cc, ss = c[:, None, None, None], s[:, None, None, None]
        z = _rot(cc, -ss, z)
        dl = _rot(c[:, None], -s[:, None], d)[:, :, None, None].expand_as(z)  # d in the body frame
        tb, axb = _slab(z, dl, p[:, None, None, :, 2:].expand_as(z))
        nb_local = torch.nn.functional.one_hot(axb, 2).to(d.dtype) * torch.sign(dl)  # into the part
        nb = _rot(cc, ss, nb_local)
        pb = (q[:, :, :, None] + tb[..., None].clamp(max=1.0) * d[:, :, None, None]).expand_as(z)
        n_, c_ = d.shape[:2]
        t = torch.cat([ta, tb.reshape(n_, c_, -1)], dim=2)
        pts = torch.cat([pa, pb.reshape(n_, c_, -1, 2)], dim=2)
        nrm = torch.cat([na, nb.reshape(n_, c_, -1, 2)], dim=2)
        tmin = t.min(dim=2).values
        near = (t <= tmin[..., None] + 1e-3).to(d.dtype)[..., None]  # touching along a face: average its ends
        point = (pts * near).sum(2) / near.sum(2).clamp_min(1.0)
        normal = _unit((nrm * near).sum(2))
        return tmin, point, normal

    def _twist(self, r: torch.Tensor, n: torch.Tensor, d: torch.Tensor):
        """Object twist (velocity of its centre of area, yaw rate) per unit mover speed along ``d``, pushing at
        ``r`` (from the centre of area) with contact normal ``n`` (into the object): quasi-static, ellipsoidal limit
        surface ``V = k F``, ``w = k (r x F) / c^2``, Coulomb friction at the contact."""
        c2 = self._c2 if isinstance(self._c2, float) else self._c2[:, None, None]  # per world: (N, 1, 1)
        pp = _perp(r)  # velocity of the contact point per unit yaw rate
        # sticking: the contact point moves with the mover: (I + pp pp^T / c2) F = d
        f_stick = d - pp * ((pp * d).sum(-1, keepdim=True) / (c2 + (pp * pp).sum(-1, keepdim=True)))
        fn = (f_stick * n).sum(-1, keepdim=True)
        ft = (f_stick * _perp(n)).sum(-1, keepdim=True)
        stick = ft.abs() <= self.mu * fn
        # sliding: the force on the friction cone's edge, scaled so the contact's normal speed matches the mover's
        edge = n + self.mu * torch.sign(ft) * _perp(n)
        normal_speed = ((edge * n).sum(-1, keepdim=True)
                        + (pp * n).sum(-1, keepdim=True) * (pp * edge).sum(-1, keepdim=True) / c2)
        f_slide = edge * ((d * n).sum(-1, keepdim=True) / normal_speed.clamp_min(1e-6))
        f = torch.where(stick, f_stick, f_slide)
        return f, _cross(r, f) / (c2 if isinstance(c2, float) else c2[..., 0])

    # ------------------------------------------------------------------ motion helpers
    def _profile(self, gap: torch.Tensor, brake: float | None = None) -> torch.Tensor:
        """Speed from which the mover still stops within ``gap`` (m) at ``brake`` (default ``approach_brake``),
        with one held step of latency."""
        brake = self.approach_brake if brake is None else brake
        bl = brake * self.latency
        return -bl + torch.sqrt(bl * bl + 2 * brake * gap)

    def _wall_limit(self, pos: torch.Tensor, vel: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        """Cap the speed toward each side of the safe region to what can still brake before it (per axis), from
        where the mover will be after one held step."""
        ahead = pos + vel * self.latency
        room_lo = (ahead - self._lo).clamp_min(0.0)
        room_hi = (self._hi - ahead).clamp_min(0.0)
        v = torch.maximum(v, -torch.sqrt(2 * self.approach_brake * room_lo))
        return torch.minimum(v, torch.sqrt(2 * self.approach_brake * room_hi))

    def _clip(self, acc: torch.Tensor) -> torch.Tensor:
        return clip_norm(acc, self.a_max)

    def _wall_brake(self, pos: torch.Tensor, vel: torch.Tensor, acc: torch.Tensor) -> torch.Tensor:
        """Braking toward a wall (the sides of the area, and obstacles) takes priority over the rest of the command
        (the norm clip would dilute it)."""
        ahead = pos + vel * self.latency
        v_lo = -torch.sqrt(2 * self.approach_brake * (ahead - self._lo).clamp_min(0.0))
        v_hi = torch.sqrt(2 * self.approach_brake * (self._hi - ahead).clamp_min(0.0))
        if self._obstacles is not None:
            o_lo, o_hi = self._obstacle_bounds(pos)
            v_lo, v_hi = torch.maximum(v_lo, o_lo), torch.minimum(v_hi, o_hi)
        lo = ((v_lo - vel) / self.latency).clamp(max=self.a_max)
        hi = ((v_hi - vel) / self.latency).clamp(min=-self.a_max)
        bounded = torch.maximum(torch.minimum(acc, hi), lo).clamp(-self.a_max, self.a_max)
        forced = bounded != acc  # axes where the wall decided
        other = torch.sqrt((self.a_max ** 2 - bounded.flip(-1) ** 2).clamp_min(0.0))
        free = torch.where(forced.flip(-1) & ~forced, bounded.clamp(-other, other), bounded)
        return self._clip(free)

    def _orbit_sign(self, obj, theta, err, radius) -> torch.Tensor:
        """Direction (+1 counter-clockwise, -1 clockwise) to go around the object: the shorter arc unless it leaves
        the safe region (sampled at a few angles), then the other one."""
        frac = torch.linspace(0.15, 1.0, 6, device=obj.device)
        short = -torch.sign(err)  # dtheta sign of the shorter arc
        cands = torch.stack([short, -short], dim=1)  # (N, 2, 1)
        span = torch.stack([err.abs(), 2 * torch.pi - err.abs()], dim=1)  # (N, 2, 1)
        ang = theta[:, None, None] + cands * span * frac  # (N, 2, K)
        pts = obj[:, None, None, :] + radius[:, None, None] * torch.stack([torch.cos(ang), torch.sin(ang)], -1)
        ok = ((pts >= self._lo) & (pts <= self._hi)).all(-1).all(-1)  # (N, 2)
        return torch.where(ok[:, :1] | ~ok[:, 1:], cands[:, 0], cands[:, 1])

    # ------------------------------------------------------------------ policy
    def _goal(self, com: torch.Tensor, yaw: torch.Tensor):
        """Target of the object's centre of area and its yaw error (wrapped to the shape's symmetry)."""
        env = self.env
        if self.pose_goal:
            gyaw = env.goal_yaw
            goal = env.goal_xy + _rot(torch.cos(gyaw), torch.sin(gyaw), self._com.expand_as(env.goal_xy))
            per = self._period
            dyaw = torch.remainder(gyaw - yaw + per / 2, per) - per / 2
        else:
            goal = env.goal_xy + _rot(torch.cos(yaw), torch.sin(yaw), self._com.expand_as(env.goal_xy))
            dyaw = torch.zeros_like(yaw)
        return goal, dyaw

    def __call__(self, obs=None) -> torch.Tensor:
        """Mover accelerations ``[N, 2 * num_movers]`` for the env's current state (``obs`` is not used)."""
        b = self.backend
        self._sync_env()
        pos, vel = b.mover_qpos[:, 0, :2], b.mover_qvel[:, 0, :2]
        origin, yaw, com = self._object_pose()
        e_p, e_w, e_norm, rest = self._pose_error(com, yaw)
        cand = self._candidates(origin, yaw, com, e_p, e_w, e_norm)
        choice, changed, any_valid = self._choose(self._estimated_time(pos, com, cand))
        v = self._desired_velocity(pos, com, yaw, cand, choice, changed, rest)
        v = torch.where(any_valid[:, None], v, torch.zeros_like(v))
        # Settle: hold still once well inside the success threshold (the final state is scored).
        v = torch.where(self._settled(origin, yaw)[:, None], torch.zeros_like(v), v)
        return self._action(pos, vel, v)

    def _sync_env(self) -> None:
        """Take each world's walls and object outline from the env; forget the kept choices at episode starts."""
        env = self.env
        if self._obstacles is not None:  # the env's walls may differ per world and episode (random, curriculum)
            self._set_walls(env.obstacle_boxes)
        if self._variants is not None:  # each world's object outline (object_ranges)
            idx = env.object_variant.long()
            v = self._variants
            self._parts, self._com = v["parts"][idx], v["com"][idx]
            self._c2, self._verts = v["c2"][idx], v["verts"][idx]
        fresh = env.num_steps == 0  # first step of an episode: forget the kept choices
        self._choice = torch.where(fresh, torch.full_like(self._choice, -1), self._choice)
        self._way = torch.where(fresh[:, None], torch.zeros_like(self._way), self._way)

    def _object_pose(self):
        """The object's body origin ``[N, 2]``, yaw ``[N]`` (zero for a cylinder) and centre of area ``[N, 2]``."""
        oq = self.backend.object_qpos[:, 0]
        w, x, y, z = oq[:, 3], oq[:, 4], oq[:, 5], oq[:, 6]
        yaw = torch.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        if self._round:
            yaw = torch.zeros_like(yaw)
        origin = oq[:, :2]
        com = origin + _rot(torch.cos(yaw), torch.sin(yaw), self._com.expand_as(origin))
        return origin, yaw, com

    def _pose_error(self, com: torch.Tensor, yaw: torch.Tensor):
        """Position and weighted pose errors to the target (waypoint or goal), their norm, the way left after it."""
        goal, dyaw = self._goal(com, yaw)
        target, rest = goal, torch.zeros_like(com[:, :1])
        if self._obstacles is not None:
            target, rest = self._waypoint(com, goal)
        e_p = target - com
        e_w = torch.cat([e_p, (self.yaw_scale * dyaw)[:, None]], -1)  # (N, 3)
        e_norm = e_w.norm(dim=-1, keepdim=True).clamp_min(1e-6)
        return e_p, e_w, e_norm, rest

    def _candidates(self, origin, yaw, com, e_p, e_w, e_norm) -> _Candidates:
        """Sweep the mover into the object along every candidate push line and predict each push's effect."""
        n = self.env.num_envs
        # world directions and the straight direction to the target, times lateral offsets
        u = _unit(e_p)
        dirs = torch.cat([self._dirs[None].expand(n, -1, -1), u[:, None]], 1)  # (N, D + 1, 2)
        nd, no = dirs.shape[1], self._offs.shape[0]
        d = dirs[:, :, None].expand(n, nd, no, 2).reshape(n, nd * no, 2)
        off = self._offs[None, None, :, None].expand(n, nd, no, 1).reshape(n, nd * no, 1)
        start = com[:, None] - d * self._reach + _perp(d) * off
        travel, point, normal = self._sweep(origin, yaw, start, d)
        valid = travel < _INF / 2
        m_c = start + travel.clamp(max=1.0)[..., None] * d  # mover centre at contact
        r = point - com[:, None]
        dn = (d * normal).sum(-1)
        f, omega = self._twist(r, normal, d)
        t3 = torch.cat([f, (self.yaw_scale * omega)[..., None]], -1)  # weighted twist per unit mover travel
        gain = (t3 * e_w[:, None]).sum(-1)
        rate = gain / e_norm
        amount = gain / (t3 * t3).sum(-1).clamp_min(1e-9)  # mover travel that best reduces the error
        residual = (e_w[:, None] - amount[..., None] * t3).norm(dim=-1)
        valid &= (dn > 0.2) & (rate > 0.02)
        m_pre = m_c - d * self.clearance
        valid &= self._feasible(com, d, m_c, m_pre, f, amount)
        return _Candidates(d, m_c, m_pre, point, normal, f, omega, amount, residual, valid)

    def _feasible(self, com, d, m_c, m_pre, f, amount) -> torch.Tensor:
        """Candidates with the staging point in the area and off the walls, pushing neither body into a wall."""
        ok = ((m_pre >= self._lo) & (m_pre <= self._hi)).all(-1)
        if self._obstacles is not None:
            ok &= ~self._in_walls(m_pre, 0.004)
            # the push itself must not run the mover into a wall (it would brake there and stall the object)
            for s in self.path_checks:
                ok &= ~(self._in_walls(m_c + d * s, 0.0) & (amount > s - 0.03))
                if self.object_check:  # nor the object into one (its predicted path, as a disc of its extent)
                    o_s = com[:, None] + f * min(s, 0.12)
                    ok &= ~(self._in_walls(o_s, self._extent - self._mover_half) & (amount > s - 0.03))
        return ok

    def _estimated_time(self, pos: torch.Tensor, com: torch.Tensor, cand: _Candidates) -> torch.Tensor:
        """Estimated time per candidate: way round to the staging point, push, error left (``_INF``: invalid)."""
        rel_now, rel_pre = pos - com, cand.m_pre - com[:, None]
        r_now, r_pre = rel_now.norm(dim=-1, keepdim=True), rel_pre.norm(dim=-1)
        dphi = torch.remainder(torch.atan2(rel_pre[..., 1], rel_pre[..., 0])
                               - torch.atan2(rel_now[:, 1:2], rel_now[:, 0:1]) + math.pi, 2 * math.pi) - math.pi
        way = torch.maximum(r_now, r_pre) * dphi.abs() + (r_now - r_pre).abs()
        way = torch.minimum(way, (pos[:, None] - cand.m_pre).norm(dim=-1) * (1.0 + 2.0 * (dphi.abs() > 1.2)))
        cost = way / self.approach_speed + cand.amount / self.push_speed + self.residual_cost * cand.residual
        return torch.where(cand.valid, cost, torch.full_like(cost, _INF))

    def _choose(self, cost: torch.Tensor):
        """The kept candidate unless another is clearly faster (updates it): ``(choice, changed, any_valid)``."""
        best_cost, best = cost.min(dim=1)
        kept = self._choice.clamp_min(0)
        kept_cost = cost.gather(1, kept[:, None])[:, 0]
        keep = (self._choice >= 0) & (kept_cost < _INF / 2) & (best_cost > self.switch * kept_cost)
        choice = torch.where(keep, kept, best)
        changed = choice != self._choice
        self._choice = torch.where(best_cost < _INF / 2, choice, torch.full_like(choice, -1))
        any_valid = best_cost < _INF / 2
        return choice, changed, any_valid

    def _desired_velocity(self, pos, com, yaw, cand: _Candidates, choice, changed, rest) -> torch.Tensor:
        """Desired mover velocity: push, go around the object, or fly to the staging point (records ``_info``)."""
        n = self.env.num_envs
        idx = choice[:, None, None].expand(n, 1, 2)
        dc = cand.d.gather(1, idx)[:, 0]
        mc = cand.m_c.gather(1, idx)[:, 0]
        need = cand.amount.gather(1, choice[:, None]).clamp_min(0.0) + rest
        along, lateral, speed, cone, v_push = self._push_velocity(pos, dc, mc, need)
        back, v_direct, blocked = self._approach_velocity(pos, com, yaw, dc, mc, speed)
        v_orbit = self._orbit_velocity(pos, com, yaw, back, blocked, changed)
        v = torch.where(cone, v_push, torch.where(blocked, v_orbit, v_direct))
        # the chosen candidate and mode per world (0 push, 1 around the object, 2 straight approach), for debugging
        self._info = {"mode": torch.where(cone, 0, torch.where(blocked, 1, 2))[:, 0],
                      "along": along[:, 0], "lateral": lateral[:, 0],
                      "omega": cand.omega.gather(1, choice[:, None])[:, 0], "force": cand.f.gather(1, idx)[:, 0],
                      "point": cand.point.gather(1, idx)[:, 0] - com, "normal": cand.normal.gather(1, idx)[:, 0]}
        return v

    def _push_velocity(self, pos, dc, mc, need):
        """Push along the chosen line, braking over the gap and the remaining push ``need``, steering onto it."""
        nc = _perp(dc)
        rel = pos - mc
        along = (rel * dc).sum(-1, keepdim=True)
        lateral = (rel * nc).sum(-1, keepdim=True)
        gap = (-along).clamp_min(0.0)
        speed = torch.sqrt(2 * self.push_brake * (need + gap - self.stop_at).clamp_min(0.0)).clamp(
            max=self.push_speed)
        cone = (along < self.overlap) & (lateral.abs() < self.lateral_tol + self.cone * gap)
        v_push = dc * speed - nc * (lateral * 15.0).clamp(-self.cruise, self.cruise)
        return along, lateral, speed, cone, v_push

    def _approach_velocity(self, pos, com, yaw, dc, mc, speed):
        """Fly straight to a point behind the contact clear of the object (and whether the object blocks that)."""
        back = mc - dc * self.clearance
        for s in (0.03, 0.06, 0.1, 0.15, 0.22):
            farther = mc - dc * s
            back = torch.where((back == mc - dc * self.clearance).all(-1, keepdim=True)
                               & ~self._clear(back, com, yaw, 0.5 * self.clearance)[:, None], farther, back)
        dvec = back - pos
        dist_b = dvec.norm(dim=-1, keepdim=True)
        arrive = _unit(dvec) * self._profile(dist_b, self.arrive_brake).clamp(max=self.cruise)
        v_direct = arrive + dc * self.engage * speed * (1.0 - dist_b / 0.05).clamp(0.0, 1.0)
        # the segment passes the object: go around it instead
        t = ((com - pos) * dvec).sum(-1, keepdim=True) / (dist_b * dist_b).clamp_min(1e-9)
        closest = pos + t.clamp(0.0, 1.0) * dvec
        blocked = ~self._clear(closest, com, yaw, 0.5 * self.clearance)[:, None]
        return back, v_direct, blocked

    def _orbit_velocity(self, pos, com, yaw, back, blocked, changed) -> torch.Tensor:
        """Go around the object toward ``back`` on a circle at a clearance, keeping the way round once chosen."""
        rel_o = pos - com
        r_o = rel_o.norm(dim=-1, keepdim=True).clamp_min(1e-6)
        e_r = rel_o / r_o
        e_t = _perp(e_r)  # counter-clockwise
        theta = torch.atan2(e_r[:, 1], e_r[:, 0])
        to_back = back - com
        theta_t = torch.atan2(to_back[:, 1], to_back[:, 0])
        err = torch.remainder(theta - theta_t + torch.pi, 2 * torch.pi)[:, None] - torch.pi
        contact = (self._object_support(yaw, e_r) + self._mover_support(e_r))[:, None]
        r_des = contact + self.clearance
        dr = r_des - r_o
        v_rad = e_r * torch.sign(dr) * self._profile(dr.abs(), self.orbit_brake).clamp(max=self.cruise)
        # Keep the way round once chosen: in front of the object the shorter arc flips with every step.
        sign = self._orbit_sign(com, theta, err, r_des)
        sign = torch.where(blocked & (self._way != 0) & ~changed[:, None], self._way, sign)
        self._way = torch.where(blocked, sign, torch.zeros_like(sign))
        v_tan = e_t * sign * self._profile(err.abs() * r_o, self.orbit_brake).clamp(max=self.cruise)
        return self.backend.object_qvel[:, 0, :2] + v_rad + v_tan

    def _settled(self, origin: torch.Tensor, yaw: torch.Tensor) -> torch.Tensor:
        """Worlds whose goal is well inside the success threshold ``[N]`` (bool): the mover holds still there."""
        env, b = self.env, self.backend
        if self.pose_goal:
            from magwarp.physics import coverage

            pose = torch.stack([origin[:, 0], origin[:, 1], yaw], -1)
            gpose = torch.stack([env.goal_xy[:, 0], env.goal_xy[:, 1], env.goal_yaw], -1)
            left = (env.max_episode_steps - env.num_steps).clamp_min(0).to(pose.dtype)
            margin = self.hold_coverage * (left / 8.0).clamp(0.1, 1.0)  # late in the episode, keep what is reached
            # the env's own shape table: each world's outline, and no device upload per call
            covered = coverage(pose, gpose, env.shapes, env.object_variant)
            return covered >= (env.min_coverage + margin).clamp(max=0.99)
        ov = b.object_qvel[:, 0, :2]  # where the object will come to rest if let go now
        rest_at = origin + ov * ov.norm(dim=-1, keepdim=True) / (2 * self.slide_decel)
        return (env.goal_xy - rest_at).norm(dim=-1) < self.settle * env.max_position_err

    def _action(self, pos: torch.Tensor, vel: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        """The env action: mover 0 accelerates toward ``v`` (wall braking first), the other movers brake to rest."""
        env, n = self.env, self.env.num_envs
        if self._obstacles is not None:
            v = self._wall_guard(pos, vel, v)
        v = self._wall_limit(pos, vel, v)
        acc = self._wall_brake(pos, vel, self._clip((v - vel) / self.latency))
        out = torch.zeros(n, env.num_movers, 2, device=env.device)
        out[:, 0] = acc
        if env.num_movers > 1:  # helpers hold still
            out[:, 1:] = (-self.backend.mover_qvel[:, 1:, :2] / self.latency).clamp(-self.a_max, self.a_max)
        return out.reshape(n, -1)

    # ------------------------------------------------------------------ obstacles
    def _waypoint(self, com: torch.Tensor, goal: torch.Tensor):
        """Until the object is past the walls, aim it at points in front of and behind the gap, at a height where
        the mover pushing it fits through too (the goal's height, clamped to that range); returns the target and
        the way left from it to the goal."""
        x_pass = self._gap_x[1] + self._extent + self.pass_margin
        margin = self._mover_half + self.wall_gap + self.wall_band + self.pass_slack
        y_pass = goal[:, 1].clamp(self._gap_y[0] + margin, self._gap_y[1] - margin)
        entry = torch.stack([torch.full_like(y_pass, self._gap_x[0]), y_pass], -1)
        exit_ = torch.stack([torch.full_like(y_pass, x_pass + 0.05), y_pass], -1)
        before = (com[:, 0] < self._gap_x[0] - 0.05)[:, None]
        inside = (com[:, 0] < x_pass)[:, None]
        target = torch.where(before, entry, torch.where(inside, exit_, goal))
        rest = torch.where(before, (exit_ - entry).norm(dim=-1, keepdim=True), torch.zeros_like(com[:, :1]))
        rest = torch.where(inside, rest + (goal - exit_).norm(dim=-1, keepdim=True), rest)
        return target, rest

    def _in_walls(self, x: torch.Tensor, margin: float) -> torch.Tensor:
        """Mover centres ``x [..., 2]`` whose footprint comes within ``margin`` of a wall."""
        if self._obstacles is None:
            return torch.zeros(x.shape[:-1], dtype=torch.bool, device=x.device)
        g = self._mover_half + margin
        w = self._walls.view(self._walls.shape[0], *([1] * (x.dim() - 2)), *self._walls.shape[1:])  # per world
        xx, yy = x[..., 0:1], x[..., 1:2]
        inside = (xx > w[..., 0] - g) & (xx < w[..., 2] + g) & (yy > w[..., 1] - g) & (yy < w[..., 3] + g)
        return inside.any(-1)

    def _obstacle_bounds(self, ahead: torch.Tensor):
        """Per-axis velocity bounds ``(lo, hi) [N, 2]`` that can still brake before each wall (grown by the mover's
        half-size and ``wall_gap``), for a mover at ``ahead [N, 2]`` within the wall's other span (plus
        ``wall_band``)."""
        g = self._mover_half + self.wall_gap
        w = self._walls
        band = self.wall_band
        ax, ay = ahead[:, 0:1], ahead[:, 1:2]
        in_x = (ax > w[..., 0] - g - band) & (ax < w[..., 2] + g + band)  # (N, K): within the wall's x span
        in_y = (ay > w[..., 1] - g - band) & (ay < w[..., 3] + g + band)
        big = torch.full_like(in_x, 1e3, dtype=ahead.dtype)

        def cap(mask, room):  # from where the mover is now (one held step of latency in the profile)
            return torch.where(mask, self._profile(room.clamp_min(0.0)), big).amin(-1)

        left, below = ax < 0.5 * (w[..., 0] + w[..., 2]), ay < 0.5 * (w[..., 1] + w[..., 3])
        hi_x = cap(in_y & left, w[..., 0] - g - ax)
        lo_x = -cap(in_y & ~left, ax - (w[..., 2] + g))
        hi_y = cap(in_x & below, w[..., 1] - g - ay)
        lo_y = -cap(in_x & ~below, ay - (w[..., 3] + g))
        return torch.stack([lo_x, lo_y], -1), torch.stack([hi_x, hi_y], -1)

    def _wall_guard(self, pos: torch.Tensor, vel: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        """Cap the desired velocity to the obstacle bounds."""
        lo, hi = self._obstacle_bounds(pos)
        return torch.maximum(torch.minimum(v, hi), lo)
