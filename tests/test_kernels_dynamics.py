"""Planar command limits and rigid-body integration vs :mod:`magwarp.reference` (float64 numpy).

* ``planar_acceleration`` for one cycle, acceleration and jerk modes, random states and commands (many over the
  limits);
* ``integrate_rotation`` and ``angular_acceleration`` against numpy;
* the simulator over hundreds of cycles with random commands: every cycle the x/y acceleration and velocity norms
  stay within a_max / v_max (and jerk within j_max where the speed cap does not bind), each cycle matches the
  reference applied to the simulator's own state, and the whole trajectory matches a float64 integration.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
import warp as wp

from magwarp import reference as ref
from magwarp.kernels.dynamics import angular_acceleration, integrate_rotation, planar_acceleration
from magwarp.layout import Layout
from magwarp.sim import Simulator
from magwarp.types import Limits

DT, V_MAX, A_MAX, J_MAX = 0.001, 2.0, 10.0, 100.0


def make_limits(jerk: bool) -> Limits:
    lim = Limits()
    lim.dt, lim.v_max, lim.a_max, lim.j_max = DT, V_MAX, A_MAX, J_MAX
    lim.jerk_mode = int(jerk)
    lim.gravity = 9.81
    return lim


def random_in_ball(rng, n, max_norm):
    v = rng.normal(size=(n, 2))
    return v / np.linalg.norm(v, axis=1, keepdims=True) * rng.uniform(0, max_norm, (n, 1))


@wp.kernel
def _planar_kernel(lim: Limits, vel: wp.array(dtype=wp.vec3), acc: wp.array(dtype=wp.vec2),
                   cmd: wp.array(dtype=wp.vec2), out: wp.array(dtype=wp.vec2)):
    i = wp.tid()
    out[i] = planar_acceleration(vel[i], acc[i], cmd[i], lim)


@pytest.mark.parametrize("mode", ["acceleration", "jerk"])
def test_planar_acceleration_matches_reference(mode, rng):
    n = 4000
    jerk = mode == "jerk"
    vel = random_in_ball(rng, n, V_MAX)
    vel[: n // 4] *= V_MAX / np.linalg.norm(vel[: n // 4], axis=1, keepdims=True)  # a quarter exactly at the cap
    acc = random_in_ball(rng, n, A_MAX)
    acc[n // 4: n // 2] *= A_MAX / np.linalg.norm(acc[n // 4: n // 2], axis=1, keepdims=True)
    cmd = random_in_ball(rng, n, 3 * (J_MAX if jerk else A_MAX))  # two thirds over the limit
    vel, acc, cmd = (np.asarray(x, np.float32).astype(np.float64) for x in (vel, acc, cmd))
    out = wp.zeros(n, dtype=wp.vec2, device="cpu")
    vel3 = np.concatenate([vel, rng.normal(size=(n, 1))], 1).astype(np.float32)
    wp.launch(_planar_kernel, dim=n, device="cpu",
              inputs=[make_limits(jerk), wp.array(vel3, dtype=wp.vec3, device="cpu"),
                      wp.array(acc.astype(np.float32), dtype=wp.vec2, device="cpu"),
                      wp.array(cmd.astype(np.float32), dtype=wp.vec2, device="cpu"), out])
    got = out.numpy().astype(np.float64)
    want, want_vel, _ = ref.planar_cycle(vel, acc, cmd, dt=DT, v_max=V_MAX, a_max=A_MAX, j_max=J_MAX, jerk_mode=jerk)
    # (capped velocity - velocity) / dt loses ~1e-4 m/s^2 to float32 cancellation; everything else is exact.
    np.testing.assert_allclose(got, want, atol=2e-3, rtol=1e-5, err_msg=str(rng))
    np.testing.assert_allclose(vel + DT * got, want_vel, atol=2e-6, err_msg=str(rng))
    assert np.linalg.norm(got, axis=1).max() <= A_MAX * (1 + 1e-5), rng
    assert np.linalg.norm(vel + DT * got, axis=1).max() <= V_MAX * (1 + 1e-6), rng
    # The caps bind in this sample (so the test exercises them).
    assert (np.linalg.norm(want, axis=1) > A_MAX * 0.999).mean() > 0.1, rng
    assert (np.linalg.norm(want_vel, axis=1) > V_MAX * 0.999999).mean() > 0.1, rng


# ---------------------------------------------------------------------------------------------- rotation
@wp.kernel
def _rotation_kernel(q: wp.array(dtype=wp.quat), omega: wp.array(dtype=wp.vec3), torque: wp.array(dtype=wp.vec3),
                     inertia: wp.vec3, dt: float, q_out: wp.array(dtype=wp.quat), alpha_out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    q_out[i] = integrate_rotation(q[i], omega[i], dt)
    alpha_out[i] = angular_acceleration(q[i], omega[i], torque[i], inertia)


def test_rotation_integration_matches_reference(rng):
    n = 500
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    omega = rng.normal(size=(n, 3)) * rng.choice([1e-3, 1.0, 30.0], (n, 1))
    torque = rng.normal(size=(n, 3)) * 0.1
    inertia = np.array([0.0025, 0.0030, 0.0050])
    q, omega, torque = (np.asarray(x, np.float32).astype(np.float64) for x in (q, omega, torque))
    q_out = wp.zeros(n, dtype=wp.quat, device="cpu")
    a_out = wp.zeros(n, dtype=wp.vec3, device="cpu")
    f = lambda x, t: wp.array(x.astype(np.float32), dtype=t, device="cpu")  # noqa: E731
    wp.launch(_rotation_kernel, dim=n, device="cpu",
              inputs=[f(q, wp.quat), f(omega, wp.vec3), f(torque, wp.vec3), wp.vec3(*inertia), 0.01, q_out, a_out])
    want_q = np.array([ref.integrate_rotation(q[k], omega[k], 0.01) for k in range(n)])
    got_q = q_out.numpy()
    # q and -q are the same rotation
    sign = np.sign(np.sum(got_q * want_q, axis=1, keepdims=True))
    np.testing.assert_allclose(got_q * sign, want_q, atol=2e-6, err_msg=str(rng))
    want_a = np.array([ref.angular_acceleration(q[k], omega[k], torque[k], inertia) for k in range(n)])
    np.testing.assert_allclose(a_out.numpy(), want_a, rtol=1e-4, atol=1e-3, err_msg=str(rng))


# ---------------------------------------------------------------------------------------------- simulator
def run_planar(mode, rng, num_cycles=600, hold=20, w=2, m=3):
    """Random commands (held ``hold`` cycles, most over the limit) on a large grid; returns per-cycle arrays."""
    jerk = mode == "jerk"
    sim = Simulator(Layout.grid(8, 8), num_movers=m, num_worlds=w, control=mode, device="cpu",
                    stop_on_collision=False)
    limit = J_MAX if jerk else A_MAX
    cmds, vel, acc, pos = [], [], [], []
    base = random_in_ball(rng, w * m, 1.0).reshape(w, m, 2)
    base /= np.linalg.norm(base, axis=-1, keepdims=True)
    for c in range(num_cycles):
        if c % hold == 0:
            if c < num_cycles // 2:  # mostly one direction per mover first, so that the speed cap is reached
                noisy = base + 0.3 * random_in_ball(rng, w * m, 1.0).reshape(w, m, 2)
                cmd = noisy * limit * rng.uniform(0.5, 3.0, (w, m, 1))
            else:  # then anything, reversals included
                cmd = random_in_ball(rng, w * m, 3 * limit).reshape(w, m, 2) * rng.choice([0.2, 1.0], (w, m, 1))
            cmd = np.asarray(cmd, np.float32)
            sim.set_command(torch.as_tensor(cmd))
        cmds.append(cmd.astype(np.float64))
        sim.step(1)
        pos.append(sim.pos.numpy().astype(np.float64))
        vel.append(sim.vel.numpy().astype(np.float64))
        acc.append(sim.acc.numpy().astype(np.float64))
    start = sim.start_pos.numpy().astype(np.float64)
    return sim, start, np.array(cmds), np.array(pos), np.array(vel), np.array(acc)


@pytest.mark.parametrize("mode", ["acceleration", "jerk"])
def test_simulator_planar_limits_and_trajectory(mode, rng):
    jerk = mode == "jerk"
    sim, start, cmds, pos, vel, acc = run_planar(mode, rng)
    n = len(cmds)
    v_xy = vel[..., :2]
    # Limits, every cycle, every mover.
    a_norm = np.linalg.norm(acc, axis=-1)
    v_norm = np.linalg.norm(v_xy, axis=-1)
    assert a_norm.max() <= A_MAX * (1 + 2e-5), f"{rng}: |a| max {a_norm.max()}"
    assert v_norm.max() <= V_MAX * (1 + 1e-6), f"{rng}: |v| max {v_norm.max()}"
    assert (v_norm > V_MAX * 0.9999).any(), f"{rng}: speed cap never reached"
    assert (a_norm > A_MAX * 0.9999).any(), f"{rng}: acceleration cap never reached"

    # One cycle at a time: the reference applied to the simulator's own previous state.
    prev_v = np.concatenate([np.zeros_like(v_xy[:1]), v_xy[:-1]])
    prev_a = np.concatenate([np.zeros_like(acc[:1]), acc[:-1]])
    prev_p = np.concatenate([start[None, ..., :2], pos[:-1, ..., :2]])
    a1, v1, dp1 = ref.planar_cycle(prev_v, prev_a, cmds, dt=DT, v_max=V_MAX, a_max=A_MAX, j_max=J_MAX, jerk_mode=jerk)
    np.testing.assert_allclose(acc, a1, atol=1e-3, err_msg=f"{rng}: applied acceleration")
    np.testing.assert_allclose(v_xy, v1, atol=3e-6, err_msg=f"{rng}: velocity")
    np.testing.assert_allclose(pos[..., :2], prev_p + dp1, atol=1e-6, err_msg=f"{rng}: position")
    if jerk:
        # Where the speed cap does not bind, the acceleration changes by at most j_max * dt per cycle.
        free = (np.linalg.norm(v1, axis=-1) < V_MAX * 0.999) & (np.linalg.norm(prev_v, axis=-1) < V_MAX * 0.999)
        jerk_norm = np.linalg.norm(acc - prev_a, axis=-1) / DT
        assert jerk_norm[free].max() <= J_MAX * (1 + 1e-3) + 0.5, f"{rng}: |jerk| max {jerk_norm[free].max()}"
        assert (jerk_norm[free] > J_MAX * 0.99).any(), f"{rng}: jerk cap never reached"

    # Whole trajectory vs a float64 integration from the same start.
    v = np.zeros_like(v_xy[0])
    a = np.zeros_like(acc[0])
    p = start[..., :2].copy()
    ref_pos = []
    for c in range(n):
        a, v, dp = ref.planar_cycle(v, a, cmds[c], dt=DT, v_max=V_MAX, a_max=A_MAX, j_max=J_MAX, jerk_mode=jerk)
        p = p + dp
        ref_pos.append(p)
    # The x/y law runs in float64 with the acceleration carried as state (jerk mode included): what is left is the
    # float32 rounding of the outputs and of the start poses.
    np.testing.assert_allclose(pos[..., :2], np.array(ref_pos), atol=1e-6, err_msg=f"{rng}: trajectory")

    # Held axes stay at hover: z, roll, pitch, yaw do not move under planar commands.
    np.testing.assert_allclose(pos[..., 2], sim.model.hover_z, atol=1e-6, err_msg=str(rng))
    np.testing.assert_allclose(sim.quat.numpy(), sim.start_quat.numpy(), atol=1e-6, err_msg=str(rng))


def test_velocity_cap_holds_under_constant_command(rng):
    """A saturating command held for 0.5 s: the speed reaches v_max and stays there, never above."""
    sim = Simulator(Layout.grid(10, 10), num_movers=1, device="cpu", stop_on_collision=False)
    direction = rng.normal(size=2)
    direction /= np.linalg.norm(direction)
    cmd = torch.as_tensor((50.0 * direction).reshape(1, 1, 2), dtype=torch.float32)
    sim.step(250, cmd=cmd)
    speed = float(torch.linalg.norm(sim.vel[0, 0, :2]))
    assert abs(speed - V_MAX) < 1e-5, f"{rng}: speed {speed}"
    # Reached in 200 cycles at the clipped 10 m/s^2; position = area under the clipped profile.
    expected = 0.5 * A_MAX * 0.2**2 + V_MAX * 0.05  # 0.2 + 0.1 m (+ semi-implicit Euler's half step)
    moved = float(torch.linalg.norm(sim.pos[0, 0, :2] - sim.start_pos[0, 0, :2]))
    assert abs(moved - expected) < 2e-3, f"{rng}: moved {moved}, expected ~{expected}"
    np.testing.assert_allclose(sim.vel[0, 0, :2].numpy() / speed, direction, atol=1e-5, err_msg=str(rng))
