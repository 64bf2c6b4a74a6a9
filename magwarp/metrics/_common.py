"""Shared plumbing of the metric trackers: device state with torch views, masked resets, per-repeat sums."""

from __future__ import annotations

import torch
import warp as wp

__all__ = ["MetricState", "group_sum"]


def _expand(mask: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    return mask.view(-1, *([1] * (t.dim() - 1)))


def group_sum(x: torch.Tensor, num_groups: int) -> torch.Tensor:
    """Sum of per-world values ``[W, ...]`` over consecutive blocks of ``W / num_groups`` worlds -> ``[G]`` float64."""
    x = x.reshape(x.shape[0], -1).to(torch.float64).sum(1)
    if x.shape[0] % num_groups:
        raise ValueError(f"{x.shape[0]} worlds do not split into {num_groups} equal groups")
    return x.view(num_groups, -1).sum(1)


class MetricState:
    """Named Warp arrays (for the kernels) with zero-copy torch views ``t[name]`` (for resets and summaries).

    ``episode`` fields hold the previous cycle's values (they restart with every physical reset of a world);
    ``total`` fields are the accumulators (they restart only with :meth:`clear`).
    """

    def __init__(self, device: wp.context.Device, num_worlds: int):
        self.device = device
        self.num_worlds = num_worlds
        self.arrays: dict[str, wp.array] = {}
        self.t: dict[str, torch.Tensor] = {}
        self._fill: dict[str, float] = {}
        self.episode: list[str] = []
        self.total: list[str] = []

    def add(self, name: str, shape: tuple[int, ...], dtype, *, fill: float = 0, episode: bool = False) -> wp.array:
        arr = wp.zeros(shape, dtype=dtype, device=self.device)
        self.arrays[name] = arr
        self.t[name] = wp.to_torch(arr)
        self.t[name].fill_(fill)
        self._fill[name] = fill
        (self.episode if episode else self.total).append(name)
        return arr

    def add_torch(self, name: str, shape: tuple[int, ...], dtype: torch.dtype, device: torch.device, *,
                  fill: float = 0) -> torch.Tensor:
        """An accumulator updated by torch ops once per env step (no kernel reads it)."""
        self.t[name] = torch.full(shape, fill, dtype=dtype, device=device)
        self._fill[name] = fill
        self.total.append(name)
        return self.t[name]

    def _fill_masked(self, names: list[str], mask: torch.Tensor) -> None:
        for name in names:
            t = self.t[name]
            t.masked_fill_(_expand(mask, t), self._fill[name])

    def restart_episode(self, mask: torch.Tensor) -> None:
        self._fill_masked(self.episode, mask)

    def clear(self, mask: torch.Tensor) -> None:
        self._fill_masked(self.episode + self.total, mask)


class Tracker:
    """Base of the per-family trackers: the ``active`` flags, :meth:`reset`, :meth:`freeze` and the env hooks.

    Subclasses allocate ``self.state`` fields, register their cycle hook, and implement ``on_step`` and ``summary``.
    """

    #: rows of the paper's table for this task family: (summary key, label, count key)
    ROWS: tuple[tuple[str, str, str], ...] = ()

    def __init__(self, env, device: wp.context.Device):
        if getattr(env, "benchmark_metrics", None) is not None:
            raise ValueError("this env already has a metrics tracker (env.benchmark_metrics)")
        self.env = env
        self.num_worlds = env.num_envs
        self.torch_device = env.device
        self.state = MetricState(device, self.num_worlds)
        self.active = self.state.add("active", (self.num_worlds,), int, fill=1)
        self._all = torch.ones(self.num_worlds, dtype=torch.bool, device=self.torch_device)

    @property
    def t(self) -> dict[str, torch.Tensor]:
        return self.state.t

    def _mask(self, mask) -> torch.Tensor:
        if mask is None:
            return self._all
        mask = torch.as_tensor(mask, device=self.torch_device)
        if mask.shape != (self.num_worlds,) or mask.dtype != torch.bool:
            raise ValueError(f"mask must be a bool tensor of shape ({self.num_worlds},), "
                             f"got {mask.dtype} {tuple(mask.shape)}")
        return mask

    def reset(self, mask=None) -> None:
        """Zero every accumulator of the worlds in ``mask`` (all if None) and let them count again."""
        self.state.clear(self._mask(mask))

    def freeze(self, mask) -> None:
        """Stop counting in the worlds of ``mask`` (e.g. once their evaluation episode is over); no sync."""
        self.t["active"].masked_fill_(self._mask(mask), 0)

    def episode_reset(self, mask: torch.Tensor) -> None:
        """Called by the env when it physically resets worlds: forget their previous-cycle values."""
        self.state.restart_episode(mask)
