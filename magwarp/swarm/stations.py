"""Pick-up and drop-off stations for the material-flow variant of the swarm env.

Each mover carries jobs: it drives to a pick-up station (its goal), picks a job up on arrival, drives to a drop-off
station and delivers the job there, then heads for a pick-up station again. Stations are drawn uniformly from
their set for every new leg. ``Stations.auto`` places ``num`` stations of each kind as a collision-free set on the
layout (:class:`~magwarp.swarm.Placer`), pick-ups on the side of smaller x, drop-offs on the other, so that jobs
cross the layout as on a transport line.
"""

from __future__ import annotations

import numpy as np
import torch

from magwarp.layout import Layout, MoverSpec
from magwarp.swarm.placement import Placer

__all__ = ["Stations"]


class Stations:
    """Station positions ``pickup`` ``(P, 2)`` and ``dropoff`` ``(D, 2)`` (m), checked against the wall rule: a
    mover's footprint (grown by the sampling offset and the wall margin) must fit on the tiles at each."""

    def __init__(self, pickup, dropoff, layout: Layout, mover: MoverSpec, *, offset: float = 0.0, device=None):
        placer = Placer(layout, 1, 1, mover=mover, offset=offset, device=device)
        self.device = placer.torch_device
        sets = {}
        for name, value in (("pickup", pickup), ("dropoff", dropoff)):
            arr = np.asarray(value, dtype=np.float64)
            if arr.ndim != 2 or arr.shape[1] != 2 or len(arr) == 0 or not np.all(np.isfinite(arr)):
                raise ValueError(f"{name} stations must be a non-empty finite (n, 2) array of x/y, got shape "
                                 f"{arr.shape}")
            xy = torch.as_tensor(arr, dtype=torch.float32, device=self.device)
            bad = torch.nonzero(~placer.on_tiles(xy)).flatten().tolist()
            if bad:
                where = tuple(np.round(arr[bad[0]], 4).tolist())
                raise ValueError(f"{name} station {bad[0]} at {where} leaves no room for a mover on the tiles "
                                 f"(collision size, wall margin and sampling offset)")
            sets[name] = xy
        self.pickup, self.dropoff = sets["pickup"], sets["dropoff"]

    @classmethod
    def auto(cls, layout: Layout, mover: MoverSpec, num: int, *, offset: float = 0.0, device=None, seed: int = 0):
        """``num`` pick-ups and ``num`` drop-offs, placed clear of each other; pick-ups are the half with smaller x."""
        if int(num) < 1:
            raise ValueError(f"num_stations must be >= 1, got {num!r}")
        xy = Placer(layout, 2 * int(num), 1, mover=mover, offset=offset, device=device, seed=seed).sample()[0]
        order = torch.argsort(xy[:, 0])
        return cls(xy[order[:num]].cpu().numpy(), xy[order[num:]].cpu().numpy(), layout, mover, offset=offset,
                   device=device)

    def sample(self, dropoff: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """A station per entry of ``dropoff`` (bool ``[...]``): a drop-off where true, else a pick-up; ``[..., 2]``."""
        shape = tuple(dropoff.shape)
        p = self.pickup[torch.randint(len(self.pickup), shape, generator=generator, device=self.device)]
        d = self.dropoff[torch.randint(len(self.dropoff), shape, generator=generator, device=self.device)]
        return torch.where(dropoff[..., None], d, p)
