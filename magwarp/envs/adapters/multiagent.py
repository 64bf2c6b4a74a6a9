"""A batched, torch-native multi-agent view of a magwarp env: one agent per mover.

Two kinds of env have one: trajectory-planning-like envs (per-mover goals; :class:`AgentObservations` below) and envs
that define their own per-agent view through a method ``agent_observations(obs_mode)`` returning an object with
``num_movers``, ``action_dim``, ``spaces()`` and ``__call__(obs, state)`` (e.g.
:class:`~magwarp.envs.coop_push.CoopPushEnv`, whose agents share one object and goal). :func:`make_agent_view` picks.
The rest of this docstring describes the trajectory-planning view.

The per-agent observations are gathered from the env's goal-dict observation with a few batched tensor ops (no loop
over envs or movers), so the same code serves the PettingZoo adapter (one world, numpy) and the TorchRL multi-agent
group (thousands of worlds, on the device).

Per-agent observation of mover ``i`` (``obs_mode="flat"``, a ``float32`` vector)::

    [ v_i (2), a_i (2, jerk mode only), p_i (2), g_i (2),
      p_j - p_i for every other mover j in index order (2 (M-1)),
      v_j        for every other mover j in index order (2 (M-1)) ]

with ``v`` velocities, ``a`` accelerations, ``p`` positions and ``g`` goals, all x/y in the layout frame (m, m/s,
m/s²). ``obs_mode="dict"`` gives a per-agent goal dict instead, ready for per-agent hindsight relabelling:
``observation`` = ``[v_i, (a_i), p_j - p_i ..., v_j ...]``, ``achieved_goal`` = ``p_i``, ``desired_goal`` = ``g_i``.

Per-agent action: mover ``i``'s x/y acceleration (or jerk) command, shape ``(2,)``. Rewards are *shared*: every
agent gets the task's reward for the world (MagBotSim's trajectory planning reward is a team reward); termination
and truncation are per world and so the same for every agent of a world.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import torch

__all__ = ["AgentObservations", "MultiAgentVecEnv", "agent_names", "make_agent_view"]

OBS_MODES = ("flat", "dict")


def agent_names(num_movers: int) -> list[str]:
    return [f"mover_{i}" for i in range(num_movers)]


def _check_task(env) -> tuple[int, bool]:
    """The mover count and jerk flag of ``env``, after checking it has the trajectory-planning observation layout."""
    m = getattr(env, "num_movers", None)
    if not isinstance(m, int) or m < 1:
        raise TypeError(f"a multi-agent view needs an env with an integer num_movers, got {type(env).__name__} "
                        f"with num_movers={m!r}")
    jerk = bool(getattr(env, "learn_jerk", False))
    space = env.single_observation_space
    keys = ("observation", "achieved_goal", "desired_goal")
    if not isinstance(space, gym.spaces.Dict) or any(k not in space.spaces for k in keys):
        raise TypeError(f"a multi-agent view needs goal-dict observations {keys}, got {space}")
    want = {"observation": (m * 2 * (2 if jerk else 1),), "achieved_goal": (m * 2,), "desired_goal": (m * 2,)}
    for k, shape in want.items():
        if space[k].shape != shape:
            raise TypeError(f"observation {k!r} must have shape {shape} for {m} movers, got {space[k].shape}")
    if env.single_action_space.shape != (m * 2,):
        raise TypeError(f"the action space must have shape ({m * 2},) (x/y per mover), got {env.single_action_space.shape}")
    return m, jerk


def multi_agent_capable(env) -> bool:
    """Does ``env`` (an instance or a class) have a multi-agent view (trajectory planning, or its own)?"""
    from magwarp.envs.trajectory import TrajectoryPlanningEnv

    cls = env if isinstance(env, type) else type(env)
    return isinstance(cls, type) and (issubclass(cls, TrajectoryPlanningEnv) or
                                      callable(getattr(cls, "agent_observations", None)))


def make_agent_view(env, obs_mode: str = "flat"):
    """The per-agent observation view of ``env``: its own (``env.agent_observations(obs_mode)``) where it defines
    one, else :class:`AgentObservations` after checking the trajectory-planning observation layout."""
    if obs_mode not in OBS_MODES:
        raise ValueError(f"obs_mode must be one of {OBS_MODES}, got {obs_mode!r}")
    hook = getattr(env, "agent_observations", None)
    if callable(hook):
        view = hook(obs_mode)
        m = env.num_movers
        if env.single_action_space.shape != (m * view.action_dim,):
            raise TypeError(f"the action space must have shape ({m * view.action_dim},) ({view.action_dim} per mover), "
                            f"got {env.single_action_space.shape}")
        return view
    m, jerk = _check_task(env)
    return AgentObservations(m, jerk, obs_mode, env.device)


class AgentObservations:
    """Splits batched goal-dict observations ``[..., ...]`` into per-mover observations ``[..., M, D]``.

    Every per-agent feature is one column of the flat world state ``[observation, achieved_goal, desired_goal]`` (or
    a difference of two, for relative positions), so the split is two gathers and a subtraction whatever the mover
    count: no loop over envs or movers, no chain of small ops.
    """

    def __init__(self, num_movers: int, learn_jerk: bool, obs_mode: str = "flat", device=None):
        if obs_mode not in OBS_MODES:
            raise ValueError(f"obs_mode must be one of {OBS_MODES}, got {obs_mode!r}")
        self.num_movers = m = int(num_movers)
        self.learn_jerk = bool(learn_jerk)
        self.obs_mode = obs_mode
        self.action_dim = 2  # x/y per mover
        o = 2 * m * (2 if learn_jerk else 1)  # width of "observation"
        zero = o + 4 * m  # index of an appended zero column

        def xy(base: int, k: int) -> list[int]:
            return [base + 2 * k, base + 2 * k + 1]

        rows_obs, rows_sub, rows_pos, rows_goal = [], [], [], []
        for i in range(m):
            others = [j for j in range(m) if j != i]
            own = xy(0, i) + (xy(2 * m, i) if learn_jerk else [])
            rel = sum((xy(o, j) for j in others), [])
            vel = sum((xy(0, j) for j in others), [])
            head = own + (xy(o, i) + xy(o + 2 * m, i) if obs_mode == "flat" else [])
            rows_obs.append(head + rel + vel)
            rows_sub.append([zero] * len(head) + xy(o, i) * (m - 1) + [zero] * len(vel))
            rows_pos.append(xy(o, i))
            rows_goal.append(xy(o + 2 * m, i))
        self._idx = torch.tensor(rows_obs, device=device)  # (M, D)
        self._sub = torch.tensor(rows_sub, device=device)
        self._pos = torch.tensor(rows_pos, device=device)  # (M, 2)
        self._goal = torch.tensor(rows_goal, device=device)
        own = 4 if learn_jerk else 2
        self.dim_flat = own + 4 + 4 * (m - 1)
        self.dim_dict_obs = own + 4 * (m - 1)

    def spaces(self) -> gym.Space:
        """The observation space of one agent."""
        if self.obs_mode == "flat":
            return gym.spaces.Box(-np.inf, np.inf, (self.dim_flat,), np.float32)
        return gym.spaces.Dict({
            "observation": gym.spaces.Box(-np.inf, np.inf, (self.dim_dict_obs,), np.float32),
            "achieved_goal": gym.spaces.Box(-np.inf, np.inf, (2,), np.float32),
            "desired_goal": gym.spaces.Box(-np.inf, np.inf, (2,), np.float32),
        })

    def __call__(self, obs: dict[str, torch.Tensor], state: torch.Tensor | None = None):
        """Per-agent observations from a goal-dict observation (``state``: its :func:`global_state`, if at hand)."""
        state = global_state(obs) if state is None else state
        ext = torch.cat([state, state.new_zeros(*state.shape[:-1], 1)], dim=-1)
        dev = ext.device
        if self._idx.device != dev:
            self._idx, self._sub, self._pos, self._goal = (t.to(dev) for t in (self._idx, self._sub, self._pos, self._goal))
        lead = ext.shape[:-1]

        def take(index: torch.Tensor) -> torch.Tensor:  # index_select: much faster than advanced indexing on CPU
            return torch.index_select(ext, -1, index.reshape(-1)).view(*lead, *index.shape)

        out = take(self._idx) - take(self._sub)  # (..., M, D)
        if self.obs_mode == "flat":
            return out
        return {"observation": out, "achieved_goal": take(self._pos), "desired_goal": take(self._goal)}


def global_state(obs: dict[str, torch.Tensor]) -> torch.Tensor:
    """The flat world state ``[observation, achieved_goal, desired_goal]`` (for centralised critics)."""
    return torch.cat([obs["observation"], obs["achieved_goal"], obs["desired_goal"]], dim=-1)


class MultiAgentVecEnv:
    """Batched multi-agent view of ``env`` (a :class:`~magwarp.envs.MagwarpVecEnv` with the trajectory-planning
    observation layout, e.g. :class:`~magwarp.envs.TrajectoryPlanningEnv`, or one with its own
    ``agent_observations``, see :func:`make_agent_view`); torch in and out, on the env's device.

    * ``reset(seed=None, options=None)`` -> ``obs, info``;
    * ``step(actions)`` with ``actions`` ``[num_envs, num_movers, A]`` (``A = action_dim``, 2: x/y) -> ``obs, reward,
      terminated, truncated, info``
      where ``obs`` is ``[num_envs, num_movers, D]`` (or a dict of such tensors), ``reward``, ``terminated`` and
      ``truncated`` are ``[num_envs, num_movers]`` (shared within a world) and ``info`` is the env's info, plus
      ``info["state"]`` ``[num_envs, S]`` (the flat world state). With the env's autoreset on, ``info["final_obs"]``
      holds the per-agent final observations of finished worlds.
    """

    def __init__(self, env, obs_mode: str = "flat"):
        self.env = env
        self.num_envs = env.num_envs
        self.device = env.device
        self.split = make_agent_view(env, obs_mode)
        self.num_movers, self.action_dim = self.split.num_movers, self.split.action_dim
        self.learn_jerk = bool(getattr(env, "learn_jerk", False))
        self.agents = agent_names(self.num_movers)
        self.single_agent_observation_space = self.split.spaces()
        high = np.asarray(env.single_action_space.high, np.float32).reshape(self.num_movers, self.action_dim)[0]
        self.single_agent_action_space = gym.spaces.Box(-high, high, dtype=np.float32)
        s_dim = sum(int(np.prod(env.single_observation_space[k].shape)) for k in ("observation", "achieved_goal", "desired_goal"))
        self.state_space = gym.spaces.Box(-np.inf, np.inf, (s_dim,), np.float32)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        info = dict(info)
        info["state"] = state = global_state(obs)
        return self.split(obs, state), info

    def step(self, actions):
        n, m, a = self.num_envs, self.num_movers, self.action_dim
        if isinstance(actions, np.ndarray):
            actions = torch.from_numpy(actions)
        if not isinstance(actions, torch.Tensor):
            raise TypeError(f"actions must be a torch tensor or numpy array, got {type(actions).__name__}")
        if tuple(actions.shape) != (n, m, a):
            raise ValueError(f"actions must have shape ({n}, {m}, {a}) (env, mover, action), "
                             f"got {tuple(actions.shape)}")
        obs, reward, terminated, truncated, info = self.env.step(actions.reshape(n, a * m))
        info["state"] = state = global_state(obs)
        if "final_obs" in info:
            info["final_obs"] = self.split(info["final_obs"])
        shape = (n, m)
        return (self.split(obs, state), reward[:, None].expand(shape), terminated[:, None].expand(shape),
                truncated[:, None].expand(shape), info)

    def render(self):
        return self.env.render()

    def close(self):
        self.env.close()
