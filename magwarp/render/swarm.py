"""Top-down views of big swarms (1000+ movers per world): a whole-world overview and zoomed windows.

* :func:`fit_px_per_tile`: the resolution at which a mosaic of whole worlds (or of windows) fits ``max_image_px``;
* :func:`swarm_renderer`: a :class:`~magwarp.render.TopDownRenderer` for that view: under 12 pixels per tile the
  movers are dots of at least 2 x 2 pixels, coloured by state, with no safety zones, headings, goals or grid (which
  would blur into each other); from 12 pixels per tile on, safety zones and headings are drawn, and goals from 24
  on (zoomed windows);
* :func:`mover_states`: each mover's state (the index into :data:`~magwarp.render.colors.STATE_PALETTE`), computed
  on the device from plain tensors: waiting for a respawn, collided this step, carrying a job, idle (slow and away
  from its goal), else moving.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from magwarp.layout import Layout, MoverSpec
from magwarp.render.topdown import TopDownRenderer

__all__ = ["DETAIL_PX_PER_TILE", "GOALS_PX_PER_TILE", "fit_px_per_tile", "mover_states", "swarm_renderer"]

DETAIL_PX_PER_TILE = 12  # from here on, safety zones and headings are drawn
GOALS_PX_PER_TILE = 24  # from here on, goals too
MAX_PX_PER_TILE = 48
MOVING, IDLE, COLLIDED, CARRYING, WAITING = range(5)


def fit_px_per_tile(layout: Layout, num_worlds: int = 1, window: Sequence[float] | None = None,
                    max_image_px: int = 1024) -> int:
    """The largest resolution (1 to 48 pixels per tile) at which ``num_worlds`` worlds (or their ``window``s,
    ``(cx, cy, width, height)`` m) fit a square mosaic whose longest side is at most ``max_image_px`` (views wider
    than ``max_image_px`` tiles get 1 pixel per tile, and a bigger image)."""
    if isinstance(max_image_px, bool) or int(max_image_px) != max_image_px or max_image_px < 16:
        raise ValueError(f"max_image_px must be an integer >= 16, got {max_image_px!r}")
    cols = math.ceil(math.sqrt(num_worlds))
    rows = math.ceil(num_worlds / cols)
    if window is None:
        ex, ey = layout.shape
    else:
        ex, ey = (float(window[2]) / layout.tile.size, float(window[3]) / layout.tile.size)
    fit = int(max_image_px) / max(cols * ex, rows * ey)
    return int(min(MAX_PX_PER_TILE, max(1, math.floor(fit))))


def swarm_renderer(layout: Layout, mover: MoverSpec, *, worlds=1, window=None, px_per_tile: int | None = None,
                   max_image_px: int = 1024, device=None) -> tuple[TopDownRenderer, bool]:
    """The renderer of a swarm view and whether goals are worth drawing at its resolution: see the module."""
    n = int(worlds) if isinstance(worlds, int) else len(worlds)
    if px_per_tile is None:
        px_per_tile = fit_px_per_tile(layout, n, window, max_image_px)
    elif isinstance(px_per_tile, bool) or int(px_per_tile) != px_per_tile or px_per_tile < 1:
        raise ValueError(f"px_per_tile must be an integer >= 1, got {px_per_tile!r}")
    detail = px_per_tile >= DETAIL_PX_PER_TILE
    renderer = TopDownRenderer(layout, mover, worlds=worlds, px_per_tile=int(px_per_tile), window=window,
                               grid=px_per_tile >= 8, safety_zone=detail, heading=detail, goal_lines=False,
                               border_px=2 if n > 1 else 0, device=device)
    return renderer, px_per_tile >= GOALS_PX_PER_TILE


def mover_states(vel: torch.Tensor, pos: torch.Tensor, goals: torch.Tensor, collided: torch.Tensor,
                 carrying: torch.Tensor | None, waiting: torch.Tensor, threshold: float,
                 idle_speed: float = 0.05) -> torch.Tensor:
    """``int32 [W, M]`` states (see the module) from velocities and positions ``[W, M, >=2]``, goals ``[W, M, 2]``
    and bool ``[W, M]`` flags (``carrying`` None: no jobs)."""
    speed = vel[..., :2].norm(dim=-1)
    away = (goals - pos[..., :2]).norm(dim=-1) > threshold
    state = torch.where((speed < idle_speed) & away, IDLE, MOVING)
    if carrying is not None:
        state = torch.where(carrying, CARRYING, state)
    state = torch.where(collided, COLLIDED, state)
    return torch.where(waiting, WAITING, state).to(torch.int32)
