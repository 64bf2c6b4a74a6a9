"""The fused control cycle (wrench-table look-up + commutation in one launch) against the two launches it replaces
and the float64 references."""

from __future__ import annotations

import types

import numpy as np
import pytest
import warp as wp

from magnetics_helpers import CYCLE_PARAMS as PARAMS, CYCLE_SPEC as SPEC  # the coarse table (tests/ is on sys.path)
from magnetics_helpers import cpu_blocks, cycle_model  # noqa: F401  (fixtures)

from magwarp.layout import Layout
from magwarp.magnetics import reference as ref
from magwarp.magnetics.commutation import FLAG_NOT_CONVERGED, Commutation, CommutationResult
from magwarp.magnetics.commutation import vec6f as ModelCol
from magwarp.magnetics.cycle import ControlCycle
from magwarp.magnetics.exact import vec6d
from magwarp.magnetics.geometry import MagneticsError
from magwarp.magnetics.table import TableModel


@pytest.fixture(scope="module")
def model(cycle_model):
    """The coarse table model (magnetics_helpers.cycle_model)."""
    return cycle_model


@pytest.mark.parametrize("block_dim", [1, 8])
def test_cycle_matches_lookup_then_commutation(model, rng, cpu_blocks, block_dim):
    """One launch gives the look-up's ids, columns and counts and the commutation's currents, saturations, flags,
    wrench and loss (hover plus accelerations up to 12 m/s^2: some movers saturate); the currents match the
    float64 reference on the same columns and never exceed the limits."""
    n = 24
    poses = np.c_[rng.uniform(0.05, 0.67, n), rng.uniform(0.05, 0.43, n), rng.uniform(0.003, 0.005, n) + 0.006,
                  np.zeros((n, 2)), rng.uniform(-4.0, 4.0, n)]
    acc = rng.uniform(-12.0, 12.0, (n, 2))
    wanted = np.c_[1.24 * acc, np.full(n, 1.24 * 9.81), rng.uniform(-0.05, 0.05, (n, 3))]
    pos, quat = model.as_arrays(poses)
    w = wp.array(wanted, dtype=vec6d, device="cpu")
    com = Commutation(model.coilset, device="cpu", block_dim=block_dim)
    ids, gamma, count = model.columns(pos, quat)
    two = com.solve(gamma, ids, count, w)
    slots = model.max_active
    f_ids = wp.empty((n, slots), dtype=wp.int32, device="cpu")  # the model's device (not the default: a GPU there)
    f_gamma = wp.empty((n, slots), dtype=ModelCol, device="cpu")
    f_count = wp.zeros(n, dtype=wp.int32, device="cpu")
    one = ControlCycle(model, com).run(pos, quat, w, f_ids, f_gamma, f_count,
                                       CommutationResult.zeros(n, slots, "cpu"))
    assert np.array_equal(f_ids.numpy(), ids.numpy()) and np.array_equal(f_count.numpy(), count.numpy())
    np.testing.assert_array_equal(f_gamma.numpy(), gamma.numpy())
    for key in ("currents", "delivered", "loss"):  # the same sums (block_dim 8: in another order than one thread's)
        np.testing.assert_allclose(getattr(one, key).numpy(), getattr(two, key).numpy(), rtol=1e-10, atol=1e-10,
                                   err_msg=f"{rng} {key}")
    for key in ("saturated", "flags"):
        assert np.array_equal(getattr(one, key).numpy(), getattr(two, key).numpy()), (rng, key)
    sat = one.saturated.numpy().any(1)
    assert sat.any() and not sat.all(), rng
    cur, g, i = one.currents.numpy(), f_gamma.numpy().astype(np.float64), ids.numpy()
    limit = model.coilset.current_limit
    for m in range(n):
        act = i[m] >= 0
        want, delivered, s, regd, conv = ref.commutate(g[m][act].T, model.coilset.resistance[i[m][act]],
                                                    limit[i[m][act]], wanted[m])
        # many coils at their limit: many steps, each carrying the last one's rounding (amplified by the 6 x 6
        # system's conditioning: seed 2965831887303052183 put one current 3.3e-8 A, 2.3e-8 of it, off the reference)
        np.testing.assert_allclose(cur[m][act], want, rtol=1e-7, atol=1e-7, err_msg=f"{rng} {m}")
        assert np.abs(cur[m][act]).max() <= limit[i[m][act]].max()
        assert bool(one.flags.numpy()[m] & FLAG_NOT_CONVERGED) == (not conv)
        if conv and not regd:  # feasible (and well-conditioned): delivered exactly
            np.testing.assert_allclose(one.delivered.numpy()[m], wanted[m], atol=1e-9, err_msg=f"{rng} {m}")


def test_cycle_refuses_wrong_shapes(model):
    com = Commutation(model.coilset, device="cpu")
    pos, quat = model.as_arrays(np.array([[0.3, 0.2, 0.01, 0.0, 0.0, 0.0]]))
    slots = model.max_active

    def arrays(ids_slots=slots):
        return (wp.zeros(1, dtype=vec6d, device="cpu"), wp.empty((1, ids_slots), dtype=wp.int32, device="cpu"),
                wp.empty((1, slots), dtype=ModelCol, device="cpu"), wp.zeros(1, dtype=wp.int32, device="cpu"),
                CommutationResult.zeros(1, slots, "cpu"))

    with pytest.raises(MagneticsError, match="coil_ids"):
        ControlCycle(model, com).run(pos, quat, *arrays(ids_slots=slots + 1))
    # an array on another device is refused before the launch (it crashed the process)
    wanted, ids, gamma, count, res = arrays()
    if wp.is_cuda_available():
        count = wp.zeros(1, dtype=wp.int32, device="cuda:0")
    else:  # a stand-in of the right shape that says it lives on cuda:0
        count = types.SimpleNamespace(shape=count.shape, device="cuda:0")
    with pytest.raises(MagneticsError, match="count is on cuda:0, the model on cpu"):
        ControlCycle(model, com).run(pos, quat, wanted, ids, gamma, count, res)

    with pytest.raises(MagneticsError, match="TableModel"):
        ControlCycle(object(), com)


def test_gpu_cycle_matches_one_cpu_thread(model, devices, rng):
    """On a GPU (when there is one): the one-launch cycle (32 threads per mover, warp sums) gives the currents,
    saturations and flags of one CPU thread per mover on the GPU's own columns (movers that saturate included)."""
    if len(devices) < 2:
        pytest.skip("no CUDA device")
    gpu = TableModel(Layout.grid(3, 2), PARAMS, SPEC, device=devices[1])  # the same cached table
    n = 256
    poses = np.c_[rng.uniform(0.05, 0.67, n), rng.uniform(0.05, 0.43, n), rng.uniform(0.003, 0.005, n) + 0.006,
                  np.zeros((n, 2)), rng.uniform(-4.0, 4.0, n)]
    wanted = np.c_[1.24 * rng.uniform(-12.0, 12.0, (n, 2)), np.full(n, 1.24 * 9.81), rng.uniform(-0.05, 0.05, (n, 3))]
    pos, quat = gpu.as_arrays(poses)
    com = Commutation(gpu.coilset, device=gpu.device)
    slots = gpu.max_active
    ids, gamma = wp.empty((n, slots), dtype=wp.int32, device=gpu.device), wp.empty((n, slots), dtype=ModelCol,
                                                                                    device=gpu.device)
    count = wp.zeros(n, dtype=wp.int32, device=gpu.device)
    w = wp.array(wanted, dtype=vec6d, device=gpu.device)
    res = ControlCycle(gpu, com).run(pos, quat, w, ids, gamma, count, CommutationResult.zeros(n, slots, gpu.device))
    one = Commutation(model.coilset, device="cpu", block_dim=1).solve(
        *[wp.clone(a, device="cpu") for a in (gamma, ids, count, w)])
    np.testing.assert_allclose(res.currents.numpy(), one.currents.numpy(), rtol=1e-8, atol=1e-8, err_msg=str(rng))
    assert np.array_equal(res.saturated.numpy(), one.saturated.numpy()), rng
    assert np.array_equal(res.flags.numpy(), one.flags.numpy()), rng
    assert res.saturated.numpy().any(), rng
