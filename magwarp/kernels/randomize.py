"""Domain randomisation of the planar simulator in one launch: :func:`fire_terms` fires every event term whose time
has come, drawn per world and target with Warp's counter-based generator, written into the per-world parameter rows,
then packs the body rows of the worlds drawn for and advances their counters (:mod:`magwarp.envs.planar_randomization`
builds the term table; the torch step and the fused step graph both launch this kernel, so they draw the same
numbers).

:func:`fire_terms` runs one thread per world and target on a GPU (a target: a mover; the per-world fields are target
0's), or one per world on the CPU (where a thread's cost is mostly its setup). A thread fires its targets' items
(:class:`Item`: a (term, target) pair, one load: the term, the target's built value and the component streams), packs
its movers' rows and advances its targets' copies of the world's firing counter: nothing it reads is written by
another thread, so one launch does what took two (the draws, then the packing) until #24's fourth cost pass. Of the
items that fire in one launch the last one in the table of a field and target sets it (a payload term also its
offset and ``known``): the startup and reset lists hold only those (every term of those modes fires), an interval item
checks the later ones of its field and target (``later``). The scale and add operations use the built value. A world
that is not drawn for exits first thing.

Draws: world ``w``'s seed for one firing is ``rand_init(rand_init(key, counter[w]), w)``: the key follows the env's
seed, ``counter[w]`` counts the firings that drew for world ``w`` (so a world that is not reset draws nothing and
keeps its stream; every target keeps its own copy, all equal). Component ``k`` of target ``m`` of term ``i`` draws from
its own state ``rand_init(seed, 3 (i n + m) + k)`` (``n``: the target table's width, the simulator's movers), so the
draws do not depend on the order the threads run in or on how targets are shared among threads: uniform
``lo + u (hi - lo)``, log-uniform ``exp(log lo + u (log hi - log lo))`` (``u``: ``wp.randf``, 24 bits), Gaussian
``mean + std z`` (``z``: ``wp.randn``), clipped where asked. (Until #24's second cost pass one thread per world drew
every term, target and component in turn from one state: the values for a given seed changed then. The later passes
kept the draws.)
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

PACK_NONE = wp.constant(0)  # no body field drawn: the counters only
PACK_LIMITS = wp.constant(1)  # only v_max, a_max, j_max drawn: the rows take them verbatim
PACK_ALL = wp.constant(2)  # the whole rows (pack_mover)

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
    elif field == COLLISION_MARGIN:  # its own component: the wall margin's item may write the other one meanwhile
        margins[w][0] = wp.float32(v[0])
    elif field == WALL_MARGIN:
        margins[w][1] = wp.float32(v[0])


@wp.struct
class Item:
    """One (term, target) pair of a mode's firing as the kernel reads it: one load, with no dependent one after it."""

    t: Term
    nominal: wp.vec3d  # the target's built value (scale, add), ``t.dim`` components
    target: int  # the mover (the per-world fields: 0)
    stream: int  # 3 (i n + target): component k draws from rand_init(seed, stream + k)
    later: int  # the next item of the mode that writes the same field of the same target (interval only), -1: none


@wp.func
def wins(it: Item, items: wp.array(dtype=Item), mode: int, steps: int) -> bool:
    """Item ``it`` fires now and no later item of its field and target does (the last one that fires sets a field).
    The startup and reset lists hold only their winners (every term of those modes fires): no ``later`` to check."""
    if not is_due(it.t, mode, steps):
        return False
    k = it.later
    while k >= 0:
        if is_due(items[k].t, mode, steps):
            return False
        k = items[k].later
    return True


@wp.func
def draw_item(it: Item, seed: int) -> wp.vec3d:
    """Item ``it``'s value for a firing's ``seed``: its ``t.dim`` components drawn and put through its operation."""
    t = it.t
    v = wp.vec3d()
    for k in range(3):
        if k < t.dim:
            v[k] = apply_op(t.op, it.nominal[k], draw(t, seed, it.stream + k))
    return v


@wp.func
def fire_item(it: Item, seed: int, w: int, params: MoverParams, radius: wp.array2d(dtype=float),
              half_size: wp.array2d(dtype=wp.vec2), margins: wp.array(dtype=wp.vec2)):
    """Draw item ``it`` for world ``w`` (its firing's ``seed``) and write its field (a payload: also its offset and
    ``known``)."""
    t = it.t
    m = it.target
    v = draw_item(it, seed)
    write_field(t.field, w, m, v, params, radius, half_size, margins)
    if t.field == PAYLOAD_MASS:
        params.offset[w, m] = t.offset
        known = wp.float64(0.0)
        if t.known != 0:
            known = v[0]
        params.known[w, m] = known


@wp.kernel
def fire_terms(
    mode: int,
    steps: int,  # MODE_INTERVAL: the env step count
    all_worlds: int,  # 1: every world (startup, interval), 0: the worlds in mask
    mask: wp.array(dtype=wp.bool),
    per_thread: int,  # targets per thread: thread (w, j) takes targets [j per_thread, (j + 1) per_thread)
    pack: int,  # PACK_ALL: pack the body rows of the thread's movers; PACK_LIMITS: only their limits; PACK_NONE
    # Model:
    items: wp.array(dtype=Item),  # the mode's (term, target) pairs by target (startup, reset: their winners only)
    first: wp.array(dtype=wp.int32),  # [targets + 1]: target t's items are items[first[t]:first[t + 1]]
    key: wp.array(dtype=wp.int32),  # [1]: the generator key (the env's seed)
    # State in/out:
    counter: wp.array2d(dtype=wp.int32),  # [W, targets] firings drawn per world (a copy per target, all equal)
    # State out:
    params: MoverParams,
    radius: wp.array2d(dtype=float),
    half_size: wp.array2d(dtype=wp.vec2),
    margins: wp.array(dtype=wp.vec2),
    body: wp.array2d(dtype=Body),
):
    """Fire the items of ``mode`` for the targets of world ``w`` that thread ``j`` holds: each (term, target) pair
    draws its components (each from its own generator state, see the module doc) and writes its field when it is
    the last of its field and target that fires now; then (``pack``) the thread packs the body rows of its movers
    (:func:`~magwarp.kernels.params.pack_mover`; a firing of the limits only: those fields of the rows) and advances
    their counters. A target's items, its row and its counter belong to one thread (the per-world fields are target
    0's; the two margins are components of one ``margins[w]``, both written by that thread), so no thread reads what
    another writes: one launch, and a thread's latency is its target's items, not the world's."""
    w, j = wp.tid()
    if not drawn(all_worlds, mask, w):
        return
    t0 = j * per_thread
    t1 = wp.min(t0 + per_thread, counter.shape[1])
    if t0 >= t1:
        return
    count = counter[w, t0]
    seed = world_seed(key[0], count, w)
    for t in range(t0, t1):
        for q in range(first[t], first[t + 1]):
            it = items[q]
            if wins(it, items, mode, steps):
                fire_item(it, seed, w, params, radius, half_size, margins)
        if t < body.shape[1]:
            if pack == PACK_ALL:
                body[w, t] = pack_mover(params, w, t)
            elif pack == PACK_LIMITS:  # pack_body copies them: the same bits, without the row's other loads
                body[w, t].v_max = params.v_max[w, t]
                body[w, t].a_max = params.a_max[w, t]
                body[w, t].j_max = params.j_max[w, t]
        counter[w, t] = count + 1
