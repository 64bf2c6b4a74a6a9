"""The impedance controller vs :mod:`magwarp.reference`.

* ``impedance_wrench`` on random poses, velocities and targets (orientation errors up to and beyond pi);
* the simulator: movers displaced in z, tilted in roll / pitch, yawed, all at once, or given a new yaw target,
  return to their hover pose. Each trajectory matches a float64 numpy integration of the same law
  (``reference.impedance_wrench`` + semi-implicit Euler + Euler's equations + ``reference.integrate_rotation``),
  single-axis responses match the analytic critically damped curve ``x0 (1 + w t) exp(-w t)`` with
  ``w = sqrt(K / M)`` (mass for z, principal inertia for rotations), and nothing overshoots beyond the numpy
  integration's own (tiny) overshoot.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
import warp as wp

from magwarp import reference as ref
from magwarp.kernels.impedance import impedance_wrench
from magwarp.layout import Layout, MoverSpec
from magwarp.sim import Simulator
from magwarp.types import Body, Impedance, Pose

K_LIN = np.array([1.0, 1.0, 100.0])
K_ROT = np.array([0.1, 0.1, 1.0])
HOLD_LIN = np.array([0.0, 0.0, 1.0])
HOLD_ROT = np.array([1.0, 1.0, 1.0])


def quat_from_rotvec(v):
    v = np.asarray(v, dtype=np.float64)
    a = np.linalg.norm(v)
    if a < 1e-15:
        return np.array([0.0, 0.0, 0.0, 1.0])
    return np.concatenate([v / a * np.sin(0.5 * a), [np.cos(0.5 * a)]])


# ---------------------------------------------------------------------------------------------- wrench function
@wp.kernel
def _wrench_kernel(pose: wp.array(dtype=Pose), body: Body, tp: wp.array(dtype=wp.vec3), tq: wp.array(dtype=wp.quat),
                   imp: Impedance, force: wp.array(dtype=wp.vec3), torque: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    w = impedance_wrench(pose[i], body, tp[i], tq[i], imp)
    force[i] = w.force
    torque[i] = w.torque


def random_quats(rng, n, max_angle):
    axes = rng.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    return np.array([quat_from_rotvec(a * t) for a, t in zip(axes, rng.uniform(0, max_angle, n))])


def test_impedance_wrench_matches_reference(rng):
    n = 600
    mass, inertia = 1.24, np.array([0.0025, 0.003, 0.005])
    k_lin, k_rot = rng.uniform(0.5, 200.0, 3), rng.uniform(0.05, 2.0, 3)
    mask_lin, mask_rot = rng.integers(0, 2, 3).astype(float), rng.integers(0, 2, 3).astype(float)
    mask_lin[2] = mask_rot[2] = 1.0
    pos = rng.normal(size=(n, 3)) * 0.1
    tpos = pos + rng.normal(size=(n, 3)) * 0.01
    q = random_quats(rng, n, np.pi)
    # targets up to 3.1 rad away (shortest arc) and a few beyond pi (the long way round must be taken short)
    tq = np.array([ref.quat_mul(qq, dq) for qq, dq in zip(q, random_quats(rng, n, 3.1))])
    tq[::7] *= -1  # the same rotations with the other quaternion sign
    vel, omega = rng.normal(size=(n, 3)) * 0.1, rng.normal(size=(n, 3))
    pos, tpos, q, tq, vel, omega = (np.asarray(x, np.float32).astype(np.float64) for x in (pos, tpos, q, tq, vel, omega))

    poses = np.zeros(n, dtype=Pose.numpy_dtype())
    poses["pos"], poses["quat"], poses["vel"], poses["omega"] = pos, q, vel, omega
    d_lin, d_rot = 2 * np.sqrt(k_lin * mass), 2 * np.sqrt(k_rot * inertia)
    body = Body()
    body.mass, body.inertia = mass, wp.vec3(*inertia)
    body.damp_lin, body.damp_rot = wp.vec3(*d_lin), wp.vec3(*d_rot)  # the simulator precomputes 2 sqrt(K M)
    imp = Impedance()
    imp.k_lin, imp.k_rot, imp.mask_lin, imp.mask_rot = (wp.vec3(*x) for x in (k_lin, k_rot, mask_lin, mask_rot))
    f_out, t_out = wp.zeros(n, dtype=wp.vec3, device="cpu"), wp.zeros(n, dtype=wp.vec3, device="cpu")
    wp.launch(_wrench_kernel, dim=n, device="cpu",
              inputs=[wp.array(poses, dtype=Pose, device="cpu"), body, wp.array(tpos.astype(np.float32), dtype=wp.vec3, device="cpu"),
                      wp.array(tq.astype(np.float32), dtype=wp.quat, device="cpu"), imp, f_out, t_out])
    want = [ref.impedance_wrench(pos[k], q[k], vel[k], omega[k], tpos[k], tq[k], k_lin, k_rot, d_lin, d_rot, mask_lin,
                                 mask_rot) for k in range(n)]
    want_f = np.array([f for f, _ in want])
    want_t = np.array([t for _, t in want])
    np.testing.assert_allclose(f_out.numpy(), want_f, rtol=1e-4, atol=1e-4, err_msg=str(rng))
    np.testing.assert_allclose(t_out.numpy(), want_t, rtol=1e-4, atol=2e-5, err_msg=str(rng))
    # The orientation error drives toward the target: the undamped torque has a positive component along the
    # rotation that takes q to the target.
    assert np.abs(want_t).max() > 0.1, rng


# ---------------------------------------------------------------------------------------------- simulator
def numpy_hover(mover: MoverSpec, pos, quat, tpos, tquat, dt, n, k_lin=K_LIN, k_rot=K_ROT, hold_lin=HOLD_LIN,
                hold_rot=HOLD_ROT):
    """Float64 semi-implicit Euler of one mover under gravity compensation + the impedance law (no x/y command)."""
    m, inertia = mover.mass, np.array(mover.inertia)
    d_lin, d_rot = 2 * np.sqrt(k_lin * m), 2 * np.sqrt(k_rot * inertia)
    pos, quat = np.array(pos, np.float64), np.array(quat, np.float64)
    vel, omega = np.zeros(3), np.zeros(3)
    out_pos, out_quat = [], []
    for _ in range(n):
        f, t = ref.impedance_wrench(pos, quat, vel, omega, tpos, tquat, k_lin, k_rot, d_lin, d_rot, hold_lin, hold_rot)
        vel = vel + (f / m) * dt  # gravity compensation cancels gravity exactly
        pos = pos + vel * dt
        omega = omega + ref.angular_acceleration(quat, omega, t, inertia) * dt
        quat = ref.integrate_rotation(quat, omega, dt)
        out_pos.append(pos)
        out_quat.append(quat)
    return np.array(out_pos), np.array(out_quat)


def rotation_error(quats, target):
    """Rotation vectors (world frame) taking each quaternion to ``target``."""
    conj = np.array([-1, -1, -1, 1.0])
    return np.array([ref.quat_rotate(q, ref.quat_to_rotvec(ref.quat_mul(q * conj, target))) for q in quats])


CASES = {
    # name: (z offset (m), rotation vector of the initial attitude relative to the target, yaw target)
    "z-up": (0.003, (0.0, 0.0, 0.0), None),
    "z-down": (-0.002, (0.0, 0.0, 0.0), None),
    "roll": (0.0, (0.05, 0.0, 0.0), None),
    "pitch": (0.0, (0.0, -0.08, 0.0), None),
    "yaw": (0.0, (0.0, 0.0, 0.6), None),
    "yaw-large": (0.0, (0.0, 0.0, 2.9), None),
    "all": (0.002, (0.04, -0.03, 0.5), None),
    "yaw-target": (0.0, (0.0, 0.0, 0.0), 1.2),
}
AXIS = {"z-up": 0, "z-down": 0, "roll": 1, "pitch": 2, "yaw": 3, "yaw-large": 3, "yaw-target": 3}


def test_displaced_movers_return_to_hover_critically_damped(rng):
    names = list(CASES)
    m = len(names)
    mover = MoverSpec()
    layout = Layout.grid(4, 2)
    # Random start headings: the hover pose to return to includes the start yaw.
    start_yaw = rng.uniform(-np.pi, np.pi, m)
    sim = Simulator(layout, num_movers=m, mover=mover, start_yaw=start_yaw, device="cpu", stop_on_collision=False)
    dt, chunk, n_chunks = 0.001, 25, 80  # 2 s
    init_pos = sim.pos[0].numpy().astype(np.float64).copy()
    init_quat = sim.quat[0].numpy().astype(np.float64).copy()
    yaw_target = start_yaw.copy()
    for k, name in enumerate(names):
        dz, rv, yt = CASES[name]
        sim.pos[0, k, 2] += dz
        sim.quat[0, k] = torch.as_tensor(ref.quat_mul(quat_from_rotvec(rv), init_quat[k]), dtype=torch.float32)
        if yt is not None:
            yaw_target[k] = start_yaw[k] + yt
    sim.set_targets(yaw=torch.as_tensor(yaw_target[None], dtype=torch.float32))
    start_pos = sim.pos[0].numpy().astype(np.float64)
    start_quat = sim.quat[0].numpy().astype(np.float64)
    target_quat = np.array([ref.yaw_quat(y) for y in yaw_target])
    target_pos = init_pos

    got_pos, got_quat = [], []
    for _ in range(n_chunks):
        sim.step(chunk)
        got_pos.append(sim.pos[0].numpy().astype(np.float64))
        got_quat.append(sim.quat[0].numpy().astype(np.float64))
    got_pos, got_quat = np.array(got_pos), np.array(got_quat)
    assert int(sim.flags_any.sum()) == 0 and (sim.cycles.numpy() == chunk).all()
    t = dt * chunk * np.arange(1, n_chunks + 1)

    for k, name in enumerate(names):
        msg = f"{rng}, case {name}"
        np_pos, np_quat = numpy_hover(mover, start_pos[k], start_quat[k], target_pos[k], target_quat[k], dt,
                                      chunk * n_chunks)
        np_pos, np_quat = np_pos[chunk - 1::chunk], np_quat[chunk - 1::chunk]
        # 1. Same trajectory as the float64 integration of the same law.
        np.testing.assert_allclose(got_pos[:, k], np_pos, atol=2e-6, err_msg=msg)
        sign = np.sign(np.sum(got_quat[:, k] * np_quat, axis=1, keepdims=True))
        np.testing.assert_allclose(got_quat[:, k] * sign, np_quat, atol=2e-5, err_msg=msg)
        # 2. Back at the hover pose after 2 s (x/y never moved).
        np.testing.assert_allclose(got_pos[-1, k], target_pos[k], atol=max(1e-4 * abs(CASES[name][0]), 1e-7), err_msg=msg)
        err_rot = rotation_error(got_quat[:, k], target_quat[k])
        err_rot_np = rotation_error(np_quat, target_quat[k])
        err0 = rotation_error(start_quat[k:k + 1], target_quat[k])[0]
        assert np.linalg.norm(err_rot[-1]) <= 2e-3 * np.linalg.norm(err0) + 1e-6, msg
        # 3. No overshoot beyond the numpy integration's: the error never changes sign by more than numpy's does.
        e = np.concatenate([got_pos[:, k, 2:3] - target_pos[k, 2], err_rot], 1)
        e_np = np.concatenate([np_pos[:, 2:3] - target_pos[k, 2], err_rot_np], 1)
        e0 = np.concatenate([[start_pos[k, 2] - target_pos[k, 2]], err0])
        for ax in range(4):
            if abs(e0[ax]) < 1e-6:
                continue
            over = np.max(-np.sign(e0[ax]) * e[:, ax])
            over_np = np.max(-np.sign(e0[ax]) * e_np[:, ax])
            assert over <= max(over_np, 0.0) + 1e-6 * abs(e0[ax]) + 1e-9, f"{msg}: axis {ax} overshoots {over} > {over_np}"
            assert over_np <= 1e-3 * abs(e0[ax]), f"{msg}: the law itself overshoots ({over_np}): not critically damped"
        # 4. Single-axis cases follow the analytic critically damped response with w = sqrt(K / M).
        if name in AXIS:
            ax = AXIS[name]
            stiff = [K_LIN[2], *K_ROT][ax]
            inertia = [mover.mass, *mover.inertia][ax]
            w = np.sqrt(stiff / inertia)
            analytic = e0[ax] * (1 + w * t) * np.exp(-w * t)
            np.testing.assert_allclose(e[:, ax], analytic, atol=0.01 * abs(e0[ax]), err_msg=f"{msg}: not critical")


def test_hover_height_and_attitude_are_held(rng):
    """At rest at the hover pose, nothing drifts over 1 s (gravity compensation is exact)."""
    mover = MoverSpec(hover_gap=float(rng.uniform(0.003, 0.005)))
    sim = Simulator(Layout.grid(2, 2), num_movers=4, num_worlds=2, mover=mover,
                    start_yaw=rng.uniform(-np.pi, np.pi, 4), device="cpu")
    p0, q0 = sim.pos.clone(), sim.quat.clone()
    sim.step(1000)
    np.testing.assert_allclose(sim.pos.numpy(), p0.numpy(), atol=1e-6, err_msg=str(rng))
    np.testing.assert_allclose(sim.quat.numpy(), q0.numpy(), atol=1e-6, err_msg=str(rng))
    np.testing.assert_allclose(sim.pos[..., 2].numpy(), mover.hover_gap + 0.5 * mover.size[2], atol=1e-6)


def test_z_target_and_hold_mask(rng):
    """A new height target is reached along the numpy trajectory; axes outside ``hold_mask`` are not held."""
    mover = MoverSpec()
    dz = float(rng.uniform(-0.002, 0.002))
    sim = Simulator(Layout.grid(2, 1), num_movers=2, mover=mover, device="cpu", stop_on_collision=False)
    z0 = sim.model.hover_z
    sim.set_targets(z=torch.full((1, 2), z0 + dz))
    sim.step(1000)
    start = sim.start_pos[0, 0].numpy().astype(np.float64)
    np_pos, _ = numpy_hover(mover, start, np.array([0, 0, 0, 1.0]), start + [0, 0, dz], np.array([0, 0, 0, 1.0]),
                            1e-3, 1000)
    np.testing.assert_allclose(sim.pos[0, :, 2].numpy(), np_pos[-1, 2], atol=2e-7, err_msg=str(rng))
    assert abs(float(sim.pos[0, 0, 2]) - (z0 + dz)) < 0.01 * abs(dz) + 1e-7, rng  # (1 + 9) e^-9 left

    # Nothing held: a displaced, tilted mover stays where it was put (gravity compensation only).
    free = Simulator(Layout.grid(2, 1), num_movers=1, mover=mover, device="cpu", hold_mask=(0, 0, 0, 0, 0, 0))
    free.pos[0, 0, 2] += 0.002
    q = torch.as_tensor(quat_from_rotvec([0.05, 0.0, 0.0]), dtype=torch.float32)
    free.quat[0, 0] = q
    free.step(300)
    assert abs(float(free.pos[0, 0, 2]) - (z0 + 0.002)) < 1e-6
    np.testing.assert_allclose(free.quat[0, 0].numpy(), q.numpy(), atol=1e-6)
    # Only yaw held: the yaw error goes away, the tilt is not corrected (its axis turns with the body, and the
    # gyroscopic coupling of the unequal inertias moves it a little: compare with the numpy integration).
    yaw_only = Simulator(Layout.grid(2, 1), num_movers=1, mover=mover, device="cpu", hold_mask=(0, 0, 0, 0, 0, 1))
    q = ref.quat_mul(quat_from_rotvec([0, 0, 0.3]), quat_from_rotvec([0.05, 0, 0]))
    yaw_only.quat[0, 0] = torch.as_tensor(q, dtype=torch.float32)
    q = yaw_only.quat[0, 0].numpy().astype(np.float64)
    yaw_only.step(1500)
    got = yaw_only.quat[0, 0].numpy().astype(np.float64)
    _, np_quat = numpy_hover(mover, start, q, start, np.array([0, 0, 0, 1.0]), 1e-3, 1500, hold_lin=np.zeros(3),
                             hold_rot=np.array([0, 0, 1.0]))
    np.testing.assert_allclose(got * np.sign(got @ np_quat[-1]), np_quat[-1], atol=2e-5, err_msg=str(rng))
    rv = ref.quat_to_rotvec(got)
    assert abs(rv[2]) < 1e-3 and abs(np.hypot(rv[0], rv[1]) - 0.05) < 1e-3, f"{rng}: {rv}"
