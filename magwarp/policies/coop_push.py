"""A scripted cooperative push for :class:`~magwarp.envs.coop_push.CoopPushEnv` (a baseline, no learning).

Every env step, per world (batched torch, no loop over worlds or movers):

* **line**: the push direction ``d`` points from the object to the goal; the movers' slots lie side by side on a line
  behind the object (opposite the goal), ``spacing`` apart and centred on the object's centre line, at the object's
  support distance behind its centre. Movers take the slots in the order of their lateral positions (so their paths
  do not cross);
* **approach**: a mover flies to a staging point ``standoff`` behind its slot at up to ``cruise`` speed, braking to
  arrive; where the straight way would clip the object it circles the object at a clearance (towards its staging
  point the short way round); movers closer than a slot spacing are pushed apart, and each pair's closing speed is
  capped to what can still brake before their collision shapes touch;
* **push**: once every mover is at its staging point (or already pushing), they all drive along ``d`` at a speed that
  brakes (at ``push_brake``) to reach zero ``stop_at`` short of the goal, holding their slots laterally; the heavy
  object lags behind that speed, so each mover pushes at its full force until the object is moving;
* **settle**: once the object would come to rest (decelerating by friction) within ``settle`` of the position
  threshold of the goal, the movers stop: the episode is scored on its final state.

Speeds towards the layout's sides are capped to what can still brake before the wall-check shape leaves the tiles
(the layout's bounding rectangle). The desired velocity becomes an acceleration through a deadbeat velocity loop over
one held env step, norm-clipped to ``a_max``.
"""

from __future__ import annotations

import math
from typing import Dict, Union

import numpy as np
import torch
from torch import nn

from magwarp._vectors import clip_norm
from magwarp.envs.coop_push import GRAVITY, _OBJECT_OBS

__all__ = ["CoopPushPolicy", "CoopPushCore", "CoopPushResidualPolicy"]


def _unit(v: torch.Tensor) -> torch.Tensor:
    return v / v.norm(p=2, dim=-1, keepdim=True).clamp_min(1e-9)


def _perp(v: torch.Tensor) -> torch.Tensor:
    return torch.stack([-v[..., 1], v[..., 0]], dim=-1)


class CoopPushPolicy:
    """``policy(obs) -> action [N, 2 M]`` for a :class:`~magwarp.envs.coop_push.CoopPushEnv` (torch in and out).

    Args:
        env: the batched env (mover count and sizes, object outline, friction, limits and layout are read from it).
        cruise: top speed (m/s) while approaching; push_speed: top speed while pushing.
        approach_brake: deceleration (m/s^2) planned when arriving at points and before the layout's sides.
        push_brake: deceleration (m/s^2) of the planned push speed towards the goal.
        spacing: distance (m) between neighbouring slots (default: the collision box width + 40 mm); with box checks
            the larger of its x and y components is this (slots along a diagonal are further apart).
        standoff: distance (m) of the staging points behind the slots (default: enough to clear the object at any yaw).
        clearance: gap (m) kept around the object's bounding circle while circling it.
        tolerance: lateral and longitudinal distance (m) from the staging point within which a mover counts as lined up.
        settle: the movers stop once the object's resting place is within this fraction of the position threshold.
        stop_at: distance (m) short of the goal at which the planned push speed reaches zero.
        lateral_share: largest share of ``a_max`` a pushing mover spends holding its slot sideways.
    """

    def __init__(self, env, cruise: float = 1.2, push_speed: float = 0.6, approach_brake: float = 5.0,
                 push_brake: float = 3.0, spacing: float | None = None, standoff: float | None = None,
                 clearance: float = 0.015, tolerance: float = 0.03, settle: float = 0.5, stop_at: float = 0.01,
                 lateral_share: float = 0.35):
        self.env = env
        self.m = m = env.num_movers
        self.jerk = bool(env.learn_jerk)
        if self.jerk:
            raise ValueError("CoopPushPolicy commands accelerations: build the env with learn_jerk=False")
        dev = env.device
        mover = env.mover
        self.half = 0.5 * float(max(mover.size[:2]))  # mover body half size
        c_half = (float(mover.collision_radius) if mover.collision_shape == "circle" else
                  float(max(mover.collision_half_size)))
        self.box = mover.collision_shape == "box"
        self.c_half = c_half
        self.spacing = 2 * c_half + 0.04 if spacing is None else float(spacing)
        self.slots = torch.arange(m, device=dev, dtype=torch.float32) - 0.5 * (m - 1)  # [M], in spacings
        obj = env.object
        rects = (np.array([[0.0, 0.0, obj.radius, obj.radius]]) if obj.shape == "cylinder" else
                 np.asarray(obj.rects(), float))
        corners = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]], float)
        verts = (rects[:, None, :2] + corners[None] * rects[:, None, 2:]).reshape(-1, 2)
        self.verts = torch.as_tensor(verts, dtype=torch.float32, device=dev)  # [V, 2] body frame
        extent = float(np.max(np.linalg.norm(verts, axis=1)))
        min_support = float(min(np.max(verts @ np.array([math.cos(a), math.sin(a)])) for a in
                                np.linspace(0, 2 * math.pi, 72, endpoint=False)))
        self.radius = extent + self.half + clearance  # circle around object and mover kept while circling
        self.standoff = (max(0.04, extent - min_support + 2 * clearance) if standoff is None else float(standoff))
        self.cruise, self.push_speed = float(cruise), float(push_speed)
        self.approach_brake, self.push_brake = float(approach_brake), float(push_brake)
        self.tolerance = float(tolerance)
        self.lateral_share = float(lateral_share)
        self.settle = float(settle) * env.max_position_err
        self.stop_at = float(stop_at)
        self.decel = float(env.object.friction[0]) * GRAVITY  # the object's friction deceleration when let go
        control = env.backend.control
        self.a_max = float(control.a_max)
        self.dt = float(env.num_cycles) * 1e-3  # one held env step (1 ms control cycles)
        wall = c_half + float(mover.wall_margin) + 0.01
        ext = np.asarray(env.layout.extent, float)
        self.lo = torch.tensor([wall, wall], dtype=torch.float32, device=dev)
        self.hi = torch.as_tensor(ext - wall, dtype=torch.float32, device=dev)
        self.hold_dir = 3 * env.max_position_err
        self.num_envs = int(env.num_envs)
        self.core = CoopPushCore(self)

    @property
    def pushing(self) -> torch.Tensor:
        """``[N]`` bool: the worlds whose movers push (else they approach their staging points)."""
        return self.core.pushing

    def reset(self, mask: torch.Tensor | None = None) -> None:
        """Forget the push phase of the worlds in ``mask`` (all by default); new episodes start approaching."""
        if mask is None:
            self.core.pushing.zero_()
        else:
            self.core.pushing.masked_fill_(mask.to(self.core.pushing.device), False)

    def __call__(self, obs) -> torch.Tensor:
        o = obs["observation"]
        n = o.shape[0]
        if n != self.num_envs:
            raise ValueError(f"CoopPushPolicy was built for {self.num_envs} worlds, got observations of {n}")
        return self.core(o, obs["desired_goal"], self.env.num_steps == 0)  # a new episode starts approaching


class CoopPushCore(nn.Module):
    """The baseline's step as a TorchScript-able module, with its per-world state (push phase, held direction):
    ``core(observation [N, D], desired_goal [N, G], fresh [N] bool) -> action [N, 2 M]``, ``fresh`` marking the worlds
    whose episode has just begun. Built from a :class:`CoopPushPolicy` (its numbers); a batch of another size than
    the state's starts every world afresh."""

    def __init__(self, p: CoopPushPolicy):
        super().__init__()
        self.m, self.box = int(p.m), bool(p.box)
        self.object_obs = _OBJECT_OBS  # the observation's tail: object x, y, sin yaw, cos yaw, vx, vy
        for name in ("half", "c_half", "spacing", "radius", "standoff", "cruise", "push_speed", "approach_brake",
                     "push_brake", "tolerance", "lateral_share", "settle", "stop_at", "decel", "a_max", "dt",
                     "hold_dir"):
            setattr(self, name, float(getattr(p, name)))
        for name in ("slots", "verts", "lo", "hi"):
            self.register_buffer(name, getattr(p, name).clone())
        dev = p.verts.device
        self.register_buffer("pushing", torch.zeros(p.num_envs, dtype=torch.bool, device=dev))
        self.register_buffer("dir", torch.zeros(p.num_envs, 2, device=dev))

    def _support(self, yaw: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """Support distance of the object outline at ``yaw [N]`` in world directions ``u [N, 2]``."""
        c, s = torch.cos(yaw)[:, None], torch.sin(yaw)[:, None]
        vx, vy = self.verts[:, 0], self.verts[:, 1]
        world = torch.stack([c * vx - s * vy, s * vx + c * vy], -1)  # [N, V, 2]
        return (world * u[:, None, :]).sum(-1).amax(-1)

    def _wall_cap(self, pos: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        """``v`` with its components towards the layout's sides capped to what can still brake before them."""
        b, lag = self.approach_brake, self.approach_brake * self.dt  # one held step of latency
        up = (torch.sqrt(lag * lag + 2 * b * (self.hi - pos).clamp_min(0.0)) - lag).clamp_min(0.0)
        down = (torch.sqrt(lag * lag + 2 * b * (pos - self.lo).clamp_min(0.0)) - lag).clamp_min(0.0)
        return torch.maximum(torch.minimum(v, up), -down)

    def _goto(self, pos: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """Velocity towards ``target`` at up to cruise speed, braking to arrive."""
        gap = target - pos
        dist = gap.norm(p=2, dim=-1, keepdim=True)
        speed = torch.minimum(torch.sqrt(2 * self.approach_brake * dist), torch.full_like(dist, self.cruise))
        return _unit(gap) * torch.minimum(speed, dist / self.dt)

    def forward(self, o: torch.Tensor, desired_goal: torch.Tensor, fresh: torch.Tensor) -> torch.Tensor:
        m = self.m
        n = o.shape[0]
        if self.pushing.shape[0] != n:  # a new batch: every world starts approaching
            self.pushing = torch.zeros(n, dtype=torch.bool, device=o.device)
            self.dir = torch.zeros(n, 2, device=o.device)
            fresh = torch.ones(n, dtype=torch.bool, device=o.device)
        pos = o[:, :2 * m].reshape(n, m, 2)
        vel = o[:, 2 * m:4 * m].reshape(n, m, 2)
        ob = o[:, o.shape[1] - self.object_obs:]
        obj, yaw, ovel = ob[:, :2], torch.atan2(ob[:, 2], ob[:, 3]), ob[:, 4:6]
        goal = desired_goal[:, :2]
        to_goal = goal - obj
        dist = to_goal.norm(p=2, dim=-1)
        # the push direction; while pushing near the goal it is held (it would swing as the object passes the goal)
        d = torch.where((self.pushing & (dist < self.hold_dir))[:, None], self.dir, _unit(to_goal))
        self.dir = d
        side = _perp(d)
        back = self._support(yaw, -d)  # [N]
        rel = pos - obj[:, None]
        u = (rel * d[:, None]).sum(-1)  # [N, M] along the push direction
        lat = (rel * side[:, None]).sum(-1)
        # slots by lateral order: the mover with the k-th smallest lateral position takes slot k
        rank = torch.argsort(torch.argsort(lat, dim=1), dim=1)
        # axis-aligned collision boxes side by side along a diagonal line need more room: max(|dx|, |dy|) >= spacing
        spacing = self.spacing / (side.abs().amax(-1) if self.box else torch.ones_like(dist))
        offset = self.slots[rank] * spacing[:, None]  # [N, M]
        contact = -(back + self.half)[:, None]  # u of a mover touching the object's back
        stage_u = contact - self.standoff
        staging = obj[:, None] + d[:, None] * stage_u[..., None] + side[:, None] * offset[..., None]

        # approach: straight to the staging point, or round the object where the straight way clips it
        v_app = self._goto(pos, staging)
        to_t = staging - pos
        t_star = (-(rel * to_t).sum(-1) / (to_t * to_t).sum(-1).clamp_min(1e-9)).clamp(0.0, 1.0)
        closest = (rel + t_star[..., None] * to_t).norm(p=2, dim=-1)
        r = rel.norm(p=2, dim=-1)
        clips = (closest < self.radius) & (to_t.norm(p=2, dim=-1) > self.tolerance)
        r_hat = _unit(rel)
        stage_rel = staging - obj[:, None]
        sign = torch.sign(rel[..., 0] * stage_rel[..., 1] - rel[..., 1] * stage_rel[..., 0])
        sign = torch.where(sign == 0, torch.ones_like(sign), sign)
        orbit = _perp(r_hat) * sign[..., None] * self.cruise + r_hat * ((self.radius + 0.02 - r) / self.dt)[..., None]
        v_app = torch.where(clips[..., None], clip_norm(orbit, self.cruise), v_app)
        # keep movers apart while approaching
        diff = pos[:, :, None] - pos[:, None]  # [N, M, M, 2]
        gap = (diff.abs().amax(-1) if self.box else diff.norm(p=2, dim=-1)) + torch.eye(m, device=o.device) * 1e3
        near = (self.spacing - 0.004 - gap).clamp_min(0.0)
        v_app = v_app + (_unit(diff) * near[..., None]).sum(2) * (2 / self.dt)
        # and cap each pair's closing speed to what can still brake before their collision shapes touch
        r_hat = _unit(diff)  # from mover j to mover i
        closing = -((v_app[:, :, None] - v_app[:, None]) * r_hat).sum(-1)  # [N, M, M]
        room = (gap - 2 * self.c_half - 0.005).clamp_min(0.0)
        lag = self.approach_brake * self.dt  # one held step of latency
        excess = (closing - torch.sqrt(lag * lag + 2 * self.approach_brake * room) + lag).clamp_min(0.0)
        v_app = v_app + (r_hat * (0.5 * excess)[..., None]).sum(2)

        # push: all movers drive along d, holding their slots and closing up on the object's back
        lined = (((u - stage_u).abs() < self.tolerance) & ((lat - offset).abs() < self.tolerance)
                 & (vel.norm(p=2, dim=-1) < self.cruise * 0.1))
        behind = (u < 0.0) & ((lat - offset).abs() < 2 * self.tolerance)
        rest = obj + ovel * (ovel.norm(p=2, dim=-1, keepdim=True) / (2 * self.decel))
        settled = (rest - goal).norm(p=2, dim=-1) < self.settle
        was = self.pushing & ~fresh  # a new episode starts approaching
        self.pushing = torch.where(was, behind.all(1), lined.all(1))
        speed = torch.sqrt(2 * self.push_brake * (dist - self.stop_at).clamp_min(0.0)).clamp_max(self.push_speed)
        speed = torch.where(settled, torch.zeros_like(speed), speed)
        # lateral first (holding the slots keeps the movers apart), the rest of the acceleration along d
        v_lat = (vel * side[:, None]).sum(-1)
        a_lat = ((offset - lat) * 0.5 / self.dt - v_lat) / self.dt
        # (capped: a mover held sideways by the object's face must not spend its push on that)
        lat_max = self.lateral_share * self.a_max
        a_lat = torch.where(settled[:, None], -v_lat / self.dt, a_lat).clamp(-lat_max, lat_max)
        v_long = torch.where(settled, torch.zeros_like(speed), speed)[:, None]
        room = torch.sqrt((self.a_max ** 2 - a_lat ** 2).clamp_min(0.0))
        a_long = torch.maximum(torch.minimum((v_long - (vel * d[:, None]).sum(-1)) / self.dt, room), -room)
        a_push = d[:, None] * a_long[..., None] + side[:, None] * a_lat[..., None]
        v_app = torch.where((dist < self.settle)[:, None, None], torch.zeros_like(v_app), v_app)
        a_app = clip_norm((self._wall_cap(pos, v_app) - vel) / self.dt, self.a_max)
        acc = torch.where(self.pushing[:, None, None], a_push, a_app)
        return acc.reshape(n, 2 * m)


class CoopPushResidualPolicy(nn.Module):
    """A policy for plain ``magwarp/CoopPush-v0`` observations: the scripted baseline's action plus ``scale`` times a
    residual policy's (one trained on ``magwarp/CoopPushResidual-v0``, whose env adds them the same way), so it acts
    as that policy did in its residual env. It follows the policy-file contract (:mod:`magwarp.training.policy`:
    a goal-dict or the flattened observation in, actions out; ``obs_dim``, ``action_dim``, ``env_id``) but is not a
    pure function of the observation: the baseline keeps its per-world state (push phase, held direction) between
    calls, and a world whose goal changes (or a batch of another size) starts a new episode. So call it once per env
    step, in step order; it has no ``flat`` path (ONNX export would drop that state)."""

    def __init__(self, core: CoopPushCore, residual: nn.Module, scale: float, goal_dim: int, obs_dim: int,
                 action_dim: int, env_id: str = "magwarp/CoopPush-v0"):
        super().__init__()
        self.core = core
        self.residual = residual
        self.scale = float(scale)
        self.goal_dim, self.obs_dim, self.action_dim = int(goal_dim), int(obs_dim), int(action_dim)
        self.env_id = str(env_id)
        self.stateful = True  # magwarp export refuses it (an ONNX graph holds no state)
        self.register_buffer("last_goal", torch.zeros(0, self.goal_dim, device=core.verts.device))

    def forward(self, obs: Union[torch.Tensor, Dict[str, torch.Tensor]]) -> torch.Tensor:
        if isinstance(obs, torch.Tensor):
            flat = obs.to(torch.float32)
        else:
            flat = torch.cat([obs["achieved_goal"], obs["desired_goal"], obs["observation"]], -1).to(torch.float32)
        g = self.goal_dim
        desired, observation = flat[:, g:2 * g], flat[:, 2 * g:]
        if self.last_goal.shape[0] != flat.shape[0]:
            self.last_goal = torch.full_like(desired, float("nan"))  # a new batch: every world starts afresh
        fresh = (desired != self.last_goal).any(-1)
        self.last_goal = desired.clone()
        return self.core(observation, desired, fresh) + self.scale * self.residual(flat)
