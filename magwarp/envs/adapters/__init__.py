"""Adapters from magwarp's batched torch envs to other RL libraries. Each is a thin module, imported on first use,
so that a missing optional library only fails when its adapter is asked for:

* :class:`MultiAgentVecEnv` (``multiagent``): a batched, torch-native multi-agent view, one agent per mover;
* :class:`MagwarpParallelEnv` (``pettingzoo``): a PettingZoo ``ParallelEnv`` over one world, numpy in and out;
* :class:`SB3VecEnv` (``sb3``): a Stable-Baselines3 ``VecEnv`` (extra ``stable-baselines3``), HER-ready;
* :class:`TorchRLEnv` (``torchrl``): a TorchRL ``EnvBase`` with ``batch_size=[num_envs]`` (extras ``torchrl``,
  ``tensordict``), single- or multi-agent;
* :class:`RslRlVecEnv` (``rsl_rl``): an rsl_rl ``VecEnv`` for its ``OnPolicyRunner`` (extra ``rsl_rl``);
* :class:`SkrlVecEnv` (``skrl``): an skrl torch env wrapper for its agents and trainers (extra ``skrl``).
"""

from __future__ import annotations

import importlib

__all__ = ["AgentObservations", "MultiAgentVecEnv", "MagwarpParallelEnv", "SB3VecEnv", "TorchRLEnv", "RslRlVecEnv",
           "SkrlVecEnv"]

_WHERE = {
    "AgentObservations": "multiagent",
    "MultiAgentVecEnv": "multiagent",
    "MagwarpParallelEnv": "pettingzoo",
    "SB3VecEnv": "sb3",
    "TorchRLEnv": "torchrl",
    "RslRlVecEnv": "rsl_rl",
    "SkrlVecEnv": "skrl",
}


def __getattr__(name: str):
    if name in _WHERE:
        return getattr(importlib.import_module(f"{__name__}.{_WHERE[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + list(_WHERE))
