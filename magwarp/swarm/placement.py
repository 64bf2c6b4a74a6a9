"""Collision-free placement of many movers per world: the host side of :mod:`magwarp.kernels.placement`.

:class:`Placer` draws start positions (or goals) for every mover of every world in parallel, by rounds of dart
throwing on a uniform grid (see the kernel module), on any layout with holes, for circle and box collision shapes
with the simulator's margins plus a sampling offset. Work is O(movers) per round.

* :meth:`Placer.place` (reset time): places the masked movers of ``[W, M, 2]`` positions around the others, in
  batches of rounds with one host check after each batch, and raises :class:`PlacementError` with the density asked
  and the density possible when a request cannot be met;
* :meth:`Placer.place_async` (step time): a fixed number of rounds with no host synchronisation; movers that found
  no room stay marked and can try again later. Its launches can be recorded in a CUDA graph: the random streams and
  round numbers come from a device counter (``[seed, calls, round]``, advanced by the call's first kernel), not from
  the host, so each replay draws fresh spots; the seeds are the ones the host counter gave before (same spots, bit for
  bit, for the same seed and calls).

A request is refused at once when it exceeds the densest packing of the exclusion shapes over the valid area
(hexagonal for circles, square tiling for axis-aligned boxes), and reported after the rounds when random
placement stalls before that bound (random sequential placement jams near 55% of the packing's density).
"""

from __future__ import annotations

import contextlib
import math
import os

import numpy as np
import torch
import warp as wp
from scipy import ndimage

from magwarp._checks import as_count
from magwarp._streams import torch_stream as _torch_stream
from magwarp.kernels import placement as kpl
from magwarp.kernels.options import PLACE_SCAN
from magwarp.kernels.collision import footprints_on_tiles
from magwarp.layout import Layout, LayoutError, MoverSpec
from magwarp.types import SHAPE_BOX, SHAPE_CIRCLE, Collision

__all__ = ["Placer", "PlacementError"]

#: relative slack on the exclusion distance, so that float rounding in the simulator's own test never flags a pair
PAIR_SLACK = 1e-5
#: finest spacing (m) of the point grid on which the valid area is measured once (for the density bound), and the
#: most points it may have (large layouts get a coarser grid)
AREA_STEP = 0.005
MAX_AREA_POINTS = 4_000_000
#: the density bound is raised by this factor, so that the measuring grid's resolution never refuses a request
BOUND_SLACK = 1.03
#: densest packing of equal discs (hexagonal): fraction of the plane covered
HEX_DENSITY = math.pi / (2.0 * math.sqrt(3.0))
#: how placement checks a candidate against the other movers (:class:`Placer`'s ``search``)
SEARCHES = ("grid", "world")
#: the most movers per world for which the default search scans the world (CUDA, CPU). CUDA: the respawn placement
#: of the swarm step at 16,384 worlds on an H100 took 0.42 / 0.75 / 3.73 ms with the scan against 0.85 / 1.12 / 2.56
#: with the grid at 64 / 100 / 256 movers (benchmarks/results/swarm_fused_s35_*_gpu.json): the crossover is near 160
WORLD_SCAN_CUDA = 160
WORLD_SCAN_CPU = 64
#: how the rounds of ``search="world"`` check a round's tries (:class:`Placer`'s ``scan``): ``"serial"``
#: (:func:`~magwarp.kernels.placement.propose`: one try after another, one mover after another) or ``"chunked"``
#: (:func:`~magwarp.kernels.placement.make_scan_propose`: the world's movers read a chunk at a time); the same spots,
#: bit for bit
SCAN_SHAPES = ("serial", "chunked")
#: the default ``scan`` (CUDA, CPU; ``MAGWARP_PLACE_SCAN`` sets both: :data:`magwarp.kernels.options.PLACE_SCAN`).
#: CPU (this project's 2 cores, 256 worlds, benchmarks/results/swarm_place_scan_s38_cpu.json): the respawn call at
#: 64 / 100 movers took 3.18 / 5.84 ms serial and 2.95 / 5.23 chunked. CUDA (H100, 16,384 worlds,
#: benchmarks/results/swarm_place_scan_s38_gpu*.json): 0.71 / 1.59 / 3.86 ms serial against 0.93 / 1.99 / 4.74 chunked
#: at 100 / 160 / 256 movers (at 64 within the launches' noise): the GPU's rounds are throughput-bound. In the env
#: step itself (benchmarks/swarm_load.py under seek, swarm_load_scan_*_s39_gpu.json) chunked is 2.5% / 4% slower at
#: 64 / 100 movers
SCAN_CUDA = "serial" if PLACE_SCAN == "device" else PLACE_SCAN
SCAN_CPU = "chunked" if PLACE_SCAN == "device" else PLACE_SCAN
#: the threads of a round's launch in the lane shape (:class:`Placer`'s ``lanes``): its groups walk the list of movers
#: to place (an H100 holds 132 * 2048 resident threads)
LANE_GRID_THREADS = 1 << 18
#: the default thread blocks per multiprocessor of a CUDA round's launches (:class:`Placer`'s ``blocks``; 0: no
#: cap, a thread per index). With ``blocks`` > 0, :func:`begin_todo`, the rounds'
#: :func:`~magwarp.kernels.placement.propose` and :func:`~magwarp.kernels.placement.resolve`, and the grid search's
#: binning walk their ``W * M`` indices with Warp's grid-stride loop (their
#: :func:`~magwarp.kernels.placement.strided` twins) in at most that many 256-thread blocks per SM (8: every thread
#: resident at once), not one thread per index: the same work per index in the same order, so the same spots bit for
#: bit, and a round with few movers to place no longer launches a block for every 256 movers of every world (at
#: 16,384 worlds of 100 movers those near-empty launches took about 6 us each on the H200, 8 per env step,
#: ``benchmarks/results/swarm_kernels_still_cap96_s43_gpu.json``). Measured on an H100 (2026-12-08, 16,384 worlds
#: of 100 movers, ``swarm_small_{new,old}_s45_gpu.json``) 8 blocks per SM stepped the swarm 1.0% faster than
#: grid-stride kernels uncapped, but that run was 8-37% slower than the lean kernels uncapped on another H100 the same
#: night: the default stays the lean launch until one run on one card compares them. ``MAGWARP_PLACE_BLOCKS`` sets
#: the default, for measuring.
ROUND_BLOCKS_PER_SM = 0
#: the most blocks per SM ``blocks`` takes
MAX_ROUND_BLOCKS = 1024


def round_blocks_per_sm() -> int:
    """The default of :class:`Placer`'s ``blocks`` per SM (:data:`ROUND_BLOCKS_PER_SM` or ``MAGWARP_PLACE_BLOCKS``)."""
    value = os.environ.get("MAGWARP_PLACE_BLOCKS", "").strip()
    if not value:
        return ROUND_BLOCKS_PER_SM
    if not value.isdigit() or int(value) > MAX_ROUND_BLOCKS:
        raise ValueError(f"MAGWARP_PLACE_BLOCKS must be an integer from 0 (no cap) to {MAX_ROUND_BLOCKS} (blocks per "
                         f"SM), got {value!r}")
    return int(value)


class PlacementError(LayoutError):
    """A placement request that cannot be met (too many movers for the valid area)."""


def on_torch_stream(device):
    """A context that makes Warp launch on torch's current stream of ``device`` (CUDA; its one wrapper per stream,
    :func:`magwarp._streams.torch_stream`), so that kernels and torch ops on the same tensors are ordered without a
    host synchronisation; a no-op on the CPU. (Until 2026-12-06 this context was called ``torch_stream`` too and
    called itself instead of that helper, with a torch device Warp refused: every swarm placement on CUDA failed.)"""
    device = wp.get_device(device)
    if not device.is_cuda:
        return contextlib.nullcontext()
    return wp.ScopedStream(_torch_stream(torch.device("cuda", device.ordinal)))


def _collision(layout: Layout, mover: MoverSpec) -> Collision:
    col = Collision()
    col.shape = SHAPE_CIRCLE if mover.collision_shape == "circle" else SHAPE_BOX
    col.margin = float(mover.margin)
    col.wall_margin = float(mover.wall_margin)
    col.tile_size = float(layout.tile.size)
    col.stop_on_collision = 0
    col.full_rect = 1 if bool(layout.tiles.all()) else 0
    col.extent = wp.vec2(*layout.extent)
    return col


class Placer:
    """Places movers of ``num_worlds`` worlds of ``num_movers`` each on ``layout``.

    ``mover``: the :class:`MoverSpec` (collision shape, size, ``margin`` for mover-mover checks, ``wall_margin``).
    ``offset``: sampling safety offset added to every shape (MagBotSim's ``collision_params["offset"]``): two placed
    movers keep ``2 * (size + margin + offset)`` apart and every footprint grown by ``offset + wall_margin`` lies on
    the tiles. ``radius`` / ``half_size`` override the mover's collision size (use the largest of per-mover sizes).
    ``tries``: candidates per mover and round. ``seed``: base seed of the device random streams. ``search``: how a
    candidate is checked against the other movers (:data:`SEARCHES`; the same spots either way, bit for bit):
    ``"grid"`` (the neighbouring cells' lists, built and emptied by each call: work per mover near the candidate) or
    ``"world"`` (every mover of its world, no lists: for small worlds, where the lists' binning, emptying and
    scattered cell reads cost more than the scan); None: ``"world"`` up to :data:`WORLD_SCAN_CUDA` movers per world
    on CUDA and :data:`WORLD_SCAN_CPU` on the CPU, else ``"grid"``. ``lanes``: the rounds' launch shape with
    ``search="world"`` (:func:`~magwarp.kernels.placement.make_lane_kernels`; the same spots, bit for bit): None (the
    default) one thread per mover of every world, threads past the list's count exiting at once; 1-32 (a power of two)
    that many threads per listed mover in a fixed grid of :data:`LANE_GRID_THREADS` threads whose groups walk the
    list, the world's movers split over the lanes (in registers) and a vote per try. More than 1 on a CPU needs
    ``warp.config.enable_cpu_blocks`` (a block per group, ``wp.tile_sum`` votes). ``scan``: with ``search="world"``
    and ``lanes`` None, how a round's tries and winners are checked (:data:`SCAN_SHAPES`; the same spots, bit for bit;
    ``"chunked"`` takes ``tries`` up to :data:`~magwarp.kernels.placement.MAX_SCAN_TRIES`, more go serially);
    None: :data:`SCAN_CUDA` on CUDA, :data:`SCAN_CPU` on the CPU. ``blocks``: on CUDA the most thread blocks per SM of
    the launches that walk every mover index (:data:`ROUND_BLOCKS_PER_SM`; 0: no cap, the default; no effect on the
    CPU; the same spots, bit for bit). ``search``, ``lanes``, ``scan`` and ``blocks`` are settable between calls.
    """

    def __init__(self, layout: Layout | np.ndarray, num_movers: int, num_worlds: int = 1, *,
                 mover: MoverSpec | None = None, offset: float = 0.0, radius: float | None = None,
                 half_size=None, tries: int = 8, device=None, seed: int = 0, search: str | None = None,
                 lanes: int | None = None, scan: str | None = None, blocks: int | None = None):
        self.layout = layout if isinstance(layout, Layout) else Layout(np.asarray(layout))
        self.mover = mover or MoverSpec()
        if int(num_movers) < 1 or int(num_worlds) < 1:
            raise ValueError(f"num_movers and num_worlds must be >= 1, got {num_movers!r} and {num_worlds!r}")
        if not (np.isfinite(offset) and offset >= 0):
            raise ValueError(f"sampling offset must be a finite number >= 0, got {offset!r}")
        if int(tries) < 1:
            raise ValueError(f"tries must be >= 1, got {tries!r}")
        self.num_movers, self.num_worlds, self.tries = int(num_movers), int(num_worlds), int(tries)
        self.offset = float(offset)
        self.device = wp.get_device(device)
        self.torch_device = torch.device(wp.device_to_torch(self.device))
        if search is None:
            search = "world" if self.num_movers <= (WORLD_SCAN_CUDA if self.device.is_cuda else WORLD_SCAN_CPU) \
                else "grid"
        self.search = search
        self.lanes = lanes
        self.scan = (SCAN_CUDA if self.device.is_cuda else SCAN_CPU) if scan is None else scan
        self.blocks = round_blocks_per_sm() if blocks is None else blocks
        # the device counter [base seed, rounds since the reseed, rounds ever (claims of older rounds lose)]: the
        # rounds' kernels read their seeds and round numbers from it (kpl.round_seed), so that a call recorded in a
        # CUDA graph draws fresh numbers at every replay
        self._counter = wp.array(np.array([int(seed) & 0x3FFFFFFF, 0, 0], dtype=np.int64), dtype=wp.int64,
                                 device=self.device)
        self._counter_t = wp.to_torch(self._counter)
        self.col = _collision(self.layout, self.mover)
        self.circle = self.col.shape == SHAPE_CIRCLE
        r = float(self.mover.collision_radius if radius is None else radius)
        h = np.asarray(self.mover.collision_half_size if half_size is None else half_size, dtype=np.float64)
        if not (r > 0 and h.shape == (2,) and np.all(h > 0)):
            raise ValueError(f"collision size must be positive, got radius {radius!r}, half_size {half_size!r}")
        # the footprint the wall rule sees (the wall margin is added by the rule itself)
        self.foot_radius = r + self.offset
        self.foot_half = h + self.offset
        grow = self.mover.margin + self.offset
        g = kpl.PlaceGrid()
        g.shape = self.col.shape
        if self.circle:
            self.excl = 2.0 * (r + grow) * (1.0 + PAIR_SLACK)  # centre distance at or below which two conflict
            g.excl = wp.vec2(self.excl * self.excl, 0.0)
            cell = np.full(2, self.excl / math.sqrt(2.0))  # two points of one cell are always closer than excl
        else:
            self.excl = 2.0 * (h + grow) * (1.0 + PAIR_SLACK)
            g.excl = wp.vec2(*self.excl)
            cell = np.asarray(self.excl, dtype=np.float64)
        ext = np.asarray(self.layout.extent)
        cell = np.maximum(cell * (1.0 - 1e-6), 1e-4)  # strictly inside the exclusion, also after float rounding
        g.cell = wp.vec2(*cell)
        g.ncx, g.ncy = (int(v) for v in np.maximum(1, np.ceil(ext / cell)))
        excl = np.broadcast_to(np.asarray(self.excl, dtype=np.float64), (2,))
        g.reach = int(np.max(np.ceil(excl / cell)))
        self.grid = g
        self.num_cells = g.ncx * g.ncy
        i, j = np.nonzero(self.layout.tiles)
        self._tile_list = wp.array(np.stack([i, j], axis=1).astype(np.int32), dtype=wp.vec2i, device=self.device)
        self._tiles = wp.array(self.layout.tiles.astype(np.int32), dtype=wp.int32, device=self.device)
        shape = (self.num_worlds, self.num_movers)
        self._head = wp.zeros(self.num_worlds * self.num_cells, dtype=wp.int32, device=self.device)
        self._claim = wp.zeros(self.num_worlds * self.num_cells, dtype=wp.int64, device=self.device)
        self._head_old = wp.zeros(self.num_worlds * self.num_cells, dtype=wp.int32, device=self.device)
        self._next = wp.zeros(shape, dtype=wp.int32, device=self.device)
        self._next_old = wp.zeros(shape, dtype=wp.int32, device=self.device)
        self._cand = wp.zeros(shape, dtype=wp.vec2, device=self.device)
        self._cand_ok = wp.zeros(shape, dtype=wp.int32, device=self.device)
        self._todo = wp.zeros(shape, dtype=wp.int32, device=self.device)
        self._old_cell = wp.zeros(shape, dtype=wp.int32, device=self.device)
        self._active = wp.zeros(self.num_worlds, dtype=wp.int32, device=self.device)  # worlds with movers to place
        self._left = wp.zeros(self.num_worlds, dtype=wp.int32, device=self.device)
        # the movers to place this call (flat indices, any order) and their count: the rounds run a thread per one
        self._listed = wp.zeros(self.num_worlds * self.num_movers, dtype=wp.int32, device=self.device)
        self._count = wp.zeros(1, dtype=wp.int32, device=self.device)
        self._grid_clean = False  # every cell list empty and every claim free (kept so between calls)
        self.valid_area, self.grown_area = self._measure_area()
        if self.valid_area <= 0.0:
            raise PlacementError(
                f"no valid position on this layout for a mover of collision size {self._size_text()} with wall margin "
                f"{self.col.wall_margin:g} m and sampling offset {self.offset:g} m: reduce the size or the margins")

    @property
    def search(self) -> str:
        """How a candidate is checked against the other movers (:data:`SEARCHES`); settable between calls."""
        return self._search

    @search.setter
    def search(self, value: str) -> None:
        if value not in SEARCHES:
            raise ValueError(f"search must be None or one of {SEARCHES}, got {value!r}")
        self._search = value

    @property
    def scan(self) -> str:
        """How the rounds of ``search="world"`` check a round's tries (:data:`SCAN_SHAPES`); settable between calls."""
        return self._scan_shape

    @scan.setter
    def scan(self, value: str) -> None:
        if value not in SCAN_SHAPES:
            raise ValueError(f"scan must be None or one of {SCAN_SHAPES}, got {value!r}")
        self._scan_shape = value

    @property
    def blocks(self) -> int:
        """CUDA thread blocks per SM of the launches that walk every mover index (0: no cap); settable between
        calls."""
        return self._blocks

    @blocks.setter
    def blocks(self, value: int) -> None:
        value = as_count(value, "blocks", minimum=0)
        if value > MAX_ROUND_BLOCKS:
            raise ValueError(f"blocks must be at most {MAX_ROUND_BLOCKS} per SM (0: no cap), got {value!r}")
        self._blocks = value

    def _max_blocks(self) -> int:
        """The launches' ``max_blocks`` (0: Warp's default, a block per 256 indices)."""
        return self._blocks * self.device.sm_count if self.device.is_cuda else 0

    def _walk(self, kernel: wp.Kernel) -> wp.Kernel:
        """``kernel`` for a launch with :meth:`_max_blocks`: its grid-stride twin where that caps the blocks."""
        return kpl.strided(kernel) if self._max_blocks() else kernel

    @property
    def shape(self) -> tuple:
        """What the launches of a call depend on: ``(search, lanes, scan, blocks)`` (a recorded step graph holding
        this placer's rounds is recorded anew when it changes)."""
        return self.search, self._lanes, self.scan, self._blocks

    @property
    def lanes(self) -> int | None:
        """The rounds' launch shape with ``search="world"`` (see the class): None or threads per listed mover."""
        return self._lanes

    @lanes.setter
    def lanes(self, value: int | None) -> None:
        if value is not None:
            if value not in kpl.LANE_CHOICES:
                raise ValueError(f"lanes must be None or one of {kpl.LANE_CHOICES}, got {value!r}")
            if self.device.is_cpu and value > 1 and not wp.config.enable_cpu_blocks:
                raise ValueError(f"lanes={value} on a CPU needs warp.config.enable_cpu_blocks (the lanes' votes are "
                                 "emulated by blocks there)")
            value = int(value)
        self._lanes = value

    def _lane_kernels(self):
        """The lane shape's kernels for this placer's lanes and worlds, and its groups per launch."""
        L = self._lanes
        per_lane = -(-self.num_movers // L)
        groups = max(1, min(self.num_worlds * self.num_movers, LANE_GRID_THREADS // L))
        return (*kpl.make_lane_kernels(L, per_lane, bool(self.device.is_cpu and L > 1), per_lane <= kpl.MAX_PER_LANE),
                groups)

    # ------------------------------------------------------------------ geometry of the request
    def _size_text(self) -> str:
        if self.circle:
            return f"radius {self.foot_radius - self.offset:g} m"
        return f"half size {tuple(round(float(v), 6) for v in self.foot_half - self.offset)} m"

    def _measure_area(self) -> tuple[float, float]:
        """Areas (m^2) of the valid centres (footprint on the tiles) and of that set grown by half the exclusion
        (the room the movers' exclusion shapes can take), measured once on a point grid."""
        ext = np.asarray(self.layout.extent)
        step = max(AREA_STEP, math.sqrt(float(np.prod(ext)) / MAX_AREA_POINTS))
        half = 0.5 * np.broadcast_to(np.asarray(self.excl, dtype=np.float64), (2,))
        pad = int(np.ceil(half.max() / step)) + 1
        xs = np.arange(0.5 * step, ext[0], step)
        ys = np.arange(0.5 * step, ext[1], step)
        pts = np.stack(np.meshgrid(xs, ys, indexing="ij"), axis=-1).reshape(-1, 2).astype(np.float32)
        ok = wp.zeros(len(pts), dtype=wp.int32, device=self.device)
        wp.launch(footprints_on_tiles, dim=len(pts), device=self.device,
                  inputs=[self._tiles, self.col, self.foot_radius - self.offset,
                          wp.vec2(*(self.foot_half - self.offset)), self.offset,
                          wp.array(pts, dtype=wp.vec2, device=self.device)], outputs=[ok])
        valid = np.pad(ok.numpy().reshape(len(xs), len(ys)).astype(bool), pad)
        if self.circle:
            grown = ndimage.distance_transform_edt(~valid) * step <= half[0]
        else:
            size = tuple(2 * int(np.floor(h / step)) + 1 for h in half)
            grown = ndimage.maximum_filter(valid, size=size, mode="constant")
        return float(valid.sum()) * step * step, float(grown.sum()) * step * step

    def on_tiles(self, xy) -> torch.Tensor:
        """Bool ``(...)``: the footprint at the points ``(..., 2)`` (yaw 0, grown by the sampling offset) lies on
        the tiles by the simulator's wall rule."""
        pts = torch.as_tensor(xy, dtype=torch.float32, device=self.torch_device)
        flat = pts.reshape(-1, 2).contiguous()
        ok = torch.zeros(flat.shape[0], dtype=torch.int32, device=self.torch_device)
        if flat.shape[0]:
            with on_torch_stream(self.device):
                wp.launch(footprints_on_tiles, dim=flat.shape[0], device=self.device,
                          inputs=[self._tiles, self.col, self.foot_radius - self.offset,
                                  wp.vec2(*(self.foot_half - self.offset)), self.offset,
                                  wp.from_torch(flat, dtype=wp.vec2)], outputs=[wp.from_torch(ok)])
        return ok.reshape(pts.shape[:-1]).bool()

    @property
    def exclusion_area(self) -> float:
        """Area one placed mover keeps to itself in the densest packing (m^2)."""
        if self.circle:
            return math.pi * (0.5 * self.excl) ** 2 / HEX_DENSITY
        return float(np.prod(self.excl))

    @property
    def max_movers(self) -> int:
        """Upper bound (up to the measuring grid's resolution) on the movers that fit in one world: the densest
        packing of the exclusion shapes over the valid centres grown by half the exclusion."""
        return int(BOUND_SLACK * self.grown_area / self.exclusion_area)

    def _density(self, movers: float) -> str:
        tiles = self.layout.num_tiles
        return f"{movers / tiles:.3f} movers per tile ({movers:.0f} movers on {tiles} tiles)"

    # ------------------------------------------------------------------ placement
    @property
    def _seed(self) -> int:
        """The base seed of the random streams (on the device: reading it synchronises)."""
        return int(self._counter.numpy()[kpl.COUNTER_SEED])

    @_seed.setter
    def _seed(self, value: int) -> None:
        self._counter_t[kpl.COUNTER_SEED].fill_(int(value) & 0x3FFFFFFF)

    @property
    def _calls(self) -> int:
        """Rounds run since the last reseed (on the device: reading it synchronises); with :attr:`_seed`, the next
        round's random stream."""
        return int(self._counter.numpy()[kpl.COUNTER_CALLS])

    @_calls.setter
    def _calls(self, value: int) -> None:
        self._counter_t[kpl.COUNTER_CALLS].fill_(int(value))

    def _check(self, xy: torch.Tensor, mask: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
        shape = (self.num_worlds, self.num_movers)
        if not isinstance(xy, torch.Tensor) or tuple(xy.shape) != (*shape, 2) or xy.dtype != torch.float32:
            raise ValueError(f"positions must be a float32 tensor of shape {(*shape, 2)}, got "
                             f"{getattr(xy, 'dtype', type(xy))} {tuple(getattr(xy, 'shape', ()))}")
        if xy.device != self.torch_device or not xy.is_contiguous():
            raise ValueError(f"positions must be contiguous on {self.torch_device}, got {xy.device}")
        if mask is None:
            mask = torch.ones(shape, dtype=torch.bool, device=self.torch_device)
        if tuple(mask.shape) != shape or mask.device != self.torch_device:
            raise ValueError(f"mask must have shape {shape} on {self.torch_device}, got {tuple(mask.shape)} on "
                             f"{mask.device}")
        return xy, mask

    def _begin(self, xy: torch.Tensor, mask: torch.Tensor, hold: bool, advance: int = 0) -> wp.array:
        """Start a call: list the movers to place and bin the others; ``advance``: the call's rounds, by which
        :func:`~magwarp.kernels.placement.begin_todo` advances the counter (0: each batch of :meth:`_rounds` does)."""
        pos = wp.from_torch(xy, dtype=wp.vec2)
        dev, dim = self.device, (self.num_worlds, self.num_movers)
        if not self._grid_clean:  # the first call (or one after a failed call): empty every cell
            wp.launch(kpl.clear_grid, dim=self._head.shape[0], inputs=[self._head, self._head_old, self._claim],
                      device=dev)
        self._grid_clean = False
        self._active.zero_()
        self._count.zero_()
        blocks = self._max_blocks()
        wp.launch(self._walk(kpl.begin_todo), dim=dim,
                  inputs=[int(advance), wp.from_torch(mask.to(torch.bool).contiguous(), dtype=wp.bool)],
                  outputs=[self._todo, self._active, self._listed, self._count, self._counter], device=dev,
                  max_blocks=blocks)
        self._hold = int(hold)
        self._world_scan = int(self.search == "world")  # this call's search (the setter may change it before the next)
        if self._world_scan:  # no lists: the rounds scan the world's movers
            return pos
        wp.launch(self._walk(kpl.bin_fixed), dim=dim, inputs=[self.grid, int(hold), pos, self._todo, self._active],
                  outputs=[self._head, self._next, self._head_old, self._next_old, self._old_cell], device=dev,
                  max_blocks=blocks)
        return pos

    def _end(self, pos: wp.array) -> None:
        """Empty the cells this call filled (the next call finds the grid clean without clearing every cell)."""
        if not self._world_scan:
            wp.launch(self._walk(kpl.unbin), dim=(self.num_worlds, self.num_movers), device=self.device,
                      inputs=[self.grid, pos, self._todo, self._active, self._old_cell],
                      outputs=[self._head, self._head_old], max_blocks=self._max_blocks())
        self._grid_clean = True

    def _rounds(self, pos: wp.array, rounds: int, advanced: bool = False) -> None:
        """``rounds`` rounds; ``advanced``: :meth:`_begin` advanced the counter by them (else one launch does)."""
        # a thread per listed mover (the count stays on the device: threads past it exit)
        dev, dim, g = self.device, self.num_worlds * self.num_movers, self.grid
        if not advanced:
            wp.launch(kpl.advance_counter, dim=1, inputs=[int(rounds)], outputs=[self._counter], device=dev)
        lanes = self._lanes if self._world_scan else None
        blocks = self._max_blocks()
        if lanes is not None:
            propose, resolve, groups = self._lane_kernels()
            block = lanes if dev.is_cpu else 256  # a CPU block is a group (its votes); a CUDA warp holds 32 / lanes
        for r in range(rounds):
            back = rounds - 1 - r  # the counter stands at the last round
            if lanes is not None:
                wp.launch(propose, dim=groups * lanes, block_dim=block, device=dev,
                          inputs=[g, self._tiles, self.col, self.foot_radius, wp.vec2(*self.foot_half),
                                  self._tile_list, self.tries, self._hold, back, self._counter, pos, self._todo,
                                  self._listed, self._count, groups],
                          outputs=[self._cand, self._cand_ok, self._claim])
                wp.launch(resolve, dim=groups * lanes, block_dim=block, device=dev,
                          inputs=[g, back, self._counter, self._cand, self._cand_ok, self._claim, self._listed,
                                  self._count, groups], outputs=[self._todo, pos])
                continue
            if self._world_scan and self.scan != "serial" and self.tries <= kpl.MAX_SCAN_TRIES:
                wp.launch(kpl.make_scan_propose(self.tries, blocks > 0), dim=dim, device=dev,
                          inputs=[g, self._tiles, self.col, self.foot_radius, wp.vec2(*self.foot_half),
                                  self._tile_list, self._hold, back, self._counter, pos, self._todo, self._listed,
                                  self._count], outputs=[self._cand, self._cand_ok, self._claim], max_blocks=blocks)
            else:
                wp.launch(self._walk(kpl.propose), dim=dim, device=dev,
                          inputs=[g, self._tiles, self.col, self.foot_radius, wp.vec2(*self.foot_half),
                                  self._tile_list, self.tries, self._hold, back, self._world_scan, self._counter, pos,
                                  self._todo, self._head, self._next, self._head_old, self._next_old, self._listed,
                                  self._count], outputs=[self._cand, self._cand_ok, self._claim], max_blocks=blocks)
            wp.launch(self._walk(kpl.resolve), dim=dim, device=dev,
                      inputs=[g, back, self._world_scan * (1 if self.scan == "serial" else 2), self._counter,
                              self._cand, self._cand_ok, self._claim, self._listed, self._count, self._todo, pos,
                              self._head, self._next], max_blocks=blocks)

    def place_async(self, xy: torch.Tensor, mask: torch.Tensor | None = None, rounds: int = 2, *,
                    hold: bool = False, out: torch.Tensor | None = None) -> torch.Tensor:
        """Place the movers where ``mask`` (``[W, M]`` bool, default all) is true into ``xy`` (``[W, M, 2]``
        float32, written in place) around the others, in ``rounds`` rounds and without a host synchronisation.
        With ``hold``, the current rows of the masked movers are real spots too (e.g. movers to respawn, which stay
        where they are until placed): nothing is placed onto them. Returns the ``[W, M]`` bool tensor of the movers
        still unplaced (their rows of ``xy`` are unchanged), written into ``out`` when given. Work: per mover of the
        worlds with movers to place (the others' threads exit at once)."""
        xy, mask = self._check(xy, mask)
        if out is not None and (not isinstance(out, torch.Tensor) or tuple(out.shape) != tuple(mask.shape)
                                or out.dtype != torch.bool or out.device != self.torch_device):
            raise ValueError(f"out must be a bool tensor of shape {tuple(mask.shape)} on {self.torch_device}, got "
                             f"{getattr(out, 'dtype', type(out))} {tuple(getattr(out, 'shape', ()))} on "
                             f"{getattr(out, 'device', None)}")
        with on_torch_stream(self.device):
            todo = wp.to_torch(self.place_device(xy, mask, rounds, hold=hold, checked=True))
            return todo.bool() if out is None else torch.ne(todo, 0, out=out)

    def place_device(self, xy: torch.Tensor, mask: torch.Tensor, rounds: int = 2, *, hold: bool = False,
                     checked: bool = False) -> wp.array:
        """:meth:`place_async` without the conversion of its result: returns the placer's own ``[W, M]`` int32
        array of the movers still unplaced (nonzero), valid until its next call (the swarm env's respawn kernel
        reads it directly: one launch less per step). ``checked``: ``xy`` and ``mask`` were checked already."""
        if not checked:
            xy, mask = self._check(xy, mask)
        rounds = int(rounds)
        with on_torch_stream(self.device):
            pos = self._begin(xy, mask, hold, advance=rounds)
            self._rounds(pos, rounds, advanced=True)
            self._end(pos)
        return self._todo

    def place(self, xy: torch.Tensor, mask: torch.Tensor | None = None, *, rounds_per_check: int = 16,
              max_rounds: int = 256) -> torch.Tensor:
        """Place the masked movers like :meth:`place_async`, until all are placed (checking after every
        ``rounds_per_check`` rounds: one host synchronisation each) or ``max_rounds``; raises
        :class:`PlacementError` if some cannot be placed. Returns ``xy``."""
        xy, mask = self._check(xy, mask)
        asked = int(self.num_movers)
        if asked > self.max_movers:
            raise PlacementError(
                f"cannot place {asked} movers per world: asked {self._density(asked)}, possible at most "
                f"{self._density(self.max_movers)} (densest packing of collision {self._size_text()}, safety margin "
                f"{self.mover.margin:g} m, sampling offset {self.offset:g} m over {self.valid_area:.3f} m^2 of valid "
                f"centres): choose fewer movers, more tiles or smaller margins")
        with on_torch_stream(self.device):
            pos = self._begin(xy, mask, False)
            done = 0
            while done < max_rounds:
                n = min(int(rounds_per_check), max_rounds - done)
                self._rounds(pos, n)
                done += n
                self._left.zero_()
                wp.launch(kpl.count_todo, dim=(self.num_worlds, self.num_movers), inputs=[self._todo, self._left],
                          device=self.device)
                left = self._left.numpy()
                if not left.any():
                    break
            self._end(pos)
        if not left.any():
            return xy
        w = int(np.argmax(left))
        placed = self.num_movers - int(left[w])
        raise PlacementError(
            f"could not place {asked} movers per world in {max_rounds} rounds (world {w} has {int(left[w])} left): "
            f"asked {self._density(asked)}, possible by random placement about {self._density(placed)} (a packing "
            f"bound allows {self._density(self.max_movers)}; collision {self._size_text()}, safety margin "
            f"{self.mover.margin:g} m, sampling offset {self.offset:g} m): choose fewer movers or more tiles")

    def sample(self, mask: torch.Tensor | None = None, **kwargs) -> torch.Tensor:
        """Fresh ``[W, M, 2]`` positions for all movers (rows outside ``mask`` are zeros and ignored)."""
        xy = torch.zeros(self.num_worlds, self.num_movers, 2, device=self.torch_device)
        if mask is not None:
            raise ValueError("sample() places every mover; use place() to place some around others")
        return self.place(xy, **kwargs)

    def reseed(self, seed: int) -> None:
        """Restart the device random streams from ``seed`` (what ``reset(seed=...)`` of an env calls): written into
        the device counter in place (no synchronisation), so recorded CUDA graphs follow it."""
        self._seed = seed
        self._calls = 0
