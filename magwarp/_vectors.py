"""Torch vector helpers shared by the scripted policies (TorchScript-compatible: exported policies script them), the
swarm planner and the swarm env's shield. The numpy twin is :func:`magwarp.reference.clip_norm`, the Warp one
:func:`magwarp.kernels.dynamics.clip_norm2`."""

from __future__ import annotations

import torch

__all__ = ["clip_norm"]


def clip_norm(v: torch.Tensor, limit: float) -> torch.Tensor:
    """The rows ``v[..., :]`` longer than ``limit`` (> 0) scaled down to it; the others returned bit for bit."""
    n = v.norm(p=2, dim=-1, keepdim=True)  # p given: TorchScript (scripted policies) needs it
    return torch.where(n > limit, v * (limit / n.clamp_min(1e-9)), v)
