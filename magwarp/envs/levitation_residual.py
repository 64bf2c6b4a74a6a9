"""Residual learning on the levitation baseline: ``magwarp/LevitationResidual-v0``.

The env of :mod:`magwarp.envs.levitation` (every option the same; ``action="wrench"`` by default here) whose action
is a correction to the scripted baseline's (:class:`~magwarp.policies.levitation.LevitationPD`: a PD law through
the commutation): the applied action is ``pd(obs) + residual_scale * action`` in the base env's action units
(wrench shares of ``wrench_scale``, or current shares of the coil limit), unclipped as in the base env (currents
beyond their limit saturate; the commutation holds a wrench's currents within the limits). A zero action is the
baseline exactly, so a policy starts from a controller that already holds the mover and learns what the reward
(pose error plus ``loss_weight`` times the copper loss) asks beyond it, e.g. a transient that spends less energy.
Observation, reward, ends and ``info`` are the base env's.

Why: from scratch, PPO first has to learn to levitate a free 6-DoF body at 1 kHz from a 19-number observation
that holds yaw as an angle (the wrench is world-frame, so tilt corrections turn with the yaw); on a CPU in
minutes it learns to hover but not to track (``benchmarks/levitation_policy.py``).
"""

from __future__ import annotations

import math

import torch

from magwarp.envs.levitation import LevitationEnv
from magwarp.policies.levitation import DEFAULT_MAX_ACC, LevitationPD

__all__ = ["LevitationResidualEnv"]


class LevitationResidualEnv(LevitationEnv):
    """:class:`LevitationEnv` whose action corrects the PD baseline's (see the module docstring).

    ``residual_scale``: the correction's range as a share of the action range (default 0.25: 10 N and 0.5 N m with
    the default ``wrench_scale``); ``pd_frequency``: the baseline's natural frequency (Hz); ``pd_max_acc``: its
    feedback acceleration limits (m/s^2 linear, rad/s^2 angular; default the shipped baseline's). A softer or
    otherwise retuned baseline (``paper.py``'s ``lev_residual_soft``) changes what the policy corrects, not what
    it is compared with: ``benchmarks/levitation_policy.py`` measures the shipped PD."""

    def __init__(self, num_envs: int = 1, *, residual_scale: float = 0.25, pd_frequency: float = 15.0,
                 pd_max_acc: tuple[float, float] = DEFAULT_MAX_ACC, action: str = "wrench", **kwargs):
        ok = isinstance(residual_scale, (int, float)) and math.isfinite(residual_scale)
        if not ok or not 0.0 < residual_scale <= 2.0:
            raise ValueError(f"residual_scale must be a number in (0, 2], got {residual_scale!r}")
        super().__init__(num_envs, action=action, **kwargs)
        self.residual_scale = float(residual_scale)
        self.baseline = LevitationPD(self, frequency=pd_frequency, max_acc=pd_max_acc)
        self.pd_frequency, self.pd_max_acc = float(pd_frequency), tuple(self.baseline.max_acc)

    def _apply_action(self, action: torch.Tensor) -> None:
        base = self.baseline(self._get_obs())  # at the current state (what the policy saw)
        super()._apply_action(base + self.residual_scale * action)
