"""Residual learning on the levitation baseline: ``magwarp/LevitationResidual-v0``.

The env of :mod:`magwarp.envs.levitation` (every option the same; ``action="wrench"`` by default here) whose action
is a correction to the scripted baseline's (:class:`~magwarp.policies.levitation.LevitationPD`: a PD law through
the commutation; the mechanism is :class:`~magwarp.envs.residual.ResidualAction`): the applied action is
``pd(obs) + residual_scale * action`` in the base env's action units (wrench shares of ``wrench_scale``, or current
shares of the coil limit), unclipped as in the base env (currents beyond their limit saturate; the commutation holds
a wrench's currents within the limits). A zero action is the baseline exactly, so a policy starts from a controller
that already holds the mover and learns what the reward (pose error plus ``loss_weight`` times the copper loss) asks
beyond it, e.g. a transient that spends less energy.
Observation, reward, ends and ``info`` are the base env's.

Why: from scratch, PPO first has to learn to levitate a free 6-DoF body at 1 kHz from a 19-number observation
that holds yaw as an angle (the wrench is world-frame, so tilt corrections turn with the yaw); on a CPU in
minutes it learns to hover but not to track (``benchmarks/levitation_policy.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

from magwarp.envs.levitation import LevitationEnv
from magwarp.envs.levitation_config import LevitationConfig
from magwarp.envs.residual import ResidualAction, check_residual_scale
from magwarp.policies.levitation import DEFAULT_MAX_ACC, LevitationPD

__all__ = ["LevitationResidualConfig", "LevitationResidualEnv"]


@dataclass(frozen=True)
class LevitationResidualConfig(LevitationConfig):
    """Options of :class:`LevitationResidualEnv`: :class:`~magwarp.envs.levitation_config.LevitationConfig`'s
    (``action="wrench"`` by default here), and ``residual_scale``: the correction's range as a share of the action
    range (default 0.25: 10 N and 0.5 N m with the default ``wrench_scale``); ``pd_frequency``: the baseline's natural
    frequency (Hz); ``pd_max_acc``: its feedback acceleration limits (m/s^2 linear, rad/s^2 angular; default the
    shipped baseline's; checked by the baseline). A softer or otherwise retuned baseline (``paper.py``'s
    ``lev_residual_soft``) changes what the policy corrects, not what it is compared with:
    ``benchmarks/levitation_policy.py`` measures the shipped PD."""

    action: str = "wrench"
    residual_scale: float = 0.25
    pd_frequency: float = 15.0
    pd_max_acc: tuple[float, float] = DEFAULT_MAX_ACC

    def __post_init__(self):
        super().__post_init__()
        check_residual_scale(self.residual_scale)


class LevitationResidualEnv(ResidualAction, LevitationEnv):
    """:class:`LevitationEnv` whose action corrects the PD baseline's (see the module docstring):
    ``LevitationResidualEnv(num_envs, config=None, **options)`` with a :class:`LevitationResidualConfig` and/or its
    fields as keywords."""

    config_type = LevitationResidualConfig

    def __init__(self, num_envs: int = 1, config: LevitationResidualConfig | None = None, **kwargs):
        super().__init__(num_envs, config, **kwargs)  # the config (the residual's options too) is checked first
        cfg = self.config
        baseline = LevitationPD(self, frequency=cfg.pd_frequency, max_acc=cfg.pd_max_acc)
        self._init_residual(baseline, cfg.residual_scale)
        self.pd_frequency, self.pd_max_acc = float(cfg.pd_frequency), tuple(baseline.max_acc)
