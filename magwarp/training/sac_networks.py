"""The networks of SAC + HER (:mod:`magwarp.training.sac_her`): the squashed-Gaussian actor and the twin critics.

The twin critics (clipped double Q) come two ways, with the same maths and the same initial weights for a seed:

* :class:`EnsembleCritic` (``--critic-impl ensemble``): both Q networks as one ensemble, each layer's
  weights stacked ``[2, in, out]``: one batched matmul (``torch.baddbmm``), one layer norm and one affine per layer
  for both heads: fewer kernels per update (720 against 1023 with foreach Adam), which paid on one H100 at batch 1024
  only (1.52 against 2.04 ms; at 4096, with fused Adam, 1.43 against 1.30 ms).
* :class:`Critic` (``--critic-impl pair``, the default): two separate MLPs (the layout of checkpoints written
  before the ensemble; on one H100 its two plain matmuls beat the batched ones at batch 4096 and above:
  ``benchmarks/sac_update.py``).

A checkpoint of either layout loads into the other (:func:`convert_critic_state`, :func:`convert_critic_optimizer`):
the ensemble's tensors are the pair's, stacked (linear weights transposed to ``[in, out]``, vectors as
``[2, 1, out]``), and its parameters come in the pair's order within a head, so the Adam moments convert the same way.
"""

from __future__ import annotations

import copy

import torch
import torch.nn.functional as F
from torch import nn

from magwarp.training.common import autocast
from magwarp.training.policy import mlp

__all__ = ["Actor", "Critic", "EnsembleCritic", "make_critic", "q_min", "q_regression_loss", "critic_layout",
           "convert_critic_state", "convert_critic_optimizer", "CRITIC_IMPLS"]

#: ``--critic-impl`` choices
CRITIC_IMPLS = ("ensemble", "pair")
HEADS = 2  # clipped double Q


class Actor(nn.Module):
    """Tanh-squashed Gaussian policy; ``amp``: bf16 autocast of the MLP (its output back in float32)."""

    def __init__(self, n_obs: int, n_act: int, hidden: list[int], amp: str = "off"):
        super().__init__()
        self.net = mlp(n_obs, hidden, 2 * n_act, act=nn.ReLU)
        self.n_act = n_act
        self.amp = amp

    def forward(self, x: torch.Tensor, deterministic: bool = False):
        with autocast(x.device, self.amp):
            out = self.net(x)
        mu, log_std = out.float().split(self.n_act, dim=-1)
        log_std = log_std.clamp(-5.0, 2.0)
        if deterministic:
            return torch.tanh(mu), None
        eps = torch.randn_like(mu)
        u = mu + log_std.exp() * eps
        a = torch.tanh(u)
        logp = (-0.5 * eps.square() - log_std - 0.9189385332046727).sum(-1)
        logp = logp - (2 * (0.6931471805599453 - u - F.softplus(-2 * u))).sum(-1)  # tanh correction
        return a, logp

    def mean_net(self) -> nn.Sequential:
        """A copy that outputs only the pre-tanh mean (what the exported policy runs)."""
        net = copy.deepcopy(self.net)
        last = net[-1]
        head = nn.Linear(last.in_features, self.n_act)
        with torch.no_grad():
            head.weight.copy_(last.weight[: self.n_act])
            head.bias.copy_(last.bias[: self.n_act])
        net[-1] = head
        return net


def _q_mlp(n_in: int, hidden: list[int]) -> nn.Sequential:
    """One Q network: ReLU MLP with layer norm (stability at large batches), one output."""
    return mlp(n_in, hidden, 1, act=nn.ReLU, layer_norm=True)


class Critic(nn.Module):
    """Two Q networks (clipped double Q) as two MLPs. ``forward([x, a]) -> (q1, q2)``, each ``[B]``; ``forward(x, a)``
    the same."""

    def __init__(self, n_in: int, hidden: list[int], amp: str = "off"):
        super().__init__()
        self.q1 = _q_mlp(n_in, hidden)
        self.q2 = _q_mlp(n_in, hidden)
        self.amp = amp

    def forward(self, xa: torch.Tensor, a: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Q values of ``[x, a]`` (given joined, or as ``x`` and ``a``)."""
        xa = xa if a is None else torch.cat([xa, a], -1)
        with autocast(xa.device, self.amp):
            return self.q1(xa).float().squeeze(-1), self.q2(xa).float().squeeze(-1)


class EnsembleLinear(nn.Module):
    """``heads`` linear layers at once: ``y[h] = x[h] @ weight[h] + bias[h]`` (``x`` ``[B, in]`` is shared)."""

    def __init__(self, weight: torch.Tensor, bias: torch.Tensor):
        super().__init__()
        self.weight = nn.Parameter(weight)  # [heads, in, out]
        self.bias = nn.Parameter(bias)  # [heads, 1, out]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.dim() == 2:  # the input of the first layer, the same for every head (a view: no copy)
            x = x.expand(self.weight.shape[0], *x.shape)
        return torch.baddbmm(self.bias, x, self.weight)


class EnsembleLayerNorm(nn.Module):
    """``heads`` layer norms over the last dimension, each with its own affine ``weight[h], bias[h]`` (``[1, out]``)."""

    def __init__(self, weight: torch.Tensor, bias: torch.Tensor, eps: float):
        super().__init__()
        self.weight = nn.Parameter(weight)
        self.bias = nn.Parameter(bias)
        self.eps = float(eps)

    def forward(self, h: torch.Tensor) -> torch.Tensor:
        return torch.addcmul(self.bias, F.layer_norm(h, h.shape[-1:], eps=self.eps), self.weight)


def _stack(tensors: list[torch.Tensor]) -> torch.Tensor:
    """One parameter of every head's MLP -> the ensemble's: linear weights ``[out, in]`` -> ``[heads, in, out]``,
    vectors ``[out]`` -> ``[heads, 1, out]``."""
    if tensors[0].dim() == 2:
        return torch.stack([t.t() for t in tensors]).contiguous()
    return torch.stack(tensors).unsqueeze(1)


def _unstack(tensor: torch.Tensor) -> list[torch.Tensor]:
    """The inverse of :func:`_stack`: one ensemble parameter -> every head's (contiguous, in the MLP's layout)."""
    if tensor.shape[1] == 1:
        return [t[0].clone() for t in tensor]
    return [t.t().contiguous() for t in tensor]


class EnsembleCritic(nn.Module):
    """The two Q networks of :class:`Critic` as one ensemble. ``forward([x, a]) -> q`` ``[2, B]`` (``q[0]``, ``q[1]``
    as :class:`Critic`'s pair). Initialised as :class:`Critic` would be (the same draws), then stacked; the module
    indices mirror :func:`~magwarp.training.policy.mlp`'s (``net.0`` linear, ``net.1`` layer norm, ``net.2`` ReLU...),
    so its parameters come in the pair's order within a head."""

    def __init__(self, n_in: int, hidden: list[int], amp: str = "off"):
        super().__init__()
        heads = [_q_mlp(n_in, hidden) for _ in range(HEADS)]
        layers: list[nn.Module] = []
        for parts in zip(*heads):
            if isinstance(parts[0], nn.Linear):
                layers.append(EnsembleLinear(_stack([p.weight.data for p in parts]),
                                             _stack([p.bias.data for p in parts])))
            elif isinstance(parts[0], nn.LayerNorm):
                layers.append(EnsembleLayerNorm(_stack([p.weight.data for p in parts]),
                                                _stack([p.bias.data for p in parts]), parts[0].eps))
            else:
                layers.append(copy.deepcopy(parts[0]))
        self.net = nn.Sequential(*layers)
        self.amp = amp

    def forward(self, xa: torch.Tensor, a: torch.Tensor | None = None) -> torch.Tensor:
        """Q values ``[2, B]`` of ``[x, a]`` (given joined, or as ``x`` and ``a``)."""
        xa = xa if a is None else torch.cat([xa, a], -1)
        with autocast(xa.device, self.amp):
            return self.net(xa).float().squeeze(-1)


def make_critic(impl: str, n_in: int, hidden: list[int], amp: str = "off") -> nn.Module:
    """``--critic-impl``: :class:`EnsembleCritic` (``ensemble``) or :class:`Critic` (``pair``)."""
    if impl == "ensemble":
        return EnsembleCritic(n_in, hidden, amp)
    if impl == "pair":
        return Critic(n_in, hidden, amp)
    raise ValueError(f"--critic-impl must be one of {CRITIC_IMPLS}, got {impl!r}")


def q_min(q) -> torch.Tensor:
    """The smaller of the two Q values (either critic's output)."""
    return torch.min(q[0], q[1])


def q_regression_loss(q, target: torch.Tensor) -> torch.Tensor:
    """The sum over both heads of the mean squared error to ``target`` ``[B]``: for the ensemble's ``[2, B]`` one
    loss over both heads (the mean over ``2 B`` times 2), for the pair's two tensors the sum of their two losses."""
    if isinstance(q, torch.Tensor):
        return F.mse_loss(q, target.expand_as(q)) * q.shape[0]
    return F.mse_loss(q[0], target) + F.mse_loss(q[1], target)


# ------------------------------------------------------------------------------------------------ checkpoints
def critic_layout(state: dict) -> str:
    """``pair`` (keys ``q1.*``/``q2.*``) or ``ensemble`` (``net.*``) of a critic state dict; ValueError otherwise."""
    keys = list(state)
    if keys and all(k.startswith(("q1.", "q2.")) for k in keys):
        return "pair"
    if keys and all(k.startswith("net.") for k in keys):
        return "ensemble"
    raise ValueError(f"not a SAC critic state (keys {keys[:4]}...): expected q1.*/q2.* (pair) or net.* (ensemble)")


def _pair_keys(state: dict) -> list[str]:
    """A pair state's parameter names within a head, in the MLP's order (``0.weight``, ``0.bias``, ``1.weight``...)."""
    return [k[len("q1."):] for k in state if k.startswith("q1.")]


def convert_critic_state(state: dict, to: str) -> dict:
    """A critic state dict (either layout) in the layout ``to`` (``ensemble`` or ``pair``); the same tensors."""
    have = critic_layout(state)
    if have == to:
        return state
    if to == "ensemble":
        return {f"net.{k}": _stack([state[f"q1.{k}"], state[f"q2.{k}"]]) for k in _pair_keys(state)}
    if to != "pair":
        raise ValueError(f"critic layout must be one of {CRITIC_IMPLS}, got {to!r}")
    out: dict[str, torch.Tensor] = {}
    for k, v in state.items():
        for h, t in enumerate(_unstack(v)):
            out[f"q{h + 1}.{k[len('net.'):]}"] = t
    return dict(sorted(out.items(), key=lambda kv: kv[0][:2]))  # q1's keys first, each in the MLP's order


def convert_critic_optimizer(opt_state: dict, have: str, to: str) -> dict:
    """An Adam state dict of a critic in layout ``have`` -> one for the layout ``to``: the moments (``exp_avg``,
    ``exp_avg_sq``) convert as the weights do, ``step`` is shared. One parameter group (the critic's optimiser)."""
    if have == to:
        return opt_state
    groups = opt_state["param_groups"]
    if len(groups) != 1:
        raise ValueError(f"a critic optimiser state has one parameter group, got {len(groups)}")
    ids = groups[0]["params"]
    state = opt_state["state"]
    per_head = len(ids) // HEADS if have == "pair" else len(ids)
    new_state: dict[int, dict] = {}
    if to == "ensemble":
        for j in range(per_head):
            heads = [state.get(ids[h * per_head + j]) for h in range(HEADS)]
            if heads[0] is None:
                continue
            new_state[j] = {k: (_stack([s[k] for s in heads]) if k.startswith("exp_avg") else v.clone())
                            for k, v in heads[0].items()}
        count = per_head
    else:
        for j, i in enumerate(ids):
            s = state.get(i)
            if s is None:
                continue
            split = {k: _unstack(v) if k.startswith("exp_avg") else [v.clone() for _ in range(HEADS)]
                     for k, v in s.items()}  # a step tensor of its own per head (an optimiser steps it in place)
            for h in range(HEADS):
                new_state[h * per_head + j] = {k: v[h] for k, v in split.items()}
        count = per_head * HEADS
    return {"state": new_state, "param_groups": [{**groups[0], "params": list(range(count))}]}
