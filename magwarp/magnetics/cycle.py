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

__all__ = ["ControlCycle", "CycleOutputs", "CycleParams", "cycle_kernel", "cycle_mover"]

commutate_block = COMMUTATE[vec6f]


@wp.struct
class CycleParams:
    """What a cycle reads besides the movers' state: the wrench table and its window, the coils' resistances and
    limits, the commutation's options."""

    table: WrenchTable
    slot_layer: wp.array(dtype=wp.int32)
    slot_offset: wp.array(dtype=wp.vec2i)
    resistance: wp.array(dtype=wp.float64)
    limit: wp.array(dtype=wp.float64)
    max_iter: int
    reg: wp.float64


@wp.struct
class CycleOutputs:
    """What a cycle writes per mover (flat index): the look-up's coil ids, columns and counts, and the commutation's
    result (:class:`~magwarp.magnetics.commutation.CommutationResult`)."""

    coil_ids: wp.array2d(dtype=wp.int32)
    gamma: wp.array2d(dtype=vec6f)
    count: wp.array(dtype=wp.int32)
    currents: wp.array2d(dtype=wp.float64)
    saturated: wp.array2d(dtype=wp.int32)
    delivered: wp.array(dtype=vec6d)
    residual: wp.array(dtype=vec6d)
    loss: wp.array(dtype=wp.float64)
    flags: wp.array(dtype=wp.int32)


@wp.func
def cycle_mover(m: int, lane: int, c: CycleParams, pos: wp.vec3d, quat: wp.quatd, wanted: vec6d, o: CycleOutputs):
    """Mover ``m``'s cycle by its block (this thread: ``lane``): the look-up of its slots, then the commutation;
    thread 0 writes the mover's count, wrench, residual, loss and flags. Returns the delivered wrench, the copper
    loss and the flags (the same on every thread)."""
    x = float(pos[0])
    y = float(pos[1])
    z = float(pos[2])
    yaw = quat_yaw(quat)
    a = mat66d()
    for j in range(lane, o.gamma.shape[1], wp.block_dim()):
        k, col = slot_column(c.table, c.slot_layer, c.slot_offset, j, x, y, z, yaw)
        o.coil_ids[m, j] = k
        o.gamma[m, j] = col
        o.saturated[m, j] = 0
        if k >= 0:
            a = add_coil(a, as_vec6d(col), c.resistance[k])
    out, p, flag, n = commutate_block(m, lane, c.resistance, c.limit, c.max_iter, c.reg, o.gamma, o.coil_ids, wanted,
                                      a, o.currents, o.saturated)
    if lane == 0:
        o.count[m] = n
        o.delivered[m] = out
        o.residual[m] = wanted - out
        o.loss[m] = p
        o.flags[m] = flag
    return out, p, flag


@wp.kernel
def cycle_kernel(
    # Model:
    c: CycleParams,
    # State in:
    pos: wp.array(dtype=wp.vec3d),
    quat: wp.array(dtype=wp.quatd),
    wanted: wp.array(dtype=vec6d),
    # State out:
    o: CycleOutputs,
):
    """One block per mover: the look-up of its slots, then least-loss currents within the limits."""
    m, lane = wp.tid()
    cycle_mover(m, lane, c, pos[m], quat[m], wanted[m], o)


def cycle_params(model: TableModel, commutation: Commutation) -> CycleParams:
    """The :class:`CycleParams` of a table model and a commutation (on the same device)."""
    if not isinstance(model, TableModel):
        raise MagneticsError(f"the control cycle needs a TableModel, got {type(model).__name__}")
    if model.device != commutation.device:
        raise MagneticsError(f"the control cycle: the model is on {model.device}, the commutation on "
                             f"{commutation.device}")
    c = CycleParams()
    c.table, c.slot_layer, c.slot_offset = model.table, model.slot_layer, model.slot_offset
    c.resistance, c.limit = commutation.resistance, commutation.limit
    c.max_iter, c.reg = int(commutation.options.max_iter), wp.float64(commutation.options.regularization)
    return c


def cycle_outputs(coil_ids: wp.array, gamma: wp.array, count: wp.array, res: CommutationResult) -> CycleOutputs:
    """The :class:`CycleOutputs` of these arrays."""
    o = CycleOutputs()
    o.coil_ids, o.gamma, o.count = coil_ids, gamma, count
    o.currents, o.saturated, o.delivered, o.residual = res.currents, res.saturated, res.delivered, res.residual
    o.loss, o.flags = res.loss, res.flags
    return o


def cycle_buffers(model: TableModel, commutation: Commutation, n: int):
    """The arrays of ``n`` movers' control cycles, zeroed (coil ids -1): ``(coil_ids, count, gamma, result)`` (as
    :meth:`TableModel.columns` and :meth:`Commutation.solve` fill them), with the one-launch cycle's
    :class:`CycleParams` and :class:`CycleOutputs` over them."""
    dev, slots = model.device, model.max_active
    ids = wp.full((n, slots), -1, dtype=wp.int32, device=dev)
    count = wp.zeros(n, dtype=wp.int32, device=dev)
    gamma = wp.zeros((n, slots), dtype=vec6f, device=dev)
    res = CommutationResult.zeros(n, slots, dev)
    return ids, count, gamma, res, cycle_params(model, commutation), cycle_outputs(ids, gamma, count, res)


def check_arrays(where: str, shapes: dict, arrays: dict, device) -> None:
    """Refuse, naming it, an array whose shape is not its expected one (``shapes``: name -> (shape, expected)) or
    that lives on another device than ``device`` (a kernel on one device reading another's memory crashes the
    process); ``None`` arrays are skipped."""
    for name, (got, want) in shapes.items():
        if tuple(got) != want:
            raise MagneticsError(f"{where}: {name} has shape {tuple(got)}, expected {want}")
    for name, a in arrays.items():
        if a is not None and a.device != device:
            raise MagneticsError(f"{where}: {name} is on {a.device}, the model on {device}")


class ControlCycle:
    """The wrench-table look-up of ``model`` (:class:`~magwarp.magnetics.table.TableModel`) and the commutation of
    ``commutation`` (its resistances, limits, options and threads per mover) in one launch."""

    def __init__(self, model: TableModel, commutation: Commutation):
        self.params = cycle_params(model, commutation)
        self.model, self.commutation = model, commutation

    def run(self, pos: wp.array, quat: wp.array, wanted: wp.array, coil_ids: wp.array, gamma: wp.array,
            count: wp.array, out: CommutationResult) -> CommutationResult:
        """Coil ids, columns and counts (as :meth:`TableModel.columns`) and the commutation's result ``out`` (as
        :meth:`Commutation.solve`) for movers at ``pos``/``quat`` (float64) wanting ``wanted`` (``vec6d``)."""
        n, slots = pos.shape[0], self.model.max_active
        shapes = {"quat": (quat.shape, (n,)), "wanted": (wanted.shape, (n,)), "coil_ids": (coil_ids.shape, (n, slots)),
                  "gamma": (gamma.shape, (n, slots)), "count": (count.shape, (n,)),
                  "currents": (out.currents.shape, (n, slots))}
        arrays = {"pos": pos, "quat": quat, "wanted": wanted, "coil_ids": coil_ids, "gamma": gamma, "count": count,
                  "currents": out.currents}
        check_arrays("ControlCycle.run", shapes, arrays, self.model.device)
        wp.launch_tiled(cycle_kernel, dim=[n], block_dim=self.commutation.block_dim, device=self.model.device,
                        inputs=[self.params, pos, quat, wanted],
                        outputs=[cycle_outputs(coil_ids, gamma, count, out)])
        return out
