"""A Stable-Baselines3 ``VecEnv`` over a batched magwarp env: the whole batch is one object, numpy at the boundary.

SB3 sees ``num_envs`` envs with the single-env spaces; one ``step_wait`` is one batched torch step (autoreset in the
same step, as SB3 expects), converted to numpy once. ``infos`` is the list of per-env dicts SB3 needs and nothing
more: ``mover_collision``, ``wall_collision`` (what ``compute_reward`` reads, so HER can store and relabel with
them), ``TimeLimit.truncated`` (truncated and not terminated, for bootstrapping), and ``terminal_observation`` for
envs that finished this step.

``env_method`` / ``get_attr`` / ``set_attr`` act on the one batched env (a method is called once, its result repeated
for each requested index). ``env_method("compute_reward", achieved, desired, infos)`` — what SB3's
``HerReplayBuffer`` calls — runs the batched, numpy-in/numpy-out reward of :meth:`SB3VecEnv.compute_reward`.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.vec_env import VecEnv

from magwarp.envs.adapters.common import resolve_env, time_outs
from magwarp.envs.base import MagwarpVecEnv

__all__ = ["SB3VecEnv"]


def _np(x: torch.Tensor) -> np.ndarray:
    return x.detach().cpu().numpy()


def _obs_np(obs):
    if isinstance(obs, dict):
        return {k: _np(v) for k, v in obs.items()}
    return _np(obs)


class SB3VecEnv(VecEnv):
    """SB3 ``VecEnv`` around a :class:`~magwarp.envs.MagwarpVecEnv` instance, or an env id / class with
    ``num_envs`` and keyword arguments (``SB3VecEnv("magwarp/TrajectoryPlanningB0-v0", num_envs=64)``).
    The wrapped env must autoreset (the default)."""

    def __init__(self, env: MagwarpVecEnv | str | type, num_envs: int | None = None, **env_kwargs):
        env = resolve_env(env, num_envs, env_kwargs, "SB3VecEnv")
        self.env = env
        self._actions: torch.Tensor | None = None
        super().__init__(env.num_envs, env.single_observation_space, env.single_action_space)

    # ------------------------------------------------------------------ stepping
    def reset(self):
        seed = self._seeds[0]
        options = self._options[0] or None
        obs, info = self.env.reset(seed=seed, options=options)
        self._reset_seeds()
        self._reset_options()
        self.reset_infos = [{} for _ in range(self.num_envs)]
        return _obs_np(obs)

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = torch.from_numpy(np.ascontiguousarray(actions)).to(self.env.device)

    def step_wait(self):
        if self._actions is None:
            raise RuntimeError("step_wait() called without step_async()")
        actions, self._actions = self._actions, None
        obs, reward, terminated, truncated, info = self.env.step(actions)
        done = terminated | truncated
        obs_np = _obs_np(obs)
        rew_np = _np(reward).astype(np.float32, copy=False)
        done_np = _np(done)
        timeout = time_outs(terminated, truncated).tolist()
        columns = [info[k].tolist() for k in ("mover_collision", "wall_collision") if k in info]
        if len(columns) == 2:
            infos = [{"mover_collision": mc, "wall_collision": wc, "TimeLimit.truncated": to}
                     for mc, wc, to in zip(*columns, timeout)]
        else:
            infos = [{"TimeLimit.truncated": to} for to in timeout]
        finished = np.flatnonzero(done_np)
        if len(finished):
            final = info["final_obs"]
            # One gather per key for all finished envs, then one small dict (or row) per finished env only.
            if isinstance(final, dict):
                keys = list(final)
                rows = zip(*(list(_np(final[k][torch.as_tensor(finished, device=final[k].device)])) for k in keys))
                terminal = [dict(zip(keys, r)) for r in rows]
            else:
                terminal = list(_np(final[torch.as_tensor(finished, device=final.device)]))
            for i, t in zip(finished.tolist(), terminal):
                infos[i]["terminal_observation"] = t
        return obs_np, rew_np, done_np, infos

    # ------------------------------------------------------------------ HER
    def compute_reward(self, achieved_goal, desired_goal, info) -> np.ndarray:
        """Batched reward, numpy in and out; ``info`` is a dict of arrays, a list/array of per-transition dicts (as
        SB3's HER passes them; empty dicts mean no collision), or None."""
        dev = self.env.device
        if isinstance(info, (list, tuple, np.ndarray)):
            dicts = list(info)
            keys = set().union(*(d.keys() for d in dicts)) if dicts else set()
            keys &= {"mover_collision", "wall_collision"}
            info = {k: np.array([bool(d.get(k, False)) for d in dicts]) for k in keys} if keys else None
        info_t = None if info is None else {k: torch.as_tensor(np.asarray(v), device=dev) for k, v in info.items()
                                            if not isinstance(v, (dict, list))}
        achieved = torch.as_tensor(np.asarray(achieved_goal, np.float32), device=dev)
        desired = torch.as_tensor(np.asarray(desired_goal, np.float32), device=dev)
        return _np(self.env.compute_reward(achieved, desired, info_t)).astype(np.float32)

    # ------------------------------------------------------------------ VecEnv plumbing
    def _count(self, indices) -> int:
        return len(list(self._get_indices(indices)))

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
        if method_name == "compute_reward":
            fn = self.compute_reward
        else:
            fn = getattr(self.env, method_name)
        result = fn(*method_args, **method_kwargs)
        return [result] * self._count(indices)

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        return [getattr(self.env, attr_name)] * self._count(indices)

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        setattr(self.env, attr_name, value)

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False] * self._count(indices)

    def get_images(self):
        return [self.env.render()]

    def close(self) -> None:
        self.env.close()

    def _get_indices(self, indices) -> Iterable[int]:
        if indices is None:
            return range(self.num_envs)
        if isinstance(indices, int):
            return [indices]
        return indices
