"""Counter-based draws of the sim2real models (:mod:`magwarp.envs.sim2real`): sensor noise and biases, dropped
readings and action delays, computed by any kernel that needs them, with no state and no launch of their own.

A draw is a pure function of ``(key, clock, world, slot, index)`` through Warp's counter-based generator
(:func:`draw_state`)::

    s = rand_init(int32(rand_init(key, hi32(clock))), lo32(clock))     # the env step's stream
    s = rand_init(int32(s), world)                                     # the world's (:func:`world_state`)
    s = rand_init(int32(rand_init(int32(s), slot)), index)             # one value's (:func:`value_state`)

* ``key``: int32, follows the env's seed (:func:`magwarp.envs.sim2real.draw_key`);
* ``clock``: int64, the env steps since the last reseed for the draws of a step (``0`` for the first step), and
  ``-1, -2, ...`` for the draws of the 1st, 2nd, ... ``reset()`` outside a step since the last reseed;
* ``slot``: what is drawn (the constants below): a world's new velocity/position bias, its dropped-reading uniform,
  its action delay, and reading ``r``'s velocity/position noise (``READ + 2 r``, ``READ + 2 r + 1``; a step's own
  reading is ``r = 0``, an autoreset's first reading ``r = 1``);
* ``index``: the mover (noise and biases: one Box-Muller pair gives its x and y, :func:`normal2`), 0 for per-world
  draws.

Uniforms are ``wp.randf`` (24 bits, in ``[0, 1)``); an integer in ``[low, low + span)`` is ``low + (u24 * span) >> 24``
(exact integer arithmetic). Floating-point contraction is off (``fuse_fp``), as in :mod:`magwarp.kernels.task`: the
funcs compile into the kernels that call them, and the fill kernels here must round as those do.
"""

from __future__ import annotations

import warp as wp

wp.set_module_options({"enable_backward": False, "fuse_fp": False})

# slots (see the module docstring)
BIAS_VEL = wp.constant(0)
BIAS_POS = wp.constant(1)
DROP = wp.constant(2)
DELAY = wp.constant(3)
READ = wp.constant(4)  # reading r: velocity noise READ + 2 r, position noise READ + 2 r + 1


@wp.func
def world_state(key: wp.int32, clock: wp.int64, world: int):
    """The generator state of ``world``'s draws at ``clock`` (the prefix of :func:`draw_state`)."""
    s = wp.rand_init(key, wp.int32(clock >> wp.int64(32)))
    s = wp.rand_init(wp.int32(s), wp.int32(clock & wp.int64(0xFFFFFFFF)))
    return wp.rand_init(wp.int32(s), world)


@wp.func
def value_state(ws: wp.uint32, slot: int, index: int):
    """The generator state of value ``(slot, index)`` of a world's draws (``ws``: :func:`world_state`)."""
    return wp.rand_init(wp.int32(wp.rand_init(wp.int32(ws), slot)), index)


@wp.func
def draw_state(key: wp.int32, clock: wp.int64, world: int, slot: int, index: int):
    """The generator state of one value (the module docstring's layout)."""
    return value_state(world_state(key, clock, world), slot, index)


@wp.func
def normal2(state: wp.uint32):
    """Two independent standard normals (Box-Muller on two 24-bit uniforms; ``1 - u`` keeps the log finite)."""
    s = state
    u1 = wp.randf(s)
    u2 = wp.randf(s)
    r = wp.sqrt(-2.0 * wp.log(1.0 - u1))
    t = 2.0 * wp.pi * u2
    return wp.vec2(r * wp.cos(t), r * wp.sin(t))


@wp.func
def uniform(state: wp.uint32):
    """A uniform in ``[0, 1)`` (``wp.randf``: 24 bits)."""
    s = state
    return wp.randf(s)


@wp.func
def uniform_int(state: wp.uint32, low: int, span: int):
    """A uniform integer in ``[low, low + span)``: ``low + (u24 * span) >> 24`` in int64 (no rounding)."""
    s = state
    u24 = wp.int64(wp.randf(s) * 16777216.0)  # exact: randf is a multiple of 2^-24
    return low + int((u24 * wp.int64(span)) >> wp.int64(24))


# ---------------------------------------------------------------------------------------------------- fills
# The same draws into arrays, for the torch step of the envs (the fused trajectory step computes them in its kernels).


@wp.kernel
def fill_normals(
    # Model:
    key: wp.array(dtype=wp.int32),
    clock: wp.int64,
    slot: int,
    # State out:
    out: wp.array2d(dtype=wp.vec2),  # [W, M]: the x/y standard normals of (world, mover)
):
    w, m = wp.tid()
    out[w, m] = normal2(draw_state(key[0], clock, w, slot, m))


@wp.kernel
def fill_uniforms(
    # Model:
    key: wp.array(dtype=wp.int32),
    clock: wp.int64,
    slot: int,
    # State out:
    out: wp.array(dtype=float),  # [W]
):
    w = wp.tid()
    out[w] = uniform(draw_state(key[0], clock, w, slot, 0))


@wp.kernel
def fill_ints(
    # Model:
    key: wp.array(dtype=wp.int32),
    clock: wp.int64,
    slot: int,
    low: int,
    span: int,
    # State out:
    out: wp.array(dtype=wp.int32),  # [W]
):
    w = wp.tid()
    out[w] = uniform_int(draw_state(key[0], clock, w, slot, 0), low, span)
