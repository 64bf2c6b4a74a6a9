"""Large swarms: scalable placement, local observations and the swarm env (issue #18).

* :class:`Placer` (:mod:`magwarp.swarm.placement`): collision-free starts and goals for up to hundreds of thousands
  of movers per world, drawn on the device by parallel dart throwing;
* :class:`LocalObservations` (:mod:`magwarp.swarm.observations`): each mover's k nearest neighbours within a radius
  and its distances to the walls in a few directions, O(k) per mover;
* :class:`SwarmEnv` (:mod:`magwarp.swarm.env`): per-mover goals, rewards and collisions on any layout, and its
  multi-agent views (:mod:`magwarp.swarm.views`);
* :class:`SwarmPlanner` (:mod:`magwarp.swarm.planner`): a scripted ORCA planner on the local view, O(k) per mover,
  made provably collision-free by :class:`SafetyFilter` (:mod:`magwarp.swarm.safety`);
* :class:`SwarmResidualEnv` (:mod:`magwarp.swarm.residual`): the swarm env whose action is a per-mover correction
  to the planner's (``magwarp/SwarmResidual-v0``: residual RL, the shield on);
* :class:`SwarmMetrics` / :func:`run_policy` (:mod:`magwarp.swarm.metrics`): throughput, collisions per 1000 goals,
  deadlocked movers, makespan.
"""

from __future__ import annotations

import importlib

__all__ = ["Placer", "PlacementError", "LocalObservations", "SwarmEnv", "SwarmConfig", "FlatSwarmEnv",
           "SwarmTorchRLEnv", "SwarmParallelEnv", "SwarmPlanner", "SafetyFilter", "SwarmMetrics", "run_policy",
           "SwarmResidualEnv", "SwarmResidualConfig"]

_WHERE = {
    "Placer": "placement",
    "PlacementError": "placement",
    "LocalObservations": "observations",
    "SwarmEnv": "env",
    "SwarmConfig": "env",
    "FlatSwarmEnv": "views",
    "SwarmTorchRLEnv": "views",
    "SwarmParallelEnv": "views",
    "SwarmPlanner": "planner",
    "SafetyFilter": "safety",
    "SwarmMetrics": "metrics",
    "run_policy": "metrics",
    "SwarmResidualEnv": "residual",
    "SwarmResidualConfig": "residual",
}


def __getattr__(name: str):
    if name in _WHERE:
        return getattr(importlib.import_module(f"{__name__}.{_WHERE[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
