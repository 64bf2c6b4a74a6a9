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

import functools

import warp as wp

from magwarp.kernels.options import MODULE_OPTIONS
from magwarp.kernels.params import MoverParams, pack_mover, pack_values
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
    fire_targets(w, j, mode, steps, per_thread, pack, items, first, key, counter, params, radius, half_size, margins,
                 body)


@wp.func
def fire_targets(w: int, j: int, mode: int, steps: int, per_thread: int, pack: int, items: wp.array(dtype=Item),
                 first: wp.array(dtype=wp.int32), key: wp.array(dtype=wp.int32), counter: wp.array2d(dtype=wp.int32),
                 params: MoverParams, radius: wp.array2d(dtype=float), half_size: wp.array2d(dtype=wp.vec2),
                 margins: wp.array(dtype=wp.vec2), body: wp.array2d(dtype=Body)):
    """:func:`fire_terms`' work for world ``w`` and thread column ``j`` (its targets ``[j per_thread, (j + 1)
    per_thread)``): each item drawn and written as it comes, then the rows packed from the parameter arrays."""
    t0 = j * per_thread
    t1 = wp.min(t0 + per_thread, counter.shape[1])
    if t0 < t1:
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


# ---------------------------------------------------------------------------------------------------------------------
# #24's fire-cost candidates (benchmarks/fire_cost.py times them; magwarp.envs.planar_randomization's ``fire`` options
# pick one). Every one draws the same numbers and writes the same bits as fire_terms (tests/test_fire_variants.py):
# the draws depend only on (key, world, counter, item), not on the thread that makes them.
#
# * lean (fire_target_lean): one target's firing with its row's parameters loaded first, the items' values kept in
#   registers and every store after the last draw (no item load waits behind a store that might alias it), the row
#   packed from the values at hand (pack_values) instead of reloading what was just stored; the reset and startup
#   lists hold only winners, so their items skip ``wins``.
# * compact (list_worlds, then fire_listed): the masked worlds listed in the graph (an atomic count; the list's
#   order varies from run to run, the draws do not), then a fixed grid whose thread i takes list entry i // cols and
#   column i % cols (dense: only the listed worlds' threads, ~1 wave), a grid-stride loop past the grid.
# * split (list_worlds, draw_listed, pack_listed): one thread per (listed world, item), then one per (listed world,
#   target) packing the row and advancing the counter.
# ---------------------------------------------------------------------------------------------------------------------


@wp.func
def fire_target_lean(w: int, t: int, seed: int, mode: int, steps: int, pack: int, items: wp.array(dtype=Item),
                     first: wp.array(dtype=wp.int32), params: MoverParams, radius: wp.array2d(dtype=float),
                     half_size: wp.array2d(dtype=wp.vec2), margins: wp.array(dtype=wp.vec2),
                     body: wp.array2d(dtype=Body)):
    """Target ``t`` of world ``w``: :func:`fire_targets`' draws, writes and packing in another order (the row's
    parameters loaded before any store, the drawn values held, stored after the last draw, the row packed from the
    values): the same bits."""
    zero = wp.float64(0.0)
    mw = zero
    iw = wp.vec3d()
    pay = zero
    off = wp.vec3d()
    known = zero
    kl = wp.vec3d()
    kr = wp.vec3d()
    vm = zero
    am = zero
    jm = zero
    row = t < body.shape[1]
    if row and pack == PACK_ALL:  # (a firing without a body field: the parameter arrays may be empty)
        mw = params.mass[w, t]
        iw = params.inertia[w, t]
        pay = params.payload[w, t]
        off = params.offset[w, t]
        known = params.known[w, t]
        kl = params.k_lin[w, t]
        kr = params.k_rot[w, t]
    if row and pack != PACK_NONE:
        vm = params.v_max[w, t]
        am = params.a_max[w, t]
        jm = params.j_max[w, t]
    rad = wp.float32(0.0)
    hs = wp.vec2()
    mg0 = wp.float32(0.0)
    mg1 = wp.float32(0.0)
    dirty = int(0)  # bit f: field code f drawn
    for q in range(first[t], first[t + 1]):
        it = items[q]
        fires = True
        if mode == MODE_INTERVAL:  # the other modes' lists hold only winners, all due
            fires = wins(it, items, mode, steps)
        if fires:
            v = draw_item(it, seed)
            f = it.t.field
            dirty = dirty | (1 << f)
            if f == MOVER_MASS:
                mw = v[0]
            elif f == MOVER_INERTIA:
                iw = v
            elif f == PAYLOAD_MASS:
                pay = v[0]
                off = it.t.offset
                known = zero
                if it.t.known != 0:
                    known = v[0]
            elif f == STIFFNESS_LIN:
                kl = v
            elif f == STIFFNESS_ROT:
                kr = v
            elif f == V_MAX:
                vm = v[0]
            elif f == A_MAX:
                am = v[0]
            elif f == J_MAX:
                jm = v[0]
            elif f == COLLISION_RADIUS:
                rad = wp.float32(v[0])
            elif f == COLLISION_HALF_SIZE:
                hs = wp.vec2(wp.float32(v[0]), wp.float32(v[1]))
            elif f == COLLISION_MARGIN:
                mg0 = wp.float32(v[0])
            elif f == WALL_MARGIN:
                mg1 = wp.float32(v[0])
    if dirty != 0:
        if dirty & (1 << MOVER_MASS) != 0:
            params.mass[w, t] = mw
        if dirty & (1 << MOVER_INERTIA) != 0:
            params.inertia[w, t] = iw
        if dirty & (1 << PAYLOAD_MASS) != 0:
            params.payload[w, t] = pay
            params.offset[w, t] = off
            params.known[w, t] = known
        if dirty & (1 << STIFFNESS_LIN) != 0:
            params.k_lin[w, t] = kl
        if dirty & (1 << STIFFNESS_ROT) != 0:
            params.k_rot[w, t] = kr
        if dirty & (1 << V_MAX) != 0:
            params.v_max[w, t] = vm
        if dirty & (1 << A_MAX) != 0:
            params.a_max[w, t] = am
        if dirty & (1 << J_MAX) != 0:
            params.j_max[w, t] = jm
        if dirty & (1 << COLLISION_RADIUS) != 0:
            radius[w, t] = rad
        if dirty & (1 << COLLISION_HALF_SIZE) != 0:
            half_size[w, t] = hs
        if dirty & (1 << COLLISION_MARGIN) != 0:
            margins[w][0] = mg0
        if dirty & (1 << WALL_MARGIN) != 0:
            margins[w][1] = mg1
    if row:
        if pack == PACK_ALL:
            body[w, t] = pack_values(params, mw, iw, pay, off, known, kl, kr, vm, am, jm)
        elif pack == PACK_LIMITS:
            body[w, t].v_max = vm
            body[w, t].a_max = am
            body[w, t].j_max = jm


@wp.func
def fire_targets_lean(w: int, j: int, mode: int, steps: int, per_thread: int, pack: int, items: wp.array(dtype=Item),
                      first: wp.array(dtype=wp.int32), key: wp.array(dtype=wp.int32),
                      counter: wp.array2d(dtype=wp.int32), params: MoverParams, radius: wp.array2d(dtype=float),
                      half_size: wp.array2d(dtype=wp.vec2), margins: wp.array(dtype=wp.vec2),
                      body: wp.array2d(dtype=Body)):
    """:func:`fire_targets` through :func:`fire_target_lean`."""
    t0 = j * per_thread
    t1 = wp.min(t0 + per_thread, counter.shape[1])
    if t0 < t1:
        count = counter[w, t0]
        seed = world_seed(key[0], count, w)
        for t in range(t0, t1):
            fire_target_lean(w, t, seed, mode, steps, pack, items, first, params, radius, half_size, margins, body)
            counter[w, t] = count + 1


@wp.kernel
def fire_terms_lean(
    mode: int,
    steps: int,
    all_worlds: int,
    mask: wp.array(dtype=wp.bool),
    per_thread: int,
    pack: int,
    items: wp.array(dtype=Item),
    first: wp.array(dtype=wp.int32),
    key: wp.array(dtype=wp.int32),
    counter: wp.array2d(dtype=wp.int32),
    params: MoverParams,
    radius: wp.array2d(dtype=float),
    half_size: wp.array2d(dtype=wp.vec2),
    margins: wp.array(dtype=wp.vec2),
    body: wp.array2d(dtype=Body),
):
    """:func:`fire_terms` (same arguments, same bits) through :func:`fire_targets_lean`."""
    w, j = wp.tid()
    if not drawn(all_worlds, mask, w):
        return
    fire_targets_lean(w, j, mode, steps, per_thread, pack, items, first, key, counter, params, radius, half_size,
                      margins, body)


@wp.kernel
def list_worlds(
    mask: wp.array(dtype=wp.bool),
    # State in/out (zeroed before the launch):
    count: wp.array(dtype=wp.int32),  # [1]: the worlds listed
    # State out:
    ids: wp.array(dtype=wp.int32),  # [W]: ids[:count] the worlds in mask, in no fixed order
):
    """The worlds in ``mask``, listed: one atomic per masked world (no host sync: the firing reads ``count``)."""
    w = wp.tid()
    if mask[w]:
        ids[wp.atomic_add(count, 0, 1)] = w


def _listed_kernel(lean: bool):
    fire = fire_targets_lean if lean else fire_targets

    def kernel(
        mode: int,
        steps: int,
        count: wp.array(dtype=wp.int32),  # [1]: the listed worlds (list_worlds)
        ids: wp.array(dtype=wp.int32),
        cols: int,  # thread columns per world (targets / per_thread, rounded up)
        threads: int,  # this launch's threads: thread i takes entries i, i + threads, ... (of count cols)
        per_thread: int,
        pack: int,
        items: wp.array(dtype=Item),
        first: wp.array(dtype=wp.int32),
        key: wp.array(dtype=wp.int32),
        counter: wp.array2d(dtype=wp.int32),
        params: MoverParams,
        radius: wp.array2d(dtype=float),
        half_size: wp.array2d(dtype=wp.vec2),
        margins: wp.array(dtype=wp.vec2),
        body: wp.array2d(dtype=Body),
    ):
        i = wp.tid()
        n = count[0] * cols
        while i < n:
            e = i // cols
            w = ids[e]
            fire(w, i - e * cols, mode, steps, per_thread, pack, items, first, key, counter, params, radius,
                 half_size, margins, body)
            i += threads

    kernel.__doc__ = (f":func:`fire_terms` for the listed worlds (through :func:`{fire.key}`) over a fixed grid: "
                      "entry ``i`` (of ``count[0] cols``) is column ``i % cols`` of world ``ids[i // cols]``.")
    return wp.kernel(kernel, name="fire_listed_lean" if lean else "fire_listed")


fire_listed = _listed_kernel(False)
fire_listed_lean = _listed_kernel(True)


@wp.kernel
def draw_listed(
    mode: int,
    steps: int,
    count: wp.array(dtype=wp.int32),
    ids: wp.array(dtype=wp.int32),
    threads: int,
    items: wp.array(dtype=Item),
    key: wp.array(dtype=wp.int32),
    counter: wp.array2d(dtype=wp.int32),  # read only here (pack_listed advances it)
    params: MoverParams,
    radius: wp.array2d(dtype=float),
    half_size: wp.array2d(dtype=wp.vec2),
    margins: wp.array(dtype=wp.vec2),
):
    """The split firing's draws: entry ``i`` (of ``count[0] n``, ``n`` the mode's items) is item ``i % n`` of world
    ``ids[i // n]``, drawn and written when it wins (the two margins: components of one ``margins[w]``, each its own
    store)."""
    i = wp.tid()
    n_items = items.shape[0]
    n = count[0] * n_items
    while i < n:
        e = i // n_items
        w = ids[e]
        it = items[i - e * n_items]
        if wins(it, items, mode, steps):
            fire_item(it, world_seed(key[0], counter[w, it.target], w), w, params, radius, half_size, margins)
        i += threads


@wp.kernel
def pack_listed(
    count: wp.array(dtype=wp.int32),
    ids: wp.array(dtype=wp.int32),
    threads: int,
    pack: int,
    params: MoverParams,
    counter: wp.array2d(dtype=wp.int32),
    body: wp.array2d(dtype=Body),
):
    """The split firing's packing: entry ``i`` (of ``count[0] targets``) packs target ``i % targets`` of world
    ``ids[i // targets]`` (its row from the parameter arrays, as :func:`fire_targets`) and advances its counter."""
    i = wp.tid()
    cols = counter.shape[1]
    n = count[0] * cols
    while i < n:
        e = i // cols
        w = ids[e]
        t = i - e * cols
        if t < body.shape[1]:
            if pack == PACK_ALL:
                body[w, t] = pack_mover(params, w, t)
            elif pack == PACK_LIMITS:
                body[w, t].v_max = params.v_max[w, t]
                body[w, t].a_max = params.a_max[w, t]
                body[w, t].j_max = params.j_max[w, t]
        counter[w, t] = counter[w, t] + 1
        i += threads


@functools.cache
def fire_terms_capped(max_registers: int):
    """:func:`fire_terms` (same arguments, same bits; its work through :func:`fire_targets`) compiled with at most
    ``max_registers`` registers per thread on CUDA (``__maxnreg__``; its own module): more warps resident per SM."""

    def kernel(
        mode: int,
        steps: int,
        all_worlds: int,
        mask: wp.array(dtype=wp.bool),
        per_thread: int,
        pack: int,
        items: wp.array(dtype=Item),
        first: wp.array(dtype=wp.int32),
        key: wp.array(dtype=wp.int32),
        counter: wp.array2d(dtype=wp.int32),
        params: MoverParams,
        radius: wp.array2d(dtype=float),
        half_size: wp.array2d(dtype=wp.vec2),
        margins: wp.array(dtype=wp.vec2),
        body: wp.array2d(dtype=Body),
    ):
        w, j = wp.tid()
        if not drawn(all_worlds, mask, w):
            return
        fire_targets(w, j, mode, steps, per_thread, pack, items, first, key, counter, params, radius, half_size,
                     margins, body)

    return wp.kernel(kernel, name=f"fire_terms_r{int(max_registers)}", module="unique", enable_backward=False,
                     module_options=dict(MODULE_OPTIONS), cuda_max_registers=int(max_registers))
