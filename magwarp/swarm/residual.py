"""Residual learning on the swarm planner: ``magwarp/SwarmResidual-v0``.

:class:`~magwarp.swarm.SwarmEnv` (every option the same, ``shield=True`` by default here) whose action is a
per-mover correction to the scripted planner's (:class:`~magwarp.swarm.SwarmPlanner`: one-way lanes, ORCA and its
provably collision-free safety filter; the mechanism is :class:`~magwarp.envs.residual.ResidualAction`): the applied
acceleration is ``planner + residual_scale * action`` (m/s^2), the action in the base env's range ``[-a_max, a_max]``
per component, so the correction reaches ``residual_scale * a_max`` (5 m/s^2 by default: a velocity change of up
to 0.2 m/s per 40 ms step). With the shield on (the default) the sum then passes the env's safety filter
(:meth:`SwarmEnv._shield <magwarp.swarm.SwarmEnv>`), so no correction can add a collision: a policy only has to
learn throughput. A zero action is the planner exactly: the planner run on ``SwarmEnv(shield=True)``, bit for bit
(the shield rarely changes one of the planner's own commands, e.g. one it cannot reach within ``a_max``; a run on the
unshielded env is the same until it does, then parts from it), so a policy trained from a zero-initialised actor
starts at the planner's numbers; ``magwarp eval magwarp/SwarmResidual-v0 --policy scripted`` runs the zero
correction.

Observation: the base env's per-mover observation followed by the planner's action for the current state divided by
``a_max`` (2 columns: the policy sees what it corrects). Reward, ends and ``info`` are the base env's.

Why an env and not only a policy: the planner reads the env's state, not the observation (the simulator's positions
and goals, its own neighbour search within the safety filter's reach), and keeps state between calls (each mover's
deadlock counter, updated on every call), so it runs inside the env, once per env step: at observation time,
after the step's goals and respawns, into :attr:`SwarmResidualEnv.planner_action`, which the
observation shows and the next step adds the correction to. Resets keep it consistent: a world that is reset (by
``reset()``, a ``reset_mask`` or an autoreset) and a mover that respawns start with the counter of a fresh planner
(:meth:`SwarmPlanner.reset`). Where worlds can end (``max_episode_steps``, ``on_collision="end"``) the step's
autoreset plans a second time for the worlds that restart (its action and counters kept for them alone, the other
worlds keep those of the step's observation; the step has no host sync to skip it when no world ends, so such envs
run the planner twice a step); the training regime (respawns, no step limit) plans once. The planner's torch
operations and Warp launches run on the current stream, so on CUDA they are part of the env's recorded step graph.

Every option is a field of :class:`SwarmResidualConfig` (:class:`~magwarp.swarm.SwarmConfig`'s, plus
``residual_scale`` and ``planner``, the keyword options of :class:`SwarmPlanner`).
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
import torch

from magwarp.envs.residual import ResidualAction, check_residual_scale
from magwarp.swarm.env import SwarmConfig, SwarmEnv
from magwarp.swarm.planner import SwarmPlanner

__all__ = ["SwarmResidualConfig", "SwarmResidualEnv", "PLANNER_OPTIONS"]

#: the keyword options of :class:`SwarmPlanner` (``planner={...}``)
PLANNER_OPTIONS = tuple(n for n, p in inspect.signature(SwarmPlanner.__init__).parameters.items()
                        if p.kind is p.KEYWORD_ONLY)


@dataclass(frozen=True)
class SwarmResidualConfig(SwarmConfig):
    """Options of :class:`SwarmResidualEnv`: :class:`~magwarp.swarm.SwarmConfig`'s (``shield`` on by default), and
    ``residual_scale``: the correction's range as a share of ``a_max`` (in (0, 2], default 0.5, as
    ``magwarp/CoopPushResidual-v0``); ``planner``: keyword options of :class:`~magwarp.swarm.SwarmPlanner` (e.g.
    ``{"traffic": "lanes"}``; None: its defaults). The names are checked here, the values by the planner.
    ``gate_speed`` (m/s, >= 0; 0: off): the correction moves only movers at least this fast that are not in the
    planner's deadlock escape; the others take the planner's action alone (a correction kept on stopped movers and
    against the escapes jams a crowd: the 256-mover policy at 1,024 movers over 80 s, 0.69x the planner's goals with
    592 movers deadlocked, 0.96x with 1 when gated at 0.3 m/s, CPU)."""

    shield: bool = True
    residual_scale: float = 0.5
    planner: dict | None = None
    gate_speed: float = 0.0

    def __post_init__(self):
        super().__post_init__()
        check_residual_scale(self.residual_scale)
        if self.planner is not None:
            if not isinstance(self.planner, dict):
                raise TypeError(f"planner must be a dict of SwarmPlanner options or None, got {self.planner!r}")
            unknown = sorted(str(k) for k in self.planner if k not in PLANNER_OPTIONS)
            if unknown:
                raise TypeError(f"unknown planner options {unknown}; SwarmPlanner takes {list(PLANNER_OPTIONS)}")
        g = self.gate_speed
        if isinstance(g, bool) or not isinstance(g, (int, float, np.integer, np.floating)) or not 0.0 <= g < np.inf:
            raise ValueError(f"gate_speed must be a finite speed >= 0 (m/s), got {g!r}")
        if self.learn_jerk:
            raise ValueError("SwarmResidualEnv corrects the planner's accelerations: learn_jerk must be False, got "
                             "learn_jerk=True")


class SwarmResidualEnv(ResidualAction, SwarmEnv):
    """:class:`SwarmEnv` whose action corrects the scripted planner's (see the module docstring).
    ``SwarmResidualEnv(num_envs, config=None, **options)`` with a :class:`SwarmResidualConfig` and/or its fields as
    keywords. :attr:`planner` is the :class:`SwarmPlanner` it runs (the mixin's ``baseline``)."""

    config_type = SwarmResidualConfig
    #: what the next observation plans: None (nothing: the action is current), True (every world: the state moved on)
    #: or a ``[num_envs]`` bool mask (the worlds reset since)
    _replan = None

    def __init__(self, num_envs: int = 1, config: SwarmResidualConfig | None = None, **kwargs):
        # the config (the residual's and the planner's option names too) is checked before the env is built; the
        # base constructor's first reset runs before the planner exists (its observation is not returned)
        super().__init__(num_envs, config, **kwargs)
        cfg = self.config
        self.planner_action = torch.zeros(self.num_envs, self.num_movers, 2, device=self.device)
        self._init_residual(SwarmPlanner(self, **(cfg.planner or {})), cfg.residual_scale)
        self._obs_scale = 1.0 / float(cfg.a_max)
        m = self.num_movers
        self._set_spaces(gym.spaces.Box(-np.inf, np.inf, (m, self.own_dim + self.local.dim + 2), np.float32),
                         self.single_action_space)
        self._replan = True  # the planner's action for the state the constructor's reset left (a fresh planner's)
        self._policy_obs = self._get_obs()

    @property
    def planner(self) -> SwarmPlanner:
        """The scripted planner whose action the policy corrects."""
        return self.baseline

    def baseline_action(self) -> torch.Tensor:
        """The planner's action for the state the last observation showed (computed once, at observation time)."""
        return self.planner_action

    def _plan(self, worlds: torch.Tensor | None = None) -> None:
        """Run the planner once on the current state: its action into :attr:`planner_action`. ``worlds`` (bool
        ``[num_envs]``): only those worlds take the new action and deadlock counters, the others keep theirs."""
        planner = self.baseline
        if worlds is None:
            self.planner_action.copy_(planner())
            return
        kept = planner.stuck.clone()
        action = planner()
        planner.stuck.copy_(torch.where(worlds[:, None], planner.stuck, kept))
        self.planner_action.copy_(torch.where(worlds[:, None, None], action, self.planner_action))

    # ------------------------------------------------------------------ the base env's hooks
    def _apply_action(self, action: torch.Tensor) -> None:
        gate = float(self.config.gate_speed)
        if gate > 0.0:  # no correction for slow movers and the planner's deadlock escapes
            planner = self.baseline
            moving = self.sim.vel[..., :2].norm(dim=-1) >= gate
            if planner.patience > 0:
                moving = moving & (planner.stuck < planner.patience)
            action = action.reshape(moving.shape + (2,)) * moving[..., None]
        super()._apply_action(action)  # the planner's action + residual_scale * action, through the shield
        self._replan = True  # the state moves on: the next observation plans every world once

    def _get_obs(self) -> torch.Tensor:
        obs = super()._get_obs()  # also points the local view (what the planner reads) at the new state
        if self.baseline is None:  # the base constructor's reset, before the planner exists
            return obs
        if self._replan is not None:
            self._plan(None if self._replan is True else self._replan)
            self._replan = None
        return torch.cat([obs, self.planner_action * self._obs_scale], dim=-1)

    def _reset_envs(self, mask: torch.Tensor) -> None:
        super()._reset_envs(mask)
        if self.baseline is None:
            return
        self.baseline.reset(mask)  # a fresh planner's deadlock counters for the new episodes
        if mask is self._all or self._replan is True:
            self._replan = True
        else:
            self._replan = mask if self._replan is None else mask | self._replan

    def _respawn(self, want: torch.Tensor) -> torch.Tensor:
        pending = super()._respawn(want)
        self.baseline.reset(want)  # a respawned mover starts a new agent episode: a fresh deadlock counter
        return pending
