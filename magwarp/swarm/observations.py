"""Local observations of every mover of a swarm: O(k) per mover, on the device, as torch tensors.

:class:`LocalObservations` holds its own uniform grid (cells at least ``radius`` wide, so a 3 x 3 block of cells
covers the neighbourhood), bins the movers with the simulator's ``bin_movers`` kernel and fills, per call of
:meth:`LocalObservations.compute`:

* ``rel_pos`` / ``rel_vel`` ``[W, M, k, 2]``: the k nearest other movers within ``radius`` (nearest first, ties by
  index), their x/y position and velocity relative to the mover; padded slots are zeros;
* ``mask`` ``[W, M, k]`` (bool) and ``index`` ``[W, M, k]`` (int32, -1 where padded);
* ``walls`` ``[W, M, num_rays]``: the distance from the mover's centre to the first point off the tiles (hole or
  edge) along ``num_rays`` directions evenly spread from +x counter-clockwise, capped at ``max_range``.
"""

from __future__ import annotations

import math

import numpy as np
import torch
import warp as wp

from magwarp.kernels import neighbors as knb
from magwarp.kernels.collision import bin_movers
from magwarp.layout import Layout
from magwarp.swarm.placement import torch_stream
from magwarp.types import Grid

__all__ = ["LocalObservations", "ray_directions"]


def ray_directions(num_rays: int) -> np.ndarray:
    """``(num_rays, 2)`` unit vectors at angles ``2 pi r / num_rays``."""
    a = 2.0 * np.pi * np.arange(num_rays) / num_rays
    return np.stack([np.cos(a), np.sin(a)], axis=1)


class LocalObservations:
    """Neighbour and wall observations for ``num_worlds`` worlds of ``num_movers`` movers on ``layout``."""

    def __init__(self, layout: Layout | np.ndarray, num_worlds: int, num_movers: int, *, k: int = 8,
                 radius: float = 1.0, num_rays: int = 8, max_range: float = 1.0, device=None):
        self.layout = layout if isinstance(layout, Layout) else Layout(np.asarray(layout))
        for name, value in (("k", k), ("num_rays", num_rays)):
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
                raise ValueError(f"{name} must be an integer >= 0, got {value!r}")
        for name, value in (("radius", radius), ("max_range", max_range)):
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite number, got {value!r}")
        self.k, self.num_rays = int(k), int(num_rays)
        self.radius, self.max_range = float(radius), float(max_range)
        self.num_worlds, self.num_movers = int(num_worlds), int(num_movers)
        self.device = wp.get_device(device)
        dev = self.device
        ext = self.layout.extent
        g = Grid()
        # no more cells than about 4 per mover: a large radius on a sparse world scans a few more cells instead
        area_cell = math.sqrt(ext[0] * ext[1] / (4.0 * self.num_movers))
        g.cell_size = max(self.radius, area_cell, 1e-3)
        g.ncx = max(1, int(np.ceil(ext[0] / g.cell_size)))
        g.ncy = max(1, int(np.ceil(ext[1] / g.cell_size)))
        self.grid = g
        self.reach = int(np.ceil(self.radius / g.cell_size))
        shape = (self.num_worlds, self.num_movers)
        self._head = wp.zeros(self.num_worlds * g.ncx * g.ncy, dtype=wp.int32, device=dev)
        self._next = wp.zeros(shape, dtype=wp.int32, device=dev)
        kk = max(self.k, 1)
        self._rel_pos = wp.zeros((*shape, kk), dtype=wp.vec2, device=dev)
        self._rel_vel = wp.zeros((*shape, kk), dtype=wp.vec2, device=dev)
        self._index = wp.full((*shape, kk), -1, dtype=wp.int32, device=dev)
        self._walls = wp.zeros((*shape, max(self.num_rays, 1)), dtype=float, device=dev)
        self._dirs = wp.array(ray_directions(max(self.num_rays, 1)).astype(np.float32), dtype=wp.vec2, device=dev)
        self._tiles = wp.array(self.layout.tiles.astype(np.int32), dtype=wp.int32, device=dev)
        self._knn = knb.make_knn_kernel(kk) if self.k > 0 else None
        self.rel_pos = wp.to_torch(self._rel_pos)[..., : self.k, :]
        self.rel_vel = wp.to_torch(self._rel_vel)[..., : self.k, :]
        self.index = wp.to_torch(self._index)[..., : self.k]
        self.walls = wp.to_torch(self._walls)[..., : self.num_rays]

    @property
    def mask(self) -> torch.Tensor:
        """``[W, M, k]`` bool: the slot holds a neighbour."""
        return self.index >= 0

    @property
    def dim(self) -> int:
        """Width of :meth:`features` per mover: 5 per neighbour slot plus one per ray."""
        return 5 * self.k + self.num_rays

    def compute(self, pos: wp.array, vel: wp.array) -> None:
        """Fill the observations from ``[W, M]`` vec3 positions and velocities (e.g. a simulator's state)."""
        dev, dim = self.device, (self.num_worlds, self.num_movers)
        with torch_stream(dev):
            if self._knn is not None:
                wp.launch(knb.clear_heads, dim=self._head.shape[0], inputs=[self._head], device=dev)
                wp.launch(bin_movers, dim=dim, inputs=[self.grid, pos, self._head, self._next], device=dev)
                wp.launch(self._knn, dim=dim, device=dev,
                          inputs=[self.grid, self.radius, self.reach, pos, vel, self._head, self._next],
                          outputs=[self._rel_pos, self._rel_vel, self._index])
            if self.num_rays > 0:
                wp.launch(knb.wall_distances, dim=(*dim, self.num_rays), device=dev,
                          inputs=[self._tiles, float(self.layout.tile.size), self._dirs, self.max_range, pos],
                          outputs=[self._walls])

    def features(self, out: torch.Tensor | None = None) -> torch.Tensor:
        """``[W, M, 5 k + num_rays]``: per neighbour slot (relative x, y, relative vx, vy, mask), then the rays.
        Written into ``out`` (a ``[W, M, dim]`` tensor or view) when given: slice copies, no concatenation."""
        w, m, k = self.num_worlds, self.num_movers, self.k
        if out is None:
            out = torch.empty(w, m, self.dim, device=self.rel_pos.device)
        slots = out[..., : 5 * k].unflatten(-1, (k, 5))
        slots[..., 0:2].copy_(self.rel_pos)
        slots[..., 2:4].copy_(self.rel_vel)
        slots[..., 4].copy_(self.mask)
        out[..., 5 * k:].copy_(self.walls)
        return out
