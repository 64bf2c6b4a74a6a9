"""Copper energy in an evaluation: what the coils spend (the physical energy, J), beside MagBotSim's kinematic
smoothness proxy. Only for envs whose simulator runs the magnetic model (``force_model="magnetic"``:
:class:`magwarp.magnetics.drive.MagneticDrive` integrates every mover's copper loss, sum of R i^2, over every 1 ms
cycle inside the step graph).

``e = CopperEnergy.attach(env)`` is None without the magnetic model. ``e.reset()`` marks the start of a window (a
device copy, no sync); ``e.summary(num_groups)`` gives, per group of consecutive worlds (one evaluation repeat
each), the energy spent since (J, all movers of the group) and the mean copper loss per mover (W) over the
window's simulated time.
"""

from __future__ import annotations

import torch

__all__ = ["CopperEnergy"]


class CopperEnergy:
    """Copper energy of a batched env's movers since :meth:`reset` (see the module docstring)."""

    def __init__(self, env, drive):
        self.env = env
        self.drive = drive
        self._start = drive.energy.clone()

    @classmethod
    def attach(cls, env) -> "CopperEnergy | None":
        base = getattr(env, "unwrapped", env)
        drive = getattr(getattr(base, "sim", None), "magnetic_drive", None)
        return cls(base, drive) if drive is not None else None

    def reset(self) -> None:
        self._start.copy_(self.drive.energy)

    def summary(self, num_groups: int, seconds: float) -> dict[str, torch.Tensor]:
        """``copper_energy_j`` (J per group) and ``copper_power_w`` (mean W per mover over ``seconds`` of simulated
        time) since :meth:`reset`."""
        spent = (self.drive.energy - self._start).sum(dim=1)  # [W] J
        per_group = spent.reshape(num_groups, -1)
        power = per_group.mean(dim=1) / max(float(seconds), 1e-12) / self.env.sim.num_movers
        return {"copper_energy_j": per_group.sum(dim=1), "copper_power_w": power}
