"""Domain randomisation of the planar simulator in two launches: :func:`apply_terms` fires every event term whose time
has come, drawn per world and target with Warp's counter-based generator and written into the per-world parameter
rows; :func:`pack_rows` then packs the body rows of the worlds drawn for and advances their counters
(:mod:`magwarp.envs.planar_randomization` builds the term table; the torch step and the fused step graph both launch
these kernels, so they draw the same numbers).

Both run one thread per world and target (mover; the per-world fields: target 0) on a GPU, or per world and
``per_thread`` targets (on the CPU, where a thread's cost is mostly its setup: all of a world's), and a world that is
not drawn for exits first thing. The thread of target ``m`` runs the due terms that target it in their order (the
last one that fires sets a field; a payload term also sets its offset and ``known``); the scale and add operations
use the built value.

Draws: world ``w``'s seed for one firing is ``rand_init(rand_init(key, counter[w]), w)``: the key follows the env's
seed, ``counter[w]`` counts the firings that drew for world ``w`` (so a world that is not reset draws nothing and
keeps its stream). Component ``k`` of target ``m`` of term ``i`` draws from its own state
``rand_init(seed, 3 (i n + m) + k)`` (``n``: the target table's width, the simulator's movers), so the draws do not
depend on the order the threads run in: uniform ``lo + u (hi - lo)``, log-uniform
``exp(log lo + u (log hi - log lo))`` (``u``: ``wp.randf``, 24 bits), Gaussian ``mean + std z`` (``z``: ``wp.randn``),
clipped where asked. (Until #24's second cost pass one thread per
world drew every term, target and component in turn from one state: the values for a given seed changed then.)
"""

from __future__ import annotations

import warp as wp

from magwarp.kernels.options import MODULE_OPTIONS
from magwarp.kernels.params import MoverParams, pack_mover
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
def is_due(t: Term, mode: int, steps: int) -> bool:
    """``t`` fires in a launch for ``mode`` at env step ``steps`` (interval terms: when their period divides it)."""
    if t.mode != mode:
        return False
    if mode == MODE_INTERVAL:
        return steps % t.interval == 0
    return True


@wp.func
def drawn(all_worlds: int, mask: wp.array(dtype=wp.bool), w: int) -> bool:
    """World ``w`` is drawn for in this launch: every world (``all_worlds``), else the worlds in ``mask``."""
    if all_worlds != 0:
        return True
    return mask[w]


@wp.func
def world_seed(key: int, count: int, w: int) -> int:
    """World ``w``'s seed for its firing number ``count`` (the key: the env's seed)."""
    return wp.int32(wp.rand_init(wp.int32(wp.rand_init(key, count)), w))


@wp.func
def draw(t: Term, seed: int, stream: int) -> wp.float64:
    """One draw of ``t``'s distribution (float64) from its own generator state ``rand_init(seed, stream)``."""
    s = wp.rand_init(seed, stream)
    if t.dist == GAUSSIAN:
        v = t.a + t.b * wp.float64(wp.randn(s))
        if t.clip != 0:
            v = wp.clamp(v, t.lo, t.hi)
        return v
    v = t.a + wp.float64(wp.randf(s)) * (t.b - t.a)
    if t.dist == LOG_UNIFORM:
        v = wp.exp(v)
    return v


@wp.func
def apply_op(op: int, nominal: wp.float64, value: wp.float64) -> wp.float64:
    if op == OP_SCALE:
        return nominal * value
    if op == OP_ADD:
        return nominal + value
    return value


@wp.func
def write_field(field: int, w: int, m: int, v: wp.vec3d, p: MoverParams,
                radius: wp.array2d(dtype=float), half_size: wp.array2d(dtype=wp.vec2),
                margins: wp.array(dtype=wp.vec2)):
    """Target ``m`` of world ``w`` of ``field`` <- ``v`` (its first ``dim`` components; the float32 fields rounded)."""
    if field == MOVER_MASS:
        p.mass[w, m] = v[0]
    elif field == MOVER_INERTIA:
        p.inertia[w, m] = v
    elif field == PAYLOAD_MASS:
        p.payload[w, m] = v[0]
    elif field == STIFFNESS_LIN:
        p.k_lin[w, m] = v
    elif field == STIFFNESS_ROT:
        p.k_rot[w, m] = v
    elif field == V_MAX:
        p.v_max[w, m] = v[0]
    elif field == A_MAX:
        p.a_max[w, m] = v[0]
    elif field == J_MAX:
        p.j_max[w, m] = v[0]
    elif field == COLLISION_RADIUS:
        radius[w, m] = wp.float32(v[0])
    elif field == COLLISION_HALF_SIZE:
        half_size[w, m] = wp.vec2(wp.float32(v[0]), wp.float32(v[1]))
    elif field == COLLISION_MARGIN:
        g = margins[w]
        margins[w] = wp.vec2(wp.float32(v[0]), g[1])
    elif field == WALL_MARGIN:
        g = margins[w]
        margins[w] = wp.vec2(g[0], wp.float32(v[0]))


@wp.func
def fire_target(mode: int, steps: int, terms: wp.array(dtype=Term), targets: wp.array2d(dtype=wp.int32),
                nominal: wp.array2d(dtype=wp.vec3d), seed: int, w: int, m: int, params: MoverParams,
                radius: wp.array2d(dtype=float), half_size: wp.array2d(dtype=wp.vec2),
                margins: wp.array(dtype=wp.vec2)):
    """The terms of ``mode`` due now that target ``m``, for world ``w`` (its firing's ``seed``), in their order."""
    for i in range(terms.shape[0]):
        # the term's loads first, with no branch between them: one memory latency per term
        t = terms[i]
        hit = targets[i, m]
        nom = nominal[i, m]
        if hit == 0 or not is_due(t, mode, steps):
            continue
        v = wp.vec3d()
        stream = (i * targets.shape[1] + m) * 3
        for k in range(3):
            if k < t.dim:
                v[k] = apply_op(t.op, nom[k], draw(t, seed, stream + k))
        write_field(t.field, w, m, v, params, radius, half_size, margins)
        if t.field == PAYLOAD_MASS:
            params.offset[w, m] = t.offset
            known = wp.float64(0.0)
            if t.known != 0:
                known = v[0]
            params.known[w, m] = known


@wp.kernel
def apply_terms(
    mode: int,
    steps: int,  # MODE_INTERVAL: the env step count
    all_worlds: int,  # 1: every world (startup, interval), 0: the worlds in mask
    mask: wp.array(dtype=wp.bool),
    per_thread: int,  # targets per thread: thread (w, j) draws targets [j per_thread, (j + 1) per_thread)
    # Model:
    terms: wp.array(dtype=Term),
    targets: wp.array2d(dtype=wp.int32),  # [T, max targets]: 1 where the term writes that target
    nominal: wp.array2d(dtype=wp.vec3d),  # [T, max targets]: the built value (scale, add), dim components
    key: wp.array(dtype=wp.int32),  # [1]: the generator key (the env's seed)
    # State in:
    counter: wp.array(dtype=wp.int32),  # [W] firings drawn per world
    # State out:
    params: MoverParams,
    radius: wp.array2d(dtype=float),
    half_size: wp.array2d(dtype=wp.vec2),
    margins: wp.array(dtype=wp.vec2),
):
    """Fire the terms of ``mode`` due now for world ``w`` and its targets of thread ``j`` (the per-world fields:
    target 0), each target's terms in their order: the last one that fires sets a field. Every component draws from
    its own generator state (see the module doc), whichever thread draws it. :func:`pack_rows` then packs the rows
    and advances the counters."""
    w, j = wp.tid()
    if not drawn(all_worlds, mask, w):
        return
    seed = world_seed(key[0], counter[w], w)
    for m in range(j * per_thread, wp.min((j + 1) * per_thread, targets.shape[1])):
        fire_target(mode, steps, terms, targets, nominal, seed, w, m, params, radius, half_size, margins)


@wp.kernel
def pack_rows(
    all_worlds: int,
    mask: wp.array(dtype=wp.bool),
    per_thread: int,
    pack: int,  # 1: pack the body rows of the worlds drawn for (terms of body fields)
    # State in:
    params: MoverParams,
    # State in/out:
    counter: wp.array(dtype=wp.int32),  # [W] firings drawn per world
    # State out:
    body: wp.array2d(dtype=Body),
):
    """After :func:`apply_terms` (the same worlds and threads; launched only when a term is due, as it is): the worlds
    it drew for advance their counter (thread 0) and (``pack``) pack the body rows of the thread's movers
    (:func:`~magwarp.kernels.params.pack_mover`)."""
    w, j = wp.tid()
    if not drawn(all_worlds, mask, w):
        return
    if j == 0:
        counter[w] = counter[w] + 1
    if pack != 0:
        for m in range(j * per_thread, wp.min((j + 1) * per_thread, body.shape[1])):
            body[w, m] = pack_mover(params, w, m)
