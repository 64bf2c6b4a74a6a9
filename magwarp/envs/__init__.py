"""Torch-native batched RL envs and their gymnasium registrations.

``gymnasium.make("magwarp/TrajectoryPlanning-v0")`` gives a single-env numpy view;
``gymnasium.make_vec("magwarp/TrajectoryPlanning-v0", num_envs=N)`` gives the batched torch env.
Benchmark variants: ``magwarp/TrajectoryPlanningB0-v0`` .. ``B9-v0``. Object pushing on mujoco-warp:
``magwarp/PushBox-v0``, ``PushT-v0``, ``PushL-v0``, ``PushX-v0`` (each with ``B0``..``B9`` variants) and
``magwarp/PushWithObstacles-v0``.
"""

from __future__ import annotations

from magwarp.envs.base import MagwarpVecEnv
from magwarp.envs.push import PushBoxEnv, PushEnv, PushLEnv, PushTEnv, PushXEnv
from magwarp.envs.push_obstacles import PushWithObstaclesEnv
from magwarp.envs.single import SingleEnv
from magwarp.envs.trajectory import TrajectoryPlanningEnv

__all__ = ["MagwarpVecEnv", "SingleEnv", "TrajectoryPlanningEnv", "PushEnv", "PushBoxEnv", "PushTEnv", "PushLEnv",
           "PushXEnv", "PushWithObstaclesEnv", "register_envs"]


def register_envs() -> None:
    """Register every magwarp env id with gymnasium (idempotent; runs on ``import magwarp``, see
    :mod:`magwarp.registration`: string entry points, so registering imports none of the envs)."""
    from magwarp.registration import register_envs as _register

    _register()


register_envs()
