"""A PettingZoo ``ParallelEnv`` with one agent per mover, over one world of a batched magwarp env (numpy in/out).

``MagwarpParallelEnv()`` is trajectory planning on B0 (3 agents ``mover_0`` .. ``mover_2``);
``MagwarpParallelEnv(CoopPushEnv)`` is cooperative pushing (per-agent view and shared reward of
:mod:`magwarp.envs.coop_push`; per-agent infos hold the world's ``is_success`` as ``goal_reached``). For trajectory
planning: Observations, actions
and rewards are those of :mod:`magwarp.envs.adapters.multiagent`: per-agent observation of own velocity (and
acceleration in jerk mode), own position, own goal, the other movers' relative positions and velocities; per-agent
action = the mover's x/y acceleration (jerk); shared team reward; all agents terminate (collision) or truncate
(timeout) together. ``state()`` gives the flat world state for centralised critics. Per-agent infos hold the world's
``mover_collision`` / ``wall_collision`` flags, the agent's own ``goal_reached`` flag and ``collected_goals`` count.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import torch
from pettingzoo import ParallelEnv

from magwarp.envs.adapters.multiagent import MultiAgentVecEnv
from magwarp.envs.base import MagwarpVecEnv

__all__ = ["MagwarpParallelEnv"]


def _np(x: torch.Tensor) -> np.ndarray:
    return x.detach().cpu().numpy()


def _check_multi_agent_env(env) -> None:
    """The adapter gives every mover its own agent: trajectory-planning envs (per-mover goals) and envs with their own
    per-agent view (``agent_observations``, e.g. cooperative pushing); other tasks are single-agent."""
    from magwarp.envs.adapters.multiagent import multi_agent_capable

    if not multi_agent_capable(env):
        cls = env if isinstance(env, type) else type(env)
        raise TypeError(f"MagwarpParallelEnv serves multi-agent envs (a TrajectoryPlanningEnv, or an env with "
                        f"agent_observations() such as CoopPushEnv: one agent per mover), got "
                        f"{getattr(cls, '__name__', cls)!r}; single-agent pushing envs are used through gymnasium or "
                        f"the SB3/TorchRL adapters")


class MagwarpParallelEnv(ParallelEnv):
    """PettingZoo parallel env. ``env``: a :class:`~magwarp.envs.MagwarpVecEnv` subclass (default
    :class:`~magwarp.envs.TrajectoryPlanningEnv`), constructed with ``num_envs=1``, ``autoreset=False`` and
    ``env_kwargs`` (e.g. ``layout="B3"``, ``learn_jerk=True``), or an instance built that way.
    ``obs_mode``: ``"flat"`` (a vector per agent) or ``"dict"`` (a goal dict per agent)."""

    metadata = {"name": "magwarp_trajectory_planning_v0", "render_modes": ["rgb_array"], "render_fps": 25,
                "is_parallelizable": True}

    def __init__(self, env: type[MagwarpVecEnv] | MagwarpVecEnv | None = None, *, obs_mode: str = "flat",
                 render_mode: str | None = None, **env_kwargs):
        if env is None:
            from magwarp.envs.trajectory import TrajectoryPlanningEnv

            env = TrajectoryPlanningEnv
        _check_multi_agent_env(env)
        if isinstance(env, type):
            env = env(num_envs=1, autoreset=False, render_mode=render_mode, **env_kwargs)
        elif env_kwargs:
            raise TypeError(f"env_kwargs {sorted(env_kwargs)} are only accepted with an env class, not an instance")
        if env.num_envs != 1 or env.autoreset:
            raise ValueError(f"MagwarpParallelEnv wraps one world without autoreset; got num_envs={env.num_envs}, "
                             f"autoreset={env.autoreset}")
        self.vec = env
        self.ma = MultiAgentVecEnv(env, obs_mode)
        name = "".join(f"_{c.lower()}" if c.isupper() else c for c in type(env).__name__.removesuffix("Env"))
        self.metadata = {**self.metadata, "name": f"magwarp{name}_v0"}
        self.render_mode = env.render_mode
        self.possible_agents = list(self.ma.agents)
        self.agents: list[str] = []
        self._index = {a: i for i, a in enumerate(self.possible_agents)}
        self._obs_spaces = {a: self.ma.single_agent_observation_space for a in self.possible_agents}
        self._act_spaces = {a: gym.spaces.Box(self.ma.single_agent_action_space.low, self.ma.single_agent_action_space.high,
                                              dtype=np.float32) for a in self.possible_agents}
        self.state_space = self.ma.state_space
        self._state = np.zeros(self.state_space.shape, np.float32)

    # spaces: the same object on every call (PettingZoo's API test requires it)
    def observation_space(self, agent: str) -> gym.Space:
        return self._obs_spaces[agent]

    def action_space(self, agent: str) -> gym.Space:
        return self._act_spaces[agent]

    def _split(self, obs) -> dict[str, Any]:
        if isinstance(obs, dict):
            arrays = {k: _np(v[0]) for k, v in obs.items()}
            return {a: {k: v[i] for k, v in arrays.items()} for a, i in self._index.items()}
        arr = _np(obs[0])
        return {a: arr[i] for a, i in self._index.items()}

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None):
        obs, info = self.ma.reset(seed=seed, options=options)
        self.agents = list(self.possible_agents)
        self._state = _np(info["state"][0])
        return self._split(obs), {a: {} for a in self.agents}

    def step(self, actions: dict[str, Any]):
        if not self.agents:
            raise RuntimeError("the episode is over (all agents are done): call reset() before step()")
        unknown = set(actions) - set(self.agents)
        if unknown:
            raise KeyError(f"actions for unknown or finished agents {sorted(unknown)}; live agents are {self.agents}")
        missing = [a for a in self.agents if a not in actions]
        if missing:
            raise KeyError(f"no action given for agents {missing}")
        dim = self.ma.action_dim
        batch = np.empty((1, len(self.possible_agents), dim), np.float32)
        for a, i in self._index.items():
            act = np.asarray(actions[a], dtype=np.float32)
            if act.shape != (dim,):
                raise ValueError(f"action of {a} must have shape ({dim},), got {act.shape}")
            batch[0, i] = act
        obs, reward, terminated, truncated, info = self.ma.step(torch.from_numpy(batch).to(self.vec.device))
        self._state = _np(info["state"][0])
        r, te, tr = float(reward[0, 0]), bool(terminated[0, 0]), bool(truncated[0, 0])
        mc, wc = bool(info["mover_collision"][0]), bool(info["wall_collision"][0])
        reached = (_np(info["goals_reached"][0]) if "goals_reached" in info else  # per-mover goals, or the world's
                   np.full(len(self._index), bool(info["is_success"][0])) if "is_success" in info else
                   np.zeros(len(self._index), bool))
        collected = _np(info["collected_goals"][0]) if "collected_goals" in info else np.zeros(len(self._index), int)
        agents = self.agents
        infos = {a: {"mover_collision": mc, "wall_collision": wc, "goal_reached": bool(reached[self._index[a]]),
                     "collected_goals": int(collected[self._index[a]])} for a in agents}
        per_agent = self._split(obs)
        out = ({a: per_agent[a] for a in agents}, {a: r for a in agents}, {a: te for a in agents},
               {a: tr for a in agents}, infos)
        if te or tr:
            self.agents = []
        return out

    def state(self) -> np.ndarray:
        return self._state.copy()

    def render(self):
        return self.vec.render()

    def close(self):
        self.vec.close()
