"""A single-env, numpy view of a batched env: what ``gymnasium.make("magwarp/...")`` returns.

It runs the batched env with ``num_envs=1`` and autoreset off, and converts tensors to numpy at the boundary, so
standard single-env tooling (``gymnasium.utils.env_checker.check_env``, SB3, HER) works unchanged.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import torch

from magwarp._checks import as_seed

__all__ = ["SingleEnv", "to_numpy"]

# The info entries that rewards depend on (collisions of every kind), forwarded to the batched compute_reward.
_REWARD_INFO_KEYS = ("mover_collision", "wall_collision", "obstacle_mover_collision", "obstacle_object_collision",
                     "limit_violation")


def to_numpy(value: Any, index: int | None = None) -> Any:
    """Tensors (and dicts of them) to numpy, optionally taking batch entry ``index``."""
    if isinstance(value, dict):
        return {k: to_numpy(v, index) for k, v in value.items()}
    if isinstance(value, torch.Tensor):
        arr = value.detach().cpu().numpy()
        return arr[index] if index is not None else arr
    return value


class SingleEnv(gym.Env):
    """Gymnasium ``Env`` around one world of a :class:`~magwarp.envs.base.MagwarpVecEnv` subclass."""

    def __init__(self, vec_env_cls, render_mode: str | None = None, **kwargs):
        self.vec = vec_env_cls(num_envs=1, autoreset=False, render_mode=render_mode, **kwargs)
        self.metadata = {k: v for k, v in self.vec.metadata.items() if k != "autoreset_mode"}
        self.render_mode = render_mode
        self.observation_space = self.vec.single_observation_space
        self.action_space = self.vec.single_action_space

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        if seed is not None:
            seed = as_seed(seed)
        super().reset(seed=seed)
        obs, info = self.vec.reset(seed=seed, options=options)
        return to_numpy(obs, 0), to_numpy(info, 0)

    def step(self, action):
        try:
            with np.errstate(over="ignore"):  # a float64 beyond float32's range becomes inf: refused by the vec env
                action = np.asarray(action, dtype=np.float32)
        except (TypeError, ValueError):
            raise TypeError(f"action must be an array of numbers of shape {self.action_space.shape}, "
                            f"got {action!r}") from None
        if action.shape != self.action_space.shape:
            raise ValueError(f"action must have shape {self.action_space.shape}, got {action.shape}")
        batch = torch.as_tensor(action, device=self.vec.device).unsqueeze(0)
        obs, reward, terminated, truncated, info = self.vec.step(batch)
        return (to_numpy(obs, 0), float(reward[0]), bool(terminated[0]), bool(truncated[0]), to_numpy(info, 0))

    def compute_reward(self, achieved_goal, desired_goal, info):
        """Numpy-in, numpy-out batched reward (SB3's HER calls it with a list of info dicts)."""
        if isinstance(info, (list, tuple, np.ndarray)):
            info = {k: np.array([bool(i.get(k, False)) for i in info]) for k in _REWARD_INFO_KEYS}
        device = self.vec.device
        info_t = None if info is None else {
            k: torch.as_tensor(np.asarray(v), device=device) for k, v in info.items() if k in _REWARD_INFO_KEYS
        }
        reward = self.vec.compute_reward(torch.as_tensor(np.asarray(achieved_goal, np.float32), device=device),
                                         torch.as_tensor(np.asarray(desired_goal, np.float32), device=device), info_t)
        out = reward.cpu().numpy().astype(np.float64)
        return out if out.ndim else float(out)

    def render(self):
        return self.vec.render()

    def close(self):
        self.vec.close()
