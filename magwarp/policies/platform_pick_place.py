"""Scripted baseline for :class:`magwarp.envs.platform_pick_place.PlatformPickPlaceEnv`: waypoints per phase.

A state machine per world (batched tensors, no loop over worlds) picks the waypoint; a
:class:`~magwarp.policies.platform.CarrotTracker` with an acceleration limit (so the product does not slip) drives the
platform there through the IK. Phases, each left when the platform is within ``tolerance`` of its waypoint:

0. approach: in front of the rack, level, at the dock height, aligned with the product in x;
1. dock: under the product;
2. lift: up to the lift height (the product leaves the rails);
3. retreat: back out in front of the rack;
4. carry: to the container's edge (``env.drop_y``);
5. tilt: roll toward the container until the product has slid off and the next one is on the rack, then back to 0.

In phases 3 and 4 a product that is no longer on the plate (dropped) sends the world back to phase 0.
"""

from __future__ import annotations

import torch

from magwarp.policies.platform import CarrotTracker

__all__ = ["PickPlacePolicy"]

APPROACH, DOCK, LIFT, RETREAT, CARRY, TILT = range(6)


class PickPlacePolicy:
    """``policy(obs=None) -> action`` for a :class:`PlatformPickPlaceEnv` (either action mode).

    :param approach: distance (m, +y) of the approach point in front of the product on the rack.
    :param tilt: roll at the container as a fraction of the platform's tilt limit.
    """

    def __init__(self, env, *, approach: float = 0.2, tilt: float = 0.85, tolerance: float = 0.006,
                 carrot_step=(0.008, 0.008, 0.004, 0.015, 0.015, 0.05),
                 carrot_change=(0.0012, 0.0012, 0.001, 0.003, 0.003, 0.01)):
        self.env = env
        self.approach, self.tilt, self.tolerance = float(approach), float(tilt), float(tolerance)
        if not 0.0 < self.tilt <= 1.0:
            raise ValueError(f"tilt must lie in (0, 1], got {tilt!r}")
        self.tracker = CarrotTracker(env, carrot_step, carrot_change)
        self.phase = torch.zeros(env.num_envs, dtype=torch.int64, device=env.device)
        self.anchor = torch.zeros(env.num_envs, 2, device=env.device)  # the product's xy on the rack, latched
        s = env.scene
        self.dock_z, self.lift_z = s.dock_height, s.lift_height
        self.rest_z = s.rail_height + s.product.depth

    def _waypoints(self, product: torch.Tensor) -> torch.Tensor:
        """``[W, 6, 6]``: the waypoint of every phase for every world (from the lift on, at the product's xy when
        it was docked: it moves with the plate then)."""
        env = self.env
        n, dev = env.num_envs, env.device
        w = torch.zeros(n, 6, 6, device=dev)
        front = env.supply[1] + self.approach
        w[:, APPROACH, 0], w[:, APPROACH, 1], w[:, APPROACH, 2] = product[:, 0], front, self.dock_z
        w[:, DOCK, 0], w[:, DOCK, 1], w[:, DOCK, 2] = product[:, 0], product[:, 1], self.dock_z
        w[:, LIFT, 0], w[:, LIFT, 1], w[:, LIFT, 2] = self.anchor[:, 0], self.anchor[:, 1], self.lift_z
        w[:, RETREAT] = w[:, LIFT]
        w[:, RETREAT, 1] = front
        w[:, CARRY, 0], w[:, CARRY, 1], w[:, CARRY, 2] = env.container[0], env.drop_y, self.lift_z
        w[:, TILT] = w[:, CARRY]
        w[:, TILT, 3] = -self.tilt * env.geometry.max_tilt
        return w

    def __call__(self, obs=None) -> torch.Tensor:
        env = self.env
        fresh = env.num_steps == 0
        self.phase.masked_fill_(fresh, APPROACH)
        product, _ = env.product_pose()
        product = product.float()
        pose = env.platform_pose()
        rel = product - pose[:, :3]
        on_plate = (rel[:, :2].abs().amax(-1) < 0.1) & (rel[:, 2] > 0.0) & (rel[:, 2] < 0.05)
        at_supply = ((product[:, :2] - env.supply[:2]).norm(dim=-1) < 0.03) & (product[:, 2] < self.rest_z + 0.005)
        self.anchor = torch.where((self.phase <= DOCK)[:, None], product[:, :2], self.anchor)
        ways = self._waypoints(product)
        goal = ways.gather(1, self.phase[:, None, None].expand(-1, 1, 6))[:, 0]
        err = (goal - pose).abs()
        reached = (err[:, :3].amax(-1) <= self.tolerance) & (err[:, 3:5].amax(-1) <= 0.02)
        nxt = torch.where(reached & (self.phase < TILT), self.phase + 1, self.phase)
        nxt = torch.where((self.phase == TILT) & at_supply, APPROACH, nxt)
        nxt = torch.where(((self.phase == RETREAT) | (self.phase == CARRY)) & ~on_plate, APPROACH, nxt)
        changed = nxt != self.phase
        self.phase = nxt
        goal = torch.where(changed[:, None], ways.gather(1, nxt[:, None, None].expand(-1, 1, 6))[:, 0], goal)
        return self.tracker(goal, fresh)
