"""Torch-native batched RL envs and their gymnasium registrations.

``gymnasium.make("magwarp/TrajectoryPlanning-v0")`` gives a single-env numpy view;
``gymnasium.make_vec("magwarp/TrajectoryPlanning-v0", num_envs=N)`` gives the batched torch env.
Benchmark variants: ``magwarp/TrajectoryPlanningB0-v0`` .. ``B9-v0``. Object pushing on mujoco-warp:
``magwarp/PushBox-v0``, ``PushT-v0``, ``PushL-v0``, ``PushX-v0`` (each with ``B0``..``B9`` variants) and
``magwarp/PushWithObstacles-v0``.

Every env's options are one typed, frozen config dataclass (:mod:`magwarp.envs.config`): ``TrajectoryConfig``,
``PushConfig`` (and its task subclasses), ``magwarp.envs.levitation_config.LevitationConfig``,
``magwarp.swarm.SwarmConfig`` and the MagBot configs; give a config, its fields as keywords, or both.
"""

from __future__ import annotations

from magwarp.envs.base import MagwarpVecEnv
from magwarp.envs.config import resolve_config
from magwarp.envs.push import PushBoxEnv, PushEnv, PushLEnv, PushTEnv, PushXEnv
from magwarp.envs.push_config import PushConfig
from magwarp.envs.push_obstacles import PushWithObstaclesEnv
from magwarp.envs.single import SingleEnv
from magwarp.envs.trajectory import TrajectoryPlanningEnv
from magwarp.envs.trajectory_config import TrajectoryConfig

__all__ = ["MagwarpVecEnv", "SingleEnv", "TrajectoryPlanningEnv", "TrajectoryConfig", "PushEnv", "PushConfig",
           "PushBoxEnv", "PushTEnv", "PushLEnv", "PushXEnv", "PushWithObstaclesEnv", "resolve_config", "register_envs"]


def register_envs() -> None:
    """Register every magwarp env id with gymnasium (idempotent; runs on ``import magwarp``, see
    :mod:`magwarp.registration`: string entry points, so registering imports none of the envs)."""
    from magwarp.registration import register_envs as _register

    _register()


register_envs()
