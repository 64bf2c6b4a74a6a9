"""Planar command limits and rigid-body integration of one mover for one control cycle.

x/y motion reproduces MagBotSim exactly: the command (acceleration, or jerk integrated into the acceleration) is
norm-clipped per mover, and where the next velocity would reach ``v_max`` the acceleration is shortened so that the
velocity lands on the cap. Integration is semi-implicit Euler (velocity first, then position), as MuJoCo's Euler
integrator does for an acceleration actuator at the 1 ms cycle.

The planar simulator runs this x/y law in float64 on its own float64 x/y state (position, velocity and the carried
drive acceleration; :data:`~magwarp.types.Planar64`), and the float32 fields are its rounding: at the speed cap the
law divides a difference of two speeds near ``v_max`` by ``dt``, which float32 rounds to ~1e-4 m/s^2, and jerk mode
carries the acceleration from cycle to cycle, so a float32 law drifts from MagBotSim's (float64 MuJoCo) by
millimetres within seconds. The same law in float32 drives the mujoco-warp backend (whose state is float32).
"""

from typing import Any

import warp as wp

from magwarp.types import Body, Limits, Planar64, Pose, Wrench


@wp.func
def clip_norm2(v: Any, limit: Any):
    """Scale ``v`` down to norm ``limit`` if it is longer (float32 or float64)."""
    n2 = wp.dot(v, v)
    if n2 > limit * limit:  # squared: no square root unless clipping
        return v * (limit / wp.sqrt(n2))
    return v


@wp.func
def capped_derivative(current: Any, deriv: Any, limit: Any, dt: Any):
    """The derivative to apply so that ``current + dt * deriv`` stays within norm ``limit`` (float32 or float64)."""
    nxt = current + deriv * dt
    n2 = wp.dot(nxt, nxt)
    if n2 >= limit * limit:  # squared: no square root unless capping
        return (nxt * (limit / wp.sqrt(n2)) - current) / dt
    return deriv


@wp.func
def planar_law(v: Any, acc: Any, cmd: Any, dt: Any, v_max: Any, a_max: Any, j_max: Any, jerk_mode: int):
    """The x/y acceleration for this cycle from the command, within the jerk, acceleration and speed limits, in the
    precision of its arguments."""
    if jerk_mode == 1:
        jerk = clip_norm2(cmd, j_max)
        a = acc + capped_derivative(acc, jerk, a_max, dt) * dt
        return capped_derivative(v, a, v_max, dt)
    return capped_derivative(v, clip_norm2(cmd, a_max), v_max, dt)


@wp.func
def planar_acceleration(vel: wp.vec3, acc: wp.vec2, cmd: wp.vec2, lim: Limits) -> wp.vec2:
    """The x/y acceleration for this cycle (float32: the mujoco-warp backend's law)."""
    return planar_law(wp.vec2(vel[0], vel[1]), acc, cmd, lim.dt, lim.v_max, lim.a_max, lim.j_max, lim.jerk_mode)


@wp.func
def planar_acceleration64(vel: wp.vec2d, acc: wp.vec2d, cmd: wp.vec2, lim: Limits, body: Body) -> wp.vec2d:
    """The x/y acceleration for this cycle in float64 (the planar simulator's law: at the speed cap the law divides
    a difference of two speeds near ``v_max`` by ``dt``, which float32 rounds to about 1e-4 m/s^2, and jerk mode
    would carry that error in its acceleration state), within the mover's own (per-world) limits."""
    c = wp.vec2d(wp.float64(cmd[0]), wp.float64(cmd[1]))
    return planar_law(vel, acc, c, lim.dt64, body.v_max, body.a_max, body.j_max, lim.jerk_mode)


@wp.func
def planar_acceleration64(vel: wp.vec2d, acc: wp.vec2d, cmd: wp.vec2, lim: Limits) -> wp.vec2d:
    """The same within the shared limits (every mover as configured)."""
    c = wp.vec2d(wp.float64(cmd[0]), wp.float64(cmd[1]))
    return planar_law(vel, acc, c, lim.dt64, lim.v_max64, lim.a_max64, lim.j_max64, lim.jerk_mode)


@wp.func
def _f32(v: wp.vec2d) -> wp.vec2:
    return wp.vec2(wp.float32(v[0]), wp.float32(v[1]))


@wp.func
def _synced(hi: wp.vec2d, lo: wp.vec2) -> wp.vec2d:
    """``hi`` while ``lo`` is its float32 rounding, else ``lo`` (the float32 field was written from outside)."""
    if _f32(hi) == lo:
        return hi
    return wp.vec2d(wp.float64(lo[0]), wp.float64(lo[1]))


@wp.func
def sync_planar64(xy: Planar64, pos: wp.vec3, vel: wp.vec3, acc: wp.vec2) -> Planar64:
    """The float64 x/y state, restarted per quantity from the float32 fields where they were written from outside."""
    p = _synced(wp.vec2d(xy[0], xy[1]), wp.vec2(pos[0], pos[1]))
    v = _synced(wp.vec2d(xy[2], xy[3]), wp.vec2(vel[0], vel[1]))
    a = _synced(wp.vec2d(xy[4], xy[5]), acc)
    return Planar64(p[0], p[1], v[0], v[1], a[0], a[1])


@wp.func
def integrate_planar64(n: Pose, xy: Planar64, a: wp.vec2d, extra: wp.vec2, lim: Limits):
    """Semi-implicit Euler of x/y in float64 under the drive acceleration ``a`` plus ``extra`` (the x/y acceleration
    of any other force of the force model; 0 by default). Writes the rounded x/y into ``n`` (integrated in float32
    with the other axes) and returns it with the new float64 state."""
    dt = lim.dt64
    acc = a + wp.vec2d(wp.float64(extra[0]), wp.float64(extra[1]))
    v = wp.vec2d(xy[2], xy[3]) + acc * dt
    p = wp.vec2d(xy[0], xy[1]) + v * dt
    out = n
    out.pos = wp.vec3(wp.float32(p[0]), wp.float32(p[1]), n.pos[2])
    out.vel = wp.vec3(wp.float32(v[0]), wp.float32(v[1]), n.vel[2])
    return out, Planar64(p[0], p[1], v[0], v[1], a[0], a[1])


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
