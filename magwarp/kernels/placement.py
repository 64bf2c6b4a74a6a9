"""Parallel dart throwing: collision-free start poses and goals for many movers per world, on the device.

A call starts by binning the movers that stay (in the worlds with movers to place only) and ends by emptying the
cells it filled (:func:`unbin`), so its work is per mover of those worlds, not per grid cell. One *round* is two
launches over the movers to place, listed at the call's start (:func:`begin_todo`; threads of movers already placed
exit at once), so a warp's threads work on movers to place, not on one among 31 idle others:

1. :func:`propose` — every mover still to place draws up to ``tries`` candidate points, each uniform over the
   present tiles, and keeps the first whose footprint (yaw 0, grown by the sampling offset) is on the tiles by the
   simulator's own wall rule (:func:`~magwarp.kernels.collision.hits_wall_cs`) and which is clear of every mover
   already placed (looked up in the neighbouring cells of a uniform grid). It then claims its grid cell with an
   ``atomic_max`` of its *claim*: the round's number in the high 32 bits, the complement of its index in the low
   ones, so the lowest index of the latest round holds the cell and older rounds' claims need no clearing.
2. :func:`resolve` — a candidate that won its cell is accepted unless a lower-indexed cell winner of this round
   nearby conflicts with it (index priority, so no two accepted candidates of a round conflict). Accepted movers are
   written out and pushed onto the cell lists the next rounds look up.

Cells are as small as the exclusion test allows (two candidates in one cell always conflict), so the claim loses
no compatible pair; the placed set lives in per-cell linked lists (``atomic_exch``, as the simulator's broad phase),
which also holds *fixed* movers that are not being placed (e.g. the other movers when one respawns). With
``hold``, the movers being placed keep their current spots blocked (second lists) until the call ends: a mover
that is respawned stays where it is until it is placed, so no other may be placed onto it. Expected work
is O(movers) per round; no sort, no scan, no host synchronisation.

The random streams and round numbers come from a device counter (``counter``: int64 ``[seed, calls, round]``), not
from the host: :func:`begin_todo` advances it by the call's rounds and each round's kernels read it back with their
offset ``back`` (the rounds still to come after it), so that a call recorded in a CUDA graph draws fresh numbers at
every replay. Round ``r`` of ``R`` draws from the seed :func:`round_seed` gives for ``calls`` (after the advance)
``- back`` with ``back = R - 1 - r``: the same seeds as the host counter gave before (``(seed * 1000003 + calls *
7919) & 0x3FFFFFFF``, ``calls`` counting rounds from the last reseed), so placements are unchanged bit for bit.
"""

import functools

import warp as wp

from magwarp.kernels.collision import hits_wall_cs
from magwarp.kernels.options import MODULE_OPTIONS
from magwarp.types import SHAPE_CIRCLE, Collision

wp.set_module_options({"enable_backward": False, **MODULE_OPTIONS})

#: claim of a free cell
NO_CLAIM = 0  # rounds are numbered from 1
INDEX_BITS = wp.constant(wp.int64(0xFFFFFFFF))


@wp.func
def claim_of(round_id: wp.int64, m: int) -> wp.int64:
    """The claim of mover ``m`` in round ``round_id``: later rounds win, then lower indices."""
    return (round_id << wp.int64(32)) | (wp.int64(0x7FFFFFFF) - wp.int64(m))


@wp.func
def claimant(claim: wp.int64, round_id: wp.int64) -> int:
    """The mover whose claim this is if it was made in round ``round_id``, else -1 (a free or older cell)."""
    if (claim >> wp.int64(32)) != round_id:
        return -1
    return 0x7FFFFFFF - int(claim & INDEX_BITS)


#: columns of a placer's device counter
COUNTER_SEED, COUNTER_CALLS, COUNTER_ROUND = wp.constant(0), wp.constant(1), wp.constant(2)
SEED_MASK = wp.constant(wp.int64(0x3FFFFFFF))


@wp.func
def round_seed(counter: wp.array(dtype=wp.int64), back: int) -> int:
    """The random seed of the round ``back`` rounds before the last one the counter was advanced to."""
    calls = counter[COUNTER_CALLS] - wp.int64(back)
    return int((counter[COUNTER_SEED] * wp.int64(1000003) + calls * wp.int64(7919)) & SEED_MASK)


@wp.func
def round_number(counter: wp.array(dtype=wp.int64), back: int) -> wp.int64:
    """The number (claims' high bits) of the round ``back`` rounds before the last one the counter was advanced to."""
    return counter[COUNTER_ROUND] - wp.int64(back)


@wp.func
def advance_rounds(counter: wp.array(dtype=wp.int64), rounds: int):
    """A placer's counter advanced by ``rounds`` rounds (one thread)."""
    counter[COUNTER_CALLS] = counter[COUNTER_CALLS] + wp.int64(rounds)
    counter[COUNTER_ROUND] = counter[COUNTER_ROUND] + wp.int64(rounds)


@wp.kernel
def advance_counter(
    # Model:
    rounds: int,
    # State out:
    counter: wp.array(dtype=wp.int64),
):
    """Advance a placer's counter by ``rounds`` rounds (one thread; :func:`begin_todo` does it for whole calls)."""
    advance_rounds(counter, rounds)


@wp.struct
class PlaceGrid:
    """Uniform grid of the placement, one block of ``ncx * ncy`` cells per world, and the exclusion test."""

    cell: wp.vec2  # cell width and height (m)
    ncx: int
    ncy: int
    reach: int  # neighbouring cells scanned on each side
    shape: int  # SHAPE_CIRCLE: conflict when |d|^2 <= excl[0]; SHAPE_BOX: when |dx| <= excl[0] and |dy| <= excl[1]
    excl: wp.vec2


@wp.func
def conflict(g: PlaceGrid, d: wp.vec2) -> bool:
    """Are two movers whose centres differ by ``d`` too close (touching counts)?"""
    if g.shape == SHAPE_CIRCLE:
        return wp.dot(d, d) <= g.excl[0]
    return wp.abs(d[0]) <= g.excl[0] and wp.abs(d[1]) <= g.excl[1]


@wp.func
def place_cell(g: PlaceGrid, p: wp.vec2) -> wp.vec2i:
    """Cell of ``p``, clamped into the grid (clamping never separates two nearby points)."""
    cx = wp.clamp(int(wp.floor(p[0] / g.cell[0])), 0, g.ncx - 1)
    cy = wp.clamp(int(wp.floor(p[1] / g.cell[1])), 0, g.ncy - 1)
    return wp.vec2i(cx, cy)


@wp.func
def cell_index(g: PlaceGrid, w: int, c: wp.vec2i) -> int:
    return (w * g.ncy + c[1]) * g.ncx + c[0]


@wp.func
def neighbor_cell(g: PlaceGrid, w: int, c: wp.vec2i, dx: int, dy: int) -> int:
    """Index of the cell ``(dx, dy)`` away from cell ``c`` of world ``w``, or -1 outside the grid."""
    cx = c[0] + dx
    cy = c[1] + dy
    if cx < 0 or cx >= g.ncx or cy < 0 or cy >= g.ncy:
        return -1
    return (w * g.ncy + cy) * g.ncx + cx


@wp.kernel
def clear_grid(head: wp.array(dtype=wp.int32), head_old: wp.array(dtype=wp.int32), claim: wp.array(dtype=wp.int64)):
    """Empty every cell list and claim."""
    i = wp.tid()
    head[i] = -1
    head_old[i] = -1
    claim[i] = wp.int64(NO_CLAIM)


@wp.kernel
def begin_todo(
    # Model:
    advance: int,
    # State in:
    mask: wp.array2d(dtype=wp.bool),
    # State out:
    todo: wp.array2d(dtype=wp.int32),
    active: wp.array(dtype=wp.int32),
    listed: wp.array(dtype=wp.int32),
    count: wp.array(dtype=wp.int32),
    counter: wp.array(dtype=wp.int64),
):
    """``todo``: the movers to place (``mask``); ``active[w]`` (zeroed before): world ``w`` has one; ``listed``: the
    flat indices ``w * M + m`` of the movers to place, ``count[0]`` (zeroed before) of them, in any order (the rounds
    launch a thread per listed mover: threads of one warp work on movers to place, not on a few among many others).
    Thread (0, 0) advances the placer's ``counter`` by the call's ``advance`` rounds (no kernel of this launch reads
    it; :func:`advance_counter` folded in)."""
    w, m = wp.tid()
    if w == 0 and m == 0 and advance != 0:
        advance_rounds(counter, advance)
    t = int(0)
    if mask[w, m]:
        t = 1
        active[w] = 1
        listed[wp.atomic_add(count, 0, 1)] = w * mask.shape[1] + m
    todo[w, m] = t


@wp.func
def listed_mover(i: int, listed: wp.array(dtype=wp.int32), num_movers: int):
    """World and mover of the ``i``-th listed mover."""
    wm = listed[i]
    w = wm // num_movers
    return w, wm - w * num_movers


@wp.kernel
def bin_fixed(
    # Model:
    g: PlaceGrid,
    hold: int,
    # State in:
    pos: wp.array2d(dtype=wp.vec2),
    todo: wp.array2d(dtype=wp.int32),
    active: wp.array(dtype=wp.int32),
    # State out:
    head: wp.array(dtype=wp.int32),
    next_in_cell: wp.array2d(dtype=wp.int32),
    head_old: wp.array(dtype=wp.int32),
    next_old: wp.array2d(dtype=wp.int32),
    old_cell: wp.array2d(dtype=wp.int32),
):
    """In the worlds with movers to place (``active``): put every mover that stays where it is (``todo == 0``) into
    its cell's list; with ``hold``, the movers to place go into the second lists at their current spots (which they
    keep until they are placed; ``old_cell``: that cell, -1 for the others)."""
    w, m = wp.tid()
    if active[w] == 0:
        return
    c = cell_index(g, w, place_cell(g, pos[w, m]))
    oc = int(-1)
    if todo[w, m] == 0:
        next_in_cell[w, m] = wp.atomic_exch(head, c, m)
    elif hold != 0:
        next_old[w, m] = wp.atomic_exch(head_old, c, m)
        oc = c
    old_cell[w, m] = oc


@wp.kernel
def unbin(
    # Model:
    g: PlaceGrid,
    # State in:
    pos: wp.array2d(dtype=wp.vec2),
    todo: wp.array2d(dtype=wp.int32),
    active: wp.array(dtype=wp.int32),
    old_cell: wp.array2d(dtype=wp.int32),
    # State out:
    head: wp.array(dtype=wp.int32),
    head_old: wp.array(dtype=wp.int32),
):
    """Empty the cells a call filled (work per mover of the worlds placed in, not per cell): every mover in the
    lists now (``todo == 0``: fixed or placed, at its position) and every held spot (``old_cell``). Claims need no
    clearing: a later round's claims beat them."""
    w, m = wp.tid()
    if active[w] == 0:
        return
    if todo[w, m] == 0:
        head[cell_index(g, w, place_cell(g, pos[w, m]))] = -1
    oc = old_cell[w, m]
    if oc >= 0:
        head_old[oc] = -1


@wp.func
def clear_of_placed(g: PlaceGrid, w: int, p: wp.vec2, skip: int, pos: wp.array2d(dtype=wp.vec2),
                    head: wp.array(dtype=wp.int32), next_in_cell: wp.array2d(dtype=wp.int32)) -> bool:
    """No mover of the lists (other than ``skip``) conflicts with a mover at ``p``."""
    c = place_cell(g, p)
    for dy in range(-g.reach, g.reach + 1):
        for dx in range(-g.reach, g.reach + 1):
            cell = neighbor_cell(g, w, c, dx, dy)
            if cell < 0:
                continue
            j = head[cell]
            while j >= 0:
                if j != skip and conflict(g, p - pos[w, j]):
                    return False
                j = next_in_cell[w, j]
    return True


@wp.func
def clear_in_world(g: PlaceGrid, w: int, m: int, p: wp.vec2, hold: int, pos: wp.array2d(dtype=wp.vec2),
                   todo: wp.array2d(dtype=wp.int32)) -> bool:
    """:func:`clear_of_placed`'s verdicts of a :func:`propose` try from a scan of the world's movers instead of the
    grid's lists (:attr:`~magwarp.swarm.Placer.search` ``"world"``): the lists hold the movers placed or fixed
    (``todo == 0``) at their positions and, with ``hold``, the movers still to place at theirs (a mover placed in an
    earlier round is found in both at its new position): so no mover other than ``m`` conflicts with ``p`` among those
    placed (every mover with ``hold``). The same verdict bit for bit (the grid's reach covers every conflict)."""
    for j in range(todo.shape[1]):
        if j != m and (hold != 0 or todo[w, j] == 0):
            if conflict(g, p - pos[w, j]):
                return False
    return True


@wp.func
def claim_candidate(g: PlaceGrid, w: int, m: int, p: wp.vec2, round_id: wp.int64, cand: wp.array2d(dtype=wp.vec2),
                    cand_ok: wp.array2d(dtype=wp.int32), claim: wp.array(dtype=wp.int64)):
    """Mover ``m``'s valid candidate ``p`` of round ``round_id``: stored, and its grid cell claimed."""
    cand[w, m] = p
    cand_ok[w, m] = 1
    wp.atomic_max(claim, cell_index(g, w, place_cell(g, p)), claim_of(round_id, m))


@wp.kernel
def propose(
    # Model:
    g: PlaceGrid,
    tiles: wp.array2d(dtype=wp.int32),
    col: Collision,
    radius: float,
    half: wp.vec2,
    tile_list: wp.array(dtype=wp.vec2i),
    tries: int,
    hold: int,
    back: int,  # this round is the counter's last one less back (round_seed, round_number)
    scan: int,  # 1: check against the world's movers (clear_in_world), not the grid's lists (unused then)
    # State in:
    counter: wp.array(dtype=wp.int64),
    pos: wp.array2d(dtype=wp.vec2),
    todo: wp.array2d(dtype=wp.int32),
    head: wp.array(dtype=wp.int32),
    next_in_cell: wp.array2d(dtype=wp.int32),
    head_old: wp.array(dtype=wp.int32),
    next_old: wp.array2d(dtype=wp.int32),
    listed: wp.array(dtype=wp.int32),
    count: wp.array(dtype=wp.int32),
    # State out:
    cand: wp.array2d(dtype=wp.vec2),
    cand_ok: wp.array2d(dtype=wp.int32),
    claim: wp.array(dtype=wp.int64),
):
    """Up to ``tries`` candidates for each mover still to place; the first valid one claims its cell.

    ``radius`` / ``half``: the footprint (circle radius or box half sizes) grown by the sampling offset; the wall
    margin is added by the wall rule itself. With ``hold``, candidates also keep clear of the spots the other movers
    to place still hold (their positions before this call; a mover placed in an earlier round keeps both). One thread
    per mover of ``listed`` (:func:`begin_todo`; threads past ``count[0]`` exit). The seed and the round's number
    come from the placer's device ``counter`` (:func:`round_seed`, :func:`round_number`)."""
    i = wp.tid()
    if i >= count[0]:
        return
    w, m = listed_mover(i, listed, todo.shape[1])
    cand_ok[w, m] = 0
    if todo[w, m] == 0:
        return
    rng = wp.rand_init(round_seed(counter, back), w * todo.shape[1] + m)
    round_id = round_number(counter, back)
    size = col.tile_size
    ntiles = tile_list.shape[0]
    for _t in range(tries):
        t = tile_list[int(wp.randu(rng) % wp.uint32(ntiles))]
        p = wp.vec2((float(t[0]) + wp.randf(rng)) * size, (float(t[1]) + wp.randf(rng)) * size)
        if hits_wall_cs(tiles, col, p, wp.vec2(1.0, 0.0), radius, half):
            continue
        if scan != 0:
            if not clear_in_world(g, w, m, p, hold, pos, todo):
                continue
            claim_candidate(g, w, m, p, round_id, cand, cand_ok, claim)
            return
        if not clear_of_placed(g, w, p, -1, pos, head, next_in_cell):
            continue
        if hold != 0 and not clear_of_placed(g, w, p, m, pos, head_old, next_old):
            continue
        claim_candidate(g, w, m, p, round_id, cand, cand_ok, claim)
        return


#: the most tries per round the chunked scan (:func:`make_scan_propose`) keeps in registers
MAX_SCAN_TRIES = 16
#: movers the chunked scan reads per pass of its loops (loads issued together, then checked)
SCAN_CHUNK = 4


@functools.cache
def make_scan_propose(tries: int, grid_stride: bool = False):
    """:func:`propose` with ``scan`` (``search="world"``), its reads of the world's movers grouped: the same spots, bit
    for bit. The round's ``tries`` candidates are drawn first (the same draws as :func:`propose`'s tries, in the same
    order) and checked against the walls; then one try after another is checked against the world's movers, read
    :data:`SCAN_CHUNK` at a time (the loads issued together, then checked), each try stopping at the chunk that
    holds its first conflict. The first valid candidate wins, as the first valid try of :func:`propose` does.
    ``tries`` at most :data:`MAX_SCAN_TRIES`; ``grid_stride``: compiled with Warp's grid-stride loop (a launch capped
    with ``max_blocks``, :func:`strided`). (:class:`~magwarp.swarm.Placer` pairs it with :func:`resolve`'s
    ``scan=2``, which reads the lower-indexed winners a chunk at a time too.) The kernel takes :func:`propose`'s
    inputs less ``tries``, ``scan`` and the cell lists.

    Measured (benchmarks/swarm_place.py, one respawn call of the swarm step): 1.08-1.12x :func:`propose`'s speed on
    this project's CPU at 64-100 movers per world, 0.76-0.82x on an H100 at 100-256 (its rounds are bound by the
    tries' work, not by the reads' latency). A variant that checked all tries in one pass over the movers was slower
    on both (0.74x on the CPU, 0.78-0.82x on the H100) and was removed."""
    if not 1 <= int(tries) <= MAX_SCAN_TRIES:
        raise ValueError(f"scan tries must be in 1..{MAX_SCAN_TRIES}, got {tries!r}")
    T = int(tries)
    Cands = wp.types.matrix(shape=(T, 2), dtype=wp.float32)
    Flags = wp.types.vector(length=T, dtype=wp.int32)
    opts = {"enable_backward": False, **MODULE_OPTIONS, "max_unroll": max(16, T * SCAN_CHUNK)}

    @wp.func
    def chunk_clear(g: PlaceGrid, w: int, m: int, j0: int, p: wp.vec2, hold: int, pos: wp.array2d(dtype=wp.vec2),
                    todo: wp.array2d(dtype=wp.int32)) -> bool:
        """No mover ``j0 .. j0 + SCAN_CHUNK - 1`` of the world that counts (:func:`clear_in_world`) conflicts."""
        clear = bool(True)
        for u in range(SCAN_CHUNK):
            j = j0 + u
            if j < todo.shape[1] and j != m:
                if hold != 0 or todo[w, j] == 0:
                    if conflict(g, p - pos[w, j]):
                        clear = False
        return clear

    @wp.kernel(module="unique", module_options=opts, grid_stride=bool(grid_stride))
    def propose_scan(
        # Model:
        g: PlaceGrid,
        tiles: wp.array2d(dtype=wp.int32),
        col: Collision,
        radius: float,
        half: wp.vec2,
        tile_list: wp.array(dtype=wp.vec2i),
        hold: int,
        back: int,
        # State in:
        counter: wp.array(dtype=wp.int64),
        pos: wp.array2d(dtype=wp.vec2),
        todo: wp.array2d(dtype=wp.int32),
        listed: wp.array(dtype=wp.int32),
        count: wp.array(dtype=wp.int32),
        # State out:
        cand: wp.array2d(dtype=wp.vec2),
        cand_ok: wp.array2d(dtype=wp.int32),
        claim: wp.array(dtype=wp.int64),
    ):
        """:func:`propose` (``scan``) with grouped reads (:func:`make_scan_propose`)."""
        i = wp.tid()
        if i >= count[0]:
            return
        num = todo.shape[1]
        w, m = listed_mover(i, listed, num)
        cand_ok[w, m] = 0
        if todo[w, m] == 0:
            return
        rng = wp.rand_init(round_seed(counter, back), w * num + m)
        size = col.tile_size
        ntiles = tile_list.shape[0]
        c = Cands()
        ok = Flags()  # 1: on the tiles
        for t in range(T):
            tl = tile_list[int(wp.randu(rng) % wp.uint32(ntiles))]
            p = wp.vec2((float(tl[0]) + wp.randf(rng)) * size, (float(tl[1]) + wp.randf(rng)) * size)
            c[t, 0] = p[0]
            c[t, 1] = p[1]
            if not hits_wall_cs(tiles, col, p, wp.vec2(1.0, 0.0), radius, half):
                ok[t] = 1
        for t in range(T):
            if ok[t] != 0:
                p = wp.vec2(c[t, 0], c[t, 1])
                clear = bool(True)
                j0 = int(0)
                while j0 < num and clear:
                    clear = chunk_clear(g, w, m, j0, p, hold, pos, todo)
                    j0 += SCAN_CHUNK
                if clear:  # the first valid try wins
                    claim_candidate(g, w, m, p, round_number(counter, back), cand, cand_ok, claim)
                    return

    return propose_scan


@wp.kernel
def resolve(
    # Model:
    g: PlaceGrid,
    back: int,  # as propose's
    scan: int,  # 1: look for lower-indexed winners among the world's movers, keep no cell lists; 2: the same, read
    # SCAN_CHUNK movers at a time
    # State in:
    counter: wp.array(dtype=wp.int64),
    cand: wp.array2d(dtype=wp.vec2),
    cand_ok: wp.array2d(dtype=wp.int32),
    claim: wp.array(dtype=wp.int64),
    listed: wp.array(dtype=wp.int32),
    count: wp.array(dtype=wp.int32),
    # State out:
    todo: wp.array2d(dtype=wp.int32),
    pos: wp.array2d(dtype=wp.vec2),
    head: wp.array(dtype=wp.int32),
    next_in_cell: wp.array2d(dtype=wp.int32),
):
    """Accept the cell winners that no lower-indexed nearby winner of this round conflicts with (one thread per listed
    mover, as :func:`propose`); with ``scan`` the winners are looked for among the world's movers and the accepted
    ones are not pushed onto cell lists (the same verdicts)."""
    i = wp.tid()
    if i >= count[0]:
        return
    w, m = listed_mover(i, listed, todo.shape[1])
    if cand_ok[w, m] == 0:
        return
    round_id = round_number(counter, back)
    p = cand[w, m]
    c = place_cell(g, p)
    own = cell_index(g, w, c)
    if claimant(claim[own], round_id) != m:
        return
    if scan != 0:
        # the cell winners of this round are the movers whose claim holds the cell of their candidate (a stale
        # candidate of an earlier call or round holds no claim of this round); the grid's cells within reach hold
        # every conflicting one
        if scan == 2:
            j0 = int(0)
            while j0 < m:
                beaten = bool(False)
                for u in range(SCAN_CHUNK):
                    j = j0 + u
                    if j < m:
                        if cand_ok[w, j] != 0:
                            q = cand[w, j]
                            if conflict(g, p - q):
                                if claimant(claim[cell_index(g, w, place_cell(g, q))], round_id) == j:
                                    beaten = True
                if beaten:
                    return
                j0 += SCAN_CHUNK
        else:
            for j in range(m):
                if cand_ok[w, j] != 0:
                    q = cand[w, j]
                    if conflict(g, p - q):
                        if claimant(claim[cell_index(g, w, place_cell(g, q))], round_id) == j:
                            return
        pos[w, m] = p
        todo[w, m] = 0
        return
    for dy in range(-g.reach, g.reach + 1):
        for dx in range(-g.reach, g.reach + 1):
            cell = neighbor_cell(g, w, c, dx, dy)
            if cell < 0:
                continue
            j = claimant(claim[cell], round_id)
            if j >= 0 and j < m and conflict(g, p - cand[w, j]):
                return
    pos[w, m] = p
    todo[w, m] = 0
    next_in_cell[w, m] = wp.atomic_exch(head, own, m)


@functools.cache
def strided(kernel: wp.Kernel) -> wp.Kernel:
    """``kernel`` (:func:`begin_todo`, :func:`bin_fixed`, :func:`unbin`, :func:`propose` or :func:`resolve`) compiled
    with Warp's grid-stride loop, as a kernel of its own module (``<name>_strided``, compiled at its first launch):
    what a launch capped with ``max_blocks`` needs (:class:`~magwarp.swarm.Placer`'s ``blocks``), since Warp refuses
    a capped launch of a lean kernel on CUDA. The same work per index, so the same spots bit for bit. The uncapped
    launches keep the lean kernels: one H100 run with every placement kernel grid-stride (2026-12-08) stepped the
    swarm 8% slower under the planner and 37% under ``seek`` than another H100 had with the lean ones, the two
    causes (card or kernels) not separated."""
    return wp.kernel(kernel.func, name=f"{kernel.key}_strided", module="unique",
                     module_options={"enable_backward": False, **MODULE_OPTIONS}, grid_stride=True)


@wp.kernel
def count_todo(todo: wp.array2d(dtype=wp.int32), per_world: wp.array(dtype=wp.int32)):
    """Movers still to place, per world (``per_world`` zeroed before)."""
    w, m = wp.tid()
    if todo[w, m] != 0:
        wp.atomic_add(per_world, w, 1)


# ---------------------------------------------------------------------------------------------------------------------
# The rounds' lane shape (:attr:`~magwarp.swarm.Placer.lanes`, ``search="world"``): a group of ``lanes`` adjacent
# threads per listed mover, in a fixed grid of groups that walk the list (group ``g`` takes the listed movers ``g, g +
# groups, ...`` up to ``count[0]``: the count stays on the device, no host sync, and the launch does not grow with the
# worlds' movers). Lane ``l`` holds the world's movers ``l, l + lanes, ...`` that a candidate is checked against in
# registers (loaded once per listed mover, not once per try; a mover that does not count sits at FAR), every lane draws
# the same candidates from the mover's one random stream (the same draws as :func:`propose`), checks its movers
# without an early exit, and the group votes (a warp's ``__any_sync`` over the group's lanes on CUDA, a block's
# ``wp.tile_sum`` with ``warp.config.enable_cpu_blocks`` on a CPU). The first valid try wins, so the same spots are
# chosen bit for bit. :func:`make_lane_kernels` builds the kernels.

#: lane counts of a group (a power of two: the groups are aligned within a warp)
LANE_CHOICES = (1, 2, 4, 8, 16, 32)
#: the most world movers a lane keeps in registers (more: it reads them from memory at every try)
MAX_PER_LANE = 32
#: where a mover that does not count sits for the register checks (conflicts with nothing on the tiles)
FAR = wp.constant(1.0e18)

# a group's lane mask within its warp (lanes a power of two, the group aligned in the warp); as fast_cycle's
_GROUP_MASK = """
#if defined(__CUDA_ARCH__)
    const unsigned lane_id = threadIdx.x & 31u;
    const unsigned group_mask = lanes >= 32 ? 0xffffffffu
                                            : (((1u << lanes) - 1u) << (lane_id & ~((unsigned)lanes - 1u)));
"""


@wp.func_native(_GROUP_MASK + """
    return __any_sync(group_mask, v != 0) ? 1 : 0;
#endif
    return v;
""")
def group_any(v: int, lanes: int) -> int:
    """1 on every lane of the group if ``v`` is nonzero on any of them, else 0 (CUDA; a CPU thread is a group of
    one)."""
    ...


@functools.cache
def make_lane_kernels(lanes: int, per_lane: int, tiles: bool = False, registers: bool | None = None):
    """``(propose_lanes, resolve_lanes)``: :func:`propose` and :func:`resolve` with ``search="world"`` in the lane
    shape (see above) for groups of ``lanes`` threads and worlds of at most ``lanes * per_lane`` movers. ``tiles``:
    vote over a block of ``lanes`` threads with ``wp.tile_sum`` (a CPU with ``warp.config.enable_cpu_blocks``; launch
    blocks of ``lanes`` threads) instead of warp votes. ``registers``: keep the lane's world movers in registers
    (None: when ``per_lane`` is at most :data:`MAX_PER_LANE`), else read them at every try. Both kernels take, after
    :func:`propose`'s or :func:`resolve`'s inputs less ``scan``, ``groups``: the groups in the launch (``groups *
    lanes`` threads)."""
    if lanes not in LANE_CHOICES:
        raise ValueError(f"lanes must be one of {LANE_CHOICES}, got {lanes!r}")
    L, P = int(lanes), int(per_lane)
    cache = P <= MAX_PER_LANE if registers is None else bool(registers)  # the lane's world movers in registers
    S = P if cache else 1
    Slots = wp.types.matrix(shape=(S, 2), dtype=wp.float32)
    opts = {"enable_backward": False, **MODULE_OPTIONS, "max_unroll": max(16, S)}

    @wp.func
    def lanes_any(v: int) -> int:
        if wp.static(L == 1):
            return v
        if wp.static(tiles):
            s = wp.tile_sum(wp.tile(v))
            return wp.where(s[0] > 0, 1, 0)
        return group_any(v, L)

    @wp.func
    def propose_one(g: PlaceGrid, tiles: wp.array2d(dtype=wp.int32), col: Collision, radius: float, half: wp.vec2,
                    tile_list: wp.array(dtype=wp.vec2i), tries: int, hold: int, back: int,
                    counter: wp.array(dtype=wp.int64), pos: wp.array2d(dtype=wp.vec2),
                    todo: wp.array2d(dtype=wp.int32), w: int, m: int, lane: int, cand: wp.array2d(dtype=wp.vec2),
                    cand_ok: wp.array2d(dtype=wp.int32), claim: wp.array(dtype=wp.int64)):
        num = todo.shape[1]
        if lane == 0:
            cand_ok[w, m] = 0
        if todo[w, m] == 0:
            return
        # the movers this lane checks (clear_in_world's: all but m with hold, else those placed or fixed)
        q = Slots()
        if wp.static(cache):
            for k in range(P):
                j = lane + k * L
                x = float(FAR)
                y = float(FAR)
                if j < num and j != m:
                    if hold != 0 or todo[w, j] == 0:
                        v = pos[w, j]
                        x = v[0]
                        y = v[1]
                q[k, 0] = x
                q[k, 1] = y
        rng = wp.rand_init(round_seed(counter, back), w * num + m)
        round_id = round_number(counter, back)
        size = col.tile_size
        ntiles = tile_list.shape[0]
        for _t in range(tries):
            t = tile_list[int(wp.randu(rng) % wp.uint32(ntiles))]
            p = wp.vec2((float(t[0]) + wp.randf(rng)) * size, (float(t[1]) + wp.randf(rng)) * size)
            if hits_wall_cs(tiles, col, p, wp.vec2(1.0, 0.0), radius, half):
                continue  # the same on every lane
            hit = int(0)
            if wp.static(cache):
                for k in range(P):
                    if conflict(g, p - wp.vec2(q[k, 0], q[k, 1])):
                        hit = 1
            else:
                for j in range(lane, num, L):
                    if j != m and (hold != 0 or todo[w, j] == 0):
                        if conflict(g, p - pos[w, j]):
                            hit = 1
                            break
            if lanes_any(hit) != 0:
                continue
            if lane == 0:
                claim_candidate(g, w, m, p, round_id, cand, cand_ok, claim)
            return

    @wp.kernel(module="unique", module_options=opts)
    def propose_lanes(
        # Model:
        g: PlaceGrid,
        tiles: wp.array2d(dtype=wp.int32),
        col: Collision,
        radius: float,
        half: wp.vec2,
        tile_list: wp.array(dtype=wp.vec2i),
        tries: int,
        hold: int,
        back: int,
        # State in:
        counter: wp.array(dtype=wp.int64),
        pos: wp.array2d(dtype=wp.vec2),
        todo: wp.array2d(dtype=wp.int32),
        listed: wp.array(dtype=wp.int32),
        count: wp.array(dtype=wp.int32),
        groups: int,
        # State out:
        cand: wp.array2d(dtype=wp.vec2),
        cand_ok: wp.array2d(dtype=wp.int32),
        claim: wp.array(dtype=wp.int64),
    ):
        """:func:`propose` (``scan``) by groups of ``lanes`` threads walking the list (:func:`make_lane_kernels`)."""
        tid = wp.tid()
        lane = tid % L
        i = tid / L
        n = count[0]
        num = todo.shape[1]
        while i < n:
            wm = listed[i]
            w = wm / num
            propose_one(g, tiles, col, radius, half, tile_list, tries, hold, back, counter, pos, todo, w,
                        wm - w * num, lane, cand, cand_ok, claim)
            i = i + groups

    @wp.func
    def resolve_one(g: PlaceGrid, back: int, counter: wp.array(dtype=wp.int64), cand: wp.array2d(dtype=wp.vec2),
                    cand_ok: wp.array2d(dtype=wp.int32), claim: wp.array(dtype=wp.int64), w: int, m: int, lane: int,
                    todo: wp.array2d(dtype=wp.int32), pos: wp.array2d(dtype=wp.vec2)):
        if cand_ok[w, m] == 0:
            return
        round_id = round_number(counter, back)
        p = cand[w, m]
        if claimant(claim[cell_index(g, w, place_cell(g, p))], round_id) != m:
            return
        hit = int(0)
        for j in range(lane, m, L):
            if cand_ok[w, j] != 0:
                qj = cand[w, j]
                if conflict(g, p - qj):
                    if claimant(claim[cell_index(g, w, place_cell(g, qj))], round_id) == j:
                        hit = 1
        if lanes_any(hit) != 0:
            return
        if lane == 0:
            pos[w, m] = p
            todo[w, m] = 0

    @wp.kernel(module="unique", module_options=opts)
    def resolve_lanes(
        # Model:
        g: PlaceGrid,
        back: int,
        # State in:
        counter: wp.array(dtype=wp.int64),
        cand: wp.array2d(dtype=wp.vec2),
        cand_ok: wp.array2d(dtype=wp.int32),
        claim: wp.array(dtype=wp.int64),
        listed: wp.array(dtype=wp.int32),
        count: wp.array(dtype=wp.int32),
        groups: int,
        # State out:
        todo: wp.array2d(dtype=wp.int32),
        pos: wp.array2d(dtype=wp.vec2),
    ):
        """:func:`resolve` (``scan``) by groups of ``lanes`` threads walking the list: the winners of lower index that
        conflict are looked for by the group's lanes together (lane ``l``: the movers ``l, l + lanes, ...``)."""
        tid = wp.tid()
        lane = tid % L
        i = tid / L
        n = count[0]
        num = todo.shape[1]
        while i < n:
            wm = listed[i]
            w = wm / num
            resolve_one(g, back, counter, cand, cand_ok, claim, w, wm - w * num, lane, todo, pos)
            i = i + groups

    return propose_lanes, resolve_lanes
