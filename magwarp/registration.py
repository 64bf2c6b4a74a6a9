"""Gymnasium registrations of the magwarp env ids, without importing the envs (only ``gymnasium``).

Each id is registered with *string* entry points and its defaults as ``kwargs``:

* ``vector_entry_point`` ``"magwarp.envs.push:PushTEnv"`` (what ``gymnasium.make_vec`` builds, ``num_envs=N``);
* ``entry_point`` ``"magwarp.registration:single_PushTEnv"`` (what ``gymnasium.make`` builds: the single-env numpy
  view :class:`magwarp.envs.single.SingleEnv` around one world of the batched class).

So ``import magwarp`` registers every id in a few milliseconds and torch, warp and mujoco-warp are imported only
when an env is made. String entry points also keep the specs picklable (``AsyncVectorEnv``).
"""

from __future__ import annotations

import importlib

__all__ = ["ENV_CLASSES", "TRAJECTORY_BENCHMARKS", "PUSH_BENCHMARKS", "env_ids", "register_envs"]

# Batched env classes by name -> module that defines them.
ENV_CLASSES = {
    "TrajectoryPlanningEnv": "magwarp.envs.trajectory",
    "PushBoxEnv": "magwarp.envs.push",
    "PushTEnv": "magwarp.envs.push",
    "PushLEnv": "magwarp.envs.push",
    "PushXEnv": "magwarp.envs.push",
    "PushWithObstaclesEnv": "magwarp.envs.push_obstacles",
    "SwarmEnv": "magwarp.swarm.env",
    "SwarmResidualEnv": "magwarp.swarm.residual",
    "PlatformPoseEnv": "magwarp.envs.platform_pose",
    "CoopPushEnv": "magwarp.envs.coop_push",
    "CoopPushResidualEnv": "magwarp.envs.coop_push_residual",
    "LevitationEnv": "magwarp.envs.levitation",
    "LevitationResidualEnv": "magwarp.envs.levitation_residual",
    # MagBots (issue 19): pick and place with the 6D platform and with the gripper
    "PlatformPickPlaceEnv": "magwarp.envs.platform_pick_place",
    "GripperPickPlaceEnv": "magwarp.envs.gripper_pick_place",
}
# Benchmark variants (names only; their layouts live in magwarp.layout.BENCHMARK_LAYOUTS and magwarp.envs.push).
TRAJECTORY_BENCHMARKS = tuple(f"B{i}" for i in range(10))
PUSH_BENCHMARKS = tuple(f"B{i}" for i in range(10))


def _load(cls_name: str):
    return getattr(importlib.import_module(ENV_CLASSES[cls_name]), cls_name)


def _single_factory(cls_name: str):
    def make(**kwargs):
        from magwarp.envs.single import SingleEnv

        return SingleEnv(_load(cls_name), **kwargs)

    make.__name__ = make.__qualname__ = f"single_{cls_name}"
    make.__doc__ = f"Single-env numpy view of one world of :class:`{ENV_CLASSES[cls_name]}.{cls_name}`."
    return make


# entry points of gymnasium.make: single_TrajectoryPlanningEnv, single_PushBoxEnv, ...
for _name in ENV_CLASSES:
    globals()[f"single_{_name}"] = _single_factory(_name)
del _name


def env_ids() -> dict[str, tuple[str, dict]]:
    """Every magwarp env id -> (batched class name, default kwargs)."""
    ids: dict[str, tuple[str, dict]] = {"magwarp/TrajectoryPlanning-v0": ("TrajectoryPlanningEnv", {})}
    for name in TRAJECTORY_BENCHMARKS:
        ids[f"magwarp/TrajectoryPlanning{name}-v0"] = ("TrajectoryPlanningEnv", {"layout": name})
    for task in ("PushBox", "PushT", "PushL", "PushX"):
        ids[f"magwarp/{task}-v0"] = (f"{task}Env", {})
        for name in PUSH_BENCHMARKS:
            ids[f"magwarp/{task}{name}-v0"] = (f"{task}Env", {"benchmark": name})
    ids["magwarp/PushWithObstacles-v0"] = ("PushWithObstaclesEnv", {})
    ids["magwarp/Swarm-v0"] = ("SwarmEnv", {})
    ids["magwarp/SwarmMaterialFlow-v0"] = ("SwarmEnv", {"stations": "auto"})
    ids["magwarp/SwarmResidual-v0"] = ("SwarmResidualEnv", {})
    ids["magwarp/PlatformPose-v0"] = ("PlatformPoseEnv", {})
    ids["magwarp/CoopPush-v0"] = ("CoopPushEnv", {})
    ids["magwarp/CoopPushResidual-v0"] = ("CoopPushResidualEnv", {})
    ids["magwarp/Levitation-v0"] = ("LevitationEnv", {})
    ids["magwarp/LevitationHover-v0"] = ("LevitationEnv", {"task": "hover"})
    ids["magwarp/LevitationWrench-v0"] = ("LevitationEnv", {"action": "wrench"})
    ids["magwarp/LevitationLiftoff-v0"] = ("LevitationEnv", {"task": "liftoff"})
    ids["magwarp/LevitationTrack-v0"] = ("LevitationEnv", {"task": "track"})
    ids["magwarp/LevitationMove-v0"] = ("LevitationEnv", {"task": "move", "max_episode_steps": 600})
    ids["magwarp/LevitationPayload-v0"] = ("LevitationEnv", {"task": "payload"})
    ids["magwarp/LevitationPendulum-v0"] = ("LevitationEnv", {"task": "pendulum"})
    ids["magwarp/LevitationResidual-v0"] = ("LevitationResidualEnv", {})
    ids["magwarp/PlatformPickPlace-v0"] = ("PlatformPickPlaceEnv", {})
    ids["magwarp/GripperPickPlace-v0"] = ("GripperPickPlaceEnv", {})
    return ids


def register_envs() -> None:
    """Register every magwarp env id with gymnasium (idempotent; runs on ``import magwarp``)."""
    import gymnasium as gym

    for env_id, (cls_name, defaults) in env_ids().items():
        if env_id in gym.registry:
            continue
        gym.register(
            id=env_id,
            entry_point=f"magwarp.registration:single_{cls_name}",
            vector_entry_point=f"{ENV_CLASSES[cls_name]}:{cls_name}",
            kwargs=dict(defaults),
            disable_env_checker=False,
        )
