"""NaN guard kernels: count the steps on the device and flag worlds whose state has become non-finite.

Both run inside the simulator's step graph (no host synchronisation): ``count_step`` advances a device step counter
and ``flag_nonfinite`` records, per world, the step at which any mover's pose or velocity first held a NaN or an
infinity (``-1`` while the world is finite). The host reads the record only when asked.
"""

from __future__ import annotations

import warp as wp

from magwarp.kernels.options import MODULE_OPTIONS

wp.set_module_options({"enable_backward": False, **MODULE_OPTIONS})


@wp.func
def vec3_finite(v: wp.vec3) -> bool:
    return wp.isfinite(v[0]) and wp.isfinite(v[1]) and wp.isfinite(v[2])


@wp.func
def state_finite(pos: wp.vec3, quat: wp.quat, vel: wp.vec3, omega: wp.vec3) -> bool:
    """Whether a mover's pose and velocity are all finite."""
    ok = vec3_finite(pos) and vec3_finite(vel) and vec3_finite(omega)
    return ok and wp.isfinite(quat[0]) and wp.isfinite(quat[1]) and wp.isfinite(quat[2]) and wp.isfinite(quat[3])


@wp.func
def flag_world(steps: wp.array(dtype=wp.int32), nonfinite_step: wp.array(dtype=wp.int32), w: int):
    """Record step ``steps[0]`` for world ``w`` unless it holds an earlier one (every writer writes the same step)."""
    if nonfinite_step[w] < 0:
        nonfinite_step[w] = steps[0]


@wp.kernel
def count_step(
    # State out:
    steps: wp.array(dtype=wp.int32),
):
    steps[0] = steps[0] + 1


@wp.kernel
def flag_nonfinite(
    # State in:
    steps: wp.array(dtype=wp.int32),
    pos: wp.array2d(dtype=wp.vec3),
    quat: wp.array2d(dtype=wp.quat),
    vel: wp.array2d(dtype=wp.vec3),
    omega: wp.array2d(dtype=wp.vec3),
    # State out:
    nonfinite_step: wp.array(dtype=wp.int32),
):
    """One thread per (world, mover), launched ``dim=(W, M)``: a world of a million movers is checked in parallel.
    Every thread that finds its mover non-finite writes the same step, so the concurrent writes agree."""
    w, k = wp.tid()
    if nonfinite_step[w] >= 0:  # keep the first step at which the world went bad
        return
    if not state_finite(pos[w, k], quat[w, k], vel[w, k], omega[w, k]):
        nonfinite_step[w] = steps[0]


@wp.kernel
def clear_reset_worlds(
    # State in:
    mask: wp.array(dtype=wp.int32),
    latency: int,  # 1: the simulator holds previous commands (action latency)
    # State out:
    nonfinite_step: wp.array(dtype=wp.int32),
    prev_cmd: wp.array2d(dtype=wp.vec2),
):
    """Reset worlds (``mask[w] != 0``) start over as finite, at rest: no NaN record, no previous command (one thread
    per (world, mover))."""
    w, m = wp.tid()
    if mask[w] == 0:
        return
    if m == 0:
        nonfinite_step[w] = -1
    if latency == 1:
        prev_cmd[w, m] = wp.vec2(0.0)
