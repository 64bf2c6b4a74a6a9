"""The paper's benchmark metrics as device-side accumulators, updated every 1 ms cycle inside the step graph.

``m = Metrics(env)`` attaches a tracker to a batched env (trajectory planning, pushing, platform or swarm). From then
on every ``env.step`` returns ``info["metrics"]`` (per-world counters, no host sync), ``m.summary(num_groups)``
reduces the accumulators per group of consecutive worlds (e.g. one evaluation repeat each), ``m.reset(mask)`` zeroes
worlds and ``m.freeze(mask)`` stops counting in worlds whose evaluation episode is over. Definitions:
:mod:`magwarp.kernels.metrics`, :mod:`magwarp.metrics.trajectory`, :mod:`magwarp.metrics.push`,
:mod:`magwarp.metrics.platform`, :mod:`magwarp.metrics.pick_place`, :mod:`magwarp.metrics.swarm`,
:mod:`magwarp.metrics.levitation`.
"""

from __future__ import annotations

from magwarp.metrics.push import PushTaskMetrics
from magwarp.metrics.trajectory import TrajectoryMetrics

__all__ = ["Metrics", "PushTaskMetrics", "TrajectoryMetrics"]


def Metrics(env, **kwargs):  # noqa: N802 - a factory that reads like the class it returns
    """The tracker for ``env``'s task family (``env`` may be a gymnasium wrapper of a magwarp vector env)."""
    from magwarp.envs.push import PushEnv
    from magwarp.envs.trajectory import TrajectoryPlanningEnv

    base = getattr(env, "unwrapped", env)
    from magwarp.envs.gripper_pick_place import GripperPickPlaceEnv
    from magwarp.envs.platform_pick_place import PlatformPickPlaceEnv
    from magwarp.envs.platform_pose import PlatformPoseEnv

    if isinstance(base, (PlatformPickPlaceEnv, GripperPickPlaceEnv)):
        from magwarp.metrics.pick_place import GripperPickPlaceMetrics, PlatformPickPlaceMetrics

        cls = PlatformPickPlaceMetrics if isinstance(base, PlatformPickPlaceEnv) else GripperPickPlaceMetrics
        return cls(base, **kwargs)

    if isinstance(base, PlatformPoseEnv):
        from magwarp.metrics.platform import PlatformMetrics

        return PlatformMetrics(base, **kwargs)
    from magwarp.envs.levitation import LevitationEnv

    if isinstance(base, LevitationEnv):
        from magwarp.metrics.levitation import LevitationMetrics

        return LevitationMetrics(base, **kwargs)
    if isinstance(base, TrajectoryPlanningEnv):
        return TrajectoryMetrics(base, **kwargs)
    from magwarp.swarm.env import SwarmEnv

    if isinstance(base, SwarmEnv):
        from magwarp.metrics.swarm import SwarmTaskMetrics

        return SwarmTaskMetrics(base, **kwargs)
    if isinstance(base, PushEnv):
        return PushTaskMetrics(base, **kwargs)
    raise TypeError(f"no benchmark metrics for {type(base).__name__}; expected a trajectory planning, push, platform, "
                    f"pick-and-place, swarm or levitation env")
