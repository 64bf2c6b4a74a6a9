"""Planar command limits and rigid-body integration of one mover for one control cycle.

x/y motion reproduces MagBotSim exactly: the command (acceleration, or jerk integrated into the acceleration) is
norm-clipped per mover, and where the next velocity would reach ``v_max`` the acceleration is shortened so that the
velocity lands on the cap. Integration is semi-implicit Euler (velocity first, then position), as MuJoCo's Euler
integrator does for an acceleration actuator at the 1 ms cycle.
"""

import warp as wp

from magwarp.types import Body, Limits, Pose, Wrench


@wp.func
def clip_norm2(v: wp.vec2, limit: float) -> wp.vec2:
    """Scale ``v`` down to norm ``limit`` if it is longer."""
    n = wp.length(v)
    if n > limit:
        return v * (limit / n)
    return v


@wp.func
def capped_derivative(current: wp.vec2, deriv: wp.vec2, limit: float, dt: float) -> wp.vec2:
    """The derivative to apply so that ``current + dt * deriv`` stays within norm ``limit``."""
    nxt = current + deriv * dt
    n = wp.length(nxt)
    if n >= limit:
        return (nxt * (limit / n) - current) / dt
    return deriv


@wp.func
def planar_acceleration(vel: wp.vec3, acc: wp.vec2, cmd: wp.vec2, lim: Limits) -> wp.vec2:
    """The x/y acceleration for this cycle from the command, within the jerk, acceleration and speed limits."""
    v = wp.vec2(vel[0], vel[1])
    if lim.jerk_mode == 1:
        jerk = clip_norm2(cmd, lim.j_max)
        a = acc + capped_derivative(acc, jerk, lim.a_max, lim.dt) * lim.dt
        return capped_derivative(v, a, lim.v_max, lim.dt)
    return capped_derivative(v, clip_norm2(cmd, lim.a_max), lim.v_max, lim.dt)


@wp.func
def integrate_rotation(q: wp.quat, omega: wp.vec3, dt: float) -> wp.quat:
    """Advance ``q`` by the world-frame angular velocity over ``dt`` (exponential map), renormalised."""
    speed = wp.length(omega)
    angle = speed * dt
    if angle < 1.0e-12:
        return q
    axis = omega / speed
    s = wp.sin(0.5 * angle)
    dq = wp.quat(axis[0] * s, axis[1] * s, axis[2] * s, wp.cos(0.5 * angle))
    return wp.normalize(dq * q)


@wp.func
def angular_acceleration(q: wp.quat, omega: wp.vec3, torque: wp.vec3, inertia: wp.vec3) -> wp.vec3:
    """Euler's equations in the body frame (diagonal inertia), returned in the world frame."""
    w_b = wp.quat_rotate_inv(q, omega)
    t_b = wp.quat_rotate_inv(q, torque)
    iw = wp.cw_mul(inertia, w_b)
    alpha_b = wp.cw_div(t_b - wp.cross(w_b, iw), inertia)
    return wp.quat_rotate(q, alpha_b)


@wp.func
def integrate_body(p: Pose, w: Wrench, body: Body, lim: Limits) -> Pose:
    """One semi-implicit Euler step under wrench ``w`` plus gravity."""
    lin_acc = w.force * body.inv_mass - wp.vec3(0.0, 0.0, lim.gravity)
    out = Pose()
    out.vel = p.vel + lin_acc * lim.dt
    out.pos = p.pos + out.vel * lim.dt
    # Exact early out for a mover with no spin and no torque (the common case): its attitude cannot change.
    if p.omega == wp.vec3(0.0) and w.torque == wp.vec3(0.0):
        out.omega = p.omega
        out.quat = p.quat
        return out
    out.omega = p.omega + angular_acceleration(p.quat, p.omega, w.torque, body.inertia) * lim.dt
    out.quat = integrate_rotation(p.quat, out.omega, lim.dt)
    return out
