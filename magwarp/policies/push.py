"""A scripted push-behind-the-object heuristic for the pushing tasks (a baseline, no learning).

Per world, mover 0 does the pushing (other movers hold still):

* **approach**: fly straight to a staging point behind the object on the object-to-goal line, braking so that it
  arrives with a little push speed; while that straight segment would clip the object, go around the object on a
  circle at a small clearance instead (the shorter way unless it leaves the safe region);
* **push**: inside a narrow cone behind the object, drive along the goal line with a speed profile that brakes
  below the box's friction deceleration (the box stays against the mover and stops at the goal), steering
  sideways back onto the line through the object's centre;
* **settle**: once the object is well inside the success threshold, hold still (near the goal the push direction
  turns erratic, and chasing it pushes the object out again).

Contact distances use the exact support of the (rotated) object parts and of the mover's square footprint. Speeds
toward the sides of the safe rectangle (where the wall-collision shape stays on the tiles) are capped to what can
still brake, and that braking has priority in the acceleration (layouts with holes are only approximated by their
bounding rectangle). The desired velocity becomes an acceleration through a deadbeat velocity loop over one held
env step. Batched torch on the env's device, no Python loop over worlds; pose goals (Push-T/L/X) are pushed as
position goals.
"""

from __future__ import annotations

import numpy as np
import torch

__all__ = ["PushHeuristic"]


def _unit(v: torch.Tensor) -> torch.Tensor:
    return v / v.norm(dim=-1, keepdim=True).clamp_min(1e-9)


def _perp(v: torch.Tensor) -> torch.Tensor:
    return torch.stack([-v[..., 1], v[..., 0]], dim=-1)


class PushHeuristic:
    """``policy(obs) -> action`` for a :class:`~magwarp.envs.push.PushEnv` (batched, torch in and out).

    Args:
        env: the batched push env (layout, object, mover sizes and limits are read from it).
        cruise: top speed (m/s) while approaching; push_speed: top speed while pushing.
        push_brake: deceleration (m/s^2) planned while pushing (below the box's friction deceleration, ~6 m/s^2).
        approach_brake: deceleration (m/s^2) planned when arriving at points and before the sides of the area.
        clearance: gap (m) kept between mover and object while going around it.
        engage: fraction of the push speed the mover already has when it reaches the staging point.
        cone: lateral tolerance (per metre of gap) of the cone behind the object in which it pushes.
        settle: the mover holds still once the object is within this fraction of the success threshold.
        stop_at: distance (m) short of the goal at which the planned push speed reaches zero.
    """

    def __init__(self, env, cruise: float = 1.8, push_speed: float = 2.0, push_brake: float = 5.0,
                 approach_brake: float = 5.0, clearance: float = 0.008, engage: float = 0.5,
                 cone: float = 0.3, settle: float = 0.8, stop_at: float = 0.005):
        self.env = env
        self.backend = env.backend
        self.cruise, self.push_speed = cruise, push_speed
        self.push_brake, self.approach_brake = push_brake, approach_brake
        self.clearance = clearance
        self.engage, self.cone, self.settle, self.stop_at = engage, cone, settle, stop_at
        c = self.backend.control
        self.latency = c.num_cycles * self.backend.dt  # one held env step
        self.a_max, self.v_max = c.a_max, c.v_max
        dev = env.device
        obj = env.object
        if obj.shape == "cylinder":
            self._parts = None
            self._radius = float(obj.radius)
        else:
            self._parts = torch.as_tensor(np.asarray(obj.rects(), np.float32), device=dev)  # (K, 4) cx, cy, hx, hy
        self._mover_half = float(0.5 * env.mover.size[0])
        # Where the mover's wall-collision footprint stays on the tiles (full rectangles; others are approximated).
        reach = env.mover.bounding_radius(env.mover.wall_margin) + 0.01
        ext = np.asarray(env.layout.extent, np.float32)
        self._lo = torch.full((2,), reach, device=dev)
        self._hi = torch.as_tensor(ext - reach, device=dev)
        self._way = torch.zeros(env.num_envs, 1, device=dev)  # per world: direction around the object (0: none)

    def _object_support(self, yaw: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
        """Extent of the object (yaw ``[N]``) along unit directions ``w`` ``[N, 2]`` from its centre."""
        if self._parts is None:
            return torch.full(w.shape[:-1], self._radius, device=w.device)
        c, s = torch.cos(yaw)[:, None], torch.sin(yaw)[:, None]  # (N, 1)
        p = self._parts
        cx = c * p[:, 0] - s * p[:, 1]  # part centres in the world frame (N, K)
        cy = s * p[:, 0] + c * p[:, 1]
        wx, wy = w[:, 0:1], w[:, 1:2]
        along_x = (wx * c + wy * s).abs()  # |w . body x|
        along_y = (-wx * s + wy * c).abs()
        return (cx * wx + cy * wy + p[:, 2] * along_x + p[:, 3] * along_y).amax(dim=1)

    def _mover_support(self, w: torch.Tensor) -> torch.Tensor:
        return self._mover_half * (w[..., 0].abs() + w[..., 1].abs())

    def _profile(self, gap: torch.Tensor) -> torch.Tensor:
        """Speed from which the mover still stops within ``gap`` (m), with one held step of latency."""
        bl = self.approach_brake * self.latency
        return -bl + torch.sqrt(bl * bl + 2 * self.approach_brake * gap)

    def _wall_limit(self, pos: torch.Tensor, vel: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        """Cap the speed toward each side of the safe region to what can still brake before it (per axis), from
        where the mover will be after one held step."""
        ahead = pos + vel * self.latency
        room_lo = (ahead - self._lo).clamp_min(0.0)
        room_hi = (self._hi - ahead).clamp_min(0.0)
        v = torch.maximum(v, -torch.sqrt(2 * self.approach_brake * room_lo))
        return torch.minimum(v, torch.sqrt(2 * self.approach_brake * room_hi))

    def _clip(self, acc: torch.Tensor) -> torch.Tensor:
        nrm = acc.norm(dim=-1, keepdim=True)
        return torch.where(nrm > self.a_max, acc * (self.a_max / nrm.clamp_min(1e-9)), acc)

    def _wall_brake(self, pos: torch.Tensor, vel: torch.Tensor, acc: torch.Tensor) -> torch.Tensor:
        """Braking toward a wall takes priority over the rest of the command (the norm clip would dilute it)."""
        ahead = pos + vel * self.latency
        v_lo = -torch.sqrt(2 * self.approach_brake * (ahead - self._lo).clamp_min(0.0))
        v_hi = torch.sqrt(2 * self.approach_brake * (self._hi - ahead).clamp_min(0.0))
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

    def __call__(self, obs=None) -> torch.Tensor:
        b, env = self.backend, self.env
        q = b.mover_qpos
        pos, vel = q[:, 0, :2], b.mover_qvel[:, 0, :2]
        oq = b.object_qpos[:, 0]
        obj, obj_vel = oq[:, :2], b.object_qvel[:, 0, :2]
        w, x, y, z = oq[:, 3], oq[:, 4], oq[:, 5], oq[:, 6]
        yaw = torch.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        to_goal = env.goal_xy - obj
        dist = to_goal.norm(dim=-1, keepdim=True)
        u = _unit(to_goal)
        n = _perp(u)

        rel = pos - obj
        r = rel.norm(dim=-1, keepdim=True).clamp_min(1e-6)
        e_r = rel / r
        along = (rel * u).sum(-1, keepdim=True)  # < 0: behind the object
        lateral = (rel * n).sum(-1, keepdim=True)
        contact_u = (self._object_support(yaw, -u) + self._mover_support(u))[:, None]
        gap = (-along - contact_u).clamp_min(0.0)

        # Push: inside a narrow cone behind the object, drive along the goal line (speed planned over the gap and
        # the object's way to the goal, braking below its friction deceleration) and steer onto the line.
        # (contact_u is the support sum: an upper bound of the touching distance when u is off the face normals,
        # so the cone does not end there; it would flip between pushing and backing off to the staging point)
        cone = (along < -0.5 * contact_u) & (lateral.abs() < 0.015 + self.cone * gap)
        speed = torch.sqrt(2 * self.push_brake * (dist + gap - self.stop_at).clamp_min(0.0)).clamp(max=self.push_speed)
        v_push = u * speed - n * (lateral * 15.0).clamp(-self.cruise, self.cruise)

        # Direct approach: straight to the staging point behind the object, arriving with a little push speed.
        stage = obj - u * (contact_u + self.clearance)
        d = stage - pos
        dn = d.norm(dim=-1, keepdim=True)
        engage = self.engage * speed * (1.0 - dn / 0.05).clamp(0.0, 1.0)
        v_direct = _unit(d) * self._profile(dn).clamp(max=self.cruise) + u * engage
        # ... unless that segment passes the object: then go around it on a circle at a clearance.
        t = ((obj - pos) * d).sum(-1, keepdim=True) / (dn * dn).clamp_min(1e-9)
        closest = pos + t.clamp(0.0, 1.0) * d
        keep_out = (self._object_support(yaw, _unit(closest - obj)) + self._mover_support(_unit(closest - obj)))[:, None]
        blocked = (closest - obj).norm(dim=-1, keepdim=True) < keep_out + 0.5 * self.clearance

        e_t = _perp(e_r)  # counter-clockwise
        theta = torch.atan2(e_r[:, 1], e_r[:, 0])
        theta_push = torch.atan2(-u[:, 1], -u[:, 0])
        err = torch.remainder(theta - theta_push + torch.pi, 2 * torch.pi)[:, None] - torch.pi
        contact = (self._object_support(yaw, e_r) + self._mover_support(e_r))[:, None]
        r_des = contact + self.clearance
        dr = r_des - r
        v_rad = e_r * torch.sign(dr) * self._profile(dr.abs()).clamp(max=self.cruise)
        # Keep the way round once chosen: in front of the object the shorter arc flips with every step.
        sign = self._orbit_sign(obj, theta, err, r_des)
        sign = torch.where(blocked & (self._way != 0), self._way, sign)
        self._way = torch.where(blocked, sign, torch.zeros_like(sign))
        v_orbit = obj_vel + v_rad + e_t * sign * self._profile(err.abs() * r).clamp(max=self.cruise)

        v = torch.where(cone, v_push, torch.where(blocked, v_orbit, v_direct))
        # Near the goal the push direction turns erratic: hold still there (MagBotSim scores the final state).
        v = torch.where(dist < self.settle * env.max_position_err, torch.zeros_like(v), v)
        v = self._wall_limit(pos, vel, v)
        acc = self._wall_brake(pos, vel, self._clip((v - vel) / self.latency))
        out = torch.zeros(env.num_envs, env.num_movers, 2, device=env.device)
        out[:, 0] = acc
        if env.num_movers > 1:  # helpers hold still
            out[:, 1:] = (-b.mover_qvel[:, 1:, :2] / self.latency).clamp(-self.a_max, self.a_max)
        return out.reshape(env.num_envs, -1)
