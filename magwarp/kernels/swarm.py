"""Per-mover collision stops for swarms: the movers involved in a collision stop, the world goes on.

:func:`stop_collided` runs after every control cycle (a simulator cycle hook, inside the step graph): a mover
flagged in this cycle (mover-mover or wall) is marked stopped, and every stopped mover has its x/y velocity,
acceleration and command zeroed, so it stays where it collided (z and attitude stay under the impedance hold).
"""

import warp as wp

from magwarp.kernels.options import MODULE_OPTIONS

wp.set_module_options({"enable_backward": False, **MODULE_OPTIONS})


@wp.kernel
def stop_collided(
    # State in:
    flags: wp.array2d(dtype=wp.int32),
    # State out:
    stopped: wp.array2d(dtype=wp.int32),
    vel: wp.array2d(dtype=wp.vec3),
    acc: wp.array2d(dtype=wp.vec2),
    cmd: wp.array2d(dtype=wp.vec2),
):
    w, m = wp.tid()
    s = stopped[w, m]
    if flags[w, m] != 0 and s == 0:
        s = 1
        stopped[w, m] = 1
    if s != 0:
        v = vel[w, m]
        vel[w, m] = wp.vec3(0.0, 0.0, v[2])
        acc[w, m] = wp.vec2(0.0)
        cmd[w, m] = wp.vec2(0.0)
