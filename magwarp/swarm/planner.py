"""A scripted, decentralised planner for the swarm env: ORCA (optimal reciprocal collision avoidance) on the
local view.

Each mover looks only at what its observation holds (its goal, the ``k`` nearest movers within the observation
radius, the wall rays), so a step costs O(k) per mover, on the device, for any swarm size. Per mover:

1. *preferred velocity*: towards the goal at ``cruise`` speed, slowing so that it can stop on the goal
   (``sqrt(2 a_brake d)``);
2. *reciprocal avoidance*: every neighbour gives one half-plane of allowed velocities, the ORCA line of van den
   Berg et al. (2011) for a time horizon ``horizon`` and the safe distance (both collision shapes' reach, the safety
   margin and a ``buffer`` for the 25 Hz control). The mover of lower index takes ``1 - yield_share`` of the
   avoidance and the other ``yield_share`` (fixed priorities break symmetric deadlocks);
3. *walls*: every wall ray gives a half-plane too: no faster towards the wall than stopping before it allows;
4. the preferred velocity is projected onto the half-planes in turn (``passes`` sweeps over the ``k`` slots and the
   rays: an approximation of ORCA's linear program that costs O(k) tensor operations, whatever the swarm size),
   clipped to ``cruise``, and the command is the acceleration that reaches it within one env step.
"""

from __future__ import annotations

import math

import torch

from magwarp.swarm.env import SwarmEnv
from magwarp.swarm.observations import ray_directions

__all__ = ["SwarmPlanner", "orca_lines"]


def _det(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def orca_lines(rel_pos: torch.Tensor, rel_vel: torch.Tensor, radius: float, horizon: float,
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


def _project(v: torch.Tensor, point: torch.Tensor, direction: torch.Tensor, live: torch.Tensor) -> torch.Tensor:
    """Move ``v`` onto the line where it violates its half-plane (and the line is live)."""
    bad = live & (_det(direction, point - v) > 0)
    on_line = point + ((v - point) * direction).sum(-1, keepdim=True) * direction
    return torch.where(bad[..., None], on_line, v)


class SwarmPlanner:
    """``action = SwarmPlanner(env)()``: x/y accelerations ``[num_envs, num_movers, 2]`` for a :class:`SwarmEnv`
    (acceleration control). See the module docstring for the rule and its parameters."""

    def __init__(self, env: SwarmEnv, *, cruise: float = 1.0, a_brake: float = 4.0, horizon: float = 1.0,
                 buffer: float = 0.06, yield_share: float = 0.5, passes: int = 2):
        if env.learn_jerk:
            raise ValueError("SwarmPlanner commands accelerations: build the env with learn_jerk=False")
        for name, value in (("cruise", cruise), ("a_brake", a_brake), ("horizon", horizon)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")
        if not 0.0 <= yield_share <= 1.0:
            raise ValueError(f"yield_share must be in [0, 1], got {yield_share!r}")
        if int(passes) < 1:
            raise ValueError(f"passes must be >= 1, got {passes!r}")
        self.env = env
        self.cruise, self.a_brake, self.horizon = float(cruise), float(a_brake), float(horizon)
        self.yield_share, self.passes = float(yield_share), int(passes)
        sim = env.sim
        col = sim.model.collision
        reach = float(sim._radii_np.max()) if col.shape == 0 else float(math.hypot(*sim._half_np.max(axis=0)))
        self.safe = 2.0 * (reach + float(col.margin)) + float(buffer)
        self.wall_reach = reach + float(col.wall_margin) + 0.5 * float(buffer)
        self.a_max = float(env.config.a_max)
        self.step_time = env.num_cycles * float(sim.model.limits.dt)
        dev = env.device
        self.rays = torch.as_tensor(ray_directions(max(env.local.num_rays, 1)), dtype=torch.float32, device=dev)
        self.index = torch.arange(env.num_movers, device=dev).view(1, -1, 1)

    def __call__(self, obs=None) -> torch.Tensor:
        env, sim = self.env, self.env.sim
        pos, vel = sim.pos[..., :2], sim.vel[..., :2]
        local = env.local
        # 1. preferred velocity: arrive at the goal
        err = env.goals - pos
        dist = err.norm(dim=-1, keepdim=True).clamp_min(1e-6)
        speed = torch.minimum(torch.full_like(dist, self.cruise), torch.sqrt(2.0 * self.a_brake * dist))
        v = err / dist * speed
        # 2. ORCA lines of the neighbours (relative velocity v_i - v_j = -rel_vel)
        lines = []
        if local.k > 0:
            direction, u = orca_lines(local.rel_pos, -local.rel_vel, self.safe, self.horizon, self.step_time)
            share = torch.where(local.index < self.index, self.yield_share, 1.0 - self.yield_share)
            point = vel[..., None, :] + share[..., None] * u
            lines = [(point[..., s, :], direction[..., s, :], local.mask[..., s]) for s in range(local.k)]
        # 3. wall lines: v . ray <= room / stop time, i.e. the line through room * ray along the ray's normal
        if local.num_rays > 0:
            room = (local.walls - self.wall_reach).clamp_min(0.0)
            limit = torch.sqrt(2.0 * self.a_brake * room)  # fastest approach that can still stop in time
            for r in range(local.num_rays):
                ray = self.rays[r]
                normal_dir = torch.stack([-ray[1], ray[0]]).expand_as(v)  # det(dir, point - v) <= 0 <=> v.ray <= lim
                lines.append((limit[..., r, None] * ray, normal_dir, torch.ones_like(room[..., r], dtype=torch.bool)))
        for _ in range(self.passes):
            for point, direction, live in lines:
                v = _project(v, point, direction, live)
        n = v.norm(dim=-1, keepdim=True)
        v = torch.where(n > self.cruise, v * (self.cruise / n.clamp_min(1e-9)), v)
        # 4. the acceleration that reaches v within one env step, within the limit
        acc = (v - vel) / self.step_time
        n = acc.norm(dim=-1, keepdim=True)
        return torch.where(n > self.a_max, acc * (self.a_max / n.clamp_min(1e-9)), acc)
