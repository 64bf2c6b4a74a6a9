"""Float64 MuJoCo C reference for the mujoco-warp backend: the same control law in numpy, stepped with ``mj_step``.

Used by tests (and benchmarks) as the oracle; one world, plain Python loops, no speed ambitions.
"""

from __future__ import annotations

import mujoco
import numpy as np

from magwarp import reference
from magwarp.physics.backend import ControlParams


def control_forces(mjm, mjd, mover_body, mover_qadr, mover_dadr, hover_z, cmd, acc, c: ControlParams,
                   yaw_state: np.ndarray | None = None) -> None:
    """Write the movers' ``qfrc_applied`` for one cycle (float64) and update ``acc`` in place.

    With ``c.rotation``, ``cmd`` is ``[M, 3]`` and ``yaw_state`` ``[M, 3]`` (yaw acceleration, accumulated yaw, last
    raw yaw) is updated in place too."""
    dt = mjm.opt.timestep
    for k, (b, qa, da) in enumerate(zip(mover_body, mover_qadr, mover_dadr)):
        m = mjm.body_subtreemass[b]
        inertia = mjm.body_inertia[b]
        vel = mjd.qvel[da : da + 2]
        # The planar simulator's numpy reference law: one definition of the x/y limits for every oracle.
        a, _, _ = reference.planar_cycle(vel, acc[k], cmd[k][:2], dt=dt, v_max=c.v_max, a_max=c.a_max, j_max=c.j_max,
                                         jerk_mode=c.jerk)
        acc[k] = a
        kz = c.k_lin[2]
        fz = kz * (hover_z[k] - mjd.qpos[qa + 2]) - 2.0 * np.sqrt(kz * m) * mjd.qvel[da + 2]
        q = mjd.qpos[qa + 3 : qa + 7] / np.linalg.norm(mjd.qpos[qa + 3 : qa + 7])
        rot = np.zeros(9)
        mujoco.mju_quat2Mat(rot, q)
        rot = rot.reshape(3, 3)
        q_xyzw = np.array([q[1], q[2], q[3], q[0]])
        omega_world = rot @ mjd.qvel[da + 3 : da + 6]
        k_rot = np.asarray(c.k_rot)
        d_rot = 2.0 * np.sqrt(k_rot * inertia)
        target, drive = np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3)
        if c.rotation:
            raw = np.arctan2(2.0 * (q[0] * q[3] + q[1] * q[2]), 1.0 - 2.0 * (q[2] ** 2 + q[3] ** 2))
            yaw = yaw_state[k, 1] + reference.wrap_angle(raw - yaw_state[k, 2])
            a_c = reference.yaw_cycle(omega_world[2], yaw_state[k, 0], cmd[k][2], yaw, dt=dt, v_max=c.v_max_c,
                                      a_max=c.a_max_c, j_max=c.j_max_c, p_max=c.p_max_c, jerk_mode=c.jerk)
            yaw_state[k] = (a_c, yaw, raw)
            drive[2] = inertia[2] * a_c
            target = reference.yaw_quat(raw)  # the yaw is driven: hold roll and pitch only
            d_rot = d_rot * np.array([1.0, 1.0, 0.0])
        # Rotation from q to the target, in the world frame; q is (w, x, y, z).
        err_world = rot @ reference.quat_to_rotvec(reference.quat_mul(q_xyzw * np.array([-1, -1, -1, 1.0]), target))
        tau = k_rot * err_world - d_rot * omega_world + drive
        mjd.qfrc_applied[da : da + 6] = np.concatenate([m * a, [fz], rot.T @ tau])


def rollout(
    xml: str,
    actions: np.ndarray,
    control: ControlParams,
    *,
    init_qpos: np.ndarray | None = None,
    init_qvel: np.ndarray | None = None,
    hover_z: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Run ``actions`` (``[steps, M, 2]``, or ``[steps, M, 3]`` with ``control.rotation``, each held for
    ``control.num_cycles`` cycles) in MuJoCo C, float64.

    Returns ``(qpos, qvel)`` after every env step, shapes ``[steps, nq]`` and ``[steps, nv]``.
    """
    from magwarp.physics.backend import _free_joint_addrs

    mjm = mujoco.MjModel.from_xml_string(xml)
    mjd = mujoco.MjData(mjm)
    movers = []
    while mujoco.mj_name2id(mjm, mujoco.mjtObj.mjOBJ_BODY, f"mover_{len(movers)}") >= 0:
        movers.append(f"mover_{len(movers)}")
    body, qadr, dadr = _free_joint_addrs(mjm, movers)
    if init_qpos is not None:
        mjd.qpos[:] = init_qpos
    if init_qvel is not None:
        mjd.qvel[:] = init_qvel
    mujoco.mj_forward(mjm, mjd)
    hz = mjd.qpos[qadr + 2].copy() if hover_z is None else np.broadcast_to(hover_z, (len(movers),)).astype(float)
    acc = np.zeros((len(movers), 2))
    yaw_state = np.zeros((len(movers), 3))
    qs, vs = [], []
    for cmd in np.asarray(actions, dtype=np.float64):
        for _ in range(control.num_cycles):
            control_forces(mjm, mjd, body, qadr, dadr, hz, cmd, acc, control, yaw_state)
            mujoco.mj_step(mjm, mjd)
        qs.append(mjd.qpos.copy())
        vs.append(mjd.qvel.copy())
    return np.array(qs), np.array(vs)
