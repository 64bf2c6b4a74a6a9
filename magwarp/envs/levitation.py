"""Low-level control of one levitating mover by its coil currents: ``magwarp/Levitation-v0`` and its variants.

Ids: ``magwarp/Levitation-v0`` (``task="setpoint"``), ``magwarp/LevitationHover-v0`` (``task="hover"``),
``magwarp/LevitationWrench-v0`` (``action="wrench"``), ``magwarp/LevitationLiftoff-v0`` (``task="liftoff"``),
``magwarp/LevitationTrack-v0`` (``task="track"``), ``magwarp/LevitationMove-v0`` (``task="move"``),
``magwarp/LevitationPayload-v0`` (``task="payload"``), ``magwarp/LevitationPendulum-v0`` (``task="pendulum"``).

The mover is a free 6-DoF rigid body (no impedance hold, no planar drive) under gravity and the magnetic wrench of
the coils under it (:class:`~magwarp.magnetics.actuator.CoilActuator`: the wrench-table model, Gamma(q) updated
every control cycle), at a 250 µs control cycle; one env step holds the action for ``num_cycles`` cycles (default
4: 1 ms, a 1 kHz policy).

* **Action** (``action="currents"``, default): the currents of the coil window under the mover, as shares of the
  coil current limit in [-1, 1] (``[slots]``; slot order: per coil layer, the block of the layer's coil grid that
  holds every coil within the footprint of the mover's centre, row by row: :attr:`coil_ids` names the coils).
  Beyond +-1 a current stays at its limit (the amplifier saturates; :attr:`saturated`). Slots without a coil are
  ignored. ``action="wrench"``: a wanted wrench (force / ``wrench_scale[0]`` N, torque / ``wrench_scale[1]`` N m,
  each in [-1, 1]) that the commutation turns into least-loss currents every cycle.
* **Observation** (SI): position (3), roll/pitch/yaw (3), velocity (3), angular velocity (3), the reference's
  position (3) and yaw (1), and the position error (3): 19 columns, then the task's own (:attr:`obs_slices` names
  every part; :mod:`magwarp.envs.levitation_tasks`).
* **Task** (``task``, options in ``task_options``: :mod:`magwarp.envs.levitation_tasks`): ``"hover"`` holds the start
  pose; ``"setpoint"`` (default) reaches a setpoint up to ``setpoint_range`` (m) away in x/y, at a gap in
  ``setpoint_gap`` and a yaw up to ``setpoint_yaw`` (rad) from the start; ``"liftoff"`` rises from the lowest gap to
  a hover gap; ``"track"`` follows a moving 6-DoF reference; ``"move"`` reaches a distant goal by a deadline on
  little copper energy; ``"payload"`` hovers with a rigid payload off the centre; ``"pendulum"`` hovers with a
  swinging one. Starts: a random x/y within ``start_range`` of the layout's centre, any yaw, level, at rest.
* **Reward** per step: ``-w (|p - p*| / pos_scale + |rotation error| / rot_scale) - loss_weight * P`` with ``P`` the
  copper loss (W, the mean over the step's cycles) and ``w`` 1 (``"move"``: 0 before its deadline);
  ``failure_reward`` when the mover fails.
* **Ends**: terminated when the gap leaves ``fail_gap`` (m; the default ``magnetics``' table covers 2-6 mm), a
  tilt exceeds ``fail_tilt`` (rad) or the x/y error exceeds ``fail_distance`` (m; ``"move"``: plus the move's
  length); truncated after ``max_episode_steps``.
* ``info``: ``copper_loss`` (W, ``[N]``), ``pos_error`` (m), ``rot_error`` (rad), ``saturated`` (coils at their
  limit), ``is_success`` (not failed and within ``success_tol``: (m, rad)); :attr:`energy` (J, since construction)
  as a torch view. ``magwarp eval`` reads them (:mod:`magwarp.metrics.levitation`).

The wrench table takes the mover level (its roll and pitch are not looked up): keep tilts small (about 1% of the
peak column per 2 mrad, :mod:`magwarp.magnetics.table`). The scripted baseline is
:class:`magwarp.policies.levitation.LevitationPD` (a PD law through the commutation; :meth:`scripted_policy`).
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from magwarp._checks import as_count
from magwarp.envs.base import MagwarpVecEnv
from magwarp.envs.config import resolve_config
from magwarp.envs.levitation_config import LevitationConfig
from magwarp.envs.levitation_tasks import make_task, wrap
from magwarp.layout import Layout, MoverSpec

__all__ = ["LevitationConfig", "LevitationEnv"]

#: the observation's common columns (name, width); the task's follow
OBS_PARTS = (("pos", 3), ("rpy", 3), ("vel", 3), ("omega", 3), ("reference", 4), ("pos_error", 3))


def _rpy(q: torch.Tensor) -> torch.Tensor:
    """roll, pitch, yaw ``[..., 3]`` of quaternions (x, y, z, w), R = Rz(yaw) Ry(pitch) Rx(roll)."""
    x, y, z, w = q.unbind(-1)
    roll = torch.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = torch.asin(torch.clamp(2 * (w * y - z * x), -1.0, 1.0))
    yaw = torch.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return torch.stack([roll, pitch, yaw], -1)


class LevitationEnv(MagwarpVecEnv):
    """Batched low-level levitation control (see the module docstring)."""

    #: the options' dataclass (:mod:`magwarp.envs.config`)
    config_type = LevitationConfig

    def __init__(self, num_envs: int = 1, config: LevitationConfig | None = None, *, device: str | None = None,
                 seed: int | None = None, render_mode: str | None = None, autoreset: bool = True,
                 check_inputs: bool = True, nan_dump: str | None = None, **options):
        """``LevitationEnv(num_envs, config=None, *, device=None, seed=None, ..., **options)``: the options are a
        :class:`~magwarp.envs.levitation_config.LevitationConfig` (None: the defaults) with its fields given as
        keywords applied on top."""
        from magwarp.magnetics.actuator import CoilActuator
        from magwarp.magnetics.drive import AUX_DIM, magnetic_force
        from magwarp.magnetics.table import WrenchTableSpec
        from magwarp.sim import Simulator

        cfg = resolve_config(type(self), config, options)
        self.config = cfg
        num_envs = as_count(num_envs, "num_envs")
        magnetics = cfg.make_magnetics()
        action, dt = cfg.action, cfg.dt
        self.action_mode = action
        self.num_cycles = cfg.num_cycles
        self.max_episode_steps = cfg.max_episode_steps
        self.start_range, self.setpoint_range, self.setpoint_yaw = cfg.start_range, cfg.setpoint_range, cfg.setpoint_yaw
        self.setpoint_gap, self.fail_gap, self.success_tol = cfg.setpoint_gap, cfg.fail_gap, cfg.success_tol
        self.pos_scale, self.rot_scale, self.loss_weight = cfg.pos_scale, cfg.rot_scale, cfg.loss_weight
        self.failure_reward, self.fail_tilt, self.fail_distance = cfg.failure_reward, cfg.fail_tilt, cfg.fail_distance
        self.wrench_scale = cfg.wrench_scale
        self.dt = dt
        self.step_dt = self.num_cycles * self.dt
        layout = Layout.grid(*cfg.tiles)
        self.mover = MoverSpec()
        self.bottom = 0.5 * self.mover.size[2]
        self.centre = (0.5 * layout.shape[0] * layout.tile.size, 0.5 * layout.shape[1] * layout.tile.size)
        self.task = cfg.task
        self.task_terms = make_task(self, cfg.task, cfg.task_options)
        self.task_options = self.task_terms.options
        terms = self.task_terms
        terms.check(layout, (magnetics.table or WrenchTableSpec()).gap)
        start = np.array([[[*self.centre, self.mover.hover_z, 0.0, 0.0, 0.0]]] * num_envs)
        sim_kwargs = {"force_model": magnetic_force, "force_aux_dim": AUX_DIM, **terms.sim_kwargs()}
        self.sim = Simulator(layout, 1, num_envs, mover=self.mover, start_pose=start, dt=dt, hold_mask=(0,) * 6,
                             stop_on_collision=False, check_inputs=False, device=device, **sim_kwargs)
        super().__init__(num_envs, self.sim.torch_device, seed=seed, render_mode=render_mode, autoreset=autoreset,
                         check_inputs=check_inputs, nan_dump=nan_dump)
        self.actuator = CoilActuator(self.sim, magnetics.params, magnetics.table, mode=action,
                                     options=magnetics.options, use_cache=magnetics.use_cache)
        self.layout = layout
        self.current_limit = float(self.actuator.model.params.coils.coil.current_limit)
        dev = self.device
        self.reference = torch.zeros((num_envs, 6), device=dev)  # x, y, z, yaw, roll, pitch
        self.setpoint = self.reference[:, :4]  # x, y, z, yaw (a view)
        self.reference_vel = torch.zeros((num_envs, 6), device=dev)  # the same order, per second
        self.reference_acc = torch.zeros((num_envs, 6), device=dev)
        self.steps = torch.zeros(num_envs, dtype=torch.int64, device=dev)
        self._xy_allow = torch.full((num_envs,), cfg.fail_distance, device=dev)
        self._scale = torch.tensor([self.wrench_scale[0]] * 3 + [self.wrench_scale[1]] * 3, device=dev)
        self._loss = torch.zeros(num_envs, device=dev)
        self._centre = torch.tensor(self.centre, device=dev)
        terms.setup()  # after the actuator: a payload's cycle hooks run after the coils'
        self.obs_slices: dict[str, slice] = {}
        col = 0
        for name, width in (*OBS_PARTS, *terms.extra_obs):
            self.obs_slices[name] = slice(col, col + width)
            col += width
        n_act = self.actuator.slots if action == "currents" else 6
        self._set_spaces(gym.spaces.Box(-np.inf, np.inf, (col,), np.float32),
                         gym.spaces.Box(-1.0, 1.0, (n_act,), np.float32))

    #: benchmark metric tracker (:func:`magwarp.metrics.Metrics` attaches one); adds ``info["metrics"]``
    benchmark_metrics = None
    num_movers = 1

    def scripted_policy(self):
        """The scripted baseline (:class:`magwarp.policies.levitation.LevitationPD`), as ``magwarp eval`` uses it."""
        from magwarp.policies.levitation import LevitationPD

        return LevitationPD(self)

    # ------------------------------------------------------------------ episodes
    def _reset_envs(self, mask: torch.Tensor) -> None:
        n = self.num_envs
        xy = self._centre + (2 * self._rand(n, 2) - 1) * self.start_range
        yaw = (2 * self._rand(n) - 1) * math.pi
        xy, gap, ref, allow = self.task_terms.episode(mask, xy, yaw)
        start_pos = self.sim.start_pos
        new_pos = torch.cat([xy, (gap + self.bottom)[:, None]], 1)[:, None]
        start_pos.copy_(torch.where(mask[:, None, None], new_pos, start_pos))
        quat = torch.stack([torch.zeros_like(yaw), torch.zeros_like(yaw), torch.sin(0.5 * yaw),
                            torch.cos(0.5 * yaw)], -1)[:, None]
        self.sim.start_quat.copy_(torch.where(mask[:, None, None], quat, self.sim.start_quat))
        self.sim.reset(mask)
        self.reference.copy_(torch.where(mask[:, None], ref, self.reference))
        self._xy_allow.copy_(torch.where(mask, allow, self._xy_allow))
        self.steps.masked_fill_(mask, 0)
        self.task_terms.advance()  # a moving reference at t = 0 (its rates)
        zero = torch.zeros_like(self.actuator.currents)
        self.actuator.currents.copy_(torch.where(mask[:, None, None], zero, self.actuator.currents))
        self.actuator.refresh()  # the slots' coils at the new poses

    # ------------------------------------------------------------------ stepping
    #: The largest action share accepted (of the current limit or of ``wrench_scale``): beyond it a wanted wrench
    #: overflows float32 on its way through the commutation (1e38 shares of 40 N), so the step refuses it.
    MAX_ACTION_SHARE = 1.0e6

    def _check_action(self, action) -> torch.Tensor:
        stored = super()._check_action(action)
        if self.check_inputs and not bool((stored.abs() <= self.MAX_ACTION_SHARE).all()):
            bad = torch.nonzero(stored.abs() > self.MAX_ACTION_SHARE)[0].tolist()
            raise ValueError(f"action share at index {bad} is {stored[tuple(bad)].item()!r}: beyond "
                             f"+-{self.MAX_ACTION_SHARE:g} of the action range (shares of the {self.action_mode} "
                             f"scale), which overflows the simulation's float32")
        return stored

    def _apply_action(self, action: torch.Tensor) -> None:
        if self.action_mode == "currents":
            self.actuator.currents.copy_((action * self.current_limit)[:, None, :])
        else:
            self.actuator.wanted.copy_((action * self._scale)[:, None, :])
        before = self.actuator.energy[:, 0].clone()
        self.sim.step(self.num_cycles)
        # the mean copper loss over the step's cycles (W): the energy it spent over its duration
        self._loss.copy_((self.actuator.energy[:, 0] - before) / self.step_dt)
        self.steps += 1
        self.task_terms.advance()

    def _state(self) -> tuple[torch.Tensor, ...]:
        pos = self.sim.pos[:, 0]
        rpy = _rpy(self.sim.quat[:, 0])
        return pos, rpy, self.sim.vel[:, 0], self.sim.omega[:, 0]

    def _get_obs(self) -> torch.Tensor:
        pos, rpy, vel, omega = self._state()
        parts = [pos, rpy, vel, omega, self.setpoint, pos - self.reference[:, :3], *self.task_terms.observe()]
        return torch.cat(parts, 1)

    def errors(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Position error (m) and rotation error (rad: roll, pitch and yaw errors together) ``[N]`` each."""
        pos, rpy, _, _ = self._state()
        ref = self.reference
        pos_err = torch.linalg.vector_norm(pos - ref[:, :3], dim=1)
        rot = torch.stack([rpy[:, 0] - ref[:, 4], rpy[:, 1] - ref[:, 5], wrap(rpy[:, 2] - ref[:, 3])], 1)
        return pos_err, torch.linalg.vector_norm(rot, dim=1)

    def _evaluate(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, dict[str, Any]]:
        pos, rpy, _, _ = self._state()
        pos_err, rot_err = self.errors()
        loss = self._loss
        gap = pos[:, 2] - self.bottom
        xy_err = torch.linalg.vector_norm(pos[:, :2] - self.reference[:, :2], dim=1)
        failed = ((gap < self.fail_gap[0]) | (gap > self.fail_gap[1]) | (rpy[:, :2].abs().amax(1) > self.fail_tilt)
                  | (xy_err > self._xy_allow))
        weight = self.task_terms.tracking_weight()
        reward = -weight * (pos_err / self.pos_scale + rot_err / self.rot_scale) - self.loss_weight * loss
        reward = torch.where(failed, torch.full_like(reward, self.failure_reward), reward)
        truncated = (self.steps >= self.max_episode_steps) & ~failed
        success = ~failed & (pos_err <= self.success_tol[0]) & (rot_err <= self.success_tol[1])
        info = {"copper_loss": loss, "pos_error": pos_err, "rot_error": rot_err, "failed": failed,
                "is_success": success, "saturated": self.actuator.saturated[:, 0].sum(1)}
        if self.benchmark_metrics is not None:
            info["metrics"] = self.benchmark_metrics.on_step(obs, info, failed, truncated)
        return reward, failed, truncated, info

    # ------------------------------------------------------------------ views
    @property
    def coil_ids(self) -> torch.Tensor:
        """``[N, slots]`` the coils of the action's slots at the last cycle's start (-1: no coil)."""
        return self.actuator.coil_ids[:, 0]

    @property
    def saturated(self) -> torch.Tensor:
        return self.actuator.saturated[:, 0]

    @property
    def energy(self) -> torch.Tensor:
        """``[N]`` copper energy (J) since construction."""
        return self.actuator.energy[:, 0]

    def state_arrays(self, worlds) -> dict[str, Any]:
        out = super().state_arrays(worlds)
        out.update(self.sim.state_arrays(worlds))
        idx = torch.as_tensor(worlds, dtype=torch.int64, device=self.device)
        out["reference"] = self.reference[idx].cpu().numpy()
        swing = getattr(self.task_terms, "swing", None)
        if swing is not None:
            out["pendulum_rod"], out["pendulum_rod_rate"] = (t[idx].cpu().numpy() for t in (swing.rod, swing.rod_rate))
        return out
