"""Local observations of every mover of a swarm: O(k) per mover, on the device, as torch tensors.

:class:`LocalObservations` holds its own uniform grid (cells at least ``radius`` wide, so a 3 x 3 block of cells
covers the neighbourhood), bins the movers with the simulator's ``bin_movers`` kernel and fills, per call of
:meth:`LocalObservations.compute`:

* ``rel_pos`` / ``rel_vel`` ``[W, M, k, 2]``: the k nearest other movers within ``radius`` (nearest first, ties by
  index), their x/y position and velocity relative to the mover; padded slots are zeros;
* ``mask`` ``[W, M, k]`` (bool) and ``index`` ``[W, M, k]`` (int32, -1 where padded);
* ``walls`` ``[W, M, num_rays]``: the distance from the mover's centre to the first point off the tiles (hole or
  edge) along ``num_rays`` directions evenly spread from +x counter-clockwise, capped at ``max_range``.

:meth:`LocalObservations.observe` writes the same values, with the mover's own state before them, straight into the
rows of an env's observation tensor: three launches per call (clear the grid, bin, one observation kernel), or for
small worlds one (``search="world"``, no grid: each mover scans its world's movers; on CUDA, up to 256 movers per
world, a thread block per world with its movers in shared memory), no copies; ``rel_pos``, ``rel_vel`` and ``walls``
are then views of those rows. Both searches write the same rows bit for bit.
"""

from __future__ import annotations

import math

import numpy as np
import torch
import warp as wp

from magwarp.kernels import neighbors as knb
from magwarp.kernels.collision import bin_movers
from magwarp.kernels.options import world_block_dim
from magwarp.layout import Layout
from magwarp.swarm.placement import on_torch_stream
from magwarp.types import Grid

__all__ = ["LocalObservations", "ray_directions"]


def ray_directions(num_rays: int) -> np.ndarray:
    """``(num_rays, 2)`` unit vectors at angles ``2 pi r / num_rays``."""
    a = 2.0 * np.pi * np.arange(num_rays) / num_rays
    return np.stack([np.cos(a), np.sin(a)], axis=1)


#: the most neighbour slots and wall rays of a row: the kernel unrolls them (each slot lives in registers)
MAX_SLOTS = 64


def check_view_sizes(k, num_rays) -> None:
    """``k`` and ``num_rays`` as integers in ``[0, MAX_SLOTS]``, or a ValueError naming the bad one."""
    for name, value in (("k", k), ("num_rays", num_rays)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 0 <= value <= MAX_SLOTS:
            raise ValueError(f"{name} must be an integer in [0, {MAX_SLOTS}], got {value!r}")


class _Switch:
    """A settable on/off launch choice of :class:`LocalObservations` (the rows are the same either way): a bool, or
    a ValueError naming the attribute and the value."""

    def __set_name__(self, owner, name):
        self.name = name

    def __get__(self, obj, objtype=None):
        return self if obj is None else obj.__dict__[self.name]

    def __set__(self, obj, value):
        if not isinstance(value, (bool, np.bool_)):
            raise ValueError(f"LocalObservations.{self.name} must be a bool, got {value!r}")
        obj.__dict__[self.name] = bool(value)


class LocalObservations:
    """Neighbour and wall observations for ``num_worlds`` worlds of ``num_movers`` movers on ``layout``. ``search``:
    ``"grid"``, ``"world"`` (up to 256 movers per world) or None (``"world"`` up to 256 movers per world on CUDA and
    128 on the CPU, where it was measured faster, else ``"grid"``): how the k nearest are found; the rows are the
    same. The launch choices ``tiled``, ``unrolled``, ``staged``, ``merge``, ``sift`` and ``rect`` are settable bools
    (documented where they are set)."""

    tiled = _Switch()
    unrolled = _Switch()
    staged = _Switch()
    merge = _Switch()
    sift = _Switch()
    rect = _Switch()

    def __init__(self, layout: Layout | np.ndarray, num_worlds: int, num_movers: int, *, k: int = 8,
                 radius: float = 1.0, num_rays: int = 8, max_range: float = 1.0, search: str | None = None,
                 device=None):
        self.layout = layout if isinstance(layout, Layout) else Layout(np.asarray(layout))
        check_view_sizes(k, num_rays)
        for name, value in (("radius", radius), ("max_range", max_range)):
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite number, got {value!r}")
        with np.errstate(over="ignore"):
            r2 = np.float32(radius) * np.float32(radius)  # the kernels' radius squared
        if not np.isfinite(r2):
            raise ValueError(f"radius squared must be a finite float32, got radius {radius!r}")
        self.k, self.num_rays = int(k), int(num_rays)
        self.radius, self.max_range = float(radius), float(max_range)
        self.num_worlds, self.num_movers = int(num_worlds), int(num_movers)
        self.device = wp.get_device(device)
        dev = self.device
        # every mover of the world for small worlds (on CUDA up to 256: a block per world, positions in shared memory;
        # on the CPU up to 128: a thread per mover), no grid to build; else the grid's neighbouring cells
        most = knb.WORLD_SEARCH_CUDA if dev.is_cuda else knb.MAX_WORLD_SCAN_CPU
        self.search = search or ("world" if self.num_movers <= most else "grid")
        #: the block-per-world launch shape of the world search (CUDA; on the CPU a tile block is one thread wide
        #: unless warp.config.enable_cpu_blocks, so there each thread scans its world's rows)
        self.tiled = dev.is_cuda
        #: how a candidate enters the sorted slots (the same slots either way): an unrolled compare-and-swap chain
        #: that keeps them in registers (CUDA), or a shift from the back (the CPU, where it takes fewer steps)
        self.unrolled = dev.is_cuda
        #: the block-per-world kernel stages its block's rows in shared memory and stores them together (consecutive
        #: addresses per lane) instead of each lane writing its own row; the same rows either way. On: on the H100 the
        #: observation of 16,384 worlds x 64 movers took 0.75 ms staged against 1.23 ms not (benchmarks/swarm.py,
        #: swarm_fused_gpu_64.json, 2026-11-25)
        self.staged = True
        #: the world search merges every candidate into the sorted slots with no branch (they come in index order;
        #: the same slots as the chain or the shift, see make_observation_kernel); off: the chain or the shift
        #: (``unrolled``), entered by a branch only for a kept candidate. On CUDA it is on by default: on the H100 the
        #: observation of 16,384 worlds x 64 movers took 0.25 ms with the merge and the closed-form rays against 0.62
        #: with the rays alone (0.81 against 1.67 at 100 movers; ``python benchmarks/swarm_obs.py --device cuda:0``,
        #: swarm_obs_s34_gpu.json, 2026-12-06). On the CPU the merge of every candidate was slower (0.40 against 0.30
        #: ms at 8 x 64), so there it is on only with the sift (below).
        sift = knb.sift_default()
        self.merge = dev.is_cuda or sift
        #: with the merge, only the candidates within the radius are merged, a word of 32 at a time (their bits first,
        #: then the set bits in index order); the same slots. On by default (:data:`~magwarp.kernels.neighbors.SIFT`;
        #: ``MAGWARP_OBS_SIFT=0|1`` overrides it, a tuning knob for benchmarks). On the H100 (16,384 worlds) 0.51
        #: against 0.78 ms without it at 100 movers, 1.25 against 2.97 at 256 (swarm_obs_sift_s42_gpu.json); on this
        #: project's CPU (64 worlds; the former CPU default: the shift, no merge) 0.22 against 0.28 ms at 16 movers,
        #: 1.09 against 1.58 at 64 and 3.05 against 3.47 at 128 (swarm_obs_sift_cpu.json, 2026-12-07)
        self.sift = sift
        #: the layout has every tile of its rectangle: the wall rays in closed form (neighbors.ray_to_rect: each axis's
        #: exit as the tile walk's own running sum, no tile read), the same distances bit for bit; settable (off: the
        #: tile walk, which any layout may use)
        self._full = bool((self.layout.tiles == 1).all())
        self.rect = self._full
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
        self._index = wp.full((*shape, kk), -1, dtype=wp.int32, device=dev)
        self._dirs = wp.array(ray_directions(max(self.num_rays, 1)).astype(np.float32), dtype=wp.vec2, device=dev)
        self._tiles = wp.array(self.layout.tiles.astype(np.int32), dtype=wp.int32, device=dev)
        self._nonfinite = wp.zeros(self.num_worlds, dtype=wp.int32, device=dev)
        self.nonfinite = wp.to_torch(self._nonfinite)  # [W] int32: a written row of the world was not finite
        self._none_vec2 = wp.empty((0, 0), dtype=wp.vec2, device=dev)
        self._none_bool = wp.empty((0, 0), dtype=wp.bool, device=dev)
        self.index = wp.to_torch(self._index)[..., : self.k]
        # the features of compute() (no own state); observe() points the views below at the rows it writes
        self._features = torch.zeros(*shape, self.dim, device=wp.device_to_torch(dev))
        self._view(self._features, 0)

    @property
    def search(self) -> str:
        """How the k nearest are found (:data:`~magwarp.kernels.neighbors.SEARCHES`; the rows are the same either
        way); settable."""
        return self._search

    @search.setter
    def search(self, value: str) -> None:
        if value not in knb.SEARCHES:
            raise ValueError(f"search must be None or one of {knb.SEARCHES}, got {value!r}")
        if value == "world" and self.num_movers > knb.MAX_WORLD_BLOCK:
            raise ValueError(f"search='world' holds at most {knb.MAX_WORLD_BLOCK} movers per world, got "
                             f"{self.num_movers}")
        self._search = value

    def _view(self, rows: torch.Tensor, start: int) -> None:
        """Point ``rel_pos``, ``rel_vel`` and ``walls`` at the local columns of ``rows`` (from column ``start``)."""
        k = self.k
        slots = rows[..., start: start + 5 * k].unflatten(-1, (k, 5))
        self.rel_pos = slots[..., 0:2]
        self.rel_vel = slots[..., 2:4]
        self.walls = rows[..., start + 5 * k: start + self.dim]

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
        self._launch(pos, vel, self._features, 0, None, None, None)
        self._view(self._features, 0)

    def observe(self, pos: wp.array, vel: wp.array, out: torch.Tensor, *, goals: torch.Tensor | None = None,
                acc: torch.Tensor | None = None, carrying: torch.Tensor | None = None) -> torch.Tensor:
        """The whole observation of every mover, written into ``out`` (contiguous float32 ``[W, M, own + dim]``) by
        one kernel (after binning the movers): with ``goals`` (``[W, M, 2]``) the own state first (x/y velocity,
        goal relative to the mover), then ``acc`` (``[W, M, 2]``) and ``carrying`` (bool ``[W, M]``, as 0/1) where
        given, then :meth:`features`' columns. :attr:`rel_pos`, :attr:`rel_vel` and :attr:`walls` become views
        of ``out``; :attr:`nonfinite` flags the worlds with a non-finite entry in ``out``. Returns ``out``."""
        if goals is None and (acc is not None or carrying is not None):
            raise ValueError("acceleration and carrying columns come after the own state: give goals too")
        own = 4 * (goals is not None) + 2 * (acc is not None) + (carrying is not None)
        shape = (self.num_worlds, self.num_movers, own + self.dim)
        dev = torch.device(wp.device_to_torch(self.device))
        if tuple(out.shape) != shape or out.dtype != torch.float32 or not out.is_contiguous() or out.device != dev:
            raise ValueError(f"observation rows must be a contiguous float32 tensor of shape {shape} on {dev}, got "
                             f"{out.dtype} {tuple(out.shape)} on {out.device}")
        for name, t, tail in (("goals", goals, (2,)), ("acc", acc, (2,)), ("carrying", carrying, ())):
            want = (self.num_worlds, self.num_movers, *tail)
            if t is not None and (tuple(t.shape) != want or t.device != dev):
                raise ValueError(f"{name} must have shape {want} on {dev}, got {tuple(t.shape)} on {t.device}")
        self._launch(pos, vel, out, own, goals, acc, carrying)
        self._view(out, own)
        return out

    def _launch(self, pos, vel, out, own, goals, acc, carrying) -> None:
        dev, dim = self.device, (self.num_worlds, self.num_movers)
        bits = (knb.OWN_STATE if goals is not None else 0) | (knb.OWN_ACC if acc is not None else 0) | \
            (knb.OWN_CARRY if carrying is not None else 0)
        grid = self.search == "grid"
        block = 0 if grid or not self.tiled else world_block_dim(self.num_movers)
        if block and not dev.is_cuda and self.num_movers != 1 and not wp.config.enable_cpu_blocks:
            raise ValueError(f"the block-per-world observation kernel runs on the CPU only with "
                             f"warp.config.enable_cpu_blocks (Warp's cooperative CPU blocks), got {self.num_movers} "
                             f"movers")
        if self.rect and not self._full:
            raise ValueError("rect rays need a layout with every tile of its rectangle")
        kernel = knb.make_observation_kernel(self.k, self.num_rays, bits, self.search, block, self.unrolled,
                                              bool(block) and self.staged, bool(self.merge), bool(self.rect),
                                              bool(self.merge and self.sift))
        with on_torch_stream(dev):
            self.nonfinite.zero_()
            if self.k > 0 and grid:
                wp.launch(knb.clear_heads, dim=self._head.shape[0], inputs=[self._head], device=dev)
                wp.launch(bin_movers, dim=dim, inputs=[self.grid, pos, self._head, self._next], device=dev)
            vec2 = (lambda t: self._none_vec2 if t is None else wp.from_torch(t.contiguous(), dtype=wp.vec2))
            args = [self.grid, self.radius, self.reach, self._tiles, float(self.layout.tile.size), self._dirs,
                    self.max_range, pos, vel, vec2(acc), vec2(goals),
                    self._none_bool if carrying is None else wp.from_torch(carrying.contiguous()), self._head,
                    self._next, wp.from_torch(out), self._index, self._nonfinite]
            if block:
                wp.launch_tiled(kernel, dim=[self.num_worlds], inputs=args, block_dim=block, device=dev)
            else:
                wp.launch(kernel, dim=dim, inputs=args, device=dev)

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
