"""Top-down images of one world or a mosaic of many, drawn by one Warp kernel launch per frame.

Usage::

    r = TopDownRenderer(layout, mover, worlds=64, px_per_tile=24)     # 8 x 8 mosaic of worlds 0..63
    big = TopDownRenderer(layout, mover, px_per_tile=2, safety_zone=False, heading=False, grid=False)
    frame = big.draw(pos, flags=collided, state=state)                # 1000s of movers: a dot each, by state
    zoom = TopDownRenderer(layout, mover, px_per_tile=48, window=(cx, cy, 1.0, 1.0))  # 1 m x 1 m around (cx, cy)
    frame = r.draw(pos, quat, flags=collision, goals=goals)          # torch uint8 [H, W, 3] on r.device
    png = r.draw_numpy(pos, quat)                                    # numpy copy

The returned tensor is the renderer's own buffer: the next ``draw`` overwrites it (``.clone()`` to keep one).
Inputs are plain arrays (torch, warp or numpy), so the renderer does not depend on the simulator.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch
import warp as wp

from magwarp._streams import torch_stream
from magwarp.layout import Layout, MoverSpec
from magwarp.render import colors
from magwarp.render import kernels as K
from magwarp.render.arrays import as_tensor, per_world, to_numpy_image, warp_device

__all__ = ["TopDownRenderer", "object_parts"]


def object_parts(kind: str, half_size=(0.06, 0.06), segment: float = 0.02, radius: float = 0.05) -> list[tuple]:
    """Drawing parts ``(cx, cy, hx, hy)`` of MagBotSim's object shapes, in the object frame.

    ``kind``: ``box`` (half sizes ``half_size``), ``cylinder`` (``radius``; a part with ``hy <= 0`` is a disc of
    radius ``hx``), ``T``, ``L`` and ``X`` built from bars of half width ``segment`` and half length ``half_size``.
    Environments with their own geometry pass their own rectangles instead.
    """
    hx, hy = (float(v) for v in half_size)
    s = float(segment)
    if kind in ("box", "square_box"):
        return [(0.0, 0.0, hx, hy)]
    if kind == "cylinder":
        return [(0.0, 0.0, float(radius), 0.0)]
    if kind == "T":  # bar along x on top, stem down the middle
        return [(0.0, hy - s, hx, s), (0.0, -s, s, hy - s)]
    if kind == "L":
        return [(-hx + s, 0.0, s, hy), (0.0, -hy + s, hx, s)]
    if kind in ("X", "plus"):
        return [(0.0, 0.0, hx, s), (0.0, 0.0, s, hy)]
    raise ValueError(f"unknown object kind {kind!r}; choose box, square_box, cylinder, T, L or X")


def _pack_object_shapes(shapes) -> np.ndarray:
    """Object shapes (one list of parts per object, or a single list) -> float32 [O, P, 4], padded with no-op parts."""
    if shapes is None or len(shapes) == 0:
        return np.zeros((0, 1, 4), dtype=np.float32)
    first = shapes[0]
    if np.ndim(first) == 1:  # a single object given as one list of parts
        shapes = [shapes]
    lists = [np.asarray(s, dtype=np.float32).reshape(-1, 4) for s in shapes]
    if any(len(p) == 0 for p in lists):
        raise ValueError("every object shape needs at least one part (cx, cy, hx, hy)")
    num_parts = max(len(p) for p in lists)
    # Padding part: a disc of negative radius, which no point is ever inside.
    packed = np.tile(np.array([0.0, 0.0, -1.0, 0.0], dtype=np.float32), (len(lists), num_parts, 1))
    for o, p in enumerate(lists):
        if not np.all(np.isfinite(p)) or np.any(p[:, 2] <= 0):
            raise ValueError(f"object {o}: parts must be finite with hx > 0, got {p.tolist()}")
        packed[o, : len(p)] = p
    return packed


class TopDownRenderer:
    """Draws tiles, movers (footprint + collision shape with margin, red when collided), goals, objects and
    obstacles, seen from above, for one world or a grid ("mosaic") of worlds.

    Args:
        layout: the tile layout (lower-left corner at the origin).
        mover: mover spec (footprint size, collision shape, radius/half sizes, margin); default ``MoverSpec()``.
        worlds: number of worlds to show (worlds ``0..n-1``) or the list of world indices, one per mosaic cell.
        cols: mosaic columns (default ``ceil(sqrt(n))``).
        px_per_tile: pixels per tile edge (resolution).
        border_px: width of the dark separators between (and around) cells.
        object_shapes: one list of parts ``(cx, cy, hx, hy)`` per object (see :func:`object_parts`).
        goal_radius: radius of the goal disc in metres (at least 2.5 pixels).
        grid, safety_zone, heading, goal_lines: toggle tile lines, collision-shape zone, yaw mark, mover->goal lines
            (``goal_lines=None``: on for up to 4 worlds, off in bigger mosaics where they are clutter).
        window: ``(cx, cy, width, height)`` in metres: draw only this part of each world (a zoomed view at
            ``px_per_tile``; the work per frame is the window's pixels). Default: the whole layout.
        state_colors: RGB colours ``[S, 3]`` (0..255) of per-mover states, for ``draw(..., state=...)`` (default
            :data:`colors.STATE_PALETTE`: moving, idle, collided, carrying, waiting).
        min_mover_px: a mover whose footprint is narrower than a few pixels is drawn as a plain square of at least
            this half width in pixels (default 1: 2 x 2 pixels), so that whole-world views of big swarms stay legible.
        device: Warp device, name or ``torch.device`` (default: Warp's preferred device); inputs are moved to it.
    """

    def __init__(
        self,
        layout: Layout,
        mover: MoverSpec | None = None,
        *,
        worlds: int | Sequence[int] = 1,
        cols: int | None = None,
        px_per_tile: int = 48,
        border_px: int = 2,
        object_shapes=None,
        goal_radius: float = 0.02,
        grid: bool = True,
        safety_zone: bool = True,
        heading: bool = True,
        goal_lines: bool | None = None,
        window: Sequence[float] | None = None,
        state_colors=None,
        min_mover_px: float = 1.0,
        device=None,
    ):
        # The steps run in this order so that the first bad option is the one reported.
        self._check_options(layout, mover, px_per_tile, min_mover_px, border_px, device)
        self._cell_geometry(window, min_mover_px, goal_radius)
        cell_worlds = self._parse_worlds(worlds)  # parsed before the style, checked after it
        self.style = self._style_bits(grid, safety_zone, heading, goal_lines, len(cell_worlds))
        self._mosaic_geometry(cell_worlds, worlds, cols)
        self._palettes_and_shapes(state_colors, object_shapes)
        row_local, col_local = self._lookup_tables()
        self._draw_background(row_local, col_local)
        self._frame_buffers()

    def _check_options(self, layout, mover, px_per_tile, min_mover_px, border_px, device) -> None:
        """Check the layout and the scalar options; keep them with the device and the pixel scale."""
        if not isinstance(layout, Layout):
            raise TypeError(f"layout must be a magwarp.layout.Layout, got {type(layout).__name__}")
        self.layout = layout
        self.mover = mover if mover is not None else MoverSpec()
        if int(px_per_tile) < 1:
            raise ValueError(f"px_per_tile must be >= 1, got {px_per_tile}")
        if not (math.isfinite(min_mover_px) and min_mover_px >= 0):
            raise ValueError(f"min_mover_px must be a number >= 0, got {min_mover_px!r}")
        if int(border_px) < 0:
            raise ValueError(f"border_px must be >= 0, got {border_px}")
        self.device = warp_device(device)
        self.torch_device = wp.device_to_torch(self.device)
        self.px_per_tile = int(px_per_tile)
        self.px_per_m = self.px_per_tile / layout.tile.size
        self.border = int(border_px)

    def _cell_geometry(self, window, min_mover_px, goal_radius) -> None:
        """What each cell shows (the window or the whole layout), its size in pixels, and the smallest dot and goal."""
        nx, ny = self.layout.shape
        self.window = self._check_window(window)
        if self.window is None:
            self.origin = (0.0, 0.0)
            self.cell_w, self.cell_h = nx * self.px_per_tile, ny * self.px_per_tile
        else:
            cx, cy, ww, wh = self.window
            self.origin = (cx - 0.5 * ww, cy - 0.5 * wh)
            self.cell_w, self.cell_h = max(1, round(ww * self.px_per_m)), max(1, round(wh * self.px_per_m))
        self.min_dot = float(min_mover_px) / self.px_per_m
        self.goal_radius = max(float(goal_radius), 2.5 / self.px_per_m)

    @staticmethod
    def _parse_worlds(worlds) -> np.ndarray:
        """World index of each mosaic cell: ``0..n-1`` for a count ``n``, else the given indices (not yet checked)."""
        return np.arange(int(worlds)) if np.ndim(worlds) == 0 else np.asarray(worlds, dtype=np.int64).reshape(-1)

    @staticmethod
    def _style_bits(grid, safety_zone, heading, goal_lines, num_cells: int) -> int:
        """The kernels' ``DRAW_*`` bits; goal lines default to on for up to 4 cells."""
        if goal_lines is None:
            goal_lines = num_cells <= 4
        return (
            (K.DRAW_GRID if grid else 0)
            | (K.DRAW_SAFETY_ZONE if safety_zone else 0)
            | (K.DRAW_HEADING if heading else 0)
            | (K.DRAW_GOAL_LINES if goal_lines else 0)
        )

    def _mosaic_geometry(self, cell_worlds: np.ndarray, worlds, cols) -> None:
        """Check the worlds and columns; lay the cells out in rows and size the image."""
        if len(cell_worlds) == 0 or np.any(cell_worlds < 0):
            raise ValueError(f"worlds must be a positive count or a list of world indices >= 0, got {worlds!r}")
        self.num_cells = len(cell_worlds)
        self.cols = int(cols) if cols is not None else math.ceil(math.sqrt(self.num_cells))
        if self.cols < 1:
            raise ValueError(f"cols must be >= 1, got {cols}")
        self.rows = math.ceil(self.num_cells / self.cols)
        self.height = self.rows * (self.cell_h + self.border) + self.border
        self.width = self.cols * (self.cell_w + self.border) + self.border
        self._cell_worlds = wp.array(cell_worlds.astype(np.int32), dtype=wp.int32, device=self.device)
        self._cell_worlds_np = cell_worlds

    def _palettes_and_shapes(self, state_colors, object_shapes) -> None:
        """Upload the fixed, mover and (checked) state colours and the packed object shapes."""
        dev = self.device
        fixed = [
            colors.BACKGROUND, colors.TILE, colors.TILE_LINE, colors.HOLE, colors.HOLE_HATCH, colors.OBSTACLE,
            colors.OBSTACLE_EDGE, colors.OBJECT, colors.OBJECT_EDGE, colors.OBJECT_GOAL, colors.COLLISION,
            colors.HEADING, colors.GOAL_RING,
        ]
        assert len(fixed) == K.NUM_FIXED_COLORS
        # The kernels blend in 0..255 floats (no rescaling per pixel).
        self._fixed_colors = wp.array(np.asarray(fixed, dtype=np.float32), dtype=wp.vec3, device=dev)
        self._mover_colors = wp.array(np.asarray(colors.MOVER_PALETTE, dtype=np.float32), dtype=wp.vec3, device=dev)
        states = np.asarray(colors.STATE_PALETTE if state_colors is None else state_colors, dtype=np.float32)
        if states.ndim != 2 or states.shape[1] != 3 or len(states) == 0 or not np.all((states >= 0) & (states <= 255)):
            raise ValueError(f"state_colors must be RGB colours [S, 3] in 0..255, got {states.tolist()}")
        self.num_states = len(states)
        self._state_colors = wp.array(states, dtype=wp.vec3, device=dev)
        parts = _pack_object_shapes(object_shapes)
        self.num_objects = parts.shape[0]
        self._parts = wp.array(parts, dtype=wp.vec4, device=dev)

    def _lookup_tables(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-row and per-column tables of cell index and world coordinate; returns the pixel indices in the cell."""
        # Per-row / per-column lookup tables: mosaic cell index (-1 on separators), pixel index inside the cell and
        # the pixel centre's world coordinate. They replace integer divisions per pixel with two loads.
        dev = self.device
        row_cell, row_local = self._axis_tables(self.height, self.cell_h)
        col_cell, col_local = self._axis_tables(self.width, self.cell_w)
        self._row_cell = wp.array(row_cell, dtype=wp.int32, device=dev)
        self._col_cell = wp.array(col_cell, dtype=wp.int32, device=dev)
        x0, y0 = self.origin
        self._row_y = wp.array((y0 + (self.cell_h - row_local - 0.5) / self.px_per_m).astype(np.float32), device=dev)
        self._col_x = wp.array((x0 + (col_local + 0.5) / self.px_per_m).astype(np.float32), device=dev)
        return row_local, col_local

    def _draw_background(self, row_local: np.ndarray, col_local: np.ndarray) -> None:
        """Draw the static background (tiles, holes, grid lines, separators) once, into ``_background``."""
        dev, layout = self.device, self.layout
        self._background = wp.zeros((self.height, self.width, 3), dtype=wp.uint8, device=dev)
        wp.launch(
            K.draw_background,
            dim=(self.height, self.width),
            inputs=[
                wp.array(layout.tiles, dtype=wp.int32, device=dev), float(layout.tile.size), float(self.px_per_m),
                self.num_cells, self.cols, self._row_cell, self._col_cell,
                wp.array(row_local, dtype=wp.int32, device=dev), wp.array(col_local, dtype=wp.int32, device=dev),
                self._row_y, self._col_x, self._fixed_colors, int(self.style),
            ],
            outputs=[self._background],
            device=dev,
        )

    def _frame_buffers(self) -> None:
        """Allocate the frame image, choose the pixels per thread and empty the per-frame caches."""
        dev = self.device
        self._image = wp.zeros((self.height, self.width, 3), dtype=wp.uint8, device=dev)
        # Pixels per thread along a row: one on GPUs; on CPUs a run amortises the per-call cost of a thread.
        self.run_length = 1 if self.device.is_cuda else 64
        self._launch_dim = (self.height, (self.width + self.run_length - 1) // self.run_length)
        self._image_torch = wp.to_torch(self._image)
        self._keep = None  # inputs of the last launch, kept alive until the next one
        self._reject_cache = (None, 0.0)
        self._bins = None  # per-tile mover/goal bins, allocated for the first big swarm
        self._no_bins = None

    def _axis_tables(self, length: int, cell: int) -> tuple[np.ndarray, np.ndarray]:
        s = np.arange(length) - self.border
        idx = np.floor_divide(s, cell + self.border)
        local = s - idx * (cell + self.border)
        idx = np.where((s < 0) | (local >= cell), -1, idx)
        return idx.astype(np.int32), local.astype(np.int32)

    def _check_window(self, window) -> tuple[float, float, float, float] | None:
        """``(cx, cy, width, height)`` metres, finite, positive sizes, overlapping the layout; None: no window."""
        if window is None:
            return None
        try:
            w = tuple(float(v) for v in window)
        except (TypeError, ValueError):
            raise ValueError(f"window must be (cx, cy, width, height) in metres, got {window!r}") from None
        if len(w) != 4 or not all(math.isfinite(v) for v in w) or w[2] <= 0 or w[3] <= 0:
            raise ValueError(f"window must be 4 finite numbers (cx, cy, width, height) with positive sizes (m), "
                             f"got {window!r}")
        sx, sy = (n * self.layout.tile.size for n in self.layout.shape)
        if w[0] + 0.5 * w[2] <= 0 or w[0] - 0.5 * w[2] >= sx or w[1] + 0.5 * w[3] <= 0 or w[1] - 0.5 * w[3] >= sy:
            raise ValueError(f"window {w} lies outside the layout (x in [0, {sx:g}], y in [0, {sy:g}] m)")
        if w[2] * self.px_per_m * w[3] * self.px_per_m > 1 << 26:
            raise ValueError(f"window {w} at {self.px_per_tile} px per tile is over 64 megapixels: lower px_per_tile")
        return w

    def _reject_radius(self, radii_t, half_t, user_sizes: bool) -> float:
        """Radius around a mover's centre that holds everything drawn for it (+2 px), for the kernel's cheap reject.

        Computed on the host; for user-given sizes it is cached per tensor version to avoid a sync every frame."""
        foot = float(np.hypot(0.5 * self.mover.size[0], 0.5 * self.mover.size[1]))
        m = self.mover.margin
        if not user_sizes:
            zone = self.mover.bounding_radius(m)
        else:
            key = (radii_t.data_ptr(), radii_t._version, tuple(radii_t.shape), half_t.data_ptr(), half_t._version,
                   tuple(half_t.shape), self.mover.collision_shape)
            if self._reject_cache[0] == key:
                return self._reject_cache[1]
            if self.mover.collision_shape == "circle":
                zone = float(radii_t.max()) + m if radii_t.numel() else 0.0
            else:
                zone = float(torch.linalg.vector_norm(half_t + m, dim=-1).max()) if half_t.numel() else 0.0
        radius = max(zone, foot, math.sqrt(2.0) * self.min_dot) + 2.0 / self.px_per_m
        if user_sizes:
            self._reject_cache = (key, radius)
        return radius

    # ------------------------------------------------------------------ geometry helpers
    @property
    def shape(self) -> tuple[int, int, int]:
        """Image shape ``(H, W, 3)``."""
        return (self.height, self.width, 3)

    @property
    def worlds(self) -> np.ndarray:
        """World index shown in each mosaic cell (row-major)."""
        return self._cell_worlds_np.copy()

    def select(self, worlds: Sequence[int]) -> None:
        """Show other worlds in the same cells (the number of cells is fixed at construction)."""
        w = np.asarray(worlds, dtype=np.int64).reshape(-1)
        if len(w) != self.num_cells or np.any(w < 0):
            raise ValueError(f"select needs {self.num_cells} world indices >= 0, got {list(w)}")
        self._cell_worlds.assign(w.astype(np.int32))
        self._cell_worlds_np = w

    def cell_origin(self, cell: int) -> tuple[int, int]:
        """Pixel (row, col) of the top-left corner of mosaic cell ``cell``."""
        r, c = divmod(int(cell), self.cols)
        return self.border + r * (self.cell_h + self.border), self.border + c * (self.cell_w + self.border)

    def world_to_pixel(self, xy, cell: int = 0) -> np.ndarray:
        """Continuous pixel coordinates ``(row, col)`` of world points ``xy [..., 2]`` in mosaic cell ``cell``
        (pixel ``(r, c)`` covers ``[r, r+1) x [c, c+1)``; its centre is at ``(r + 0.5, c + 0.5)``)."""
        xy = np.asarray(xy, dtype=np.float64)
        r0, c0 = self.cell_origin(cell)
        x0, y0 = self.origin
        return np.stack([r0 + self.cell_h - (xy[..., 1] - y0) * self.px_per_m, c0 + (xy[..., 0] - x0) * self.px_per_m],
                        axis=-1)

    # ------------------------------------------------------------------ drawing
    def draw(
        self,
        pos,
        rot=None,
        *,
        flags=None,
        radii=None,
        half_sizes=None,
        goals=None,
        object_poses=None,
        object_goals=None,
        obstacles=None,
        object_shape=None,
        state=None,
    ) -> torch.Tensor:
        """Draw one frame; returns the renderer's ``uint8 [H, W, 3]`` tensor on its device.

        Args:
            pos: mover centres ``[W, M, 2|3]`` (m); only x, y are used.
            rot: yaw ``[W, M]`` (rad) or quaternions ``[W, M, 4]`` (x, y, z, w); ``None`` means yaw 0.
            flags: collision bit flags ``[W, M]`` (non-zero = collided, drawn red).
            radii: collision circle radii ``[M]`` or ``[W, M]`` (default from the mover spec).
            half_sizes: collision box half sizes ``[M, 2]`` or ``[W, M, 2]`` (default from the mover spec).
            goals: goal positions ``[W, M, 2]``.
            object_poses: object poses ``[W, O, 3]`` (x, y, yaw) or ``[W, 3]`` for one object.
            object_goals: object goal poses, same shapes as ``object_poses``.
            obstacles: static rectangles ``[K, 4|5]`` or ``[W, K, 4|5]``: (cx, cy, hx, hy[, yaw]).
            object_shape: which of the renderer's ``object_shapes`` each world's objects have, ints ``[W, O]`` (or
                ``[W]`` for one object); default: object ``o`` has shape ``o``. Lets worlds differ (size variants).
            state: per-mover states ``[W, M]``, ints indexing ``state_colors``: each mover is drawn in its state's
                colour instead of its index colour (big swarms: moving, idle, collided, ...).
        Any per-world array may omit W (or have W = 1) to be shared by all worlds.
        """
        td = self.torch_device
        pos_t = per_world(pos, trailing=(2,), allow_trailing=(2, 3), name="pos", device=td)
        num_worlds, num_movers = pos_t.shape[0], pos_t.shape[1]
        if rot is None:
            rot_t = torch.zeros((1, num_movers, 1), dtype=torch.float32, device=td)
        else:
            rot_t = as_tensor(rot, device=td, dtype=torch.float32, name="rot")
            if rot_t.ndim >= 2 and rot_t.shape[-1] == 4 and rot_t.shape[-2] == num_movers:
                rot_t = per_world(rot_t, trailing=(4,), name="rot (quaternions)", device=td, num_items=num_movers)
            else:
                rot_t = per_world(rot_t, trailing=(), name="rot (yaw)", device=td, num_items=num_movers).unsqueeze(-1)
        if int(self._cell_worlds_np.max()) >= num_worlds:
            raise ValueError(
                f"the mosaic shows worlds up to {int(self._cell_worlds_np.max())}, but pos has only {num_worlds} world(s)"
            )
        if flags is None:
            flags_t = torch.zeros((1, 0), dtype=torch.int32, device=td)
        else:
            flags_t = per_world(flags, trailing=(), name="flags", device=td, dtype=torch.int32, num_items=num_movers)
        if radii is None:
            radii_t = torch.full((1, num_movers), self.mover.collision_radius, dtype=torch.float32, device=td)
        else:
            radii_t = per_world(radii, trailing=(), name="radii", device=td, num_items=num_movers)
        if half_sizes is None:
            half_t = torch.tensor(self.mover.collision_half_size, dtype=torch.float32, device=td).expand(1, num_movers, 2).contiguous()
        else:
            half_t = per_world(half_sizes, trailing=(2,), name="half_sizes", device=td, num_items=num_movers)
        if goals is None:
            goals_t = torch.zeros((1, 0, 2), dtype=torch.float32, device=td)
        else:
            goals_t = per_world(goals, trailing=(2,), name="goals", device=td, num_items=num_movers)
        if object_shape is None:
            shape_t = torch.arange(self.num_objects, dtype=torch.int32, device=td)[None]
        else:
            shape_t = as_tensor(object_shape, device=td, dtype=torch.int32, name="object_shape")
            shape_t = shape_t[:, None] if shape_t.ndim == 1 else shape_t
            if shape_t.ndim != 2:
                raise ValueError(f"object_shape must have shape [W, O] or [W], got {tuple(shape_t.shape)}")
            lo, hi = (int(shape_t.min()), int(shape_t.max())) if shape_t.numel() else (0, 0)
            if lo < 0 or hi >= self.num_objects:
                raise ValueError(f"object_shape must index the renderer's {self.num_objects} object shapes, "
                                 f"got values from {lo} to {hi}")
        if state is None:
            state_t = torch.zeros((1, 0), dtype=torch.int32, device=td)
        else:
            state_t = per_world(state, trailing=(), name="state", device=td, dtype=torch.int32, num_items=num_movers)
        obj_t = self._object_poses(object_poses, "object_poses", num_worlds, shape_t.shape[1])
        objg_t = self._object_poses(object_goals, "object_goals", num_worlds, shape_t.shape[1])
        if obstacles is None:
            obst_t = torch.zeros((1, 0, 5), dtype=torch.float32, device=td)
        else:
            obst_t = per_world(obstacles, trailing=(5,), allow_trailing=(4, 5), name="obstacles", device=td)
            if obst_t.shape[-1] == 4:  # no yaw given: axis-aligned
                obst_t = torch.cat([obst_t, torch.zeros_like(obst_t[..., :1])], dim=-1)

        reject = self._reject_radius(radii_t, half_t, radii is not None or half_sizes is not None)
        bins = self._bin(pos_t, goals_t, num_movers)
        inputs = [
            self._background, self.num_cells, self.cols, self._row_cell, self._col_cell, self._row_y, self._col_x,
            float(self.px_per_m), self._cell_worlds, int(self.run_length),
            K.SHAPE_BOX if self.mover.collision_shape == "box" else K.SHAPE_CIRCLE,
            wp.vec2(0.5 * self.mover.size[0], 0.5 * self.mover.size[1]), float(self.mover.margin), float(reject),
            wp.from_torch(radii_t), wp.from_torch(half_t), self._parts, wp.from_torch(shape_t.contiguous()),
            self._fixed_colors, self._mover_colors,
            float(self.goal_radius), int(self.style), float(self.layout.tile.size),
            max(1, math.ceil(reject / self.layout.tile.size)), self._state_colors, float(self.min_dot),
            wp.from_torch(pos_t), wp.from_torch(rot_t), wp.from_torch(flags_t), wp.from_torch(goals_t),
            wp.from_torch(obj_t), wp.from_torch(objg_t), wp.from_torch(obst_t), wp.from_torch(state_t), *bins,
        ]
        self._keep = (pos_t, rot_t, flags_t, radii_t, half_t, goals_t, obj_t, objg_t, obst_t, shape_t, state_t)
        if self.device.is_cuda:
            # Launch on torch's current stream so the frame is ordered with the caller's torch work.
            with wp.ScopedStream(torch_stream(td)):
                self._launch(inputs, pos_t, goals_t, bins)
        else:
            self._launch(inputs, pos_t, goals_t, bins)
        return self._image_torch

    def _launch(self, inputs, pos_t, goals_t, bins) -> None:
        dev = self.device
        if bins[0].shape[0] > 0:  # big swarm: bin movers and goals by tile first (3 small ops + 1 launch)
            for arr in (bins[0], bins[2], bins[4]):
                arr.zero_()
            wp.launch(K.bin_movers, dim=(self.num_cells, pos_t.shape[1]), device=dev,
                      inputs=[self._cell_worlds, float(self.layout.tile.size), wp.from_torch(pos_t), wp.from_torch(goals_t)],
                      outputs=list(bins))
        wp.launch(K.draw_topdown, dim=self._launch_dim, inputs=inputs, outputs=[self._image], device=dev)

    def _bin(self, pos_t, goals_t, num_movers: int) -> tuple:
        """Per-tile bins for big swarms (more movers than the kernel's 31-bit row band covers), else empty arrays."""
        if num_movers <= K.BAND_MOVERS:
            if self._no_bins is None:
                dev = self.device
                self._no_bins = (wp.zeros((0, 1, 1), dtype=wp.int32, device=dev), wp.zeros((0, 1, 1, 1), dtype=wp.int32, device=dev),
                                 wp.zeros((0, 1, 1), dtype=wp.int32, device=dev), wp.zeros((0, 1, 1, 1), dtype=wp.int32, device=dev),
                                 wp.zeros(0, dtype=wp.int32, device=dev))
            return self._no_bins
        if self._bins is None:
            dev, (nx, ny), c, cap = self.device, self.layout.shape, self.num_cells, K.BIN_CAPACITY
            self._bins = (wp.zeros((c, nx, ny), dtype=wp.int32, device=dev), wp.zeros((c, nx, ny, cap), dtype=wp.int32, device=dev),
                          wp.zeros((c, nx, ny), dtype=wp.int32, device=dev), wp.zeros((c, nx, ny, cap), dtype=wp.int32, device=dev),
                          wp.zeros(c, dtype=wp.int32, device=dev))
        return self._bins

    def draw_numpy(self, *args, **kwargs) -> np.ndarray:
        """:meth:`draw`, returned as a fresh numpy ``uint8 [H, W, 3]`` array."""
        return to_numpy_image(self.draw(*args, **kwargs))

    def _object_poses(self, poses, name: str, num_worlds: int, num_objects: int) -> torch.Tensor:
        td = self.torch_device
        if poses is None:
            return torch.zeros((1, 0, 3), dtype=torch.float32, device=td)
        if self.num_objects == 0:
            raise ValueError(f"{name} given, but the renderer was built without object_shapes")
        t = as_tensor(poses, device=td, dtype=torch.float32, name=name)
        if t.ndim == 2 and num_objects == 1 and t.shape[-1] == 3 and t.shape[0] != 1:
            t = t.unsqueeze(1)  # [W, 3] -> [W, 1, 3]
        return per_world(t, trailing=(3,), name=name, device=td, num_items=num_objects)
