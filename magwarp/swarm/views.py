"""Multi-agent views of :class:`~magwarp.swarm.SwarmEnv` that keep its scale (no loop over movers):

* :class:`FlatSwarmEnv` — a gymnasium ``VectorEnv`` with one sub-env per mover (``num_envs * num_movers`` of them),
  for parameter-shared training with any single-agent vectorised learner: observations ``[N * M, D]``, actions
  ``[N * M, 2]``, per-mover rewards and terminations;
* :class:`SwarmTorchRLEnv` — a TorchRL ``EnvBase`` with ``batch_size=[num_envs]`` and the movers as the
  ``"agents"`` group (as TorchRL's MARL envs lay it out);
* :class:`SwarmParallelEnv` — a PettingZoo ``ParallelEnv`` over one world, one agent per mover (numpy in and out).

Episode ends. A mover that collides in ``"respawn"`` mode ends *its* episode (it is terminated and re-placed, its
next observation is its new start): the flat view reports it as a terminated sub-env (no final observation is
kept for it: a terminal state is not bootstrapped). A world that ends (``"end"`` mode collisions, or
``max_episode_steps``) ends every mover's episode; the flat view then carries the movers' last observations in
``info["final_obs"]`` where ``info["_final_obs"]``. TorchRL and PettingZoo see world-level ends only (their agents
persist through respawns: the collision shows in the agent's reward and in ``("agents", "collided")`` / the agent's
info).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import torch
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from magwarp.swarm.env import SwarmEnv

__all__ = ["FlatSwarmEnv", "SwarmTorchRLEnv", "SwarmParallelEnv"]

#: per-mover info entries the flat view flattens to ``[N * M]``
AGENT_INFO = ("agent_reward", "agent_terminated", "goal_reached", "mover_collision", "wall_collision",
              "collected_goals", "respawn_pending", "shield_active", "shield_delta")


def _agent_space(env: SwarmEnv) -> tuple[gym.spaces.Box, gym.spaces.Box]:
    obs, act = env.single_observation_space, env.single_action_space
    return (gym.spaces.Box(-np.inf, np.inf, obs.shape[1:], np.float32),
            gym.spaces.Box(act.low[0], act.high[0], act.shape[1:], np.float32))


def _make(env: SwarmEnv | None, num_envs: int, autoreset: bool, kwargs: dict) -> SwarmEnv:
    if env is None:
        return SwarmEnv(num_envs, autoreset=autoreset, **kwargs)
    if kwargs:
        raise TypeError(f"options {sorted(kwargs)} are only accepted without an env instance")
    if not isinstance(env, SwarmEnv):
        raise TypeError(f"expected a SwarmEnv, got {type(env).__name__}")
    return env


class FlatSwarmEnv(VectorEnv):
    """Parameter-shared view: every mover of every world is one sub-env. ``FlatSwarmEnv(env)`` or
    ``FlatSwarmEnv(num_envs=N, **SwarmEnv options)``."""

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    def __init__(self, env: SwarmEnv | None = None, *, num_envs: int = 1, **kwargs):
        self.env = _make(env, num_envs, True, kwargs)
        self.num_worlds, self.num_movers = self.env.num_envs, self.env.num_movers
        self.num_envs = self.num_worlds * self.num_movers
        self.device = self.env.device
        self.single_observation_space, self.single_action_space = _agent_space(self.env)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        return obs.reshape(self.num_envs, -1), info

    def step(self, action):
        n, m = self.num_worlds, self.num_movers
        if isinstance(action, np.ndarray):
            action = torch.from_numpy(action).to(self.device)
        if not isinstance(action, torch.Tensor) or tuple(action.shape) != (n * m, 2):
            raise ValueError(f"action must be a tensor of shape ({n * m}, 2) (one row per mover), got "
                             f"{tuple(getattr(action, 'shape', ()))}")
        obs, _, terminated, truncated, info = self.env.step(action.reshape(n, m, 2))
        world_term = terminated[:, None].expand(n, m)
        world_trunc = truncated[:, None].expand(n, m)
        agent_term = info["agent_terminated"] | world_term
        out_info = {k: info[k].reshape(-1) for k in AGENT_INFO if k in info}
        if "final_obs" in info:
            out_info["final_obs"] = info["final_obs"].reshape(n * m, -1)
            out_info["_final_obs"] = (world_term | world_trunc).reshape(-1)
        else:  # worlds that never end: no final observation is needed (truncated is never set)
            out_info["final_obs"] = obs.reshape(n * m, -1)
            out_info["_final_obs"] = torch.zeros(n * m, dtype=torch.bool, device=self.device)
        # training statistics (magwarp.training's SuccessTracker): goals reached per mover, and the ends that are
        # only a world's time limit (not a lost goal)
        out_info["goals_reached"] = info["goal_reached"].reshape(n * m, 1)
        out_info["time_limit"] = (world_trunc & ~agent_term).reshape(-1)
        return (obs.reshape(n * m, -1), info["agent_reward"].reshape(-1), agent_term.reshape(-1),
                (world_trunc & ~agent_term).reshape(-1), out_info)

    @property
    def num_cycles(self) -> int:
        return self.env.num_cycles

    def close_extras(self, **kwargs):
        self.env.close()


def _torchrl_class():
    """Built on first use, so that importing this module needs neither torchrl nor tensordict."""
    from tensordict import TensorDict
    from torchrl.data import Bounded, Categorical, Composite, Unbounded
    from torchrl.envs import EnvBase

    class SwarmTorchRLEnv(EnvBase):
        """TorchRL env over a :class:`SwarmEnv` (``autoreset`` off: TorchRL resets worlds itself through
        ``"_reset"``): ``("agents", "observation")`` ``[N, M, D]``, ``("agents", "action")`` ``[N, M, 2]``,
        ``("agents", "reward")`` ``[N, M, 1]``, ``("agents", "collided")`` ``[N, M, 1]`` and world-level
        ``done`` / ``terminated`` / ``truncated`` ``[N, 1]``."""

        def __init__(self, env: SwarmEnv | None = None, *, num_envs: int = 1, **kwargs):
            env = _make(env, num_envs, False, kwargs)
            env.autoreset = False
            super().__init__(device=env.device, batch_size=torch.Size([env.num_envs]))
            self.env = env
            n, m, dev = env.num_envs, env.num_movers, env.device
            obs_space, act_space = _agent_space(env)
            group = (n, m)
            self.observation_spec = Composite({
                "agents": Composite({
                    "observation": Unbounded((n, m, *obs_space.shape), device=dev),
                    "collided": Categorical(2, shape=(n, m, 1), dtype=torch.bool, device=dev),
                }, shape=group, device=dev)}, shape=(n,), device=dev)
            high = float(act_space.high[0])
            self.action_spec = Composite({"agents": Composite({"action": Bounded(
                low=-high, high=high, shape=(n, m, 2), dtype=torch.float32, device=dev)}, shape=group, device=dev)},
                shape=(n,), device=dev)
            self.reward_spec = Composite({"agents": Composite({"reward": Unbounded((n, m, 1), device=dev)},
                                                              shape=group, device=dev)}, shape=(n,), device=dev)
            flag = Categorical(2, shape=(n, 1), dtype=torch.bool, device=dev)
            self.done_spec = Composite({"done": flag, "terminated": flag.clone(), "truncated": flag.clone()},
                                       shape=(n,), device=dev)

        def _agents(self, obs: torch.Tensor, collided: torch.Tensor) -> TensorDict:
            n, m = self.env.num_envs, self.env.num_movers
            return TensorDict({"observation": obs, "collided": collided[..., None]}, batch_size=(n, m),
                              device=self.device)

        def _reset(self, tensordict=None, **kwargs):
            n, m = self.env.num_envs, self.env.num_movers
            mask = None if tensordict is None else tensordict.get("_reset", None)
            if mask is not None:
                obs, _ = self.env.reset(options={"reset_mask": mask.reshape(n).to(torch.bool)})
            else:
                obs, _ = self.env.reset()
            done = torch.zeros(n, 1, dtype=torch.bool, device=self.device)
            collided = torch.zeros(n, m, dtype=torch.bool, device=self.device)
            return TensorDict({"agents": self._agents(obs, collided), "done": done, "terminated": done.clone(),
                               "truncated": done.clone()}, batch_size=self.batch_size, device=self.device)

        def _step(self, tensordict):
            obs, _, terminated, truncated, info = self.env.step(tensordict.get(("agents", "action")))
            agents = self._agents(obs, info["agent_terminated"])
            agents.set("reward", info["agent_reward"][..., None])
            terminated, truncated = terminated[:, None], truncated[:, None]
            return TensorDict({"agents": agents, "done": terminated | truncated, "terminated": terminated,
                               "truncated": truncated}, batch_size=self.batch_size, device=self.device)

        def _set_seed(self, seed: int | None) -> None:
            if seed is not None:
                self.env.reset(seed=int(seed))

    return SwarmTorchRLEnv


def _pettingzoo_class():
    from pettingzoo import ParallelEnv

    class SwarmParallelEnv(ParallelEnv):
        """PettingZoo parallel env over one world of a :class:`SwarmEnv` (agents ``mover_0`` ..). Per agent: the
        mover's observation row, its reward, and info ``collided`` / ``goal_reached`` / ``collected_goals``. All
        agents end together, when the world does."""

        metadata = {"name": "magwarp_swarm_v0", "render_modes": [], "is_parallelizable": True}

        def __init__(self, env: SwarmEnv | None = None, **kwargs):
            self.vec = _make(env, 1, False, kwargs)
            if self.vec.num_envs != 1 or self.vec.autoreset:
                raise ValueError(f"SwarmParallelEnv wraps one world without autoreset; got num_envs="
                                 f"{self.vec.num_envs}, autoreset={self.vec.autoreset}")
            self.render_mode = None
            self.possible_agents = [f"mover_{i}" for i in range(self.vec.num_movers)]
            self.agents: list[str] = []
            obs_space, act_space = _agent_space(self.vec)
            self._obs_spaces = {a: obs_space for a in self.possible_agents}
            self._act_spaces = {a: gym.spaces.Box(act_space.low, act_space.high, dtype=np.float32)
                                for a in self.possible_agents}

        def observation_space(self, agent: str) -> gym.Space:
            return self._obs_spaces[agent]

        def action_space(self, agent: str) -> gym.Space:
            return self._act_spaces[agent]

        def _split(self, obs: torch.Tensor) -> dict[str, np.ndarray]:
            arr = obs[0].cpu().numpy()
            return {a: arr[i] for i, a in enumerate(self.possible_agents)}

        def reset(self, seed: int | None = None, options: dict[str, Any] | None = None):
            obs, _ = self.vec.reset(seed=seed, options=options)
            self.agents = list(self.possible_agents)
            return self._split(obs), {a: {} for a in self.agents}

        def step(self, actions: dict[str, Any]):
            if not self.agents:
                raise RuntimeError("the episode is over: call reset() before step()")
            missing = [a for a in self.agents if a not in actions]
            unknown = sorted(set(actions) - set(self.agents))
            if missing or unknown:
                raise KeyError(f"actions needed for exactly the live agents; missing {missing}, unknown {unknown}")
            batch = np.stack([np.asarray(actions[a], dtype=np.float32).reshape(2) for a in self.possible_agents])
            obs, _, terminated, truncated, info = self.vec.step(torch.from_numpy(batch[None]).to(self.vec.device))
            rew = info["agent_reward"][0].cpu().numpy()
            col = info["agent_terminated"][0].cpu().numpy()
            reached = info["goal_reached"][0].cpu().numpy()
            goals = info["collected_goals"][0].cpu().numpy()
            te, tr = bool(terminated[0]), bool(truncated[0])
            agents = self.agents
            idx = {a: i for i, a in enumerate(self.possible_agents)}
            infos = {a: {"collided": bool(col[idx[a]]), "goal_reached": bool(reached[idx[a]]),
                         "collected_goals": int(goals[idx[a]])} for a in agents}
            per = self._split(obs)
            out = ({a: per[a] for a in agents}, {a: float(rew[idx[a]]) for a in agents}, {a: te for a in agents},
                   {a: tr for a in agents}, infos)
            if te or tr:
                self.agents = []
            return out

        def render(self):
            return None

        def close(self):
            self.vec.close()

    return SwarmParallelEnv


def __getattr__(name: str):
    if name == "SwarmTorchRLEnv":
        cls = _torchrl_class()
    elif name == "SwarmParallelEnv":
        cls = _pettingzoo_class()
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = cls
    return cls
