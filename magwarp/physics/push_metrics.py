"""Per-cycle pushing benchmark metrics inside the step graph (MagBotSim's corrective movements and time to success).

Per world and control cycle, with ``d`` the object's x/y distance to its goal and ``e`` the position threshold:

* overshoot correction: the object was at the goal last cycle (``d < e``) and is not now, by more than 2e-5 m;
* distance correction: ``d`` rose by more than 2e-5 m, and later falls by more than 2e-5 m (counted at the fall);
* time to success: time until the start of the current streak of cycles at the goal (distance ``<= e``, or
  coverage ``>= min_coverage`` for pose goals), frozen once a streak lasts 0.15 s (150 cycles of 1 ms; with a
  longer physics step, the same time in its cycles); -1 if never at the goal.

These are the definitions of MagBotSim's ``CorrectiveMovementMeasurement`` and its throughput bookkeeping, counted
on the device for all worlds. State lives in Warp arrays with torch views; :meth:`PushMetrics.reset` clears worlds.
"""

from __future__ import annotations

import numpy as np
import torch
import warp as wp

from magwarp.kernels.metrics import corrective_update
from magwarp.physics.backend import MjwBackend
from magwarp.physics.coverage import ShapeTable, shape_overlap

__all__ = ["PushMetrics"]

_STREAK_S = 0.15  # time at the goal after which time to success is frozen (MagBotSim: 150 cycles of 1 ms)


@wp.struct
class _Goal:
    threshold: float
    learn_pose: int
    min_coverage: float


@wp.kernel
def push_metrics_kernel(
    # Model:
    goal: _Goal,
    parts: wp.array2d[wp.vec4],
    radius: wp.array[float],
    shape_area: wp.array[float],
    shape_index: wp.array[int],
    qadr: int,
    dt: float,
    streak_max: int,
    # State in:
    qpos: wp.array2d[float],
    goal_xy: wp.array[wp.vec2],
    goal_yaw: wp.array[float],
    # State in/out:
    success_last: wp.array[int],
    last_dist: wp.array[float],
    dist_increased: wp.array[int],
    overshoots: wp.array[int],
    dist_corrections: wp.array[int],
    elapsed: wp.array[int],
    streak: wp.array[int],
    time_to_success: wp.array[float],
):
    w = wp.tid()
    p = wp.vec2(qpos[w, qadr], qpos[w, qadr + 1])
    dist = wp.length(p - goal_xy[w])
    # corrective movements: the shared rule (MagBotSim: strict '<' for "at goal" here)
    over, corr, succ, inc = corrective_update(dist, goal.threshold, success_last[w], last_dist[w], dist_increased[w])
    overshoots[w] += over
    dist_corrections[w] += corr
    success_last[w] = succ
    dist_increased[w] = inc
    last_dist[w] = dist
    # time to success
    if streak[w] < streak_max:
        elapsed[w] += 1
        reached = dist <= goal.threshold
        if goal.learn_pose != 0:
            qw = qpos[w, qadr + 3]
            qz = qpos[w, qadr + 6]
            qx = qpos[w, qadr + 4]
            qy = qpos[w, qadr + 5]
            yaw = wp.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
            pa = wp.vec3(p[0], p[1], yaw)
            pg = wp.vec3(goal_xy[w][0], goal_xy[w][1], goal_yaw[w])
            s = shape_index[w % shape_index.shape[0]]
            reached = shape_overlap(parts, radius, s, pa, pg) / shape_area[s] >= goal.min_coverage
        if reached:
            if streak[w] == 0:
                time_to_success[w] = float(elapsed[w]) * dt
            streak[w] += 1
        else:
            streak[w] = 0


class PushMetrics:
    """Registers the metric update as a cycle hook of ``backend`` for object ``object_index``.

    ``goal_xy`` ``[W, 2]`` and ``goal_yaw`` ``[W]`` are float32 torch tensors on the backend's device that the
    caller updates in place (they are read by the recorded graph). Counters: ``overshoots``, ``dist_corrections``
    (int32 ``[W]``), ``time_to_success`` (float32 seconds, -1 if not reached).
    """

    def __init__(self, backend: MjwBackend, obj, goal_xy: torch.Tensor, goal_yaw: torch.Tensor, *, threshold: float,
                 learn_pose: bool, min_coverage: float, object_index: int = 0,
                 shape_index: torch.Tensor | None = None):
        self.backend = backend
        dev = backend.device
        W = backend.num_worlds
        for name, t, shape in (("goal_xy", goal_xy, (W, 2)), ("goal_yaw", goal_yaw, (W,))):
            if t.dtype != torch.float32 or tuple(t.shape) != shape or not t.is_contiguous() or t.device != backend.torch_device:
                raise ValueError(f"{name} must be a contiguous float32 tensor of shape {shape} on {backend.torch_device}")
        self._goal_xy = wp.from_torch(goal_xy, dtype=wp.vec2)
        self._goal_yaw = wp.from_torch(goal_yaw)
        g = _Goal()
        g.threshold, g.learn_pose, g.min_coverage = float(threshold), int(learn_pose), float(min_coverage)
        self._goal = g
        # obj: an ObjectSpec, or a ShapeTable with shape_index (int32 [W], updated in place) naming each world's shape
        self._shapes = obj if isinstance(obj, ShapeTable) else ShapeTable([obj], dev)
        self._shape_index = self._shapes.zero_index if shape_index is None else wp.from_torch(shape_index)
        self._qadr = int(backend.object_qadr[object_index])
        self._streak_max = max(1, int(round(_STREAK_S / backend.dt)))
        self._state = {
            "success_last": wp.zeros(W, dtype=int, device=dev),
            "last_dist": wp.array(np.full(W, np.inf, np.float32), dtype=float, device=dev),
            "dist_increased": wp.zeros(W, dtype=int, device=dev),
            "overshoots": wp.zeros(W, dtype=int, device=dev),
            "dist_corrections": wp.zeros(W, dtype=int, device=dev),
            "elapsed": wp.zeros(W, dtype=int, device=dev),
            "streak": wp.zeros(W, dtype=int, device=dev),
            "time_to_success": wp.array(np.full(W, -1.0, np.float32), dtype=float, device=dev),
        }
        self.t = {k: wp.to_torch(v) for k, v in self._state.items()}
        backend.add_cycle_hook(self._launch)

    def _launch(self) -> None:
        b = self.backend
        s = self._state
        wp.launch(push_metrics_kernel, dim=b.num_worlds,
                  inputs=[self._goal, self._shapes.parts, self._shapes.radius, self._shapes.area, self._shape_index,
                          self._qadr, b.dt, self._streak_max, b.data.qpos, self._goal_xy, self._goal_yaw],
                  outputs=[s["success_last"], s["last_dist"], s["dist_increased"], s["overshoots"], s["dist_corrections"],
                           s["elapsed"], s["streak"], s["time_to_success"]],
                  device=b.device)

    def reset(self, mask: torch.Tensor) -> None:
        """Start new episodes for worlds in ``mask`` (torch ops, no sync)."""
        for key in ("success_last", "dist_increased", "overshoots", "dist_corrections", "elapsed", "streak"):
            self.t[key].masked_fill_(mask, 0)
        self.t["last_dist"].masked_fill_(mask, float("inf"))
        self.t["time_to_success"].masked_fill_(mask, -1.0)
