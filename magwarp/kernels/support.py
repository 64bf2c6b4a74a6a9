"""A resting support under the movers: the tile surface (or a mover's landing pads) as a one-sided vertical stop.

After every cycle, a mover whose centre sank below its world's support height is put back on it and loses its
downward velocity (an inelastic stop, no bounce). Only the vertical is supported: no friction in x/y, no levelling
torque (a mover that rests tilted keeps its tilt). Used by the levitation env's lift-off task
(:mod:`magwarp.envs.levitation_tasks`), where the mover starts resting on it.
"""

from __future__ import annotations

import warp as wp

from magwarp.kernels.options import MODULE_OPTIONS

wp.set_module_options({"enable_backward": False, **MODULE_OPTIONS})


@wp.kernel
def support_kernel(
    # Model:
    height: wp.array(dtype=float),  # [W] lowest height of the mover centre (m); -inf: no support
    # State out:
    pos: wp.array2d(dtype=wp.vec3),
    vel: wp.array2d(dtype=wp.vec3),
):
    w, m = wp.tid()
    p = pos[w, m]
    if p[2] < height[w]:
        pos[w, m] = wp.vec3(p[0], p[1], height[w])
        v = vel[w, m]
        vel[w, m] = wp.vec3(v[0], v[1], wp.max(v[2], 0.0))
