"""A scripted, collision-aware goal-seeking planner for trajectory planning (a baseline, no learning).

Each mover flies toward its goal on a braking velocity profile; movers closer than a safety distance push each other
apart, with the lower-index mover keeping priority (the other yields sideways), and a repulsive field keeps the
footprint away from the edges of the tiled area. The desired velocity becomes an acceleration command through a
velocity loop. All of it is batched torch on the env's device: no Python loop over envs or movers.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from magwarp.envs.trajectory import TrajectoryPlanningEnv


class GoalSeekingPlanner:
    """``planner(obs) -> action`` for a :class:`TrajectoryPlanningEnv` (batched, torch in and out).

    Args:
        env: the batched env (the planner reads layout, limits and collision sizes from it).
        cruise_speed: top planning speed (m/s); brake: deceleration (m/s^2) assumed for stopping distances.
        buffer: extra distance (m) kept between collision shapes and to the walls.
        horizon: gap (m) under which a yielding mover starts to sidestep, at speed ``sidestep`` (m/s).
        leader_share: the part of a conflict's speed correction the higher-priority mover takes (1: as much as the
            yielding one: fewer collisions, more deadlocks).
    """

    def __init__(self, env: TrajectoryPlanningEnv, cruise_speed: float = 1.2, brake: float = 5.0,
                 buffer: float = 0.015, horizon: float = 0.15, sidestep: float = 0.25, leader_share: float = 0.35, wall_resolution: float = 0.005):
        self.env = env
        self.sim = env.sim
        self.cruise = cruise_speed
        self.brake = brake
        self.buffer = buffer
        self.horizon = horizon
        lim = self.sim.model.limits
        self.latency = env.num_cycles * lim.dt  # the action is held for one env step
        self.gain = 1.0 / self.latency  # deadbeat velocity loop over one held step
        self.a_max = lim.a_max
        self.v_max = lim.v_max
        self.sidestep = sidestep
        self.leader_share = leader_share
        self._scales = torch.tensor([1.0, 0.8, 0.6, 0.45, 0.3, 0.2, 0.1], device=env.device)
        self.reach = float(self.sim._radii_np.max()) if self.sim.mover.collision_shape == "circle" else float(
            (self.sim._half_np ** 2).sum(axis=1).max() ** 0.5)
        self._build_wall_field(wall_resolution)

    def _build_wall_field(self, res: float) -> None:
        """Distance (m) from each point to the nearest point off the tiles, on a grid, and its gradient."""
        import numpy as np
        from scipy import ndimage

        lay = self.env.layout
        ext = lay.extent
        nx, ny = int(round(ext[0] / res)), int(round(ext[1] / res))
        pad = 10
        xs = (np.arange(-pad, nx + pad) + 0.5) * res
        ys = (np.arange(-pad, ny + pad) + 0.5) * res
        X, Y = np.meshgrid(xs, ys, indexing="ij")
        on = lay.on_tiles(np.stack([X, Y], axis=-1))
        dist = ndimage.distance_transform_edt(on) * res
        gx, gy = np.gradient(dist, res)
        self._field = torch.tensor(np.stack([dist, gx, gy]), dtype=torch.float32, device=self.env.device)[None]
        self._origin = -pad * res
        self._size = (len(xs) * res, len(ys) * res)

    def _sample_field(self, xy: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        n, m, _ = xy.shape
        gx = (xy[..., 0] - self._origin) / self._size[0] * 2 - 1
        gy = (xy[..., 1] - self._origin) / self._size[1] * 2 - 1
        grid = torch.stack([gy, gx], dim=-1).reshape(1, n * m, 1, 2)  # grid_sample: (x -> last dim = W = our y)
        out = F.grid_sample(self._field, grid, align_corners=False, padding_mode="border").reshape(3, n, m)
        return out[0], out[1:].permute(1, 2, 0)

    def _allowed_closing(self, gap: torch.Tensor) -> torch.Tensor:
        """Closing speed from which the mover still stops within ``gap``, with one policy step of latency."""
        g = gap.clamp_min(0.0)
        lat = self.latency
        return (-self.brake * lat + torch.sqrt((self.brake * lat) ** 2 + 2 * self.brake * g)).clamp_min(0.0)

    def _limit_walls(self, pos: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        """Remove the part of the speed toward the nearest edge that could no longer brake before it."""
        w_dist, w_grad = self._sample_field(pos)
        n_in = w_grad / w_grad.norm(dim=-1, keepdim=True).clamp_min(1e-6)
        toward = -(v * n_in).sum(-1)
        excess = (toward - self._allowed_closing(w_dist - self.reach - self.buffer)).clamp_min(0.0)
        return v + excess.unsqueeze(-1) * n_in

    def _stop_point(self, pos: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        return pos + v * self.latency + v * v.norm(dim=-1, keepdim=True) / (2 * self.brake)

    def _safe_scale(self, pos: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        """Largest of a few speed scales whose stopping point keeps the footprint off the walls (0 if none)."""
        scales = self._scales
        cand = v.unsqueeze(2) * scales.view(1, 1, -1, 1)  # (N, M, S, 2)
        stops = self._stop_point(pos.unsqueeze(2), cand)
        n, m, k, _ = stops.shape
        d, _ = self._sample_field(stops.reshape(n, m * k, 2))
        ok = d.reshape(n, m, k) >= self.reach + self.buffer
        return torch.where(ok, scales.view(1, 1, -1), torch.zeros_like(scales).view(1, 1, -1)).amax(dim=-1)

    def __call__(self, obs=None) -> torch.Tensor:
        sim, env = self.sim, self.env
        pos = sim.pos[..., :2]
        vel = sim.vel[..., :2]
        m = pos.shape[1]

        # Target: the goal, pulled inward where it lies closer to an edge than the footprint plus a buffer allows
        # (the goal only has to be reached within threshold_pos).
        goal = env.goals
        g_dist, g_grad = self._sample_field(goal)
        g_norm = g_grad / g_grad.norm(dim=-1, keepdim=True).clamp_min(1e-6)
        pull = (self.reach + self.buffer - g_dist).clamp(0.0, 0.5 * env.threshold_pos).unsqueeze(-1)
        target = goal + g_norm * pull
        to_goal = target - pos
        dist = to_goal.norm(dim=-1, keepdim=True).clamp_min(1e-6)
        speed = torch.minimum(torch.full_like(dist, self.cruise), self._allowed_closing(dist - 0.01) + 0.05)
        v = to_goal / dist * speed

        # Mover-mover: limit each pair's closing speed to what can still brake before the shapes meet. The higher
        # index yields (takes the whole correction and sidesteps when close); the lower index takes a share.
        d = pos.unsqueeze(2) - pos.unsqueeze(1)  # (N, i, j, 2) = p_i - p_j
        dn = d.norm(dim=-1).clamp_min(1e-6)
        u = d / dn.unsqueeze(-1)  # from j toward i
        gap = dn - 2 * self.reach - self.buffer
        idx = torch.arange(m, device=pos.device)
        lower = idx.view(m, 1) > idx.view(1, m)  # i yields to j
        share = torch.where(lower, 1.0, self.leader_share) * (idx.view(m, 1) != idx.view(1, m))
        side = torch.stack([-u[..., 1], u[..., 0]], dim=-1)
        near = ((gap < self.horizon) & lower).float().unsqueeze(-1)
        for _ in range(2):  # two passes settle most three-body conflicts
            closing = -((v.unsqueeze(2) - v.unsqueeze(1)) * u).sum(-1)  # > 0: i and j approach
            excess = (closing - self._allowed_closing(gap)).clamp_min(0.0)
            v = v + ((excess * share).unsqueeze(-1) * u).sum(2) + (near * side).sum(2) * self.sidestep

        # Walls: the same limit against the nearest edge, then the largest speed scale whose stopping point (one
        # held step plus braking) keeps the footprint off every edge, corners included.
        v = self._limit_walls(pos, v)
        v = v * self._safe_scale(pos, v).unsqueeze(-1)

        vn = v.norm(dim=-1, keepdim=True)
        v = torch.where(vn > self.v_max, v * (self.v_max / vn.clamp_min(1e-9)), v)
        acc = (v - vel) * self.gain
        n = acc.norm(dim=-1, keepdim=True)
        acc = torch.where(n > self.a_max, acc * (self.a_max / n.clamp_min(1e-9)), acc)
        return acc.reshape(env.num_envs, -1)
