"""The closed-form field of a uniformly polarised cuboid magnet, as Warp functions (float64).

The field is that of the surface charges sigma = J . n on the six faces (Yang 1990; Camacho & Sosa 2013; the
formula magpylib implements), B = mu0 H outside and B = mu0 H + J inside. For a face at w0 with half extents
(hu, hv), observed at (u, v, w) relative to its corners (u = pu - u', ...), with R the corner distance:

* the normal part is ``sigma / (4 pi) [[atan(u v / (w R))]]``, a double difference over the four corners;
* the in-plane parts are ``-sigma / (4 pi) [[ln(v + R)]]`` (and u, v swapped).

The logs are evaluated as log ratios that never subtract nearly equal numbers (for v < 0, ln(v + R) is rewritten
with R - v = a^2 / (R + v)), so the field stays accurate far from the magnet and close to its face planes. Float64
throughout: the field is a small difference of large terms at far points, which float32 cannot resolve.

Singular places: on an edge (and on its extension for the in-plane terms) the ideal field is infinite; there the
singular log term is dropped (the kernel returns a finite number, not the physical infinity). In a face's own plane
outside the face, the normal term is exactly 0, its limit. Coils never touch magnets, so the wrench model never
evaluates either.
"""

import warp as wp

ZERO = wp.constant(wp.float64(0.0))
ONE = wp.constant(wp.float64(1.0))
INV_4PI = wp.constant(wp.float64(0.07957747154594767))


@wp.func
def log_ratio(vl: wp.float64, vh: wp.float64, a2: wp.float64) -> wp.float64:
    """``ln((vh + Rh) / (vl + Rl))`` with ``R = sqrt(v^2 + a2)`` and ``vl < vh``, without cancellation; 0 where
    it is singular (a2 = 0 with the segment through 0: an edge of the magnet)."""
    rl = wp.sqrt(vl * vl + a2)
    rh = wp.sqrt(vh * vh + a2)
    out = ZERO
    if vl >= ZERO:
        if vl + rl > ZERO:
            out = wp.log((vh + rh) / (vl + rl))
    elif vh <= ZERO:
        if rh - vh > ZERO:
            out = wp.log((rl - vl) / (rh - vh))
    elif a2 > ZERO:
        out = wp.log((vh + rh) * (rl - vl) / a2)
    return out


@wp.func
def corner_atan(u: wp.float64, v: wp.float64, w: wp.float64) -> wp.float64:
    """``atan(u v / (w R))``, with its limit 0 at w = 0 (in the face's plane; the jump across the face itself is
    the surface's, which the caller never evaluates)."""
    out = ZERO
    if w != ZERO:
        r = wp.sqrt(u * u + v * v + w * w)
        out = wp.atan2(u * v, wp.abs(w) * r)
        if w < ZERO:
            out = -out
    return out


@wp.func
def face_field(pu: wp.float64, pv: wp.float64, pw: wp.float64, hu: wp.float64, hv: wp.float64,
               w0: wp.float64, sigma: wp.float64) -> wp.vec3d:
    """(Bu, Bv, Bw) of a face of surface charge ``sigma`` (T) at w = w0 spanning [-hu, hu] x [-hv, hv]."""
    ul = pu - hu
    uh = pu + hu
    vl = pv - hv
    vh = pv + hv
    w = pw - w0
    bw = corner_atan(uh, vh, w) - corner_atan(uh, vl, w) - corner_atan(ul, vh, w) + corner_atan(ul, vl, w)
    w2 = w * w
    bu = log_ratio(vl, vh, ul * ul + w2) - log_ratio(vl, vh, uh * uh + w2)
    bv = log_ratio(ul, uh, vl * vl + w2) - log_ratio(ul, uh, vh * vh + w2)
    return wp.vec3d(bu, bv, bw) * (sigma * INV_4PI)


@wp.func
def face_pair(pu: wp.float64, pv: wp.float64, pw: wp.float64, hu: wp.float64, hv: wp.float64, hw: wp.float64,
              jw: wp.float64) -> wp.vec3d:
    """(Bu, Bv, Bw) of the two faces normal to w (charges +jw at +hw, -jw at -hw)."""
    out = wp.vec3d(ZERO, ZERO, ZERO)
    if jw != ZERO:
        out = face_field(pu, pv, pw, hu, hv, hw, jw) + face_field(pu, pv, pw, hu, hv, -hw, -jw)
    return out


@wp.func
def cuboid_field(p: wp.vec3d, half: wp.vec3d, pol: wp.vec3d) -> wp.vec3d:
    """B (T) at ``p`` (relative to the cuboid's centre, in its axes) of a cuboid of half sizes ``half`` and
    polarization ``pol`` (T)."""
    bz = face_pair(p[0], p[1], p[2], half[0], half[1], half[2], pol[2])  # (u, v, w) = (x, y, z)
    bx = face_pair(p[1], p[2], p[0], half[1], half[2], half[0], pol[0])  # (y, z, x)
    by = face_pair(p[2], p[0], p[1], half[2], half[0], half[1], pol[1])  # (z, x, y)
    b = wp.vec3d(bz[0] + bx[2] + by[1], bz[1] + bx[0] + by[2], bz[2] + bx[1] + by[0])
    if wp.abs(p[0]) < half[0] and wp.abs(p[1]) < half[1] and wp.abs(p[2]) < half[2]:
        b = b + pol
    return b
