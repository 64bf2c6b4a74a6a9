"""An rsl_rl ``VecEnv`` (rsl-rl-lib 5.x) over a batched magwarp env, so that ``rsl_rl.runners.OnPolicyRunner`` trains
it unchanged (Isaac Lab's and mjlab's workflow)::

    from rsl_rl.runners import OnPolicyRunner
    env = RslRlVecEnv("magwarp/TrajectoryPlanningB0-v0", num_envs=4096, device="cuda:0")
    OnPolicyRunner(env, train_cfg, log_dir="runs/b0", device="cuda:0").learn(1500)

The contract of rsl-rl-lib 5.5 (``rsl_rl.env.VecEnv``), all tensors on the env's device:

* ``get_observations()`` and the first item of ``step`` are a ``TensorDict`` of observation groups, batch size
  ``[num_envs]``. ``obs_mode="flat"`` (default): one group ``"policy"``, the goal-dict observation flattened in
  sorted key order ``achieved_goal, desired_goal, observation`` (the layout of :func:`magwarp.training.flatten_obs`,
  ``magwarp eval`` and exported policies); rsl_rl's default ``obs_groups`` resolution feeds it to actor and critic.
  ``obs_mode="dict"``: one group per observation key, for ``obs_groups`` such as
  ``{"actor": ["observation", "desired_goal", "achieved_goal"], "critic": [...]}``.
* ``step(actions)`` -> ``obs, rewards [N] float32, dones [N] long, extras``; finished envs are reset inside the step
  (the returned observation is the new episode's first one). ``extras["time_outs"]`` [N] bool marks episodes cut by
  a time limit (truncated and not terminated), which PPO bootstraps; ``extras["log"]`` holds, for every boolean
  ``info`` flag of the env (collisions, ``is_success``, ``goals_reached``, ...), its per-env count this step as
  ``"Magwarp/<flag>"``: rsl_rl's logger prints their mean per env-step.
* Actions: rsl_rl's Gaussian policies are unbounded and start with unit standard deviation, so by default
  (``scale_actions=True``) a policy action of ±1 is the action space's bound (±10 m/s² for acceleration control):
  ``env action = policy action * single_action_space.high``. A trained rsl_rl policy's output must be scaled by
  :attr:`RslRlVecEnv.action_scale` before it reaches the env directly. ``clip_actions`` (Isaac Lab's option) clamps
  policy actions to ``±clip_actions`` first; nothing is clamped unless asked (the env norm-clips each mover's
  command to its physical limit, as always).
* ``num_envs``, ``num_actions``, ``device``, ``cfg``; ``episode_length_buf`` is the env's own per-episode step
  counter, and writing it (``learn(..., init_at_random_ep_len=True)``) moves every env's place towards the
  ``max_episode_steps`` cut (``max_episode_length``) without touching the trajectory-planning timeout (steps since
  the last goal).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch
from rsl_rl.env import VecEnv
from tensordict import TensorDict

from magwarp.envs.adapters.common import resolve_env, time_outs
from magwarp.envs.base import MagwarpVecEnv
from magwarp.training.common import OBS_KEYS, flatten_obs

__all__ = ["RslRlVecEnv"]

OBS_MODES = ("flat", "dict")


class RslRlVecEnv(VecEnv):
    """rsl_rl ``VecEnv`` around a :class:`~magwarp.envs.MagwarpVecEnv` instance, or an env id / class with
    ``num_envs`` and keyword arguments. The wrapped env must autoreset (the default); it is reset once here."""

    def __init__(self, env: MagwarpVecEnv | str | type, num_envs: int | None = None, *, obs_mode: str = "flat",
                 scale_actions: bool = True, clip_actions: float | None = None, **env_kwargs):
        if obs_mode not in OBS_MODES:
            raise ValueError(f"obs_mode must be one of {OBS_MODES}, got {obs_mode!r}")
        if clip_actions is not None and not (np.isfinite(clip_actions) and clip_actions > 0):
            raise ValueError(f"clip_actions must be None or a positive number, got {clip_actions!r}")
        env = resolve_env(env, num_envs, env_kwargs, "RslRlVecEnv")
        space, act_space = env.single_observation_space, env.single_action_space
        if obs_mode == "flat" and isinstance(space, gym.spaces.Dict) and set(space.spaces) != set(OBS_KEYS):
            raise ValueError(f"obs_mode='flat' flattens the observation keys {OBS_KEYS}, the env has "
                             f"{tuple(space.spaces)}: use obs_mode='dict' (one observation group per key)")
        if not isinstance(act_space, gym.spaces.Box):
            raise TypeError(f"RslRlVecEnv needs a Box action space, got {act_space}")
        self.action_scale: torch.Tensor | None = None
        if scale_actions:
            if not (np.all(np.isfinite(act_space.high)) and np.array_equal(act_space.low, -act_space.high)):
                raise ValueError(f"scale_actions=True needs a bounded action space symmetric about 0, got {act_space}"
                                 "; pass scale_actions=False to send the policy's actions unscaled")
            self.action_scale = torch.as_tensor(act_space.high, dtype=torch.float32, device=env.device).reshape(-1)
        self.env = env
        self.obs_mode = obs_mode
        self.clip_actions = None if clip_actions is None else float(clip_actions)
        self.num_envs = env.num_envs
        self.num_actions = int(np.prod(act_space.shape))
        self.device = env.device
        spec = getattr(env, "spec", None)
        self.cfg = {"env": getattr(spec, "id", None) or type(env).__name__, "num_envs": self.num_envs,
                    "obs_mode": obs_mode, "scale_actions": scale_actions, "clip_actions": self.clip_actions}
        obs, _ = env.reset()
        self._obs = self._obs_td(obs)

    # ------------------------------------------------------------------ conversion
    def _obs_td(self, obs) -> TensorDict:
        if self.obs_mode == "dict" and isinstance(obs, dict):
            groups = dict(obs)
        else:
            groups = {"policy": flatten_obs(obs)}
        return TensorDict(groups, batch_size=[self.num_envs], device=self.device)

    def _log(self, info: dict) -> dict[str, torch.Tensor]:
        """Per-env counts of the step's boolean info flags (keys starting with ``_`` are gymnasium's masks)."""
        n = self.num_envs
        return {f"Magwarp/{k}": v.reshape(n, -1).sum(dim=1, dtype=torch.float32) for k, v in info.items()
                if isinstance(v, torch.Tensor) and v.dtype == torch.bool and not k.startswith("_")
                and v.dim() >= 1 and v.shape[0] == n}

    # ------------------------------------------------------------------ rsl_rl VecEnv API
    def get_observations(self) -> TensorDict:
        """The observation of the last step (or of the reset), as rsl_rl's observation groups."""
        return self._obs

    def reset(self) -> tuple[TensorDict, dict]:
        """Reset every env (new episodes): the observation groups and empty extras."""
        obs, _ = self.env.reset()
        self._obs = self._obs_td(obs)
        return self._obs, {}

    def step(self, actions: torch.Tensor) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict]:
        if self.clip_actions is not None:
            actions = actions.clamp(-self.clip_actions, self.clip_actions)
        if self.action_scale is not None:
            actions = actions * self.action_scale
        obs, reward, terminated, truncated, info = self.env.step(actions)
        self._obs = self._obs_td(obs)
        dones = (terminated | truncated).to(torch.long)
        extras = {"time_outs": time_outs(terminated, truncated), "log": self._log(info)}
        return self._obs, reward, dones, extras

    # ------------------------------------------------------------------ episode lengths
    @property
    def episode_length_buf(self) -> torch.Tensor:
        """Steps taken in each env's current episode (the env's ``num_steps`` counter, a live ``[N]`` tensor)."""
        steps = getattr(self.env, "num_steps", None)
        if not isinstance(steps, torch.Tensor):
            raise AttributeError(f"{type(self.env).__name__} keeps no per-episode step counter (num_steps)")
        return steps

    @episode_length_buf.setter
    def episode_length_buf(self, value: torch.Tensor) -> None:
        steps = self.episode_length_buf
        value = torch.as_tensor(value, device=self.device)
        if value.shape != steps.shape or value.is_floating_point() or value.dtype == torch.bool:
            raise ValueError(f"episode_length_buf must be an integer tensor of shape {tuple(steps.shape)}, got "
                             f"{value.dtype} {tuple(value.shape)}")
        if bool((value < 0).any()):
            raise ValueError(f"episode_length_buf must be >= 0, got a minimum of {int(value.min())}")
        delta = value.to(steps.dtype) - steps
        steps.add_(delta)
        last_goal = getattr(self.env, "last_goal_step", None)
        if isinstance(last_goal, torch.Tensor):  # trajectory planning: keep the steps since the last goal
            last_goal.add_(delta)

    @property
    def max_episode_length(self) -> int:
        """The env's episode-length cut (``max_episode_steps``)."""
        limit = getattr(self.env, "max_episode_steps", None)
        if limit is None:
            raise ValueError(f"{type(self.env).__name__} has no episode-length cut (max_episode_steps=None), so "
                             "there is no max_episode_length: create the env with max_episode_steps=... (needed by "
                             "OnPolicyRunner.learn(init_at_random_ep_len=True))")
        return int(limit)

    def close(self) -> None:
        self.env.close()
