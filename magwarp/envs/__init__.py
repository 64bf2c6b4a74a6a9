"""Torch-native batched RL envs and their gymnasium registrations.

``gymnasium.make("magwarp/TrajectoryPlanning-v0")`` gives a single-env numpy view;
``gymnasium.make_vec("magwarp/TrajectoryPlanning-v0", num_envs=N)`` gives the batched torch env.
Benchmark variants: ``magwarp/TrajectoryPlanningB0-v0`` .. ``B9-v0``. Object pushing on mujoco-warp:
``magwarp/PushBox-v0``, ``PushT-v0``, ``PushL-v0``, ``PushX-v0`` (each with ``B0``..``B9`` variants) and
``magwarp/PushWithObstacles-v0``.
"""

from __future__ import annotations

import functools

import gymnasium as gym

from magwarp.envs.base import MagwarpVecEnv
from magwarp.envs.push import PUSH_BENCHMARKS, PushBoxEnv, PushEnv, PushLEnv, PushTEnv, PushWithObstaclesEnv, PushXEnv
from magwarp.envs.single import SingleEnv
from magwarp.envs.trajectory import TrajectoryPlanningEnv
from magwarp.layout import BENCHMARK_LAYOUTS

__all__ = ["MagwarpVecEnv", "SingleEnv", "TrajectoryPlanningEnv", "PushEnv", "PushBoxEnv", "PushTEnv", "PushLEnv",
           "PushXEnv", "PushWithObstaclesEnv", "register_envs"]


def _register(env_id: str, vec_cls, **defaults) -> None:
    if env_id in gym.registry:
        return
    gym.register(
        id=env_id,
        entry_point=functools.partial(SingleEnv, vec_cls, **defaults),
        vector_entry_point=functools.partial(vec_cls, **defaults),
        disable_env_checker=False,
    )


def register_envs() -> None:
    """Register every magwarp env id with gymnasium (idempotent; runs on ``import magwarp``)."""
    _register("magwarp/TrajectoryPlanning-v0", TrajectoryPlanningEnv)
    for name in BENCHMARK_LAYOUTS:
        _register(f"magwarp/TrajectoryPlanning{name}-v0", TrajectoryPlanningEnv, layout=name)
    for task, cls in (("PushBox", PushBoxEnv), ("PushT", PushTEnv), ("PushL", PushLEnv), ("PushX", PushXEnv)):
        _register(f"magwarp/{task}-v0", cls)
        for name in PUSH_BENCHMARKS:
            _register(f"magwarp/{task}{name}-v0", cls, benchmark=name)
    _register("magwarp/PushWithObstacles-v0", PushWithObstaclesEnv)


register_envs()
