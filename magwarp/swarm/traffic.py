"""Traffic rules for the swarm planner: a Manhattan grid of one-way lanes (preferred velocities only).

Without rules, movers of a dense swarm with random goals head straight for their goals, the straight paths cross
near the middle of the layout from every direction, and the crowd packs there into a still blob that grows as movers
arrive (1024 movers on 64 x 64 tiles: 56% of the first goals reached in 40 s, ``benchmarks/swarm.py``). The lanes give
the traffic a structure: lines every ``pitch`` tiles along x and along y, their directions alternating (the lanes
along x at ``y = (k + 1/2) pitch`` head +x for even ``k`` and -x for odd ``k``; the lanes along y likewise +y / -y).
Movers on one lane all head the same way (no head-on meetings), lanes of opposite directions are ``pitch`` apart,
and flows meet only at right angles where lanes cross.

A mover's route has two legs, along x then along y or along y then along x: of the two, the one whose corner
lies farther out from the middle of the layout (``outer=True``; the middle is where the routes of random goals cross
most: 1024 movers on 64 x 64 tiles, lanes every 4 tiles, reached 95.1% / 94.8% of their first goals in 40 s with
this choice, seeds 0 / 1; with lanes every 3 tiles 95.1% / 93.6%, and 90% along x first always). Its preferred velocity, from the mover's position ``p`` and goal ``g`` alone (no state, so a mover pushed
off its route by the avoidance rules picks it up again; a route re-chosen on the way still heads for the goal),
here for the route along x first (along y first: the same with x and y swapped):

* *final approach* (``|g - p| <= final``, or within ``final`` of the goal's row and between the goal's column lane
  and the goal): straight at the goal, slowing so that it stops there (``sqrt(2 a_brake d)``);
* *along y* (within ``turn_tol`` of ``x_v``, the lane along y that heads towards ``g_y`` nearest to ``g_x``): along
  that lane towards the goal's row, slowing as it nears it (``sqrt(2 a_turn d) + 0.3`` m/s), pulled onto the lane;
* *along x* (else): along the nearest lane that heads towards ``x_v`` (merging onto it, pulled by ``gain`` /s),
  slowing for the turn onto ``x_v``.

Speeds are at most ``cruise``. O(1) per mover: a few tensor operations on ``[..., 2]`` positions.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from magwarp._vectors import clip_norm
from magwarp.layout import Layout

__all__ = ["LaneField", "lanes_fit"]

TURN_SPEED = 0.3  # m/s: the speed left at a turn (the slow-down profile's floor)


def lanes_fit(layout: Layout, pitch: int) -> bool:
    """Whether the lanes of ``pitch`` tiles fit ``layout``: no holes (a lane would run into them) and at least two
    lanes along x and two along y (one each way)."""
    if isinstance(pitch, bool) or not isinstance(pitch, (int, np.integer)) or pitch < 1:
        raise ValueError(f"lane pitch must be an integer >= 1 (tiles), got {pitch!r}")
    tiles = np.asarray(layout.tiles)
    return bool(tiles.all()) and min(tiles.shape) >= 2 * pitch


def _nearest_lane(coord: torch.Tensor, sign: torch.Tensor, pitch: float, count: int) -> torch.Tensor:
    """The coordinate of the lane heading ``sign`` (+1: even lanes, -1: odd lanes) nearest to ``coord``."""
    odd = (sign < 0).to(coord.dtype)
    m = torch.round((coord / pitch - 0.5 - odd) / 2.0)
    top = torch.floor((count - 1 - odd) / 2.0)
    m = torch.minimum(m.clamp_min(0.0), top)
    return (2.0 * m + odd + 0.5) * pitch


class LaneField:
    """Preferred velocities on the one-way lanes of the module docstring: ``LaneField(layout, cruise)(pos, goal)``
    with ``pos``, ``goal`` ``[..., 2]`` (m). ``pitch``: tiles between neighbouring lanes (>= 1); ``a_brake``,
    ``a_turn`` (m/s^2): slowing for the goal and for turns; ``final``, ``turn_tol`` (m); ``gain`` (1/s): the pull
    onto a lane; ``outer``: choose the route by its corner (else always along x first)."""

    def __init__(self, layout: Layout, cruise: float, *, pitch: int = 4, a_brake: float = 4.0, a_turn: float = 6.0,
                 final: float = 0.5, turn_tol: float = 0.15, gain: float = 4.0, outer: bool = True):
        for name, value in (("cruise", cruise), ("a_brake", a_brake), ("a_turn", a_turn), ("final", final),
                            ("turn_tol", turn_tol), ("gain", gain)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")
        if not lanes_fit(layout, pitch):
            raise ValueError(f"lanes every {pitch} tiles need a layout without holes and at least {2 * pitch} tiles "
                             f"per side, got {np.asarray(layout.tiles).shape} tiles"
                             f"{'' if np.asarray(layout.tiles).all() else ' with holes'}")
        self.pitch = int(pitch) * float(layout.tile.size)  # m
        self.lanes_x, self.lanes_y = (int(n) // int(pitch) for n in np.asarray(layout.tiles).shape)
        self.cruise, self.a_brake, self.a_turn = float(cruise), float(a_brake), float(a_turn)
        self.final, self.turn_tol, self.gain = float(final), float(turn_tol), float(gain)
        self.outer = bool(outer)
        self.centre = tuple(0.5 * n * float(layout.tile.size) for n in np.asarray(layout.tiles).shape)

    def _route(self, pos: torch.Tensor, goal: torch.Tensor, lanes_x: int, lanes_y: int
               ) -> tuple[torch.Tensor, torch.Tensor]:
        """The x-first route (along a lane along x, then along ``x_v``): the preferred velocity and the route's
        corner ``(x_v, p_y)``. The y-first route is this one on swapped coordinates (the lane pattern is symmetric
        under the swap)."""
        d = goal - pos
        sy = torch.where(d[..., 1] >= 0, 1.0, -1.0)
        xv = _nearest_lane(goal[..., 0], sy, self.pitch, lanes_x)  # the lane along y heading to g_y nearest to g_x
        ex = xv - pos[..., 0]
        sx = torch.where(ex >= 0, 1.0, -1.0)
        yh = _nearest_lane(pos[..., 1], sx, self.pitch, lanes_y)  # the lane along x heading to x_v nearest to p_y
        cruise = self.cruise
        along_x = torch.stack([sx * self._slow(ex), (self.gain * (yh - pos[..., 1])).clamp(-cruise, cruise)], -1)
        along_y = torch.stack([(self.gain * ex).clamp(-cruise, cruise), sy * self._slow(d[..., 1])], -1)
        on_column = ex.abs() <= self.turn_tol
        v = torch.where(on_column[..., None], along_y, along_x)
        v = clip_norm(v, cruise)
        # final approach: near the goal, or at its row between its column lane and the goal
        dist = d.norm(dim=-1, keepdim=True).clamp_min(1e-9)
        direct = d / dist * torch.sqrt(2.0 * self.a_brake * dist).clamp_max(cruise)
        px, gx = pos[..., 0], goal[..., 0]
        between = (px >= torch.minimum(xv, gx) - self.turn_tol) & (px <= torch.maximum(xv, gx) + self.turn_tol)
        final = (dist[..., 0] <= self.final) | ((d[..., 1].abs() <= self.final) & between)
        return torch.where(final[..., None], direct, v), torch.stack([xv, pos[..., 1]], -1)

    def _slow(self, d: torch.Tensor) -> torch.Tensor:
        return (torch.sqrt(2.0 * self.a_turn * d.abs()) + TURN_SPEED).clamp_max(self.cruise)

    def __call__(self, pos: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        v_x, corner_x = self._route(pos, goal, self.lanes_x, self.lanes_y)
        if not self.outer:
            return v_x
        v_y, corner_y = self._route(pos.flip(-1), goal.flip(-1), self.lanes_y, self.lanes_x)
        # the route whose corner lies farther out from the middle of the layout (max-norm, in tiles of the layout's
        # half sizes): routes keep off the middle, where every route would cross
        centre = pos.new_tensor(self.centre)
        out_x = ((corner_x - centre) / centre).abs().amax(-1)
        out_y = ((corner_y.flip(-1) - centre) / centre).abs().amax(-1)
        return torch.where((out_x >= out_y)[..., None], v_x, v_y.flip(-1))
