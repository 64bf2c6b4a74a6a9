"""Warp kernels that drive movers inside mujoco-warp: x/y motion commands plus the impedance hold, and masked resets.

The control law per mover and control cycle (dt = model timestep) is

- x/y: MagBotSim's ``_before_mujoco_step_callback`` + ``ensure_max_dyn_val``. Acceleration mode: the command is
  norm-clipped to ``a_max`` and reduced where ``|v + dt a| >= v_max`` so the speed stays at ``v_max``. Jerk mode:
  the command is norm-clipped to ``j_max``, integrated into the commanded acceleration (capped at ``a_max``) and then
  speed-limited the same way. The generalized force is ``m a`` on the free joint's x/y dofs, exactly what
  MagBotSim's ``gainprm=mass`` actuators apply (its jerk actuators are integrators with ``actearly``, i.e. our
  ``acc`` state). The acceleration state is the *commanded* one (MagBotSim reads ``qacc``, which equals it unless
  the mover is in contact; the commanded value keeps the limits independent of contact noise).
- z, roll, pitch, yaw: impedance hold towards the hover height and level, zero-yaw attitude,
  ``f_z = K_z (z_d - z) - D_z v_z`` and ``tau = K_r e - D_r w`` (world frame, ``e`` the rotation vector from the
  current to the target orientation) with critical damping ``D = 2 sqrt(K m)`` (translation) and
  ``D = 2 sqrt(K I)`` (rotation, principal inertia). The torque enters the free joint's rotational dofs as
  ``R^T tau`` (its angular dofs are body-frame). Gravity is compensated by the model (``gravcomp="1"``, see
  :mod:`magwarp.mjcf`). Unlike MagBotSim, the law reads the current pose (not the previous cycle's ``xpos``),
  targets the body centre at ``hover_z`` and damps rotation with the inertia.
- yaw ("c") drive, when ``YawDrive.enabled`` (MagBotSim's ``learn_mover_c_rotation``): the yaw hold is released
  (the attitude target follows the current yaw, yaw rate undamped) and the command drives the yaw: acceleration
  mode, ``|a_c| <= a_max_c``; jerk mode, ``|j_c| <= j_max_c`` integrated into the acceleration state (capped at
  ``a_max_c``), as for x/y. The yaw rate is capped at ``v_max_c``; with a position limit ``p_max_c`` the cap
  shrinks to ``0.65 sqrt(2 a_max_c (p_max_c - |yaw|))`` when the command pushes toward a limit within the braking
  distance ``v_c^2 / (2 a_max_c) + 0.05`` (MagBotSim's rule, on the accumulated yaw, so crossing +-pi is no jump).
  The torque is ``I_zz a_c`` about the vertical: MagBotSim's actuator uses the mass as gain, so its "acceleration"
  is not one; ours is.

The law's mass (drive force and z damping), the gains (``K_z``, ``K_r``) and the x/y limits are per mover, in one row
shared by all worlds until domain randomisation makes them per world (:meth:`magwarp.physics.MjwBackend.batch_control`):
the mass is the built mover's (plus a payload the controller is configured for), whatever mass the model's body has;
the inertia (rotational damping) is the built mover's.
"""

from __future__ import annotations

import warp as wp

from magwarp.kernels.collision import model_row
from magwarp.kernels.dynamics import planar_acceleration
from magwarp.kernels.impedance import rotation_error
from magwarp.types import Limits

# The x/y limits and the rotation-vector error are the planar simulator's own functions: one law for both engines.
_IDENTITY = wp.constant(wp.quat(0.0, 0.0, 0.0, 1.0))


@wp.struct
class YawDrive:
    """Limits of the commanded yaw ("c") axis; ``enabled = 0`` keeps the yaw held by the impedance law."""

    enabled: int
    jerk_mode: int
    v_max: float
    a_max: float
    j_max: float
    p_max: float  # position limit |yaw| <= p_max; <= 0: none


@wp.func
def wrap_angle(a: float) -> float:
    """``a`` wrapped to [-pi, pi)."""
    return a - 2.0 * wp.pi * wp.floor((a + wp.pi) / (2.0 * wp.pi))


@wp.func
def yaw_acceleration(c_vel: float, acc_c: float, cmd: float, yaw: float, lim: YawDrive, dt: float) -> float:
    """The yaw acceleration for this cycle from the command, within the jerk, acceleration, rate and position limits."""
    a = wp.clamp(cmd, -lim.a_max, lim.a_max)
    if lim.jerk_mode == 1:
        a = wp.clamp(acc_c + wp.clamp(cmd, -lim.j_max, lim.j_max) * dt, -lim.a_max, lim.a_max)
    v_safe = lim.v_max
    if lim.p_max > 0.0:
        braking = c_vel * c_vel / (2.0 * lim.a_max) + 0.05
        dist = lim.p_max - wp.abs(yaw)
        toward = (a > 0.0 and yaw > 0.0) or (a < 0.0 and yaw < 0.0)
        if toward and dist < braking:
            v_safe = wp.min(lim.v_max, wp.sqrt(wp.max(0.0, 2.0 * lim.a_max * dist)) * 0.65)
    next_vel = wp.clamp(c_vel + a * dt, -v_safe, v_safe)
    return (next_vel - c_vel) / dt


@wp.kernel
def mover_control_kernel(
    # Model:
    qadr: wp.array[int],
    dadr: wp.array[int],
    mass: wp.array2d[float],  # the law's mass per mover (drive force, z damping); shared row or one per world
    inertia: wp.array[wp.vec3],
    hover_z: wp.array[float],
    gains: wp.array2d[wp.vec4],  # (k_lin_z, k_rot) per mover; one shared row or one per world (randomisation)
    limits: wp.array2d[wp.vec3],  # (v_max, a_max, j_max) per mover; likewise
    dt: float,
    jerk_mode: int,
    yaw_drive: YawDrive,
    # State in:
    qpos: wp.array2d[float],
    qvel: wp.array2d[float],
    cmd: wp.array2d[wp.vec2],
    cmd_c: wp.array2d[float],
    # State in/out:
    acc: wp.array2d[wp.vec2],
    acc_c: wp.array2d[float],
    yaw_track: wp.array2d[wp.vec2],  # (accumulated yaw, last raw yaw)
    # State out:
    qfrc_applied: wp.array2d[float],
):
    w, k = wp.tid()
    qa = qadr[k]
    da = dadr[k]
    m = mass[model_row(mass.shape[0], w), k]
    g = gains[model_row(gains.shape[0], w), k]
    lw = limits[model_row(limits.shape[0], w), k]
    k_lin_z = g[0]
    k_rot = wp.vec3(g[1], g[2], g[3])

    # x/y: limited acceleration, applied as m * a (semi-implicit Euler then matches MagBotSim's actuators).
    lim = Limits()
    lim.dt = dt
    lim.v_max = lw[0]
    lim.a_max = lw[1]
    lim.j_max = lw[2]
    lim.jerk_mode = jerk_mode
    a = planar_acceleration(wp.vec3(qvel[w, da], qvel[w, da + 1], 0.0), acc[w, k], cmd[w, k], lim)
    acc[w, k] = a

    # z: critically damped spring to the hover height.
    d_lin_z = 2.0 * wp.sqrt(k_lin_z * m)
    f_z = k_lin_z * (hover_z[k] - qpos[w, qa + 2]) - d_lin_z * qvel[w, da + 2]

    # attitude: spring to identity orientation (MuJoCo stores w, x, y, z; Warp quats are x, y, z, w).
    q = wp.normalize(wp.quat(qpos[w, qa + 4], qpos[w, qa + 5], qpos[w, qa + 6], qpos[w, qa + 3]))
    omega_local = wp.vec3(qvel[w, da + 3], qvel[w, da + 4], qvel[w, da + 5])
    omega_world = wp.quat_rotate(q, omega_local)
    inert = inertia[k]
    d_rot = wp.vec3(
        2.0 * wp.sqrt(k_rot[0] * inert[0]), 2.0 * wp.sqrt(k_rot[1] * inert[1]), 2.0 * wp.sqrt(k_rot[2] * inert[2])
    )
    target = _IDENTITY
    drive_c = float(0.0)
    if yaw_drive.enabled == 1:
        raw = wp.atan2(2.0 * (q[3] * q[2] + q[0] * q[1]), 1.0 - 2.0 * (q[1] * q[1] + q[2] * q[2]))
        tr = yaw_track[w, k]
        yaw = tr[0] + wrap_angle(raw - tr[1])
        yaw_track[w, k] = wp.vec2(yaw, raw)
        a_c = yaw_acceleration(omega_world[2], acc_c[w, k], cmd_c[w, k], yaw, yaw_drive, dt)
        acc_c[w, k] = a_c
        drive_c = inert[2] * a_c
        target = wp.quat(0.0, 0.0, wp.sin(0.5 * raw), wp.cos(0.5 * raw))  # hold roll and pitch only
        d_rot = wp.vec3(d_rot[0], d_rot[1], 0.0)
    err_world = rotation_error(q, target)
    tau_world = wp.cw_mul(k_rot, err_world) - wp.cw_mul(d_rot, omega_world) + wp.vec3(0.0, 0.0, drive_c)
    tau_local = wp.quat_rotate_inv(q, tau_world)

    qfrc_applied[w, da + 0] = m * a[0]
    qfrc_applied[w, da + 1] = m * a[1]
    qfrc_applied[w, da + 2] = f_z
    qfrc_applied[w, da + 3] = tau_local[0]
    qfrc_applied[w, da + 4] = tau_local[1]
    qfrc_applied[w, da + 5] = tau_local[2]


@wp.kernel
def copy_rows_masked_kernel(
    # In:
    mask: wp.array[bool],
    src: wp.array2d[float],
    # Out:
    dst: wp.array2d[float],
):
    """``dst[w] = src[w]`` for worlds with ``mask[w]`` (initial qpos/qvel on reset)."""
    w, i = wp.tid()
    if mask[w]:
        dst[w, i] = src[w, i]


@wp.kernel
def zero_float_masked_kernel(
    # In:
    mask: wp.array[bool],
    # Out:
    dst: wp.array2d[float],
):
    w, k = wp.tid()
    if mask[w]:
        dst[w, k] = 0.0


@wp.kernel
def zero_vec2_masked_kernel(
    # In:
    mask: wp.array[bool],
    # Out:
    dst: wp.array2d[wp.vec2],
):
    w, k = wp.tid()
    if mask[w]:
        dst[w, k] = wp.vec2(0.0, 0.0)
