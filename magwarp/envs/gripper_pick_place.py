"""Gripper pick and place (``magwarp/GripperPickPlace-v0``): a two-mover gripper MagBot moves an object to a goal.

The model is :func:`magwarp.magbots.gripper.generate_gripper_mjcf` (one gripper on movers A and B, its finger pads
collide) plus one object (a small box standing on the tiles) on the mujoco-warp backend, batched over worlds. The
gripper's jaw opens and closes with the movers' distance (:mod:`magwarp.magbots.gripper`); its mouth faces away
from mover B, ``grip_offset`` behind mover A. The task: grasp the object (close the jaw on it), carry it (it slides
on the tiles between the pads) to the goal, and release it there.

Per env step (``num_cycles`` control cycles of 1 ms, the same action held):

* action, ``action_mode="mover"`` (default): the x/y accelerations of movers A and B (``[4]``, bound ``a_max``);
  ``action_mode="gripper"``: an increment in ``[-1, 1]^4`` of the commanded gripper state (mover A's x, y, the
  gripper's yaw, the jaw width), scaled by ``gripper_step``, kept inside the jaw's range and mover A on the tiles
  (``info["target_clipped"]``), mapped to mover targets (:meth:`GripperPickPlaceEnv.mover_targets`) and tracked
  by :func:`magwarp.magbots.control.track_movers`, plus a squeeze of mover B toward A while the commanded width is
  below the measured one (:meth:`GripperPickPlaceEnv.squeeze_accel`: the grip);
* observation (a goal dict): ``observation`` = [mover x, y (A then B: 4), mover x/y velocities (4), gripper x, y,
  sin yaw, cos yaw, jaw width (5), object x, y, sin yaw, cos yaw (4), object x/y velocity (2), object - jaw centre
  (2), (gripper mode: the commanded gripper state x, y, sin yaw, cos yaw, width: 5)]; ``achieved_goal`` = [object
  x, y, released]; ``desired_goal`` = [goal x, y, 1]. ``released`` is 1 when the jaw is open wider than the
  object by ``release_margin`` (the object is let go);
* success: the object within ``goal_tolerance`` of the goal and released;
* reward: ``collision_penalty`` on a wall or mover collision, a jaw limit violation (mover distance outside the
  linkage's range) or a lost object (off the tiles), else ``success_reward`` at success, else ``per_step_penalty``;
  terminated on success or failure, truncated after ``max_episode_steps``.

Starts: the gripper anywhere in the middle of the tiles with any yaw and its jaw open; the object and the goal
``min_distance`` or more apart, neither under the gripper's movers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from magwarp._checks import warp_device
from magwarp.envs.base import MagwarpVecEnv
from magwarp.envs.magbot_task import MagBotConfig, MagBotTask, as_vector, option_of
from magwarp.layout import Layout, MoverSpec
from magwarp.magbots.control import track_movers
from magwarp.magbots.gripper import GripperGeometry, GripperJoints, generate_gripper_mjcf, mover_distance
from magwarp.mjcf import ObjectSpec
from magwarp.physics import ControlParams, MjwBackend
from magwarp.physics.mover_checks import MoverChecks

__all__ = ["GripperPickPlaceConfig", "GripperPickPlaceEnv", "jaw_offset"]

def jaw_offset(geometry: GripperGeometry, object_half_width: float) -> float:
    """Distance behind mover A (along the gripper's -x) of the jaw's centre when the pads touch an object of half
    width ``object_half_width``: ``hinge_back + finger cos(alpha)`` with the finger at ``alpha`` from the -x axis."""
    g = geometry
    alpha = math.asin((object_half_width + g.pad - g.hinge_side) / g.finger)
    return g.hinge_back + g.finger * math.cos(alpha)


def _default_object() -> ObjectSpec:
    return ObjectSpec(shape="square_box", width=0.02, depth=0.03, mass=0.1, friction=(0.5, 0.005, 1e-4))


@dataclass(frozen=True)
class GripperPickPlaceConfig(MagBotConfig):
    """The options of :class:`GripperPickPlaceEnv` (see the module docstring): :class:`MagBotConfig`'s and
    ``geometry`` (the jaw linkage, :class:`~magwarp.magbots.gripper.GripperGeometry`), ``obj`` (the object, a square
    box standing on the tiles, :class:`~magwarp.mjcf.ObjectSpec`), ``gripper_step`` (the gripper mode's increment
    scale: x, y in m, yaw in rad, width in m), ``jaw_squeeze`` (m/s^2, :meth:`GripperPickPlaceEnv.squeeze_accel`),
    ``goal_tolerance``, ``release_margin`` and ``min_distance`` (m). The object must fit the jaw."""

    geometry: GripperGeometry = field(default_factory=GripperGeometry)
    obj: ObjectSpec = field(default_factory=_default_object)
    gripper_step: tuple[float, float, float, float] = (0.02, 0.02, 0.1, 0.02)
    jaw_squeeze: float = 6.0
    goal_tolerance: float = 0.02
    release_margin: float = 0.02
    min_distance: float = 0.15

    ACTION_MODES = ("mover", "gripper")
    POSITIVE = ("goal_tolerance", "release_margin", "min_distance", "jaw_squeeze", *MagBotConfig.POSITIVE)

    def _check(self) -> None:
        self._set("gripper_step", as_vector(self.gripper_step, "gripper_step", 4, "(x, y, yaw, width)"))
        self._set("geometry", option_of(self.geometry, GripperGeometry, "geometry"))
        self._set("obj", self.obj or _default_object())
        if not isinstance(self.obj, ObjectSpec) or self.obj.shape != "square_box":
            raise ValueError(f"obj must be a square_box ObjectSpec, got {self.obj!r}")
        lo, hi = self.geometry.width_range
        width = 2 * self.obj.width
        if not lo < width < hi - self.release_margin:
            raise ValueError(f"the object (width {width:.4g} m) must fit the jaw: closed {lo:.4g} m, "
                             f"open {hi:.4g} m, release margin {self.release_margin:.4g} m")


class GripperPickPlaceEnv(MagBotTask, MagwarpVecEnv):
    """Batched gripper pick and place; see the module docstring. ``layout`` (default 5 x 5 tiles, a full grid);
    the task's options: ``config`` (a :class:`GripperPickPlaceConfig` or a dict of its fields) and its fields as
    keyword options on top (``geometry``: the jaw linkage, ``obj``: the object, ``action_mode``, ...)."""

    metadata = {**MagwarpVecEnv.metadata, "render_modes": ["rgb_array", "rgb_array_3d"]}
    #: benchmark metric tracker (:func:`magwarp.metrics.Metrics` attaches one); adds ``info["metrics"]``
    benchmark_metrics = None
    num_movers = 2
    FAILURE_KEYS = (*MagBotTask.FAILURE_KEYS, "object_lost")

    #: the options (:class:`GripperPickPlaceConfig`; each field is also a keyword option)
    config_class = GripperPickPlaceConfig

    def __init__(self, num_envs: int = 1, layout: Layout | np.ndarray | None = None, *,
                 config: GripperPickPlaceConfig | dict | None = None, device: str | None = None,
                 seed: int | None = None, render_mode: str | None = None, autoreset: bool = True,
                 check_inputs: bool = True, **options):
        #: the env's options (``config`` with the keyword ``options`` on top)
        self.config = cfg = self.config_class.build(config, **options)
        layout = Layout(np.ones((5, 5), dtype=np.int32)) if layout is None else layout
        self.layout = layout if isinstance(layout, Layout) else Layout(layout)
        self.action_mode = cfg.action_mode
        self.geometry = g = cfg.geometry
        self.obj = cfg.obj
        self.gains = cfg.gains
        self.goal_tolerance, self.release_margin = cfg.goal_tolerance, cfg.release_margin
        self.jaw_squeeze = cfg.jaw_squeeze
        self.min_distance = cfg.min_distance
        self.success_reward, self.per_step_penalty = cfg.success_reward, cfg.per_step_penalty
        self.collision_penalty = cfg.collision_penalty
        self.max_episode_steps = cfg.max_episode_steps
        self.mover = MoverSpec()
        lo, hi = g.width_range
        #: object width (the jaw widths that hold it, just below it, and release it: see the config's check)
        self.object_width = 2 * self.obj.width
        self.grip_offset = jaw_offset(g, self.obj.width)
        # where the gripper may be: mover B anywhere around A at the widest spread, both on the tiles
        ext = np.asarray(self.layout.extent, dtype=np.float64)
        reach = g.max_distance + self.mover.bounding_radius(self.mover.wall_margin) + 0.01
        if np.any(ext - 2 * reach <= 0) or not self.layout.tiles.all():
            raise ValueError(f"layout of shape {self.layout.shape} leaves no room for the gripper (a full grid at "
                             f"least {2 * reach:.3f} m wide in x and y is needed)")
        self.xy_low, self.xy_high = np.full(2, reach), ext - reach
        margin = self.obj.width + 0.1
        self.object_low, self.object_high = np.full(2, margin + 0.15), ext - margin - 0.15
        device = warp_device(device).alias
        centre = 0.5 * ext
        self.xml = generate_gripper_mjcf(self.layout, [centre], geometry=g, mover=self.mover, solver=cfg.solver,
                                         objects=[self.obj], object_xy=[centre + np.array([-0.3, 0.0])])
        control = ControlParams(v_max=cfg.v_max, a_max=cfg.a_max, num_cycles=cfg.num_cycles)
        self.backend = MjwBackend(self.xml, int(num_envs), control=control, nconmax=16, njmax=96, device=device)
        self.joints = GripperJoints(self.backend.mjm, g)
        self.mover_z = float(self.backend.hover_z.mean())
        self.checks = MoverChecks(self.backend, self.layout, self.mover)
        super().__init__(num_envs, self.backend.torch_device, seed=seed, render_mode=render_mode, autoreset=autoreset,
                         check_inputs=check_inputs)
        n, dev = self.num_envs, self.device
        self.gripper_step = torch.as_tensor(np.asarray(cfg.gripper_step), dtype=torch.float32, device=dev)
        self._width_low, self._width_high = lo, hi
        # gripper mode: mover A's commanded position stays a footprint inside the tiles (mover B, further on, is the
        # policy's to keep there: the wall check fails it)
        r = self.mover.bounding_radius(self.mover.wall_margin)
        self._xy_low_t = torch.full((2,), r, dtype=torch.float32, device=dev)
        self._xy_high_t = torch.as_tensor(ext - r, dtype=torch.float32, device=dev)
        self._ext_t = torch.as_tensor(ext, dtype=torch.float32, device=dev)
        # sampling ranges on the device (no host copy in a reset inside a step)
        self._start_low, self._start_high, self._object_low, self._object_high = (
            torch.as_tensor(v, dtype=torch.float32, device=dev)
            for v in (self.xy_low, self.xy_high, self.object_low, self.object_high))
        #: goals ``[W, 2]`` and (gripper mode) the commanded gripper states ``[W, 4]`` (x, y, yaw, width)
        self.goal = torch.zeros(n, 2, device=dev)
        self.target = torch.zeros(n, 4, device=dev)
        self.target_clipped = torch.zeros(n, dtype=torch.bool, device=dev)
        self.num_steps = torch.zeros(n, dtype=torch.int64, device=dev)
        self._set_spaces(self._observation_space(), self._action_space())
        self.reset()

    # ------------------------------------------------------------------ spaces
    def _observation_space(self) -> gym.spaces.Dict:
        dim = 4 + 4 + 5 + 4 + 2 + 2 + (5 if self.action_mode == "gripper" else 0)
        goal = gym.spaces.Box(-np.inf, np.inf, (3,), np.float32)
        return gym.spaces.Dict({"observation": gym.spaces.Box(-np.inf, np.inf, (dim,), np.float32),
                                "achieved_goal": goal, "desired_goal": goal})

    def _action_space(self) -> gym.spaces.Box:
        if self.action_mode == "gripper":
            return gym.spaces.Box(-1.0, 1.0, (4,), np.float32)
        a = self.backend.control.a_max
        return gym.spaces.Box(-a, a, (4,), np.float32)

    # ------------------------------------------------------------------ state
    def gripper_state(self) -> torch.Tensor:
        """``[W, 4]``: mover A's x, y, the gripper's yaw (direction A -> B) and the jaw width."""
        return self.joints.state(self.backend.qpos_t)[:, 0].float()

    def mover_state(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Mover x, y ``[W, 2, 2]`` and x/y velocities ``[W, 2, 2]``."""
        b = self.backend
        return b.mover_qpos[..., :2].float(), b.mover_qvel[..., :2].float()

    def object_state(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Object x, y ``[W, 2]``, yaw ``[W]`` and x/y velocity ``[W, 2]``."""
        b = self.backend
        q = b.object_qpos[:, 0].float()
        w, z = q[:, 3], q[:, 6]
        yaw = 2 * torch.atan2(z, w)
        return q[:, :2], yaw, b.object_qvel[:, 0, :2].float()

    def jaw_centre(self, state: torch.Tensor | None = None) -> torch.Tensor:
        """``[W, 2]``: the jaw's centre, ``grip_offset`` behind mover A along the gripper's axis."""
        s = self.gripper_state() if state is None else state
        return s[:, :2] - self.grip_offset * torch.stack([torch.cos(s[:, 2]), torch.sin(s[:, 2])], -1)

    def mover_targets(self, state: torch.Tensor) -> torch.Tensor:
        """Mover positions ``[W, 2, 2]`` (A, B) for gripper states ``[W, 4]`` (x, y, yaw, width) in the jaw's range
        (the inverse of the jaw kinematics gives the mover distance)."""
        d = mover_distance(state[:, 3].double(), self.geometry).to(state.dtype)
        axis = torch.stack([torch.cos(state[:, 2]), torch.sin(state[:, 2])], -1)
        return torch.stack([state[:, :2], state[:, :2] + d[:, None] * axis], 1)

    def squeeze_accel(self, width_target: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        """``[W, 2, 2]``: the grip's extra accelerations, movers A and B toward each other by up to ``jaw_squeeze``
        (m/s^2) each, in proportion to how far (per cm) the commanded ``width_target`` ``[W]`` is below the measured
        width of the gripper ``state`` ``[W, 4]`` (0 when it is not). The jaw's linkage gears the movers' distance
        down about six to one near closed, so tracking the width alone would squeeze an object only weakly; equal and
        opposite, the squeeze does not shift the gripper off its tracked position."""
        push = self.jaw_squeeze * ((state[:, 3] - width_target) / 0.01).clamp(0.0, 1.0)
        axis = torch.stack([torch.cos(state[:, 2]), torch.sin(state[:, 2])], -1)
        return torch.stack([push[:, None] * axis, -push[:, None] * axis], 1)

    def _sample_xy(self, low: torch.Tensor, high: torch.Tensor, n: int) -> torch.Tensor:
        return low + (high - low) * self._rand(n, 2)

    # ------------------------------------------------------------------ task hooks
    def _reset_envs(self, mask: torch.Tensor) -> None:
        b, n = self.backend, self.num_envs
        start = torch.zeros(n, 4, device=self.device)
        start[:, :2] = self._sample_xy(self._start_low, self._start_high, n)
        start[:, 2] = math.pi * (2 * self._rand(n) - 1)
        start[:, 3] = self._width_high - 0.01
        movers = self.mover_targets(start)
        # the object and the goal: apart, and clear of both movers (a few tries, batched; the last is kept)
        obj = self._sample_xy(self._object_low, self._object_high, n)
        goal = self._sample_xy(self._object_low, self._object_high, n)
        clear = 2 * self.mover.bounding_radius() + self.obj.width
        for _ in range(16):
            near = ((obj[:, None] - movers).norm(dim=-1) < clear).any(-1)
            obj = torch.where(near[:, None], self._sample_xy(self._object_low, self._object_high, n), obj)
            close = (goal - obj).norm(dim=-1) < self.min_distance
            goal = torch.where(close[:, None], self._sample_xy(self._object_low, self._object_high, n), goal)
        q = b.init_qpos_t.clone()
        self.joints.write_qpos(q, start[:, None].to(q.dtype), self.mover_z, check=False)
        oq = torch.zeros(n, 7, dtype=q.dtype, device=self.device)
        oq[:, :2], oq[:, 2], oq[:, 3] = obj, self.obj.depth, 1.0
        q[:, b.object_qadr[0]:b.object_qadr[0] + 7] = oq
        b.init_qpos_t.copy_(torch.where(mask[:, None], q, b.init_qpos_t))
        b.init_qvel_t.masked_fill_(mask[:, None], 0.0)
        b.reset(mask)
        self.goal.copy_(torch.where(mask[:, None], goal, self.goal))
        self.target.copy_(torch.where(mask[:, None], start, self.target))
        self.target_clipped.masked_fill_(mask, False)
        self.num_steps.masked_fill_(mask, 0)
        if self.benchmark_metrics is not None:
            self.benchmark_metrics.episode_reset(mask)

    def scripted_policy(self):
        """The scripted baseline (:class:`magwarp.policies.gripper.GripperPickPlacePolicy`)."""
        from magwarp.policies.gripper import GripperPickPlacePolicy

        return GripperPickPlacePolicy(self)

    def _apply_action(self, action: torch.Tensor) -> None:
        self.checks.clear()
        n = self.num_envs
        if self.action_mode == "gripper":
            want = self.target + action * self.gripper_step
            xy = torch.maximum(torch.minimum(want[:, :2], self._xy_high_t), self._xy_low_t)
            width = want[:, 3].clamp(self._width_low, self._width_high)
            yaw = torch.remainder(want[:, 2] + math.pi, 2 * math.pi) - math.pi
            held = torch.cat([xy, yaw[:, None], width[:, None]], 1)
            self.target_clipped.copy_((xy != want[:, :2]).any(-1) | (width != want[:, 3]))
            self.target.copy_(held)
            pos, vel = self.mover_state()
            targets = self.mover_targets(held)
            pad = torch.zeros(n, 2, 1, device=self.device)
            acc = track_movers(torch.cat([pos, pad], -1), torch.cat([vel, pad], -1), torch.cat([targets, pad], -1),
                               self.gains)
            action = acc[..., :2] + self.squeeze_accel(held[:, 3], self.gripper_state())
        self.backend.step(action.reshape(n, 2, 2), check_finite=False)

    def _goals(self) -> tuple[torch.Tensor, torch.Tensor]:
        xy, _, _ = self.object_state()
        released = (self.gripper_state()[:, 3] >= self.object_width + self.release_margin).float()
        achieved = torch.cat([xy, released[:, None]], 1)
        desired = torch.cat([self.goal, torch.ones_like(released)[:, None]], 1)
        return achieved, desired

    def _get_obs(self) -> dict[str, torch.Tensor]:
        pos, vel = self.mover_state()
        n = self.num_envs
        s = self.gripper_state()
        xy, yaw, ovel = self.object_state()
        parts = [pos.reshape(n, 4), vel.reshape(n, 4), s[:, :2], torch.sin(s[:, 2:3]), torch.cos(s[:, 2:3]), s[:, 3:],
                 xy, torch.sin(yaw)[:, None], torch.cos(yaw)[:, None], ovel, xy - self.jaw_centre(s)]
        if self.action_mode == "gripper":
            t = self.target
            parts += [t[:, :2], torch.sin(t[:, 2:3]), torch.cos(t[:, 2:3]), t[:, 3:]]
        achieved, desired = self._goals()
        return {"observation": torch.cat(parts, 1), "achieved_goal": achieved, "desired_goal": desired}

    def _failure_info(self) -> dict[str, Any]:
        pos, _ = self.mover_state()
        d = (pos[:, 1] - pos[:, 0]).norm(dim=-1)
        g = self.geometry
        xy, _, _ = self.object_state()
        lost = ((xy < 0) | (xy > self._ext_t)).any(-1) | ~torch.isfinite(xy).all(-1)
        return {
            "mover_collision": self.checks.mover_collision.clone(),
            "wall_collision": self.checks.wall_collision.clone(),
            "limit_violation": (d < g.min_distance - 0.005) | (d > g.max_distance + 0.005) | ~torch.isfinite(d),
            "object_lost": lost,
        }

    def _evaluate(self, obs):
        info = self._failure_info()
        reached = self._reached(obs["achieved_goal"], obs["desired_goal"])
        failed = self._failed(info, reached.shape)
        reward = self._reward(reached, failed)
        self.num_steps += 1
        err = (obs["achieved_goal"][:, :2] - obs["desired_goal"][:, :2]).norm(dim=-1)
        info.update({"is_success": reached & ~failed, "position_error": err,
                     "released": obs["achieved_goal"][:, 2] > 0.5})
        return self._step_result(obs, reward, reached | failed, info)

    def _reached(self, achieved: torch.Tensor, desired: torch.Tensor) -> torch.Tensor:
        near = (achieved[..., :2] - desired[..., :2]).norm(dim=-1) <= self.goal_tolerance
        return near & (achieved[..., 2] >= desired[..., 2] - 0.5)

    def compute_reward(self, achieved_goal, desired_goal, info) -> torch.Tensor:
        """Reward for a batch ``(..., 3)``; ``info`` holds the failure flags of the batch shape (or is None)."""
        achieved_goal = torch.as_tensor(achieved_goal)
        desired_goal = torch.as_tensor(desired_goal, device=achieved_goal.device)
        reached = self._reached(achieved_goal, desired_goal)
        return self._reward(reached, self._failed(info, reached.shape, reached.device))


    def goal_ghosts(self, world: int) -> list[tuple]:
        """The object at its goal for the 3D view."""
        from magwarp.render.mujoco3d import GOAL_RGBA

        x, y = (float(v) for v in self.goal[world].tolist())
        w, d = self.obj.width, self.obj.depth
        return [((x, y, d * 1.01), 0.0, (w * 1.01, w * 1.01, d * 1.01), GOAL_RGBA, "box")]

    def _render_frame(self) -> torch.Tensor:
        """Top-down view: tiles, the movers (red after a collision), the object and its goal."""
        if self.render_mode == "rgb_array_3d":
            return self._render_3d()
        w = self.obj.width
        renderer = self._top_down([[(0.0, 0.0, w, w)]])
        pos, _ = self.mover_state()
        xy, yaw, _ = self.object_state()
        zero = torch.zeros_like(yaw)
        return renderer.draw(pos, None, flags=self.checks.flags_t[:, None].expand(-1, 2),
                             object_poses=torch.cat([xy, yaw[:, None]], 1),
                             object_goals=torch.cat([self.goal, zero[:, None]], 1))
