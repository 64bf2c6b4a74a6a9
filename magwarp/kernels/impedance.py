"""The impedance controller that holds a mover's height and attitude, and the default force model built on it.

The law is ``wrench = K * error - D * velocity`` per held axis, with critical damping ``D = 2 sqrt(K M)``: the mass
for translation and the principal inertia for rotation (MagBotSim uses the mass for rotation too, which
over-damps the attitude; we use the physically right law). The orientation error is the rotation vector that takes
the current orientation to the target, expressed in the world frame.

A *force model* is a ``@wp.func`` with the signature of :func:`default_force`: it maps a mover's pose, its body, the
planar drive force the x/y command asks for, its impedance target and gains, and a free per-mover parameter row
(``aux``, for e.g. coil currents) to the total wrench on the mover, gravity excluded (the integrator adds gravity).
"""

import warp as wp

from magwarp.types import Body, Impedance, Limits, Pose, Wrench


@wp.func
def rotation_error(q: wp.quat, target: wp.quat) -> wp.vec3:
    """World-frame rotation vector from ``q`` to ``target`` (shortest arc)."""
    if q == target:
        # Exact early out: a mover that holds its attitude (the common case) skips the trigonometry.
        return wp.vec3(0.0)
    rel = wp.quat_inverse(q) * target
    v = wp.vec3(rel[0], rel[1], rel[2])
    w = rel[3]
    if w < 0.0:
        v = -v
        w = -w
    s = wp.length(v)
    rotvec = v * 2.0
    if s > 1.0e-9:
        rotvec = v * (2.0 * wp.atan2(s, w) / s)
    return wp.quat_rotate(q, rotvec)


@wp.func
def impedance_wrench(p: Pose, body: Body, target_pos: wp.vec3, target_quat: wp.quat, imp: Impedance) -> Wrench:
    """Critically damped spring toward the target on the held axes (damping precomputed per body)."""
    out = Wrench()
    out.force = wp.cw_mul(imp.mask_lin, wp.cw_mul(imp.k_lin, target_pos - p.pos) - wp.cw_mul(body.damp_lin, p.vel))
    out.torque = wp.cw_mul(
        imp.mask_rot, wp.cw_mul(imp.k_rot, rotation_error(p.quat, target_quat)) - wp.cw_mul(body.damp_rot, p.omega)
    )
    return out


@wp.func
def default_force(
    p: Pose,
    body: Body,
    drive: wp.vec3,
    target_pos: wp.vec3,
    target_quat: wp.quat,
    imp: Impedance,
    lim: Limits,
    aux: wp.array(dtype=float),
) -> Wrench:
    """Levitation as gravity compensation, the x/y drive force, and the impedance hold of the other axes."""
    w = impedance_wrench(p, body, target_pos, target_quat, imp)
    w.force = w.force + drive + wp.vec3(0.0, 0.0, body.mass * lim.gravity)
    return w
