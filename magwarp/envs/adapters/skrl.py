"""An skrl (2.x, torch) env wrapper over a batched magwarp env, for skrl's agents and trainers::

    from skrl.trainers.torch import SequentialTrainer
    env = SkrlVecEnv("magwarp/TrajectoryPlanningB0-v0", num_envs=4096, device="cuda:0")
    agent = PPO(models=..., memory=RandomMemory(memory_size=16, num_envs=env.num_envs, device=env.device),
                observation_space=env.observation_space, action_space=env.action_space, device=env.device, cfg=...)
    SequentialTrainer(env=env, agents=agent, cfg={"timesteps": 100_000}).train()

It follows skrl's wrapper contract (``skrl.envs.wrappers.torch.Wrapper``) for vectorised, autoresetting envs, as its
Gymnasium and Isaac Lab wrappers do, with tensors on the env's device throughout:

* ``action_space`` is the single-env action space; observations are the goal-dict observation flattened as skrl
  flattens a ``Dict`` space (sorted keys: ``achieved_goal, desired_goal, observation``). ``observation_space`` is that
  flat ``Box`` (``obs_mode="flat"``, the default: skrl's model instantiators and ``"OBSERVATIONS"`` inputs take it as
  is), or the single-env ``Dict`` space itself (``obs_mode="dict"``), for models that call
  ``skrl.utils.spaces.torch.unflatten_tensorized_space(observation_space, obs)`` to get the dict back;
* ``reset()`` resets the envs on its first call only and afterwards returns the latest observation (finished envs are
  reset inside ``step``: the returned observation is the new episode's first one);
* ``step(actions)`` -> ``obs [N, D]``, ``reward [N, 1] float32``, ``terminated [N, 1] bool``, ``truncated [N, 1]
  bool``, ``info`` (the env's info dict). ``truncated`` marks episodes cut by a time limit and not terminated, which
  skrl's ``time_limit_bootstrap`` bootstraps (from the next observation, the new episode's first one, as with every
  same-step autoreset env in skrl). Actions go to the env unscaled (skrl's models clip to the action space when asked).
* ``state()`` is None (no separate critic state); ``render()`` is the env's.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import torch
from skrl import config
from skrl.envs.wrappers.torch import Wrapper
from skrl.utils.spaces.torch import flatten_tensorized_space

from magwarp.envs.adapters.common import resolve_env, time_outs
from magwarp.envs.base import MagwarpVecEnv

__all__ = ["SkrlVecEnv"]

OBS_MODES = ("flat", "dict")


class SkrlVecEnv(Wrapper):
    """skrl wrapper around a :class:`~magwarp.envs.MagwarpVecEnv` instance, or an env id / class with ``num_envs``
    and keyword arguments. The wrapped env must autoreset (the default). The first ``reset()`` seeds the env with
    skrl's seed (``skrl.config.torch.key``, set by ``skrl.utils.set_seed``)."""

    def __init__(self, env: MagwarpVecEnv | str | type, num_envs: int | None = None, *, obs_mode: str = "flat",
                 **env_kwargs):
        if obs_mode not in OBS_MODES:
            raise ValueError(f"obs_mode must be one of {OBS_MODES}, got {obs_mode!r}")
        env = resolve_env(env, num_envs, env_kwargs, "SkrlVecEnv")
        super().__init__(env)
        space = env.single_observation_space
        self.obs_mode = obs_mode
        if obs_mode == "flat" and isinstance(space, gym.spaces.Dict):  # in skrl's (sorted) key order
            space = gym.spaces.flatten_space(gym.spaces.Dict({k: space[k] for k in sorted(space.spaces)}))
        self._observation_space = space
        self._observations: torch.Tensor | None = None
        self._info: dict[str, Any] = {}

    @property
    def env(self) -> MagwarpVecEnv:
        return self._env

    @property
    def observation_space(self) -> gym.Space:
        return self._observation_space

    @property
    def action_space(self) -> gym.Space:
        return self._env.single_action_space

    def reset(self) -> tuple[torch.Tensor, dict[str, Any]]:
        if self._observations is None:
            obs, self._info = self._env.reset(seed=config.torch.key)
            self._observations = flatten_tensorized_space(obs)
        return self._observations, self._info

    def step(self, actions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, Any]:
        with torch.no_grad():
            obs, reward, terminated, truncated, self._info = self._env.step(actions)
        self._observations = flatten_tensorized_space(obs)
        return (self._observations, reward.view(-1, 1), terminated.view(-1, 1),
                time_outs(terminated, truncated).view(-1, 1), self._info)

    def state(self) -> torch.Tensor | None:
        return None

    def render(self, *args, **kwargs) -> Any:
        return self._env.render()

    def close(self) -> None:
        self._env.close()
