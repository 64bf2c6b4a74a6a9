"""Batched collision queries in MagBotSim's terms, on the device, with the simulator's own shape tests.

MagBotSim answers one configuration per call (``check_mover_collision``, ``qpos_is_valid``); :class:`CollisionQuery`
answers a whole batch of them in one launch, on CPU or GPU, with the Warp functions that the
:class:`~magwarp.sim.Simulator` runs every cycle (:func:`~magwarp.kernels.collision.movers_collide_cs`,
:func:`~magwarp.kernels.collision.hits_wall_cs`)::

    q = CollisionQuery(layout, shape="box", offset=0.01, offset_wall=0.005)
    out = q(poses, sizes, add_safety_offset=True)   # poses [..., M, 3] (x, y, yaw); sizes [..., M, 2] half sizes
    out.mover_collision  # [..., M] bool: collides with another mover of its configuration
    out.wall_valid       # [..., M] bool: MagBotSim's qpos_is_valid (footprint on the tiles, holes included)

Sizes and margins follow MagBotSim's ``collision_params``:

* ``size``: circle radius ``[M]`` / ``[..., M]`` (or one number), or box half sizes ``[M, 2]`` / ``[..., M, 2]`` (or
  one pair), so per mover and per configuration;
* ``offset``: the safety offset, added to every mover's size when ``add_safety_offset`` is true, for the
  mover-mover test *and* the wall test (MagBotSim: ``c_size + offset * add_safety_offset``);
* ``offset_wall``: always added to the size for the wall test.

Mover-mover: circles collide when ``|p_i - p_j| <= r_i + r_j``, boxes (yaw-rotated rectangles) when they overlap or
touch. Wall: a footprint that overlaps a missing tile or leaves the layout is invalid; one that only touches the
edge of the tiled area is valid. The clearance is the signed distance between two movers' (grown) shapes: the gap
when apart, 0 at contact, minus the penetration depth when they overlap (MagBotSim does not give it). The wall
clearance is the footprint's (grown by the wall offsets) signed distance to the area without tiles (holes and outside
the layout): >= 0 exactly where the pose is valid; gaps larger than one tile size read as one tile size.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass

import numpy as np
import torch
import warp as wp

from magwarp._checks import warp_device
from magwarp._streams import torch_stream
from magwarp.kernels import collision as kcol
from magwarp.layout import Layout
from magwarp.types import SHAPE_BOX, SHAPE_CIRCLE, Collision

__all__ = ["CollisionQuery", "CollisionReport"]


@dataclass
class CollisionReport:
    """Answers for poses ``[..., M, 3]`` (tensors on the query's device)."""

    pair_collision: torch.Tensor  # [..., M, M] bool, symmetric, False on the diagonal
    mover_collision: torch.Tensor  # [..., M] bool: collides with at least one other mover
    wall_valid: torch.Tensor  # [..., M] bool: True where the footprint stays on the tiles (qpos_is_valid)
    pair_clearance: torch.Tensor  # [..., M, M] float32 signed distance between the grown shapes, +inf on the diagonal
    clearance: torch.Tensor  # [..., M] float32: each mover's smallest pair clearance (+inf for a single mover)
    wall_clearance: torch.Tensor  # [..., M] float32 signed distance to the area without tiles, up to one tile size

    @property
    def any_collision(self) -> torch.Tensor:
        """[...] bool: MagBotSim's ``check_mover_collision`` answer for each configuration."""
        return self.mover_collision.any(dim=-1)


def float32_tensor(name: str, value, device: torch.device, *, check_finite: bool = True) -> torch.Tensor:
    """``value`` (a tensor, array or nested list of real numbers) as a float32 tensor on ``device``; a non-number or
    (with ``check_finite``) a NaN/inf raises an error naming ``name`` and the first bad entry."""
    if isinstance(value, torch.Tensor):
        if value.dtype.is_complex or value.dtype == torch.bool:
            raise TypeError(f"{name} must be real numbers, got dtype {value.dtype}")
        t = value.detach().to(device=device, dtype=torch.float32)
    else:
        arr = np.asarray(value)
        if arr.dtype.kind not in "fiu":
            raise TypeError(f"{name} must be numbers, got {value!r}")
        t = torch.as_tensor(arr.astype(np.float32), device=device)
    if check_finite and not bool(torch.isfinite(t).all()):
        bad = torch.nonzero(~torch.isfinite(t))[0].tolist()
        raise ValueError(f"{name} contains a non-finite value at index {bad}: {t[tuple(bad)].item()}")
    return t


class CollisionQuery:
    """Mover-mover and mover-wall checks for batches of mover poses on one tile layout.

    ``layout``: a :class:`~magwarp.layout.Layout` or 0/1 array (holes allowed). ``shape``: ``"circle"`` or ``"box"``.
    ``offset`` / ``offset_wall``: MagBotSim's ``collision_params["offset"]`` / ``["offset_wall"]`` (m, >= 0).
    ``device``: ``"cpu"``, ``"cuda:N"`` or None (the simulator's default). ``check_inputs``: refuse non-finite poses
    and non-positive sizes with an error naming the value (a device sync per call; turn off in tight device loops).
    See the module docstring.
    """

    def __init__(self, layout: Layout | np.ndarray, shape: str = "circle", *, offset: float = 0.0,
                 offset_wall: float = 0.0, device: str | None = None, check_inputs: bool = True):
        self.layout = layout if isinstance(layout, Layout) else Layout(np.asarray(layout))
        if shape not in ("circle", "box"):
            raise ValueError(f"shape must be 'circle' or 'box', got {shape!r}")
        for name, value in (("offset", offset), ("offset_wall", offset_wall)):
            if not (isinstance(value, (int, float, np.floating, np.integer)) and np.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
        self.shape = shape
        self.check_inputs = bool(check_inputs)
        self.offset = float(offset)
        self.offset_wall = float(offset_wall)
        self.device = warp_device(device)
        self.torch_device = torch.device("cuda", self.device.ordinal) if self.device.is_cuda else torch.device("cpu")
        self._tiles = wp.array(self.layout.tiles.astype(np.int32), dtype=wp.int32, device=self.device)

    def _collision(self, add_safety_offset: bool) -> Collision:
        col = Collision()
        col.shape = SHAPE_CIRCLE if self.shape == "circle" else SHAPE_BOX
        grow = self.offset if add_safety_offset else 0.0
        col.margin = grow  # added to every mover's size: r_i + r_j + 2 offset, half sizes + offset
        col.wall_margin = self.offset_wall + grow
        col.tile_size = float(self.layout.tile.size)
        col.stop_on_collision = 0
        col.full_rect = 1 if bool(self.layout.tiles.all()) else 0
        col.extent = wp.vec2(*self.layout.extent)
        return col

    # ------------------------------------------------------------------ inputs
    def _tensor(self, name: str, value) -> torch.Tensor:
        if isinstance(value, torch.Tensor) and value.device != self.torch_device:
            raise ValueError(f"{name} is on device {value.device}, but the query runs on {self.torch_device}")
        return float32_tensor(name, value, self.torch_device, check_finite=self.check_inputs)

    def _sizes(self, size, batch: tuple[int, ...], m: int) -> tuple[torch.Tensor, torch.Tensor]:
        s = self._tensor("size", size)
        if self.shape == "circle":
            try:
                r = torch.broadcast_to(s, (*batch, m))
            except RuntimeError:
                raise ValueError(f"circle sizes (radii) must broadcast to {(*batch, m)}, "
                                 f"got shape {tuple(s.shape)}") from None
            if self.check_inputs and bool((r <= 0).any()):
                raise ValueError(f"circle radii must be positive, got {r[r <= 0][0].item()}")
            return r.reshape(-1, m).contiguous(), torch.zeros(r.numel(), 2, device=self.torch_device).reshape(-1, m, 2)
        try:
            h = torch.broadcast_to(s, (*batch, m, 2))
        except RuntimeError:
            raise ValueError(f"box sizes (half sizes) must broadcast to {(*batch, m, 2)}, "
                             f"got shape {tuple(s.shape)}") from None
        if self.check_inputs and bool((h <= 0).any()):
            raise ValueError(f"box half sizes must be positive, got {h[h <= 0][0].item()}")
        return torch.zeros(h.shape[:-1], device=self.torch_device).reshape(-1, m), h.reshape(-1, m, 2).contiguous()

    # ------------------------------------------------------------------ queries
    def __call__(self, poses, size, add_safety_offset: bool = False) -> CollisionReport:
        """Check configurations ``poses [..., M, 3]`` (x, y, yaw; yaw ignored by circles) of movers of sizes ``size``
        (see the module docstring). Returns a :class:`CollisionReport`."""
        if not isinstance(add_safety_offset, (bool, np.bool_)):
            raise TypeError(f"add_safety_offset must be a bool, got {add_safety_offset!r}")
        p = self._tensor("poses", poses)
        if p.dim() < 2 or p.shape[-1] != 3:
            raise ValueError(f"poses must have shape [..., M, 3] (x, y, yaw), got {tuple(p.shape)}")
        batch, m = tuple(p.shape[:-2]), int(p.shape[-2])
        radius, half = self._sizes(size, batch, m)
        flat = p.reshape(-1, m, 3).contiguous()
        n = flat.shape[0]
        dev = self.torch_device
        pair = torch.empty(n, m, m, dtype=torch.bool, device=dev)  # the kernels write every entry
        clear = torch.empty(n, m, m, dtype=torch.float32, device=dev)
        mover = torch.empty(n, m, dtype=torch.bool, device=dev)
        mover_clear = torch.empty(n, m, dtype=torch.float32, device=dev)
        valid = torch.empty(n, m, dtype=torch.bool, device=dev)
        wall_clear = torch.empty(n, m, dtype=torch.float32, device=dev)
        col = self._collision(bool(add_safety_offset))
        if n * m > 0:
            wp_poses = wp.from_torch(flat, dtype=wp.vec3)
            wp_r = wp.from_torch(radius)
            wp_h = wp.from_torch(half, dtype=wp.vec2)
            wp_pair, wp_clear = wp.from_torch(pair, dtype=wp.bool), wp.from_torch(clear)
            stream = torch_stream(dev) if self.device.is_cuda else None
            with wp.ScopedStream(stream) if stream is not None else contextlib.nullcontext():
                wp.launch(kcol.query_poses, dim=(n, m), device=self.device,
                          inputs=[self._tiles, col, wp_poses, wp_r, wp_h],
                          outputs=[wp_pair, wp_clear, wp.from_torch(valid, dtype=wp.bool), wp.from_torch(wall_clear)])
                wp.launch(kcol.query_movers, dim=(n, m), device=self.device, inputs=[wp_pair, wp_clear],
                          outputs=[wp.from_torch(mover, dtype=wp.bool), wp.from_torch(mover_clear)])
        return CollisionReport(
            pair_collision=pair.reshape(*batch, m, m),
            mover_collision=mover.reshape(*batch, m),
            wall_valid=valid.reshape(*batch, m),
            pair_clearance=clear.reshape(*batch, m, m),
            clearance=mover_clear.reshape(*batch, m),
            wall_clearance=wall_clear.reshape(*batch, m),
        )

