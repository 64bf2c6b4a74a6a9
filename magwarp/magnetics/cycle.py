"""The magnetic control cycle in one launch: wrench-table look-up and commutation fused, one thread block per mover.

    cycle = ControlCycle(table_model, commutation)          # block_dim: 32 threads per mover on a GPU, 1 on a CPU
    cycle.run(pos, quat, wanted, coil_ids, gamma, count, result)

Each thread of a mover's block takes the window slots ``lane, lane + block_dim, ...``: it looks their columns up
(:func:`~magwarp.magnetics.table.slot_column`, the wrench-table model) and keeps them for the commutation, which
runs as in :mod:`~magwarp.magnetics.commutation` (the same primal active-set steps, float64 arithmetic, the same
results to rounding), with every per-coil pass split over the block's threads and its sums (the free coils' 6 x 6
matrix, the step length, the fixed coils' wrench, the delivered wrench and the loss) reduced over the block
(``wp.tile_sum`` / ``wp.tile_min``); every thread then solves the same 6 x 6 system. Compared with the two launches
(look-up, then one thread per mover reading its columns back in ``[mover][slot]`` order), a mover's columns are read
by the threads that wrote them, in adjacent addresses (coalesced), and a mover's serial chain of passes is
``block_dim`` times shorter. The columns still go to ``gamma`` (float32, what :attr:`TableModel.columns` gives), so
callers see the same arrays.

On a CPU, Warp runs one thread per block unless ``warp.config.enable_cpu_blocks`` is set (the tests set it, to run
the multi-thread reductions here too).
"""

from __future__ import annotations

import warp as wp

from magwarp.magnetics.commutation import (COMMUTATE, Commutation, CommutationResult, add_coil, as_vec6d, mat66d,
                                           vec6f)
from magwarp.magnetics.exact import vec6d
from magwarp.magnetics.geometry import MagneticsError
from magwarp.magnetics.table import TableModel, WrenchTable, quat_yaw, slot_column

__all__ = ["ControlCycle", "cycle_kernel", "cycle_mover"]

commutate_block = COMMUTATE[vec6f]


@wp.func
def cycle_mover(
    m: int,
    lane: int,
    t: WrenchTable,
    slot_layer: wp.array(dtype=wp.int32),
    slot_offset: wp.array(dtype=wp.vec2i),
    resistance: wp.array(dtype=wp.float64),
    limit: wp.array(dtype=wp.float64),
    max_iter: int,
    reg: wp.float64,
    pos: wp.vec3d,
    quat: wp.quatd,
    wanted: vec6d,
    coil_ids: wp.array2d(dtype=wp.int32),
    gamma: wp.array2d(dtype=vec6f),
    currents: wp.array2d(dtype=wp.float64),
    saturated: wp.array2d(dtype=wp.int32),
):
    """Mover ``m``'s cycle by its block (this thread: ``lane``): the look-up of its slots, then the commutation.
    Returns the delivered wrench, the copper loss, the flags and the coil count (the same on every thread)."""
    x = float(pos[0])
    y = float(pos[1])
    z = float(pos[2])
    yaw = quat_yaw(quat)
    a = mat66d()
    for j in range(lane, gamma.shape[1], wp.block_dim()):
        k, col = slot_column(t, slot_layer, slot_offset, j, x, y, z, yaw)
        coil_ids[m, j] = k
        gamma[m, j] = col
        saturated[m, j] = 0
        if k >= 0:
            a = add_coil(a, as_vec6d(col), resistance[k])
    return commutate_block(m, lane, resistance, limit, max_iter, reg, gamma, coil_ids, wanted, a, currents,
                           saturated)


@wp.kernel
def cycle_kernel(
    # Model:
    t: WrenchTable,
    slot_layer: wp.array(dtype=wp.int32),
    slot_offset: wp.array(dtype=wp.vec2i),
    resistance: wp.array(dtype=wp.float64),
    limit: wp.array(dtype=wp.float64),
    max_iter: int,
    reg: wp.float64,
    # State in:
    pos: wp.array(dtype=wp.vec3d),
    quat: wp.array(dtype=wp.quatd),
    wanted: wp.array(dtype=vec6d),
    # State out:
    coil_ids: wp.array2d(dtype=wp.int32),
    gamma: wp.array2d(dtype=vec6f),
    count: wp.array(dtype=wp.int32),
    currents: wp.array2d(dtype=wp.float64),
    saturated: wp.array2d(dtype=wp.int32),
    delivered: wp.array(dtype=vec6d),
    residual: wp.array(dtype=vec6d),
    loss: wp.array(dtype=wp.float64),
    flags: wp.array(dtype=wp.int32),
):
    """One block per mover: the look-up of its slots, then least-loss currents within the limits."""
    m, lane = wp.tid()
    out, p, flag, n = cycle_mover(m, lane, t, slot_layer, slot_offset, resistance, limit, max_iter, reg, pos[m],
                                  quat[m], wanted[m], coil_ids, gamma, currents, saturated)
    if lane == 0:
        count[m] = n
        delivered[m] = out
        residual[m] = wanted[m] - out
        loss[m] = p
        flags[m] = flag


class ControlCycle:
    """The wrench-table look-up of ``model`` (:class:`~magwarp.magnetics.table.TableModel`) and the commutation of
    ``commutation`` (its resistances, limits, options and threads per mover) in one launch."""

    def __init__(self, model: TableModel, commutation: Commutation):
        if not isinstance(model, TableModel):
            raise MagneticsError(f"ControlCycle needs a TableModel, got {type(model).__name__}")
        if model.device != commutation.device:
            raise MagneticsError(f"ControlCycle: the model is on {model.device}, the commutation on "
                                 f"{commutation.device}")
        self.model, self.commutation = model, commutation

    def run(self, pos: wp.array, quat: wp.array, wanted: wp.array, coil_ids: wp.array, gamma: wp.array,
            count: wp.array, out: CommutationResult) -> CommutationResult:
        """Coil ids, columns and counts (as :meth:`TableModel.columns`) and the commutation's result ``out`` (as
        :meth:`Commutation.solve`) for movers at ``pos``/``quat`` (float64) wanting ``wanted`` (``vec6d``)."""
        n, slots = pos.shape[0], self.model.max_active
        shapes = {"quat": (quat.shape, (n,)), "wanted": (wanted.shape, (n,)), "coil_ids": (coil_ids.shape, (n, slots)),
                  "gamma": (gamma.shape, (n, slots)), "count": (count.shape, (n,)),
                  "currents": (out.currents.shape, (n, slots))}
        for name, (got, want) in shapes.items():
            if tuple(got) != want:
                raise MagneticsError(f"ControlCycle.run: {name} has shape {tuple(got)}, expected {want}")
        m, c = self.model, self.commutation
        wp.launch_tiled(cycle_kernel, dim=[n], block_dim=c.block_dim, device=m.device,
                        inputs=[m.table, m.slot_layer, m.slot_offset, c.resistance, c.limit,
                                int(c.options.max_iter), wp.float64(c.options.regularization), pos, quat, wanted],
                        outputs=[coil_ids, gamma, count, out.currents, out.saturated, out.delivered, out.residual,
                                 out.loss, out.flags])
        return out
