"""Per-cycle geometric mover checks inside the mujoco-warp step graph: mover-mover and mover-wall collisions.

Movers never touch physically (contacts excluded in the MJCF), so, as in MagBotSim and :mod:`magwarp.sim`, their
collisions are detected geometrically after every control cycle with the same rules as the planar simulator
(circle or oriented-box footprints; a wall hit is any part of the footprint over a missing tile or off the grid).
The per-step result is ``flags_t[w]``: bit ``COLLIDE_MOVER`` (1) and/or ``COLLIDE_WALL`` (2), OR-ed over cycles.
Mover counts in pushing tasks are small, so the pair loop is all-pairs per world.
"""

from __future__ import annotations

import numpy as np
import torch
import warp as wp

from magwarp.kernels.collision import free_joint_xy_yaw, hits_wall, model_row, movers_collide, world_collision
from magwarp.layout import Layout, MoverSpec
from magwarp.physics.backend import MjwBackend
from magwarp.types import COLLIDE_MOVER, COLLIDE_WALL, SHAPE_BOX, SHAPE_CIRCLE, Collision

__all__ = ["MoverChecks"]


@wp.kernel
def mover_checks_kernel(
    # Model:
    tiles: wp.array2d[wp.int32],
    col_shared: Collision,
    qadr: wp.array[int],
    radius: wp.array2d[float],  # [1 or W, M]: shared until randomisation makes it per world
    half: wp.array2d[wp.vec2],
    margins: wp.array[wp.vec2],  # [1 or W]: (mover-mover margin, wall margin)
    # State in:
    qpos: wp.array2d[float],
    # State out:
    flags: wp.array[wp.int32],
):
    w, k = wp.tid()
    col = world_collision(col_shared, margins, w)
    rr = model_row(radius.shape[0], w)
    hr = model_row(half.shape[0], w)
    p, yaw = free_joint_xy_yaw(qpos, w, qadr[k])
    if hits_wall(tiles, col, p, yaw, radius[rr, k], half[hr, k]):
        wp.atomic_or(flags, w, COLLIDE_WALL)
    for j in range(k + 1, qadr.shape[0]):
        pj, yawj = free_joint_xy_yaw(qpos, w, qadr[j])
        if movers_collide(col, pj - p, yaw, radius[rr, k], half[hr, k], yawj, radius[rr, j], half[hr, j]):
            wp.atomic_or(flags, w, COLLIDE_MOVER)


class MoverChecks:
    """Registers the per-cycle check on ``backend``; ``flags_t`` ``[W]`` int32 holds this step's collision bits.

    ``mover`` gives the collision shape (``collision_shape``, ``collision_radius``/``collision_half_size``),
    ``margin`` (mover-mover) and ``wall_margin`` (per world after :meth:`per_world`). Call :meth:`clear` before each
    step.
    """

    def __init__(self, backend: MjwBackend, layout: Layout, mover: MoverSpec):
        self.backend = backend
        dev = backend.device
        m = backend.num_movers
        self._tiles = wp.array(layout.tiles.astype(np.int32), dtype=wp.int32, device=dev)
        col = Collision()
        col.shape = SHAPE_CIRCLE if mover.collision_shape == "circle" else SHAPE_BOX
        col.margin = float(mover.margin)
        col.wall_margin = float(mover.wall_margin)
        col.tile_size = float(layout.tile.size)
        col.stop_on_collision = 0
        self._col = col
        self._radius = wp.array(np.full((1, m), mover.collision_radius), dtype=float, device=dev)
        self._half = wp.array(np.tile(mover.collision_half_size, (1, m, 1)), dtype=wp.vec2, device=dev)
        self._margins = wp.array([[col.margin, col.wall_margin]], dtype=wp.vec2, device=dev)
        self.flags = wp.zeros(backend.num_worlds, dtype=wp.int32, device=dev)
        self.flags_t = wp.to_torch(self.flags)
        backend.add_cycle_hook(self._launch)

    def _launch(self) -> None:
        b = self.backend
        wp.launch(mover_checks_kernel, dim=(b.num_worlds, b.num_movers),
                  inputs=[self._tiles, self._col, b._qadr, self._radius, self._half, self._margins, b.data.qpos],
                  outputs=[self.flags], device=b.device)

    def per_world(self) -> dict[str, torch.Tensor]:
        """Give each world its own collision sizes and margins (one row shared by all until then): torch views
        ``{"radius": [W, M], "half_size": [W, M, 2], "margins": [W, 2] (mover-mover, wall)}`` to write between
        steps (the step graph reads them at every cycle). Drops the backend's recorded graphs."""
        W = self.backend.num_worlds
        for name in ("_radius", "_half", "_margins"):
            old = getattr(self, name)
            if old.shape[0] != W:
                setattr(self, name, wp.array(np.repeat(old.numpy(), W, axis=0), dtype=old.dtype, device=old.device))
        self.backend._step_graph = None
        self.backend._reset_graph = None
        return {"radius": wp.to_torch(self._radius), "half_size": wp.to_torch(self._half),
                "margins": wp.to_torch(self._margins)}

    def clear(self) -> None:
        self.flags_t.zero_()

    @property
    def mover_collision(self):
        return (self.flags_t & COLLIDE_MOVER) != 0

    @property
    def wall_collision(self):
        return (self.flags_t & COLLIDE_WALL) != 0
