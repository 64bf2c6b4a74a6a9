"""A TorchRL ``EnvBase`` over a batched magwarp env: ``batch_size=[num_envs]``, tensors stay on the env's device.

TorchRL resets finished envs itself (``step_and_maybe_reset`` / collectors pass a ``"_reset"`` mask to ``reset``),
so the wrapped env runs with its own autoreset off and ``_reset`` resets only the masked envs, through the env's
``options={"reset_mask": ...}``.

Single-agent (default): the env's observation keys (``observation``, ``achieved_goal``, ``desired_goal`` for goal
tasks, or ``observation``), ``action`` ``[N, A]``, ``reward`` ``[N, 1]``, ``done`` / ``terminated`` /
``truncated`` ``[N, 1]``. Specs are built from the gymnasium spaces.

Multi-agent (``multi_agent=True``; trajectory-planning-like envs and envs with their own per-agent view such as
:class:`~magwarp.envs.coop_push.CoopPushEnv`, see :func:`~magwarp.envs.adapters.multiagent.make_agent_view`): one
agent per mover under the ``"agents"`` group,
as TorchRL's MARL envs (VMAS) lay it out: ``("agents", "observation")`` ``[N, M, D]`` (see
:mod:`magwarp.envs.adapters.multiagent`), ``("agents", "action")`` ``[N, M, 2]``, ``("agents", "reward")``
``[N, M, 1]`` (shared team reward), plus the flat world ``state`` ``[N, S]`` for centralised critics and ``done`` /
``terminated`` / ``truncated`` ``[N, 1]`` per world.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from magwarp.envs.adapters.multiagent import global_state, make_agent_view
from magwarp.envs.base import MagwarpVecEnv

__all__ = ["TorchRLEnv"]


def _spec(space: gym.Space, batch: tuple[int, ...], device) -> object:
    """A TorchRL spec with leading ``batch`` dims for a gymnasium Box / Dict / Discrete space."""
    if isinstance(space, gym.spaces.Dict):
        return Composite({k: _spec(s, batch, device) for k, s in space.spaces.items()}, shape=batch, device=device)
    if isinstance(space, gym.spaces.Box):
        dtype = torch.from_numpy(np.zeros((), space.dtype)).dtype
        shape = (*batch, *space.shape)
        if np.all(np.isfinite(space.low)) and np.all(np.isfinite(space.high)):
            low = torch.as_tensor(space.low, dtype=dtype, device=device).expand(shape)
            high = torch.as_tensor(space.high, dtype=dtype, device=device).expand(shape)
            return Bounded(low=low, high=high, shape=shape, dtype=dtype, device=device)
        return Unbounded(shape=shape, dtype=dtype, device=device)
    if isinstance(space, gym.spaces.Discrete):
        return Categorical(int(space.n), shape=batch, dtype=torch.int64, device=device)
    raise TypeError(f"no TorchRL spec for gymnasium space {space}")


class TorchRLEnv(EnvBase):
    """TorchRL env around a :class:`~magwarp.envs.MagwarpVecEnv` instance (its ``autoreset`` is switched off: TorchRL
    resets envs itself), or an env class plus ``num_envs`` and keyword arguments."""

    def __init__(self, env: MagwarpVecEnv | type, num_envs: int | None = None, *, multi_agent: bool = False,
                 obs_mode: str = "flat", **env_kwargs):
        if isinstance(env, type):
            env = env(num_envs=num_envs or 1, autoreset=False, **env_kwargs)
        elif num_envs is not None or env_kwargs:
            raise TypeError("num_envs and env_kwargs are only accepted with an env class, not an instance")
        if not isinstance(env, MagwarpVecEnv):
            raise TypeError(f"TorchRLEnv wraps a MagwarpVecEnv, got {type(env).__name__}")
        env.autoreset = False
        super().__init__(device=env.device, batch_size=torch.Size([env.num_envs]))
        self.env = env
        self.multi_agent = multi_agent
        n, dev = env.num_envs, env.device
        self._done = torch.zeros(n, 1, dtype=torch.bool, device=dev)
        if multi_agent:
            self._split = make_agent_view(env, obs_mode)
            self.num_movers = m = self._split.num_movers
            a = self._split.action_dim
            group = (n, m)
            agent_obs = _spec(self._split.spaces(), group, dev)
            agents_obs = (Composite({"observation": agent_obs}, shape=group, device=dev) if obs_mode == "flat" else
                          Composite(dict(agent_obs.items()), shape=group, device=dev))
            s_dim = sum(int(np.prod(env.single_observation_space[k].shape)) for k in ("observation", "achieved_goal", "desired_goal"))
            self.observation_spec = Composite({"agents": agents_obs, "state": Unbounded((n, s_dim), device=dev)},
                                              shape=(n,), device=dev)
            high = torch.as_tensor(np.asarray(env.single_action_space.high, np.float32).reshape(m, a), device=dev)
            high = high.expand(n, m, a)
            act = Bounded(low=-high, high=high, shape=(n, m, a), dtype=torch.float32, device=dev)
            self.action_spec = Composite({"agents": Composite({"action": act}, shape=group, device=dev)}, shape=(n,),
                                         device=dev)
            self.reward_spec = Composite({"agents": Composite({"reward": Unbounded((n, m, 1), device=dev)}, shape=group,
                                                              device=dev)}, shape=(n,), device=dev)
        else:
            obs_spec = _spec(env.single_observation_space, (n,), dev)
            self.observation_spec = (obs_spec if isinstance(obs_spec, Composite) else
                                     Composite({"observation": obs_spec}, shape=(n,), device=dev))
            self.action_spec = _spec(env.single_action_space, (n,), dev)
            self.reward_spec = Unbounded((n, 1), device=dev)
        flag = Categorical(2, shape=(n, 1), dtype=torch.bool, device=dev)
        self.done_spec = Composite({"done": flag, "terminated": flag.clone(), "truncated": flag.clone()}, shape=(n,),
                                   device=dev)

    # ------------------------------------------------------------------ conversion
    def _obs_td(self, obs) -> dict:
        if self.multi_agent:
            state = global_state(obs)
            per = self._split(obs, state)
            agents = {"observation": per} if isinstance(per, torch.Tensor) else per
            return {"agents": TensorDict(agents, batch_size=(self.env.num_envs, self.num_movers), device=self.device),
                    "state": state}
        return dict(obs) if isinstance(obs, dict) else {"observation": obs}

    # ------------------------------------------------------------------ EnvBase hooks
    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        mask = None
        if tensordict is not None:
            mask = tensordict.get("_reset", None)
            if mask is None and self.multi_agent:
                agent_mask = tensordict.get(("agents", "_reset"), None)
                if agent_mask is not None:
                    mask = agent_mask.reshape(self.env.num_envs, -1).any(dim=-1)
        if mask is not None:
            mask = mask.reshape(self.env.num_envs).to(torch.bool)
            obs, _ = self.env.reset(options={"reset_mask": mask})
            self._done.masked_fill_(mask[:, None], False)
        else:
            obs, _ = self.env.reset()
            self._done.zero_()
        done = self._done.clone()
        return TensorDict({**self._obs_td(obs), "done": done, "terminated": done.clone(), "truncated": done.clone()},
                          batch_size=self.batch_size, device=self.device)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        n = self.env.num_envs
        if self.multi_agent:
            action = tensordict.get(("agents", "action")).reshape(n, -1)
        else:
            action = tensordict.get("action")
        obs, reward, terminated, truncated, _ = self.env.step(action)
        terminated, truncated = terminated[:, None], truncated[:, None]
        done = terminated | truncated
        self._done.copy_(done)
        out = {**self._obs_td(obs), "done": done, "terminated": terminated, "truncated": truncated}
        if self.multi_agent:
            r = reward[:, None, None].expand(n, self.num_movers, 1).clone()
            out["agents"].set("reward", r)
        else:
            out["reward"] = reward[:, None]
        return TensorDict(out, batch_size=self.batch_size, device=self.device)

    def _set_seed(self, seed: int | None) -> None:
        if seed is not None:
            self.env.reset(seed=int(seed))
            self._done.zero_()
