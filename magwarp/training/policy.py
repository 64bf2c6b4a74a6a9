"""The trained-policy file format: a self-contained TorchScript module (``policy.pt``).

Contract (what ``magwarp eval`` and ``magwarp export`` rely on):

* ``policy = torch.jit.load("policy.pt", map_location=device)``; ``policy.eval()``.
* ``action = policy(obs)`` where ``obs`` is either the env's goal-dict observation (a ``Dict[str, Tensor]`` with
  ``observation``, ``achieved_goal``, ``desired_goal``, each ``[num_envs, k]``) or the flattened tensor
  ``torch.cat([achieved_goal, desired_goal, observation], -1)`` (sorted key order: what gymnasium's Dict
  space, SB3 and ``magwarp eval`` produce) of shape ``[num_envs, policy.obs_dim]``.
  ``action`` is ``[num_envs, policy.action_dim]`` float32 in the env's units (already scaled to the action space,
  deterministic: the mean action), ready for ``env.step``. Observation normalisation is inside the module.
* ``policy.flat`` is the flat-tensor-only submodule (what ONNX export writes: input ``obs [B, obs_dim]``, output
  ``action [B, action_dim]``).
* Attributes ``policy.obs_dim``, ``policy.action_dim``, ``policy.env_id``; the file's extra file ``magwarp.json``
  (``torch.jit.load(path, _extra_files={"magwarp.json": ""})``) holds the env id, env kwargs, algorithm and training
  summary.
"""

from __future__ import annotations

import copy
import json
import os
import warnings
from typing import Any, Dict, Union

import torch
from torch import nn

__all__ = ["mlp", "FlatPolicy", "Policy", "save_policy", "load_policy", "policy_metadata"]


def mlp(inp: int, hidden: list[int] | tuple[int, ...], out: int, act: type[nn.Module] = nn.ELU,
        layer_norm: bool = False) -> nn.Sequential:
    layers: list[nn.Module] = []
    for h in hidden:
        layers.append(nn.Linear(inp, h))
        if layer_norm:
            layers.append(nn.LayerNorm(h))
        layers.append(act())
        inp = h
    layers.append(nn.Linear(inp, out))
    return nn.Sequential(*layers)


class FlatPolicy(nn.Module):
    """Flattened observation ``[B, obs_dim]`` -> deterministic action ``[B, action_dim]`` in env units."""

    def __init__(self, net: nn.Module, obs_mean: torch.Tensor, obs_std: torch.Tensor, clip: float,
                 action_scale: torch.Tensor, squash: str = "tanh"):
        super().__init__()
        if squash not in ("tanh", "clip"):
            raise ValueError(f"squash must be 'tanh' or 'clip', got {squash!r}")
        self.net = net
        self.register_buffer("obs_mean", obs_mean.detach().to(torch.float32).clone())
        self.register_buffer("obs_std", obs_std.detach().to(torch.float32).clone())
        self.register_buffer("action_scale", action_scale.detach().to(torch.float32).clone())
        self.clip = float(clip)
        self.use_tanh = squash == "tanh"

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        x = ((obs.to(torch.float32) - self.obs_mean) / self.obs_std).clamp(-self.clip, self.clip)
        y = self.net(x)
        y = torch.tanh(y) if self.use_tanh else y.clamp(-1.0, 1.0)
        return y * self.action_scale


class Policy(nn.Module):
    """``policy(obs)`` for a goal-dict or a flattened observation (see the module docstring)."""

    def __init__(self, flat: FlatPolicy, obs_dim: int, action_dim: int, env_id: str = ""):
        super().__init__()
        self.flat = flat
        self.obs_keys = ["achieved_goal", "desired_goal", "observation"]
        self.obs_dim = int(obs_dim)
        self.action_dim = int(action_dim)
        self.env_id = str(env_id)

    def forward(self, obs: Union[torch.Tensor, Dict[str, torch.Tensor]]) -> torch.Tensor:
        if isinstance(obs, torch.Tensor):
            x = obs
        else:
            x = torch.cat([obs["achieved_goal"], obs["desired_goal"], obs["observation"]], -1)
        return self.flat(x)


def save_policy(path: str, net: nn.Module, obs_rms, action_scale: torch.Tensor, *, squash: str, env_id: str,
                metadata: dict[str, Any] | None = None) -> None:
    """Write ``net`` (normalised obs -> pre-squash action mean) with the normaliser as a TorchScript policy file.

    The module is copied to the CPU (a policy file loads anywhere; ``map_location`` moves it)."""
    net = copy.deepcopy(net).to("cpu").eval()
    std = torch.sqrt(obs_rms.var + 1e-8)
    flat = FlatPolicy(net, obs_rms.mean.cpu(), std.cpu(), obs_rms.clip, action_scale.cpu(), squash)
    policy = Policy(flat, obs_rms.mean.numel(), action_scale.numel(), env_id).eval()
    meta = {"format": "magwarp-policy-v1", "env_id": env_id, "obs_keys": policy.obs_keys,
            "obs_dim": policy.obs_dim, "action_dim": policy.action_dim, **(metadata or {})}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        scripted = torch.jit.script(policy)
    tmp = f"{path}.tmp"
    torch.jit.save(scripted, tmp, _extra_files={"magwarp.json": json.dumps(meta, default=str)})
    os.replace(tmp, path)


def policy_metadata(path: str) -> dict[str, Any]:
    """The ``magwarp.json`` metadata of a TorchScript policy file ({} if it has none or is not TorchScript)."""
    from magwarp._io import _is_torchscript

    if not _is_torchscript(path):
        return {}
    extra = {"magwarp.json": ""}
    torch.jit.load(path, map_location="cpu", _extra_files=extra)
    return json.loads(extra["magwarp.json"]) if extra["magwarp.json"] else {}


def load_policy(path: str, device="cpu", *, trusted: bool = False) -> nn.Module:
    """A policy module from a TorchScript file, a ``torch.save``d module, or a training folder (its ``policy.pt``).

    No pickled code runs while loading (:mod:`magwarp._io`): a whole ``torch.save``d module needs ``trusted=True``
    (it is unpickled with a warning)."""
    from magwarp._io import load_module

    if os.path.isdir(path):
        path = os.path.join(path, "policy.pt")
    module = load_module(path, device, trusted=trusted)
    if not isinstance(module, (nn.Module, torch.jit.ScriptModule)):
        raise ValueError(f"{path!r} is neither a TorchScript policy nor a torch.save'd nn.Module "
                         f"(got {type(module).__name__}; a training checkpoint's policy is OUT/policy.pt)")
    return module.eval()
