"""A swinging payload: a point mass (the bob) on a massless rigid rod, hinged by a ball joint to a pivot fixed on a
mover, coupled to the mover's rigid-body motion (:mod:`magwarp.pendulum` attaches it to a simulator).

Equations (world frame; mover mass ``M``, inertia ``I`` about its centre, pose ``(c, R)``, velocity ``v``, angular
velocity ``omega``; pivot ``r = R r_b`` from the centre, rod ``d`` from the pivot to the bob, ``|d| = L``, ``e = d /
L``; bob mass ``m``; the mover's own wrench ``(F, tau)`` about its centre, gravity ``g`` along -z). The rod pulls the
pivot along ``e`` and the bob along ``-e`` with the tension ``T``:

* bob: ``m a_b = -m g z - T e``;
* mover: ``M a = F - M g z + T e``, ``I alpha = tau + r x T e - omega x I omega`` (Euler's equations, as the
  integrator's :func:`~magwarp.kernels.dynamics.angular_acceleration`);
* the rod keeps its length: ``e . (a_b - a_p) = -|d'|^2 / L`` with the pivot's acceleration ``a_p = a + alpha x r +
  omega x (omega x r)`` and ``d'`` the bob's velocity relative to the pivot.

All three are linear in ``T``:
``T = m (|d'|^2 / L - e . F / M - e . (alpha_0 x r) - e . (omega x (omega x r))) / (1 + m / M + m k)`` with
``alpha_0`` the mover's angular acceleration without the rod and ``k = (r x e) . R I^-1 R^T (r x e)``. Gravity
cancels (bob and mover fall alike). ``m = 0`` gives ``T = 0`` (no payload).

One control cycle: :func:`pendulum_reaction_kernel` (before the mover's integration) solves ``T`` at the cycle's
start state, writes the rod's wrench on the mover (force ``T e``, torque ``r x T e`` about the centre) for the
force model to add, and advances the bob by semi-implicit Euler (velocity first, as the mover) to its absolute
position and velocity; :func:`pendulum_constrain_kernel` (after the mover's integration) takes the bob relative to the
mover's new pivot and projects it back onto the rod (length ``L``, no velocity along the rod). The state is the rod
``d`` and the bob's velocity relative to the pivot ``d'`` (world frame), per mover.
"""

from __future__ import annotations

import warp as wp

from magwarp.kernels.collision import model_row
from magwarp.kernels.dynamics import angular_acceleration
from magwarp.kernels.options import MODULE_OPTIONS
from magwarp.types import Body, Limits

wp.set_module_options({"enable_backward": False, **MODULE_OPTIONS})


@wp.kernel
def pendulum_reaction_kernel(
    # Model:
    lim: Limits,
    body: wp.array2d(dtype=Body),
    pivot: wp.vec3,  # body frame, from the mover centre (m)
    bob_mass: wp.array(dtype=float),  # [W] kg
    length: wp.array(dtype=float),  # [W] m
    col: int,  # first of the six force_aux columns of the rod's wrench
    # State in:
    pos: wp.array2d(dtype=wp.vec3),
    quat: wp.array2d(dtype=wp.quat),
    vel: wp.array2d(dtype=wp.vec3),
    omega: wp.array2d(dtype=wp.vec3),
    rod: wp.array2d(dtype=wp.vec3),
    rod_rate: wp.array2d(dtype=wp.vec3),
    # State out:
    force_aux: wp.array3d(dtype=float),  # reads the mover's own wrench in columns 0-5
    bob_pos: wp.array2d(dtype=wp.vec3),
    bob_vel: wp.array2d(dtype=wp.vec3),
    tension: wp.array2d(dtype=float),
):
    """The rod's tension and wrench on the mover at the cycle's start; the bob advanced by one cycle."""
    w, m = wp.tid()
    b = body[model_row(body.shape[0], w), m]
    q = quat[w, m]
    om = omega[w, m]
    r = wp.quat_rotate(q, pivot)
    d = rod[w, m]
    dd = rod_rate[w, m]
    e = wp.normalize(d)
    force = wp.vec3(force_aux[w, m, 0], force_aux[w, m, 1], force_aux[w, m, 2])
    torque = wp.vec3(force_aux[w, m, 3], force_aux[w, m, 4], force_aux[w, m, 5])
    alpha0 = angular_acceleration(q, om, torque, b.inertia)
    re = wp.cross(r, e)
    k = wp.dot(re, angular_acceleration(q, wp.vec3(0.0), re, b.inertia))
    mb = bob_mass[w]
    num = (wp.dot(dd, dd) / length[w] - wp.dot(e, force) * b.inv_mass - wp.dot(e, wp.cross(alpha0, r))
           - wp.dot(e, wp.cross(om, wp.cross(om, r))))
    den = 1.0 + mb * b.inv_mass + mb * k
    t = mb * num / den
    f = e * t
    tau = wp.cross(r, f)
    for j in range(3):
        force_aux[w, m, col + j] = f[j]
        force_aux[w, m, col + 3 + j] = tau[j]
    tension[w, m] = t
    acc = wp.vec3(0.0, 0.0, -lim.gravity) - e * (num / den)  # -g z - (T / m) e, finite for m = 0
    pivot_pos = pos[w, m] + r
    pivot_vel = vel[w, m] + wp.cross(om, r)
    v = pivot_vel + dd + acc * lim.dt
    bob_vel[w, m] = v
    bob_pos[w, m] = pivot_pos + d + v * lim.dt


@wp.kernel
def pendulum_constrain_kernel(
    # Model:
    pivot: wp.vec3,
    length: wp.array(dtype=float),
    # State in:
    pos: wp.array2d(dtype=wp.vec3),
    quat: wp.array2d(dtype=wp.quat),
    vel: wp.array2d(dtype=wp.vec3),
    omega: wp.array2d(dtype=wp.vec3),
    bob_pos: wp.array2d(dtype=wp.vec3),
    bob_vel: wp.array2d(dtype=wp.vec3),
    # State out:
    rod: wp.array2d(dtype=wp.vec3),
    rod_rate: wp.array2d(dtype=wp.vec3),
):
    """The bob relative to the mover's new pivot, projected onto the rod: length ``L``, no velocity along it."""
    w, m = wp.tid()
    q = quat[w, m]
    om = omega[w, m]
    r = wp.quat_rotate(q, pivot)
    e = wp.normalize(bob_pos[w, m] - (pos[w, m] + r))
    rel = bob_vel[w, m] - (vel[w, m] + wp.cross(om, r))
    rod[w, m] = e * length[w]
    rod_rate[w, m] = rel - e * wp.dot(rel, e)
