"""Domain randomisation of the planar simulator in one launch: every event term whose time has come, drawn per world
with Warp's counter-based generator and written into the per-world parameter rows, then the world's body rows packed
(:mod:`magwarp.envs.planar_randomization` builds the term table; the torch step and the fused step graph both launch
this kernel, so they draw the same numbers).

Draws: world ``w``'s generator for one firing is ``rand_init(rand_init(key, counter[w]), w)``: the key follows the
env's seed, ``counter[w]`` counts the firings that drew for world ``w`` (so a world that is not reset draws nothing and
keeps its stream). Within a firing the terms draw in their order, each target (mover) in turn and each component in
turn: uniform ``lo + u (hi - lo)``, log-uniform ``exp(log lo + u (log hi - log lo))`` (``u``: ``wp.randf``, 24 bits),
Gaussian ``mean + std z`` (``z``: ``wp.randn``), clipped where asked.
"""

from __future__ import annotations

import warp as wp

from magwarp.kernels.options import MODULE_OPTIONS
from magwarp.kernels.params import MoverParams, pack_mover, store_body
from magwarp.types import Body

wp.set_module_options({"enable_backward": False, **MODULE_OPTIONS})

# field codes (the term table's ``field``), in magwarp.envs.planar_randomization.FIELD_CODES' order
MOVER_MASS = wp.constant(0)
MOVER_INERTIA = wp.constant(1)
PAYLOAD_MASS = wp.constant(2)
STIFFNESS_LIN = wp.constant(3)
STIFFNESS_ROT = wp.constant(4)
V_MAX = wp.constant(5)
A_MAX = wp.constant(6)
J_MAX = wp.constant(7)
COLLISION_RADIUS = wp.constant(8)
COLLISION_HALF_SIZE = wp.constant(9)
COLLISION_MARGIN = wp.constant(10)
WALL_MARGIN = wp.constant(11)

UNIFORM = wp.constant(0)
LOG_UNIFORM = wp.constant(1)
GAUSSIAN = wp.constant(2)

OP_SET = wp.constant(0)
OP_SCALE = wp.constant(1)
OP_ADD = wp.constant(2)

MODE_STARTUP = wp.constant(0)
MODE_RESET = wp.constant(1)
MODE_INTERVAL = wp.constant(2)


@wp.struct
class Term:
    """One event term (:class:`magwarp.envs.randomization.EventTerm`) as the kernel reads it."""

    field: int  # a field code (above)
    dim: int  # components per target
    dist: int  # UNIFORM, LOG_UNIFORM (a, b: log lo, log hi) or GAUSSIAN (a, b: mean, std)
    a: wp.float64
    b: wp.float64
    clip: int  # Gaussian only: clamp to [lo, hi]
    lo: wp.float64
    hi: wp.float64
    op: int  # OP_SET, OP_SCALE, OP_ADD
    mode: int  # MODE_STARTUP, MODE_RESET, MODE_INTERVAL
    interval: int  # MODE_INTERVAL: fires when the step count is a multiple of it
    known: int  # payload_mass: the controller is configured for the payload
    offset: wp.vec3d  # payload_mass: where it sits (body frame)


@wp.func
def draw(t: Term, state: wp.uint32):
    """One draw of ``t``'s distribution (float64) and the advanced generator state."""
    s = state
    if t.dist == GAUSSIAN:
        v = t.a + t.b * wp.float64(wp.randn(s))
        if t.clip != 0:
            v = wp.clamp(v, t.lo, t.hi)
        return v, s
    u = wp.float64(wp.randf(s))
    v = t.a + u * (t.b - t.a)
    if t.dist == LOG_UNIFORM:
        v = wp.exp(v)
    return v, s


@wp.func
def apply_op(op: int, nominal: wp.float64, value: wp.float64) -> wp.float64:
    if op == OP_SCALE:
        return nominal * value
    if op == OP_ADD:
        return nominal + value
    return value


@wp.func
def set_component(a: wp.array2d(dtype=wp.vec3d), w: int, m: int, k: int, v: wp.float64):
    x = a[w, m]
    x[k] = v
    a[w, m] = x


@wp.func
def write_field(field: int, w: int, m: int, k: int, v: wp.float64, p: MoverParams,
                radius: wp.array2d(dtype=float), half_size: wp.array2d(dtype=wp.vec2),
                margins: wp.array(dtype=wp.vec2)):
    """Component ``k`` of target ``m`` of world ``w`` of ``field`` <- ``v`` (the float32 fields rounded)."""
    if field == MOVER_MASS:
        p.mass[w, m] = v
    elif field == MOVER_INERTIA:
        set_component(p.inertia, w, m, k, v)
    elif field == PAYLOAD_MASS:
        p.payload[w, m] = v
    elif field == STIFFNESS_LIN:
        set_component(p.k_lin, w, m, k, v)
    elif field == STIFFNESS_ROT:
        set_component(p.k_rot, w, m, k, v)
    elif field == V_MAX:
        p.v_max[w, m] = v
    elif field == A_MAX:
        p.a_max[w, m] = v
    elif field == J_MAX:
        p.j_max[w, m] = v
    elif field == COLLISION_RADIUS:
        radius[w, m] = wp.float32(v)
    elif field == COLLISION_HALF_SIZE:
        h = half_size[w, m]
        h[k] = wp.float32(v)
        half_size[w, m] = h
    elif field == COLLISION_MARGIN:
        g = margins[w]
        g[0] = wp.float32(v)
        margins[w] = g
    elif field == WALL_MARGIN:
        g = margins[w]
        g[1] = wp.float32(v)
        margins[w] = g


@wp.kernel
def apply_terms(
    mode: int,
    steps: int,  # MODE_INTERVAL: the env step count
    all_worlds: int,  # 1: every world (startup, interval), 0: the worlds in mask
    mask: wp.array(dtype=wp.bool),
    # Model:
    terms: wp.array(dtype=Term),
    targets: wp.array2d(dtype=wp.int32),  # [T, max targets]: 1 where the term writes that target
    nominal: wp.array3d(dtype=wp.float64),  # [T, max targets, 3]: the built value (scale, add)
    key: wp.array(dtype=wp.int32),  # [1]: the generator key (the env's seed)
    pack: int,  # 1: pack the body rows of the worlds drawn for
    # State in/out:
    counter: wp.array(dtype=wp.int32),  # [W] firings drawn per world
    params: MoverParams,
    radius: wp.array2d(dtype=float),
    half_size: wp.array2d(dtype=wp.vec2),
    margins: wp.array(dtype=wp.vec2),
    # State out:
    body: wp.array2d(dtype=Body),
    body_t32: wp.array3d(dtype=wp.float32),  # the transposed rows (kernels.params.store_body)
    body_t64: wp.array3d(dtype=wp.float64),
):
    """Fire the terms of ``mode`` due now for one world (one thread per world), in their order (the one that fired
    last sets a field), then pack its body rows (:func:`~magwarp.kernels.params.pack_mover`)."""
    w = wp.tid()
    if all_worlds == 0:
        if not mask[w]:
            return
    state = wp.rand_init(wp.int32(wp.rand_init(key[0], counter[w])), w)
    fired = int(0)
    for i in range(terms.shape[0]):
        t = terms[i]
        if t.mode != mode:
            continue
        if mode == MODE_INTERVAL:
            if steps % t.interval != 0:
                continue
        fired = 1
        for m in range(targets.shape[1]):
            if targets[i, m] == 0:
                continue
            for k in range(t.dim):
                v, state = draw(t, state)
                v = apply_op(t.op, nominal[i, m, k], v)
                write_field(t.field, w, m, k, v, params, radius, half_size, margins)
                if t.field == PAYLOAD_MASS:
                    params.offset[w, m] = t.offset
                    known = wp.float64(0.0)
                    if t.known != 0:
                        known = v
                    params.known[w, m] = known
    if fired == 0:
        return
    counter[w] = counter[w] + 1
    if pack != 0:
        for m in range(body.shape[1]):
            store_body(pack_mover(params, w, m), w, m, body, body_t32, body_t64)
