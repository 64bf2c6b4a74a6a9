"""A resting support under every mover of a simulator (the tile surface, or the mover's landing pads): a one-sided
vertical stop applied after every cycle (:mod:`magwarp.kernels.support`).

    support = RestingSupport(sim, height=0.008)   # mover centres cannot sink below 8 mm
    support.height[w] = float("-inf")             # no support in world w
"""

from __future__ import annotations

import math

import torch
import warp as wp

from magwarp.kernels.support import support_kernel

__all__ = ["RestingSupport"]


class RestingSupport:
    """Attach the support to ``sim`` at ``height`` (m, the lowest height of a mover centre; per world in
    :attr:`height`)."""

    def __init__(self, sim, height: float):
        try:
            h = float(height)
        except (TypeError, ValueError):
            h = float("nan")
        if math.isnan(h) or h == math.inf:
            raise ValueError(f"height must be a number or -inf (no support), got {height!r}")
        self.sim = sim
        self._height = wp.full(sim.num_worlds, h, dtype=float, device=sim.device)
        sim.add_cycle_hook(self._after_cycle)

    def _after_cycle(self, sim) -> None:
        wp.launch(support_kernel, dim=(sim.num_worlds, sim.num_movers), device=sim.device, inputs=[self._height],
                  outputs=[sim.state.pos, sim.state.vel])

    @property
    def height(self) -> torch.Tensor:
        """[W] support height per world (m; writable)."""
        return self.sim._t(self._height)
