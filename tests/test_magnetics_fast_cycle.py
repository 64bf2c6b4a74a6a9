"""The fast control cycle (a few lanes per mover, the no-saturation answer first: magwarp/magnetics/fast_cycle.py)
against the block cycle (magwarp/magnetics/cycle.py) and the float64 least-squares reference, on the CPU (one lane,
and 8 lanes emulated by CPU blocks) and, when there is one, on a GPU (8 lanes, warp shuffles)."""

from __future__ import annotations

import re

import numpy as np
import pytest
import warp as wp

from magnetics_helpers import CYCLE_PARAMS as PARAMS, CYCLE_SPEC as SPEC  # the coarse table (tests/ is on sys.path)
from magnetics_helpers import cpu_blocks, cycle_model  # noqa: F401  (fixtures)

from magwarp.layout import Layout
from magwarp.magnetics import reference as ref
from magwarp.magnetics.commutation import (FLAG_NO_COILS, FLAG_NOT_CONVERGED, FLAG_REGULARISED, Commutation,
                                           CommutationResult, vec6f)
from magwarp.magnetics.cycle import ControlCycle
from magwarp.magnetics.exact import vec6d
from magwarp.magnetics.fast_cycle import FastCycle
from magwarp.magnetics.geometry import MagneticsError
from magwarp.magnetics.table import TableModel


@pytest.fixture(scope="module")
def model(cycle_model):
    """The coarse table model (magnetics_helpers.cycle_model)."""
    return cycle_model


def movers(rng, n: int, acc: float = 12.0, off: int = 2):
    """Random level poses over the layout (``off`` of them off the tiles: no coils) and hover wrenches plus planar
    accelerations up to ``acc`` m/s^2 (some saturate)."""
    poses = np.c_[rng.uniform(0.05, 0.67, n), rng.uniform(0.05, 0.43, n), rng.uniform(0.003, 0.005, n) + 0.006,
                  np.zeros((n, 2)), rng.uniform(-4.0, 4.0, n)]
    poses[:off, 0] = 2.0  # beyond the layout
    wanted = np.c_[1.24 * rng.uniform(-acc, acc, (n, 2)), np.full(n, 1.24 * 9.81), rng.uniform(-0.05, 0.05, (n, 3))]
    return poses, wanted


def run_block(model, pos, quat, w):
    n, slots, dev = pos.shape[0], model.max_active, model.device
    ids = wp.empty((n, slots), dtype=wp.int32, device=dev)
    gamma = wp.empty((n, slots), dtype=vec6f, device=dev)
    count = wp.zeros(n, dtype=wp.int32, device=dev)
    com = Commutation(model.coilset, device=dev, block_dim=1 if dev.is_cpu else None)
    res = ControlCycle(model, com).run(pos, quat, w, ids, gamma, count, CommutationResult.zeros(n, slots, dev))
    return ids, gamma, count, res


def check_same(fast, block, flags, where):
    """The fast cycle's result equals the block cycle's: the same saturations and flags; currents, wrench and loss to
    rounding (1e-10 A where unregularised; regularised systems amplify rounding by up to 1 / regularization)."""
    for key in ("saturated", "flags"):
        assert np.array_equal(getattr(fast, key).numpy(), getattr(block, key).numpy()), (where, key)
    regd = (flags & FLAG_REGULARISED) != 0
    for key, tol in (("currents", 1e-10), ("delivered", 1e-10), ("residual", 1e-10), ("loss", 1e-9)):
        a, b = getattr(fast, key).numpy(), getattr(block, key).numpy()
        d = np.abs(a - b).reshape(len(flags), -1).max(axis=1)
        assert d[~regd].max(initial=0.0) <= tol * max(1.0, np.abs(b).max()), (where, key, d[~regd].max())
        assert d[regd].max(initial=0.0) <= 1e-5 * max(1.0, np.abs(b).max()), (where, key, d[regd].max())


@pytest.mark.parametrize("lanes,split", [(1, False), (1, True), (8, False), (8, True)])
def test_fast_cycle_matches_block_cycle_and_reference(model, rng, cpu_blocks, lanes, split):
    """Feasible, saturating, infeasible (not converged) and coil-less movers: the fast cycle gives the block cycle's
    ids, columns, counts, saturations and flags, its currents to rounding; the currents match the float64 reference
    on the same columns, never exceed the limits, and deliver the wanted wrench where it is feasible."""
    n = 40
    poses, wanted = movers(rng, n)
    wanted[2:6, :2] = np.sign(wanted[2:6, :2]) * 500.0  # far beyond reach: every coil at its limit
    pos, quat = model.as_arrays(poses)
    w = wp.array(wanted, dtype=vec6d, device="cpu")
    ids, gamma, count, block = run_block(model, pos, quat, w)
    slots = model.max_active
    f_ids, f_gamma = wp.empty((n, slots), dtype=wp.int32, device="cpu"), wp.empty((n, slots), dtype=vec6f, device="cpu")
    f_count = wp.zeros(n, dtype=wp.int32, device="cpu")
    cyc = FastCycle(model, Commutation(model.coilset, device="cpu"), lanes=lanes, split=split)
    fast = cyc.run(pos, quat, w, CommutationResult.zeros(n, slots, "cpu"), f_count, f_ids, f_gamma)
    assert np.array_equal(f_ids.numpy(), ids.numpy()) and np.array_equal(f_count.numpy(), count.numpy())
    np.testing.assert_array_equal(f_gamma.numpy(), gamma.numpy())
    flags = block.flags.numpy()
    check_same(fast, block, flags, f"{rng} lanes={lanes} split={split}")
    sat = fast.saturated.numpy().any(1)
    assert sat.sum() >= 5 and not sat.all(), rng
    assert (flags & FLAG_NOT_CONVERGED).any() and (flags[:2] == FLAG_NO_COILS).all(), (rng, flags)
    if split:
        assert cyc.rest_movers == int(((flags != FLAG_NO_COILS) & (sat | ((flags & FLAG_NOT_CONVERGED) != 0))).sum())
    cur, g, i = fast.currents.numpy(), f_gamma.numpy().astype(np.float64), ids.numpy()
    limit, res = model.coilset.current_limit, model.coilset.resistance
    for m in range(n):
        act = i[m] >= 0
        assert np.all(cur[m][~act] == 0.0)
        if not act.any():
            continue
        want, delivered, s, regd, conv = ref.commutate(g[m][act].T, res[i[m][act]], limit[i[m][act]], wanted[m])
        # float64 against the float64 reference, the same steps: the block cycle's test saw 3.3e-8 A (2.3e-8 of it)
        # on seed 2965831887303052183, past 1e-8 + 1e-8 relative
        np.testing.assert_allclose(cur[m][act], want, rtol=1e-7, atol=1e-7 if not regd else 1e-5, err_msg=f"{rng} {m}")
        assert np.all(np.abs(cur[m][act]) <= limit[i[m][act]]), (rng, m)
        np.testing.assert_allclose(fast.loss.numpy()[m], (res[i[m][act]] * want ** 2).sum(), rtol=1e-8, atol=1e-9)
        if conv and not regd:  # feasible (and well-conditioned): delivered exactly
            np.testing.assert_allclose(fast.delivered.numpy()[m], wanted[m], atol=1e-9, err_msg=f"{rng} {m}")


@pytest.mark.parametrize("lanes", [1, 8])
def test_straight_first_kernel_matches_the_loop(model, rng, cpu_blocks, lanes):
    """The split cycle's first kernel as straight-line code gives the general mover's bits (stopped after its first
    solve) for every output; it leaves to the active-set steps the same movers and those whose system needs
    regularisation (here at the layout's edge, where few coils lie under the mover)."""
    n = 40
    poses, wanted = movers(rng, n)
    wanted[2:6, :2] = np.sign(wanted[2:6, :2]) * 500.0
    poses[6:12, 0] = np.linspace(0.675, 0.72, 6)  # at the edge: regularised
    pos, quat = model.as_arrays(poses)
    w = wp.array(wanted, dtype=vec6d, device="cpu")
    outs, rest = [], []
    for straight in (False, True):
        cyc = FastCycle(model, Commutation(model.coilset, device="cpu"), lanes=lanes, split=True, straight=straight)
        count = wp.zeros(n, dtype=wp.int32, device="cpu")
        outs.append((cyc.run(pos, quat, w, CommutationResult.zeros(n, model.max_active, "cpu"), count), count))
        rest.append(cyc.rest_movers)
    (a, ca), (b, cb) = outs
    regd = int(((a.flags.numpy() & FLAG_REGULARISED) != 0).sum())
    assert regd >= 3 and rest[0] <= rest[1] <= rest[0] + regd and 5 <= rest[0] < n - 2, (rng, rest, regd)
    np.testing.assert_array_equal(ca.numpy(), cb.numpy())
    for key in ("currents", "saturated", "delivered", "residual", "loss", "flags"):
        np.testing.assert_array_equal(getattr(a, key).numpy(), getattr(b, key).numpy(), err_msg=f"{rng} {key}")
    assert (b.flags.numpy()[:2] == FLAG_NO_COILS).all()


def test_rest_block_is_checked(model, cpu_blocks):
    com = Commutation(model.coilset, device="cpu")
    for bad in (0, 12, 2048, 1.5, True, float("nan"), float("inf"), "64"):
        want = rf"rest_block must be a multiple of lanes=8 .* got {re.escape(repr(bad))}"
        with pytest.raises(MagneticsError, match=want):
            FastCycle(model, com, lanes=8, rest_block=bad)
    for bad in (-1, 2.5, float("nan"), "128", True):
        want = rf"max_registers must be a non-negative integer, got {re.escape(repr(bad))}"
        with pytest.raises(MagneticsError, match=want):
            FastCycle(model, com, lanes=8, max_registers=bad)
    assert FastCycle(model, com, lanes=8, rest_block=16).rest_block == 16
    with pytest.raises(MagneticsError, match="straight must be True or False, got 'no'"):
        FastCycle(model, com, straight="no")


def test_fast_cycle_options_and_errors(model):
    com = Commutation(model.coilset, device="cpu")
    with pytest.raises(MagneticsError, match="lanes must be one of .* got 3"):
        FastCycle(model, com, lanes=3)
    saved = wp.config.enable_cpu_blocks
    wp.config.enable_cpu_blocks = False
    try:
        with pytest.raises(MagneticsError, match="lanes=8 on a CPU needs warp.config.enable_cpu_blocks"):
            FastCycle(model, com, lanes=8)
    finally:
        wp.config.enable_cpu_blocks = saved
    pos, quat = model.as_arrays(np.array([[0.3, 0.2, 0.01, 0.0, 0.0, 0.0]]))
    w = wp.zeros(1, dtype=vec6d, device="cpu")
    with pytest.raises(MagneticsError, match=r"currents has shape \(1, 3\)"):
        FastCycle(model, com).run(pos, quat, w, CommutationResult.zeros(1, 3, "cpu"))
    with pytest.raises(MagneticsError, match="TableModel"):
        FastCycle(object(), com)
    # no ids or columns asked: the same currents
    out = FastCycle(model, com).run(pos, quat, w, CommutationResult.zeros(1, model.max_active, "cpu"))
    assert out.flags.numpy()[0] == 0 and np.abs(out.delivered.numpy()[0]).max() < 1e-9


@pytest.mark.parametrize("split", [False, True])
def test_gpu_fast_cycle_matches_block_cycle(model, devices, rng, split):
    """On a GPU (when there is one): 8 lanes per mover (warp shuffles) give the block cycle's saturations and flags
    and its currents to rounding, on the GPU's own columns (a mover count that leaves a partly filled warp)."""
    if len(devices) < 2:
        pytest.skip("no CUDA device")
    gpu = TableModel(Layout.grid(3, 2), PARAMS, SPEC, device=devices[1])  # the same cached table
    n = 1001
    poses, wanted = movers(rng, n)
    pos, quat = gpu.as_arrays(poses)
    w = wp.array(wanted, dtype=vec6d, device=gpu.device)
    ids, gamma, count, block = run_block(gpu, pos, quat, w)
    cyc = FastCycle(gpu, Commutation(gpu.coilset, device=gpu.device), split=split)
    assert cyc.lanes == 8
    f_count = wp.zeros(n, dtype=wp.int32, device=gpu.device)
    fast = cyc.run(pos, quat, w, CommutationResult.zeros(n, gpu.max_active, gpu.device), f_count)
    assert np.array_equal(f_count.numpy(), count.numpy())
    check_same(fast, block, block.flags.numpy(), f"{rng} split={split}")
    assert fast.saturated.numpy().any(), rng
