"""The swinging payload (magwarp.pendulum, magwarp.kernels.pendulum): one control cycle of the coupled mover and bob
against a float64 numpy integration of the same equations on random states; momentum and rod length over many
cycles; bad options refused."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from magwarp.layout import Layout
from magwarp.pendulum import PENDULUM_AUX_DIM, SwingingPayload, magnetic_pendulum_force
from magwarp.reference import quat_mul, quat_to_matrix
from magwarp.sim import Simulator

DT = 2.5e-4
G = 9.81


def _sim(worlds: int, mass: float = 0.3, length: float = 0.08, pivot=(0.01, -0.02, 0.1)):
    sim = Simulator(Layout.grid(2, 2), 1, worlds, dt=DT, hold_mask=(0,) * 6, force_model=magnetic_pendulum_force,
                    force_aux_dim=PENDULUM_AUX_DIM, stop_on_collision=False, check_inputs=False, device="cpu")
    return sim, SwingingPayload(sim, mass=mass, length=length, pivot=pivot)


def _alpha(R, inertia, omega, torque):
    """Euler's equations, body frame diagonal inertia, world frame in and out."""
    wb, tb = R.T @ omega, R.T @ torque
    return R @ ((tb - np.cross(wb, inertia * wb)) / inertia)


def _cycle_np(c, q, v, om, force, torque, d, dd, M, inertia, mb, L, rb):
    """One cycle of mover and bob in float64 (the equations of magwarp.kernels.pendulum)."""
    R = quat_to_matrix(q / np.linalg.norm(q))
    r = R @ rb
    e = d / np.linalg.norm(d)
    re = np.cross(r, e)
    k = re @ (R @ ((R.T @ re) / inertia))
    num = dd @ dd / L - e @ force / M - e @ np.cross(_alpha(R, inertia, om, torque), r) - e @ np.cross(
        om, np.cross(om, r))
    den = 1 + mb / M + mb * k
    tension = mb * num / den
    f_rod = tension * e
    t_rod = np.cross(r, f_rod)
    z = np.array([0.0, 0.0, 1.0])
    v1 = v + ((force + f_rod) / M - G * z) * DT
    c1 = c + v1 * DT
    om1 = om + _alpha(R, inertia, om, torque + t_rod) * DT
    angle = np.linalg.norm(om1) * DT
    axis = om1 / np.linalg.norm(om1)
    dq = np.array([*(axis * np.sin(0.5 * angle)), np.cos(0.5 * angle)])
    q1 = quat_mul(dq, q / np.linalg.norm(q))
    q1 /= np.linalg.norm(q1)
    ub = v + np.cross(om, r) + dd + (-G * z - e * num / den) * DT
    xb = c + r + d + ub * DT
    r1 = quat_to_matrix(q1) @ rb
    e1 = xb - c1 - r1
    e1 /= np.linalg.norm(e1)
    rel = ub - v1 - np.cross(om1, r1)
    return dict(pos=c1, vel=v1, omega=om1, quat=q1, rod=L * e1, rod_rate=rel - e1 * (rel @ e1), tension=tension,
                f_rod=f_rod, t_rod=t_rod)


def test_one_cycle_matches_numpy(rng):
    W = 16
    mass, length, pivot = 0.3, 0.08, np.array([0.01, -0.02, 0.1])
    sim, swing = _sim(W, mass, length, tuple(pivot))
    pos = np.c_[rng.uniform(0.15, 0.33, (W, 2)), rng.uniform(0.008, 0.012, W)]
    quat = rng.normal(size=(W, 4)) * np.array([0.05, 0.05, 1.0, 1.0])
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    vel, omega = rng.normal(0, 0.1, (W, 3)), rng.normal(0, 1.0, (W, 3))
    force = np.c_[rng.normal(0, 5, (W, 2)), rng.uniform(5, 20, W)]
    torque = rng.normal(0, 0.2, (W, 3))
    d = rng.normal(size=(W, 3)) * np.array([0.4, 0.4, 1.0])
    d[:, 2] = -np.abs(d[:, 2])
    d *= length / np.linalg.norm(d, axis=1, keepdims=True)
    dd = np.cross(d, rng.normal(0, 8.0, (W, 3)))  # perpendicular to the rod
    for name, value in (("pos", pos), ("quat", quat), ("vel", vel), ("omega", omega)):
        getattr(sim, name)[:, 0] = torch.as_tensor(value, dtype=torch.float32)
    sim.force_aux[:, 0, :6] = torch.as_tensor(np.c_[force, torque], dtype=torch.float32)
    swing.rod[:, 0] = torch.as_tensor(d, dtype=torch.float32)
    swing.rod_rate[:, 0] = torch.as_tensor(dd, dtype=torch.float32)
    f32 = {k: getattr(sim, k)[:, 0].numpy().astype(np.float64) for k in ("pos", "quat", "vel", "omega")}
    d32, dd32 = swing.rod[:, 0].numpy().astype(np.float64), swing.rod_rate[:, 0].numpy().astype(np.float64)
    aux = sim.force_aux[:, 0].numpy().astype(np.float64)
    sim.step(1)
    M, inertia = sim.mover.mass, np.array(sim.mover.inertia)
    for w in range(W):
        ref = _cycle_np(f32["pos"][w], f32["quat"][w], f32["vel"][w], f32["omega"][w], aux[w, :3], aux[w, 3:6],
                        d32[w], dd32[w], M, inertia, mass, length, pivot)
        got = dict(pos=sim.pos[w, 0], vel=sim.vel[w, 0], omega=sim.omega[w, 0], quat=sim.quat[w, 0],
                   rod=swing.rod[w, 0], rod_rate=swing.rod_rate[w, 0], tension=swing.tension[w, 0],
                   f_rod=sim.force_aux[w, 0, 8:11], t_rod=sim.force_aux[w, 0, 11:14])
        for key, value in got.items():
            scale = np.abs(ref[key]).max() + {"pos": 0.0, "rod": 1e-3}.get(key, 1e-2)
            np.testing.assert_allclose(value.numpy(), ref[key], rtol=0, atol=2e-5 * scale,
                                       err_msg=f"{key} world {w} {rng}")
    assert np.abs(swing.tension[:, 0].numpy()).min() > 1e-3  # the rods carry load: the test can fail


def test_momentum_and_rod_length_over_many_cycles(rng):
    """Coils carry the weight of mover and bob, no horizontal force: the horizontal momentum of mover plus bob stays
    put while the bob swings, and the rod keeps its length."""
    W, mass, length = 4, 0.3, 0.08
    sim, swing = _sim(W, mass, length, (0.0, 0.0, 0.1))
    M = sim.mover.mass
    sim.force_aux[:, 0, 2] = (M + mass) * G
    angle = torch.as_tensor(rng.uniform(0.1, 0.4, W), dtype=torch.float32)
    azimuth = torch.as_tensor(rng.uniform(-np.pi, np.pi, W), dtype=torch.float32)
    swing.reset(torch.ones(W, dtype=torch.bool), angle, azimuth)

    def momentum():
        pivot_vel = sim.vel[:, 0] + torch.cross(sim.omega[:, 0], swing.pivot_offset()[:, 0], dim=-1)
        bob_vel = pivot_vel + swing.rod_rate[:, 0]
        return (M * sim.vel[:, 0] + mass * bob_vel)[:, :2].numpy().astype(np.float64)

    p0 = momentum()
    peak = 0.0
    for _ in range(40):
        sim.step(10)  # 0.1 s in all: about a fifth of a swing
        peak = max(peak, float(np.abs(sim.vel[:, 0, :2].numpy()).max()))
        np.testing.assert_allclose(torch.linalg.vector_norm(swing.rod[:, 0], dim=-1).numpy(), length, rtol=1e-5)
    bob_scale = mass * np.sqrt(2 * G * length * (1 - np.cos(0.4)))
    np.testing.assert_allclose(momentum(), p0, atol=2e-3 * bob_scale, err_msg=str(rng))
    assert peak > 1e-3  # the mover is pushed about by the swing (and the momentum check has something to check)
    angles, rates = swing.swing()
    assert angles.shape == (W, 1, 2) and torch.isfinite(rates).all()


@pytest.mark.parametrize("mover_mass", [1.24, 1e4])
def test_small_swings_have_the_textbook_period(mover_mass):
    """Pivot at the mover centre, coils carrying the weight: the bob and the (horizontally free) mover swing against
    each other with omega^2 = (g / L) (1 + m / M) (a heavy mover is a fixed pivot, omega^2 = g / L), and the centre
    of mass of mover plus bob stays put."""
    from magwarp.layout import MoverSpec

    mass, length, angle = 0.3, 0.08, 0.05
    sim = Simulator(Layout.grid(2, 2), 1, 1, mover=MoverSpec(mass=mover_mass), dt=DT, hold_mask=(0,) * 6,
                    force_model=magnetic_pendulum_force, force_aux_dim=PENDULUM_AUX_DIM, stop_on_collision=False,
                    check_inputs=False, device="cpu")
    swing = SwingingPayload(sim, mass=mass, length=length, pivot=(0.0, 0.0, 0.0))
    sim.force_aux[:, 0, 2] = (mover_mass + mass) * G
    swing.reset(torch.ones(1, dtype=torch.bool), torch.tensor([angle]), torch.tensor([0.3]))
    period = 2 * np.pi / np.sqrt(G / length * (1 + mass / mover_mass)) * (1 + angle ** 2 / 16)
    def centre_of_mass():
        return ((mover_mass * sim.pos[0, 0] + mass * swing.bob_position()[0, 0]) / (mover_mass + mass)).numpy()

    com0, xs = centre_of_mass(), []
    for _ in range(int(1.6 * period / DT / 4)):
        sim.step(4)
        xs.append(float(swing.rod[0, 0, 0] * np.cos(0.3) + swing.rod[0, 0, 1] * np.sin(0.3)))
    xs = np.array(xs)
    crossings = np.flatnonzero(np.diff(np.sign(xs)) != 0)  # half periods apart
    t = (crossings + xs[crossings] / (xs[crossings] - xs[crossings + 1])) * 4 * DT  # linear interpolation
    np.testing.assert_allclose(t[2] - t[0], period, rtol=2e-3)  # one full period
    # no net force on mover plus bob: their centre of mass stays put (the rod carries the bob's weight)
    np.testing.assert_allclose(centre_of_mass(), com0, rtol=0, atol=2e-6)


def test_swing_angles_and_rates(rng):
    _, swing = _sim(3)
    d = torch.tensor([[0.02, -0.01, -0.07], [0.0, 0.0, -0.08], [-0.03, 0.02, -0.06]])
    dd = torch.as_tensor(rng.normal(0, 0.3, (3, 3)), dtype=torch.float32)
    swing.rod[:, 0], swing.rod_rate[:, 0] = d, dd
    angles, rates = swing.swing()
    np.testing.assert_allclose(angles[:, 0].numpy(), np.arctan2(d[:, :2].numpy(), -d[:, 2:].numpy()), rtol=1e-6)
    # central differences of the angles along the rate, in float64 (a float32 forward difference with h = 1e-4 was
    # off by 3e-4 rad/s on a seed: rounding over h, and the curvature)
    d64, dd64, h = d.double().numpy(), dd.double().numpy(), 1e-6

    def angle(x):
        return np.arctan2(x[:, :2], -x[:, 2:])

    ref = (angle(d64 + h * dd64) - angle(d64 - h * dd64)) / (2 * h)
    np.testing.assert_allclose(rates[:, 0].numpy(), ref, rtol=1e-4, atol=1e-5)


def test_bad_options_are_refused():
    sim = Simulator(Layout.grid(2, 2), 1, 1, dt=DT, hold_mask=(0,) * 6, device="cpu")
    with pytest.raises(ValueError, match="force_aux_dim >= 14"):
        SwingingPayload(sim)
    sim, _ = _sim(1)
    with pytest.raises(ValueError, match="length must be .* got -0.1"):
        SwingingPayload(sim, length=-0.1)
    with pytest.raises(ValueError, match="mass must be .* got nan"):
        SwingingPayload(sim, mass=float("nan"))
    with pytest.raises(ValueError, match="pivot must be three"):
        SwingingPayload(sim, pivot=(0.0, 0.1))
