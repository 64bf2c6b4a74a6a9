"""The magnetic drive in the simulator: coil currents from the commutation move the movers. Without saturation the
motion matches the ideal model; with low current limits the wrench falls short and it is reported."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from magnetics_helpers import cpu_blocks  # noqa: F401  (a fixture; tests/ is on sys.path)

from magwarp.layout import Layout
from magwarp.magnetics.commutation import FLAG_NOT_CONVERGED, FLAG_REGULARISED
from magwarp.magnetics.drive import AUX_DIM, MagneticDrive, MagneticModel, magnetic_force
from magwarp.magnetics.fast import FieldTableSpec
from magwarp.magnetics.table import WrenchTableSpec
from magwarp.magnetics.geometry import CoilSpec, MagneticParams, MagneticsError, Quadrature, TileCoils
from magwarp.sim import Simulator

# A coarse quadrature, field table and wrench table: seconds on a CPU.
SPEC = WrenchTableSpec(step=0.004, yaw_steps=8, z_step=0.002, gap=(0.003, 0.005),
                       field=FieldTableSpec(step=0.002, z_step=0.001, margin=0.08))


def params(limit: float) -> MagneticParams:
    return MagneticParams(coils=TileCoils(CoilSpec(current_limit=limit)), quadrature=Quadrature(2, 0.01),
                          active_radius=0.2)


def make(force_model=None, aux=1):
    return Simulator(Layout.grid(3, 3), num_movers=1, num_worlds=2, start_xy=[[[0.30, 0.33]], [[0.42, 0.36]]],
                     force_model=force_model, force_aux_dim=aux, device="cpu", stop_on_collision=False)


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    mp = pytest.MonkeyPatch()
    mp.setenv("MAGWARP_CACHE_DIR", str(tmp_path_factory.mktemp("magnetics_cache")))
    yield
    mp.undo()


def run(sim, cmd, cycles):
    sim.set_command(torch.as_tensor(cmd, dtype=torch.float32))
    for _ in range(cycles):
        sim.step(1)
    return sim.pos.numpy().copy(), sim.vel.numpy().copy()


@pytest.mark.parametrize("in_step", [True, False])
def test_motion_matches_ideal_model_without_saturation(cache, rng, in_step):
    """In the step kernels (float32) or as a pre-cycle hook (float64)."""
    # at least 1.5 m/s^2 on each axis, so that the movers move (a seed with ~1 m/s^2 on both reached 0.019 m/s)
    cmd = rng.uniform(1.5, 3.0, (2, 1, 2)) * rng.choice([-1.0, 1.0], (2, 1, 2))
    ideal = make()
    mag_sim = make(magnetic_force, AUX_DIM)
    drive = MagneticDrive(mag_sim, params(limit=1e3), SPEC, in_step=in_step)
    assert mag_sim._fused == in_step and bool(mag_sim._pre_hooks) != in_step  # in-step: the fused kernel stays
    p0, v0 = run(ideal, cmd, 20)
    p1, v1 = run(mag_sim, cmd, 20)
    np.testing.assert_allclose(p1, p0, atol=1e-6, err_msg=str(rng))
    np.testing.assert_allclose(v1, v0, atol=2e-5, err_msg=str(rng))
    assert np.abs(v1[..., :2]).max() > 0.02  # it moved
    loss = drive.loss.numpy()
    assert np.all(loss > 1.0) and np.all(loss < 1e3), loss  # hovering costs watts
    cur, ids = drive.currents.numpy(), drive.coil_ids.numpy()
    assert np.all(cur[ids < 0] == 0.0) and (ids >= 0).sum() > 20
    # Energy is the loss integrated over the 20 cycles of 1 ms (the loss changes little while it accelerates).
    assert drive.energy.numpy() == pytest.approx(20e-3 * loss, rel=0.2)


@pytest.mark.parametrize("in_step", [True, False])
def test_low_current_limit_limits_the_wrench(cache, in_step):
    ideal, weak = make(), make(magnetic_force, AUX_DIM)
    drive = MagneticDrive(weak, params(limit=0.5), SPEC, in_step=in_step)
    cmd = np.zeros((2, 1, 2))
    p0, _ = run(ideal, cmd, 20)
    p1, _ = run(weak, cmd, 20)
    assert np.all(p1[..., 2] < p0[..., 2] - 1e-4), (p0[..., 2], p1[..., 2])  # it cannot hold its height: it sinks
    assert np.all(np.abs(drive.currents.numpy()) <= 0.5 + 1e-12)
    assert np.all(drive.flags.numpy().astype(int) & FLAG_NOT_CONVERGED)


def test_drive_needs_the_aux_columns(cache):
    with pytest.raises(MagneticsError, match="force_aux_dim"):
        MagneticDrive(make(), params(limit=7.0), SPEC)


def test_force_model_by_name_or_object(cache):
    """``force_model="magnetic"`` / ``MagneticModel(...)`` build the drive; unknown names are refused by name."""
    sim = make(MagneticModel(params(limit=7.0), SPEC))
    assert isinstance(sim.magnetic_drive, MagneticDrive) and sim.force_aux.shape[-1] == AUX_DIM
    run(sim, np.zeros((2, 1, 2)), 3)
    assert np.all(sim.magnetic_drive.loss.numpy() > 1.0)
    assert make().magnetic_drive is None
    with pytest.raises(ValueError, match="'magnetc'"):
        make("magnetc")


def test_drive_with_blocks_of_threads_matches_one_thread(cache, rng, cpu_blocks):
    """The drive's one launch per cycle with several threads per mover (the GPU's shape, run by Warp's CPU blocks)
    moves the movers as one thread per mover does, with the same currents (to rounding) and flags."""
    cmd = rng.uniform(-8.0, 8.0, (2, 1, 2))
    out = []
    for block_dim in (1, 8):
        sim = make(magnetic_force, AUX_DIM)
        drive = MagneticDrive(sim, params(limit=2.0), SPEC, in_step=False)
        drive.commutation.block_dim = block_dim
        p, v = run(sim, cmd, 10)
        out.append((p, v, drive.currents.numpy().copy(), drive.flags.numpy().copy()))
    (p1, v1, c1, f1), (p8, v8, c8, f8) = out
    np.testing.assert_allclose(p8, p1, atol=1e-7, err_msg=str(rng))
    np.testing.assert_allclose(v8, v1, atol=1e-6, err_msg=str(rng))
    np.testing.assert_allclose(c8, c1, rtol=1e-6, atol=1e-6, err_msg=str(rng))
    assert np.array_equal(f8, f1) and np.abs(c1).max() > 1.0, rng


def test_fast_cycle_hook_matches_the_block_cycle(cache, rng):
    """``cycle="fast"`` (the GPU's default: the wanted wrenches, :class:`FastCycle`, the store) moves the movers as
    the block cycle's one launch does, with the same currents (to rounding), coil ids, flags and energy; coils
    saturate (2 A, up to 8 m/s^2)."""
    cmd = rng.uniform(-8.0, 8.0, (2, 1, 2))
    out = []
    for cycle in ("block", "fast"):
        sim = make(magnetic_force, AUX_DIM)
        drive = MagneticDrive(sim, params(limit=2.0), SPEC, cycle=cycle)
        assert drive.cycle == cycle
        p, v = run(sim, cmd, 10)
        out.append((p, v, drive.currents.numpy().copy(), drive.coil_ids.numpy().copy(), drive.flags.numpy().copy(),
                    drive.energy.numpy().copy()))
    (p0, v0, c0, i0, f0, e0), (p1, v1, c1, i1, f1, e1) = out
    assert np.abs(c0).max() >= 2.0 - 1e-9, rng  # saturated: the active-set steps ran
    np.testing.assert_allclose(p1, p0, atol=1e-7, err_msg=str(rng))
    np.testing.assert_allclose(v1, v0, atol=1e-6, err_msg=str(rng))
    np.testing.assert_allclose(c1, c0, rtol=0, atol=1e-6, err_msg=str(rng))
    np.testing.assert_allclose(e1, e0, rtol=1e-6, err_msg=str(rng))
    assert np.array_equal(i1, i0) and np.array_equal(f1, f0), rng


def test_unknown_cycle_is_refused(cache):
    with pytest.raises(MagneticsError, match="'fastest'"):
        MagneticDrive(make(magnetic_force, AUX_DIM), params(limit=7.0), SPEC, cycle="fastest")


@pytest.mark.parametrize("precision", ["float64", "float32"])
def test_in_step_drive_matches_the_hook(cache, rng, precision):
    """The drive inside the step kernels (one thread per mover, one launch for a step of 10 cycles) moves the movers
    as the float64 pre-cycle hook does (10 steps of a cycle; coils saturate), with the same currents (float64: to
    rounding; float32: within 1e-3 of the limit), coil ids, loss and energy. float32 is compared in the worlds where
    the hook needed no regularisation (a regularised float32 solve amplifies rounding, see
    :mod:`magwarp.magnetics.thread_cycle`): at 3 A and up to 6 m/s^2, most."""
    f32 = precision == "float32"
    limit = 3.0 if f32 else 2.0
    cmd = torch.as_tensor(rng.uniform(-6.0, 6.0, (2, 1, 2)) if f32 else rng.uniform(-8.0, 8.0, (2, 1, 2)),
                          dtype=torch.float32)
    out = []
    regularised = np.zeros(2, dtype=bool)
    for in_step in (False, True):
        sim = make(magnetic_force, AUX_DIM)
        drive = MagneticDrive(sim, params(limit=limit), SPEC, in_step=in_step, precision=precision)
        sim.set_command(cmd)
        for _ in range(1 if in_step else 10):
            sim.step(10 if in_step else 1)
            regularised |= (drive.flags.numpy()[:, 0].astype(int) & FLAG_REGULARISED) != 0
        out.append([drive.currents.numpy().copy(), drive.coil_ids.numpy().copy(), sim.pos.numpy().copy(),
                    sim.vel.numpy().copy(), drive.loss.numpy().copy(), drive.energy.numpy().copy()])
    assert np.all(np.abs(out[1][0]) <= limit) and np.array_equal(out[1][1], out[0][1]), rng
    keep = ~regularised if f32 else np.ones(2, dtype=bool)
    if not keep.any():
        pytest.skip(f"both worlds regularised ({rng}): nothing to compare in float32")
    (c0, _, p0, v0, l0, e0), (c1, _, p1, v1, l1, e1) = ([a[keep] for a in o] for o in out)
    assert np.abs(c0).max() > 1.0, rng
    np.testing.assert_allclose(p1, p0, atol=1e-6 if f32 else 1e-7, err_msg=str(rng))
    np.testing.assert_allclose(v1, v0, atol=1e-4 if f32 else 1e-6, err_msg=str(rng))
    np.testing.assert_allclose(c1, c0, rtol=0, atol=1e-3 * limit if f32 else 1e-5, err_msg=str(rng))
    np.testing.assert_allclose(l1, l0, rtol=1e-3 if f32 else 1e-5, err_msg=str(rng))
    np.testing.assert_allclose(e1, e0, rtol=1e-3 if f32 else 1e-5, err_msg=str(rng))


def test_in_step_drive_saturates(cache, rng):
    """The in-step drive's coils reach their limit (2 A, up to 8 m/s^2) in a 10-cycle step, and stay within it."""
    sim = make(magnetic_force, AUX_DIM)
    drive = MagneticDrive(sim, params(limit=2.0), SPEC)
    sim.set_command(torch.as_tensor(rng.uniform(-8.0, 8.0, (2, 1, 2)), dtype=torch.float32))
    sim.step(10)
    cur = np.abs(drive.currents.numpy())
    assert cur.max() <= 2.0 and (cur >= 2.0 - 1e-9).any(), rng


@pytest.mark.parametrize("cycle", ["block", "fast"])
def test_actuator_wrench_mode_cycle_matches_commutate(cache, rng, cycle):
    """``CoilActuator(mode="wrench")`` runs its cycle in one launch (look-up, commutation, store): the currents it
    applies are those of :meth:`CoilActuator.commutate` (the two launches) at the cycle's start, within the limits,
    and the realised wrench is their Gamma i."""
    from magwarp.magnetics.actuator import CoilActuator

    sim = make(magnetic_force, AUX_DIM)
    act = CoilActuator(sim, params(limit=2.5), SPEC, mode="wrench", cycle=cycle)
    wrench = np.zeros((2, 1, 6))
    wrench[..., :2] = rng.uniform(-15.0, 15.0, (2, 1, 2))
    wrench[..., 2] = 1.24 * 9.81
    wrench = torch.as_tensor(wrench, dtype=torch.float32)
    want = act.commutate(wrench).numpy()
    act.wanted.copy_(wrench)
    sim.step(1)
    got = act.applied_currents.numpy()
    # the fast cycle: the same algorithm in other summation orders (1.2e-9 A apart for seed 5131509629914060544; a
    # regularised solve amplifies rounding: 3e-8 A on the H100's 1M movers), as in the hook's test
    tol = 1e-12 if cycle == "block" else 1e-6
    np.testing.assert_allclose(got, want, rtol=0 if cycle == "fast" else tol, atol=tol, err_msg=str(rng))
    assert np.all(np.abs(got) <= 2.5 + 1e-12) and np.abs(got).max() > 1.0
    gamma = act._gamma.numpy().astype(np.float64).reshape(2, 1, act.slots, 6)
    np.testing.assert_allclose(act.wrench.numpy(), np.einsum("wmsk,wms->wmk", gamma, got), rtol=1e-5, atol=1e-5)
    assert np.all(act.loss.numpy() > 1.0)


def test_trajectory_env_with_the_drive_takes_the_fused_step(cache):
    """The magnetic drive's hook is one device launch: the B0 env keeps its fused step (on CUDA one graph) with
    ``force_model`` magnetic, and gives the torch step's results bit for bit."""
    from test_graph_step import run_twins

    from magwarp.envs.trajectory import TrajectoryPlanningEnv

    kw = {"num_envs": 6, "layout": "B0", "device": "cpu", "seed": 5,
          "force_model": MagneticModel(params(limit=3.0), SPEC)}
    eager, fused = TrajectoryPlanningEnv(fused=False, **kw), TrajectoryPlanningEnv(**kw)
    assert fused.step_path == "fused" and eager.step_path.startswith("eager")
    run_twins(eager, fused, 8, seed=1)
    assert np.all(fused.sim.magnetic_drive.energy.numpy() > 0.0)
    np.testing.assert_array_equal(fused.sim.magnetic_drive.energy.numpy(), eager.sim.magnetic_drive.energy.numpy())
