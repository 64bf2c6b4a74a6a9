"""Model writes: per-world mover parameters packed into the simulator's :class:`~magwarp.types.Body` rows (domain
randomisation changes them on the device between steps, with no rebuild)."""

from __future__ import annotations

import warp as wp

from magwarp.kernels.options import MODULE_OPTIONS
from magwarp.types import Body

wp.set_module_options({"enable_backward": False, **MODULE_OPTIONS})


#: one body row as two vectors: its float32 fields (mass, inv_mass, inertia, damp_lin, damp_rot, k_lin, k_rot, com)
#: and its float64 ones (drive_gain, v_max, a_max, j_max), as the general register step kernel holds rows
BodyF32 = wp.types.vector(length=20, dtype=wp.float32)
BodyF64 = wp.types.vector(length=4, dtype=wp.float64)


@wp.func
def body_f32(b: Body) -> BodyF32:
    """The float32 fields of a body row, as :func:`row_body` takes them."""
    return BodyF32(b.mass, b.inv_mass, b.inertia[0], b.inertia[1], b.inertia[2], b.damp_lin[0], b.damp_lin[1],
                   b.damp_lin[2], b.damp_rot[0], b.damp_rot[1], b.damp_rot[2], b.k_lin[0], b.k_lin[1], b.k_lin[2],
                   b.k_rot[0], b.k_rot[1], b.k_rot[2], b.com[0], b.com[1], b.com[2])


@wp.func
def body_f64(b: Body) -> BodyF64:
    """The float64 fields of a body row, as :func:`row_body` takes them."""
    return BodyF64(b.drive_gain, b.v_max, b.a_max, b.j_max)


@wp.func
def row_body(f: BodyF32, d: BodyF64) -> Body:
    """The body row held as :func:`body_f32` and :func:`body_f64` (the same bits)."""
    b = Body()
    b.mass = f[0]
    b.inv_mass = f[1]
    b.inertia = wp.vec3(f[2], f[3], f[4])
    b.damp_lin = wp.vec3(f[5], f[6], f[7])
    b.damp_rot = wp.vec3(f[8], f[9], f[10])
    b.k_lin = wp.vec3(f[11], f[12], f[13])
    b.k_rot = wp.vec3(f[14], f[15], f[16])
    b.com = wp.vec3(f[17], f[18], f[19])
    b.drive_gain = d[0]
    b.v_max = d[1]
    b.a_max = d[2]
    b.j_max = d[3]
    return b


@wp.func
def pack_body(m_ctrl: wp.float64, i_ctrl: wp.vec3d, mass: wp.float64, inertia: wp.vec3d, k_lin: wp.vec3d,
              k_rot: wp.vec3d, com: wp.vec3d, v_max: wp.float64, a_max: wp.float64, j_max: wp.float64) -> Body:
    """One mover's body row. The controller knows ``m_ctrl`` and ``i_ctrl`` (the configured mover): the x/y drive gain
    is ``m_ctrl / mass`` and the impedance damping ``2 sqrt(K m_ctrl)``, ``2 sqrt(K I_ctrl)``. Rounded as the
    simulator's constructor does, so that the configured values pack to the same bits."""
    b = Body()
    b.mass = wp.float32(mass)
    b.inv_mass = wp.float32(wp.float64(1.0) / mass)
    b.inertia = wp.vec3(wp.float32(inertia[0]), wp.float32(inertia[1]), wp.float32(inertia[2]))
    kl = wp.vec3(wp.float32(k_lin[0]), wp.float32(k_lin[1]), wp.float32(k_lin[2]))
    kr = wp.vec3(wp.float32(k_rot[0]), wp.float32(k_rot[1]), wp.float32(k_rot[2]))
    b.k_lin = kl
    b.k_rot = kr
    mc = wp.float32(m_ctrl)
    b.damp_lin = wp.vec3(2.0 * wp.sqrt(kl[0] * mc), 2.0 * wp.sqrt(kl[1] * mc), 2.0 * wp.sqrt(kl[2] * mc))
    two = wp.float64(2.0)
    b.damp_rot = wp.vec3(wp.float32(two * wp.sqrt(wp.float64(kr[0]) * i_ctrl[0])),
                         wp.float32(two * wp.sqrt(wp.float64(kr[1]) * i_ctrl[1])),
                         wp.float32(two * wp.sqrt(wp.float64(kr[2]) * i_ctrl[2])))
    b.drive_gain = m_ctrl / mass
    b.com = wp.vec3(wp.float32(com[0]), wp.float32(com[1]), wp.float32(com[2]))
    b.v_max = v_max
    b.a_max = a_max
    b.j_max = j_max
    return b


@wp.func
def with_payload(mass: wp.float64, inertia: wp.vec3d, payload: wp.float64, offset: wp.vec3d):
    """Mass, principal inertia about the new centre of mass (parallel axis, diagonal terms) and that centre (body
    frame, from the mover centre) of a body with a point ``payload`` at ``offset``."""
    total = mass + payload
    mu = mass * payload / total
    r2 = wp.dot(offset, offset)
    shift = wp.vec3d(r2 - offset[0] * offset[0], r2 - offset[1] * offset[1], r2 - offset[2] * offset[2])
    return total, inertia + mu * shift, offset * (payload / total)


@wp.struct
class MoverParams:
    """The per-world mover parameters a body row is packed from (:attr:`magwarp.sim.Simulator.mover_params`, float64
    ``[W, M]`` arrays) and the controller's configured mover."""

    m_ctrl: wp.float64  # the configured mass (the controller's)
    i_ctrl: wp.vec3d  # the configured principal inertia
    scale_inertia: int  # 1: use the configured inertia scaled with each mover's mass (uniform density)
    mass: wp.array2d(dtype=wp.float64)
    inertia: wp.array2d(dtype=wp.vec3d)
    payload: wp.array2d(dtype=wp.float64)
    offset: wp.array2d(dtype=wp.vec3d)
    known: wp.array2d(dtype=wp.float64)  # the payload the controller is configured for
    k_lin: wp.array2d(dtype=wp.vec3d)
    k_rot: wp.array2d(dtype=wp.vec3d)
    v_max: wp.array2d(dtype=wp.float64)
    a_max: wp.array2d(dtype=wp.float64)
    j_max: wp.array2d(dtype=wp.float64)


@wp.func
def pack_mover(p: MoverParams, w: int, m: int) -> Body:
    """Mover ``m`` of world ``w``'s body row: its own mass and inertia (``p.scale_inertia``: the configured inertia
    scaled with the mass, uniform density) plus a point payload (:func:`with_payload`; none when it is 0), then
    :func:`pack_body` with the controller's mass ``m_ctrl + known`` (the payload its feedforward is configured for:
    XPlanar's payload parametrisation)."""
    mw = p.mass[w, m]
    iw = p.inertia[w, m]
    if p.scale_inertia != 0:
        iw = iw * (mw / p.m_ctrl)
    com = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(0.0))
    pay = p.payload[w, m]
    off = p.offset[w, m]  # loaded with the others, not after the test (one memory latency less)
    if pay != wp.float64(0.0):
        mw, iw, com = with_payload(mw, iw, pay, off)
    return pack_body(p.m_ctrl + p.known[w, m], p.i_ctrl, mw, iw, p.k_lin[w, m], p.k_rot[w, m], com, p.v_max[w, m],
                     p.a_max[w, m], p.j_max[w, m])


@wp.kernel
def pack_bodies(
    mask: wp.array(dtype=wp.bool),
    # State in:
    params: MoverParams,
    # State out:
    body: wp.array2d(dtype=Body),
):
    """Pack the masked worlds' mover parameters into their body rows (one thread per mover, :func:`pack_mover`)."""
    w, m = wp.tid()
    if not mask[w]:
        return
    body[w, m] = pack_mover(params, w, m)
