"""Helpers shared by the single-agent training adapters (SB3, rsl_rl, skrl): building the wrapped env from an
instance, a class or an env id, and the time-out flag the libraries bootstrap on."""

from __future__ import annotations

import torch

from magwarp.envs.base import MagwarpVecEnv

__all__ = ["resolve_env", "time_outs"]


def resolve_env(env: MagwarpVecEnv | str | type, num_envs: int | None, env_kwargs: dict, adapter: str) -> MagwarpVecEnv:
    """The :class:`~magwarp.envs.MagwarpVecEnv` an ``adapter`` wraps: ``env`` itself, or one built from an env id
    (``gymnasium.make_vec``) or an env class, with ``num_envs`` (default 1) and ``env_kwargs``. The env must autoreset
    (these libraries expect finished envs to be reset inside ``step``)."""
    if isinstance(env, str):
        import gymnasium as gym

        env = gym.make_vec(env, num_envs=num_envs or 1, vectorization_mode="vector_entry_point", **env_kwargs)
    elif isinstance(env, type):
        env = env(num_envs=num_envs or 1, **env_kwargs)
    elif num_envs is not None or env_kwargs:
        raise TypeError("num_envs and env_kwargs are only accepted with an env id or class, not an instance")
    if not isinstance(env, MagwarpVecEnv):
        raise TypeError(f"{adapter} wraps a MagwarpVecEnv, got {type(env).__name__}")
    if not env.autoreset:
        raise ValueError(f"{adapter} needs an env with autoreset=True (its vector envs reset finished envs in step)")
    return env


def time_outs(terminated: torch.Tensor, truncated: torch.Tensor) -> torch.Tensor:
    """Episodes cut by a time limit: truncated and not also terminated (a terminal state is never bootstrapped)."""
    return truncated & ~terminated
