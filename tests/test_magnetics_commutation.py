"""Commutation: least-copper-loss coil currents under current limits, against float64 references."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from magnetics_helpers import cpu_blocks  # noqa: F401  (a fixture; tests/ is on sys.path)

from magwarp.layout import Layout
from magwarp.magnetics import reference as ref
from magwarp.magnetics.commutation import (FLAG_NO_COILS, FLAG_NOT_CONVERGED, FLAG_OVERFLOW, FLAG_REGULARISED,
                                           Commutation, CommutationOptions)
from magwarp.magnetics.exact import vec6d
from magwarp.magnetics.geometry import CoilSet, MagneticsError

SLOTS = 12
NUM_COILS = 30


class FakeCoils:
    """A coil set with random resistances and limits (commutation only needs those)."""

    def __init__(self, rng):
        self.num_coils = NUM_COILS
        self.resistance = rng.uniform(0.3, 1.0, NUM_COILS)
        self.current_limit = rng.uniform(2.0, 6.0, NUM_COILS)


def random_problem(rng, n: int, empty: float = 0.2):
    """Random Gammas (forces ~ 1 N/A, torques ~ 0.05 N m/A) with some empty slots, and coil ids."""
    gamma = rng.normal(size=(n, SLOTS, 6)) * np.array([1.0, 1.0, 1.0, 0.05, 0.05, 0.05])
    ids = np.stack([rng.choice(NUM_COILS, SLOTS, replace=False) for _ in range(n)]).astype(np.int32)
    ids[rng.random((n, SLOTS)) < empty] = -1
    ids[:, :8] = np.abs(ids[:, :8])  # at least 8 coils: full rank
    gamma[ids < 0] = 0.0
    return gamma, ids


def run(coils, gamma, ids, wrench, count=None, options=None, dtype=vec6d):
    com = Commutation(coils, options, device="cpu")
    count = (ids >= 0).sum(1) if count is None else count
    res = com.solve(wp.array(gamma, dtype=dtype, device="cpu"), wp.array(ids, dtype=wp.int32, device="cpu"),
                    wp.array(np.asarray(count, dtype=np.int32), dtype=wp.int32, device="cpu"),
                    wp.array(wrench, dtype=vec6d, device="cpu"))
    return {k: getattr(res, k).numpy() for k in ("currents", "saturated", "delivered", "residual", "loss", "flags")}


def min_loss(gamma_m, ids_m, coils, w):
    """float64 least-squares reference: i = R^-1/2 pinv(Gamma R^-1/2) w (the least sum R i^2 with Gamma i = w)."""
    act = ids_m >= 0
    r = coils.resistance[ids_m[act]]
    g = gamma_m[act].T / np.sqrt(r)
    i = np.linalg.lstsq(g, w, rcond=None)[0] / np.sqrt(r)
    return i, float((r * i * i).sum())


def test_feasible_wrench_delivered_exactly_with_least_loss(rng):
    coils = FakeCoils(rng)
    coils.current_limit[:] = 1e6  # no limit reached
    gamma, ids = random_problem(rng, 64)
    wrench = rng.normal(size=(64, 6)) * np.array([10.0, 10.0, 20.0, 0.5, 0.5, 0.5])
    out = run(coils, gamma, ids, wrench)
    assert np.allclose(out["delivered"], wrench, rtol=0, atol=1e-9 * np.abs(wrench).max()), rng
    assert np.all(out["flags"] == 0) and not out["saturated"].any(), rng
    for m in range(64):
        i, loss = min_loss(gamma[m], ids[m], coils, wrench[m])
        assert np.allclose(out["currents"][m][ids[m] >= 0], i, rtol=1e-8, atol=1e-10), (rng, m)
        assert out["loss"][m] == pytest.approx(loss, rel=1e-9), (rng, m)
    assert np.all(out["currents"][ids < 0] == 0.0)


@pytest.mark.parametrize("size", [3.0, 10.0, 1000.0])
def test_limits_match_reference_and_are_never_exceeded(rng, size):
    coils = FakeCoils(rng)
    gamma, ids = random_problem(rng, 64)
    wrench = rng.normal(size=(64, 6)) * np.array([1.0, 1.0, 1.0, 0.05, 0.05, 0.05]) * size
    out = run(coils, gamma, ids, wrench)
    limit = np.where(ids >= 0, coils.current_limit[ids], 0.0)
    assert np.all(np.abs(out["currents"]) <= limit), rng
    for m in range(64):
        act = ids[m] >= 0
        k = ids[m][act]
        stats = {}
        cur, delivered, sat, regd, conv = ref.commutate(gamma[m][act].T, coils.resistance[k], coils.current_limit[k],
                                                        wrench[m], stats=stats)
        # each solve but a converged last one fixes at least one coil; one solve where none is fixed
        assert (stats["solves"] == 1) == (not sat.any()) and stats["solves"] <= sat.sum() + 1, (rng, m, stats)
        # A regularised (nearly singular) system amplifies rounding: compare to 1e-6 of the limits there.
        atol = 1e-6 * coils.current_limit.max() if regd else 1e-12
        assert np.allclose(out["currents"][m][act], cur, rtol=1e-9, atol=atol), (rng, m)
        assert np.array_equal(out["saturated"][m][act].astype(bool), sat), (rng, m)
        assert bool(out["flags"][m] & FLAG_NOT_CONVERGED) == (not conv), (rng, m)
        assert bool(out["flags"][m] & FLAG_REGULARISED) == regd, (rng, m)
        assert np.allclose(out["delivered"][m], delivered, rtol=1e-9, atol=1e3 * atol), (rng, m)
        assert out["loss"][m] == pytest.approx((coils.resistance[k] * cur * cur).sum(), rel=1e-6 if regd else 1e-9)
        assert out["loss"][m] == pytest.approx((coils.resistance[k] * out["currents"][m][act] ** 2).sum(), rel=1e-12)
    assert np.allclose(out["residual"], wrench - out["delivered"], atol=1e-12)
    if size >= 1000.0:  # infeasible: every mover reports what it could not deliver
        assert out["saturated"].any(axis=1).all(), rng
        rel = np.linalg.norm(out["residual"], axis=1) / np.linalg.norm(wrench, axis=1)
        assert np.all(rel > 0.1), rng


def test_wrench_reachable_within_limits_is_delivered(rng):
    """Wrenches made from currents within 0.6 of the limits are delivered (the fixed-set rule suffices), with no
    more loss than those currents."""
    coils = FakeCoils(rng)
    gamma, ids = random_problem(rng, 64, empty=0.0)
    i0 = rng.uniform(-0.6, 0.6, (64, SLOTS)) * coils.current_limit[ids]
    wrench = np.einsum("msk,ms->mk", gamma, i0)
    out = run(coils, gamma, ids, wrench)
    assert np.allclose(out["delivered"], wrench, rtol=0, atol=1e-9 * np.abs(wrench).max()), rng
    assert np.all(out["loss"] <= (coils.resistance[ids] * i0 ** 2).sum(1) * (1 + 1e-12)), rng


def test_no_coils_overflow_and_ill_conditioned_are_flagged(rng):
    coils = FakeCoils(rng)
    gamma, ids = random_problem(rng, 3)
    ids[0] = -1
    gamma[0] = 0.0
    gamma[1][:, 3:] = 0.0  # no torque authority: singular
    wrench = np.ones((3, 6))
    out = run(coils, gamma, ids, wrench, count=[0, SLOTS, SLOTS + 5])
    assert out["flags"][0] == FLAG_NO_COILS and np.all(out["currents"][0] == 0)
    assert np.allclose(out["residual"][0], wrench[0])
    assert out["flags"][1] & FLAG_REGULARISED and np.all(np.isfinite(out["currents"][1]))
    assert np.linalg.norm(out["residual"][1][3:]) > 0.5  # the torque cannot be delivered, and says so
    assert out["flags"][2] & FLAG_OVERFLOW


def test_float32_columns_solve_as_their_float64_values(rng):
    """The table model's float32 columns: the same solve as the float64 kernel on the same (rounded) columns."""
    from magwarp.magnetics.commutation import vec6f

    coils = FakeCoils(rng)
    gamma, ids = random_problem(rng, 32)
    gamma = gamma.astype(np.float32).astype(np.float64)
    wrench = rng.normal(size=(32, 6)) * np.array([8.0, 8.0, 20.0, 0.3, 0.3, 0.3])
    a, b = run(coils, gamma, ids, wrench), run(coils, gamma.astype(np.float32), ids, wrench, dtype=vec6f)
    for key in ("currents", "saturated", "delivered", "loss", "flags"):
        np.testing.assert_allclose(b[key], a[key], rtol=1e-12, atol=1e-12, err_msg=f"{rng} {key}")
    assert a["saturated"].any() and not a["saturated"].all()


def test_bad_inputs_raise(rng):
    coils = CoilSet.build(Layout.grid(1, 1))
    with pytest.raises(MagneticsError, match="resistance"):
        Commutation(coils, resistance=np.zeros(coils.num_coils), device="cpu")
    with pytest.raises(MagneticsError, match="max_iter"):
        CommutationOptions(max_iter=0)
    com = Commutation(coils, device="cpu")
    g = wp.zeros((2, 4), dtype=vec6d, device="cpu")
    with pytest.raises(MagneticsError, match="agree"):
        com.solve(g, wp.zeros((2, 3), dtype=wp.int32, device="cpu"), wp.zeros(2, dtype=wp.int32, device="cpu"),
                  wp.zeros(2, dtype=vec6d, device="cpu"))


def test_block_of_threads_matches_one_thread(rng, cpu_blocks):
    """A mover's slots split over a block of threads (the GPU's shape; sums reduced over the block): the same
    currents, saturations and flags as one thread per mover, and the reference's."""
    coils = FakeCoils(rng)
    gamma, ids = random_problem(rng, 24)
    wrench = rng.normal(size=(24, 6)) * np.array([4.0, 4.0, 8.0, 0.2, 0.2, 0.2])
    com = {b: Commutation(coils, device="cpu", block_dim=b) for b in (1, 5)}
    args = [wp.array(gamma, dtype=vec6d, device="cpu"), wp.array(ids, dtype=wp.int32, device="cpu"),
            wp.array((ids >= 0).sum(1).astype(np.int32), dtype=wp.int32, device="cpu"),
            wp.array(wrench, dtype=vec6d, device="cpu")]
    out = {b: c.solve(*args) for b, c in com.items()}
    one, five = out[1], out[5]
    # Sums in another order: rounding, carried through the active-set steps.
    np.testing.assert_allclose(five.currents.numpy(), one.currents.numpy(), rtol=1e-8, atol=1e-9, err_msg=str(rng))
    np.testing.assert_allclose(five.delivered.numpy(), one.delivered.numpy(), rtol=1e-8, atol=1e-8, err_msg=str(rng))
    np.testing.assert_allclose(five.loss.numpy(), one.loss.numpy(), rtol=1e-8, err_msg=str(rng))
    assert np.array_equal(five.saturated.numpy(), one.saturated.numpy()), rng
    assert np.array_equal(five.flags.numpy(), one.flags.numpy()), rng
    assert one.saturated.numpy().any() and not one.saturated.numpy().all(), rng
    for m in range(24):
        act = ids[m] >= 0
        k = ids[m][act]
        cur, *_ = ref.commutate(gamma[m][act].T, coils.resistance[k], coils.current_limit[k], wrench[m])
        np.testing.assert_allclose(five.currents.numpy()[m][act], cur, rtol=1e-9, atol=1e-6, err_msg=f"{rng} {m}")
    with pytest.raises(MagneticsError, match="block_dim"):
        Commutation(coils, device="cpu", block_dim=0)
