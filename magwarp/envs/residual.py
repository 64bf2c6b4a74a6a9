"""Residual actions on a scripted baseline, shared by the residual envs (:mod:`magwarp.envs.levitation_residual`,
:mod:`magwarp.envs.coop_push_residual`).

:class:`ResidualAction` is a mixin of a batched env: the action the env receives is a correction, and what it
applies is ``baseline(obs) + residual_scale * action`` in the base env's action units, where ``obs`` is the
observation the env last returned (what the policy saw; ``reset`` and ``step`` keep it, so sensor noise is drawn once)
and ``baseline`` is the base env's scripted controller. A zero action is the baseline exactly, so a policy trained on
it starts from the baseline's behaviour and learns what the reward asks beyond it. The sum is passed on unclipped,
as the base env takes any action (its actuator limits it as usual).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch

__all__ = ["ResidualAction", "ZeroAction", "check_residual_scale"]


def check_residual_scale(residual_scale, high: float = 2.0) -> float:
    """``residual_scale`` as a float in ``(0, high]``; anything else is a ValueError naming it."""
    ok = isinstance(residual_scale, (int, float)) and not isinstance(residual_scale, bool)
    if not ok or not math.isfinite(residual_scale) or not 0.0 < residual_scale <= high:
        raise ValueError(f"residual_scale must be a number in (0, {high:g}], got {residual_scale!r}")
    return float(residual_scale)


class ResidualAction:
    """Mixin (before the base env class): ``baseline(obs) + residual_scale * action`` is what the base env applies.

    The env calls :meth:`_init_residual` once its base is built."""

    baseline: Callable | None = None
    residual_scale: float = 1.0
    _policy_obs = None

    def _init_residual(self, baseline: Callable, residual_scale: float) -> None:
        self.baseline = baseline
        self.residual_scale = check_residual_scale(residual_scale)

    def reset(self, *args, **kwargs):
        obs, info = super().reset(*args, **kwargs)
        self._policy_obs = obs
        return obs, info

    def step(self, action):
        out = super().step(action)
        self._policy_obs = out[0]
        return out

    def baseline_action(self) -> torch.Tensor:
        """The baseline's action for the observation the env last returned (the current state before any)."""
        obs = self._policy_obs if self._policy_obs is not None else self._get_obs()
        return self.baseline(obs)

    def _apply_action(self, action: torch.Tensor) -> None:
        base = self.baseline_action().reshape(action.shape)
        super()._apply_action(base + self.residual_scale * action)

    def scripted_policy(self):
        """The baseline alone (what ``magwarp eval --policy scripted`` runs here): the zero correction."""
        return ZeroAction(self)


class ZeroAction:
    """The scripted policy of a residual env: the zero correction (the env then applies its baseline alone)."""

    def __init__(self, env):
        self.shape = (env.num_envs, *env.single_action_space.shape)
        self.device = env.device

    def __call__(self, obs) -> torch.Tensor:
        return torch.zeros(self.shape, device=self.device)
