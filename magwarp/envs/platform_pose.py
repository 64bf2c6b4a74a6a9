"""6D-platform pose tracking (``magwarp/PlatformPose-v0``): two movers carry a platform to random 6-DoF poses.

The model is :func:`magwarp.magbots.mjcf.generate_platform_mjcf` (one platform on movers A and B) on the mujoco-warp
backend, batched over worlds. Per env step (``num_cycles`` control cycles of 1 ms, the same action held):

* action, ``action_mode="mover"`` (default): per mover (A then B) the x/y acceleration and the yaw acceleration
  (``[6]``; bounds ``a_max``, ``a_max_c``; the backend's acceleration/speed limits apply, see
  :mod:`magwarp.physics.control`); ``action_mode="pose"``: a platform-pose increment in ``[-1, 1]^6`` scaled by
  ``pose_step`` (x, y, z in m, roll, pitch, yaw in rad) added to a commanded target pose, which is kept inside the
  platform's limits and the workspace (``info["target_clipped"]`` says when an increment was cut), mapped through the
  IK to mover targets and tracked by :func:`magwarp.magbots.control.track_movers`;
* observation: mover x, y, sin/cos yaw, then x/y/yaw rates (A then B), then the platform pose (x, y, z, roll, pitch,
  sin/cos yaw) and, in pose mode, the commanded target pose likewise; achieved_goal: the platform pose (7 values as
  above); desired_goal: the goal pose likewise;
* success: position error <= ``position_tolerance`` and roll, pitch and yaw errors <= ``angle_tolerance``;
* reward: ``collision_penalty`` on a wall or mover collision or a platform limit violation (tilt beyond
  ``max_tilt``, mover distance outside its range), else ``success_reward`` at the goal, else ``per_step_penalty``;
* terminated at the goal, on a collision or on a limit violation; truncated after ``max_episode_steps``.

``render_mode="rgb_array"`` draws the worlds from above (tiles, movers, the platform plate and its goal pose).

Starts and goals are drawn uniformly inside the limits (tilt and height shrunk by ``sample_margin``), the platform
centre far enough from the layout's edge that both movers stay on the tiles at any yaw and spread.
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
from magwarp.magbots.geometry import PlatformGeometry
from magwarp.magbots.kinematics import platform_ik, platform_limit_violations, wrap_to_pi
from magwarp.magbots.mjcf import PlatformJoints, PlatformModelSpec, generate_platform_mjcf
from magwarp.physics import ControlParams, MjwBackend
from magwarp.physics.mover_checks import MoverChecks

__all__ = ["PlatformConfig", "PlatformPoseConfig", "PlatformPoseEnv", "pose_to_goal"]

def pose_to_goal(pose: torch.Tensor) -> torch.Tensor:
    """``[..., 6]`` (x, y, z, roll, pitch, yaw) -> ``[..., 7]`` (x, y, z, roll, pitch, sin yaw, cos yaw)."""
    return torch.cat([pose[..., :5], torch.sin(pose[..., 5:]), torch.cos(pose[..., 5:])], -1)


def goal_errors(achieved: torch.Tensor, desired: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(position error, largest of the roll, pitch and yaw errors) between goal vectors ``[..., 7]``."""
    pos = (achieved[..., :3] - desired[..., :3]).norm(dim=-1)
    yaw = torch.atan2(achieved[..., 5] * desired[..., 6] - achieved[..., 6] * desired[..., 5],
                      achieved[..., 6] * desired[..., 6] + achieved[..., 5] * desired[..., 5]).abs()
    ang = torch.maximum((achieved[..., 3:5] - desired[..., 3:5]).abs().amax(-1), yaw)
    return pos, ang


def _yaw(q: torch.Tensor) -> torch.Tensor:
    w, x, y, z = q.unbind(-1)
    return torch.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


@dataclass(frozen=True)
class PlatformConfig(MagBotConfig):
    """The options of the 6D-platform envs (:class:`PlatformPoseEnv`,
    :class:`~magwarp.envs.platform_pick_place.PlatformPickPlaceEnv`): :class:`MagBotConfig`'s and ``geometry`` (the
    linkage, :class:`~magwarp.magbots.geometry.PlatformGeometry`), ``model`` (masses and sizes,
    :class:`~magwarp.magbots.mjcf.PlatformModelSpec`), ``pose_step`` (the pose mode's increment scale: x, y, z in m,
    roll, pitch, yaw in rad), ``v_max_c`` (rad/s) and ``a_max_c`` (rad/s^2): the movers' yaw limits."""

    geometry: PlatformGeometry = field(default_factory=PlatformGeometry)
    model: PlatformModelSpec = field(default_factory=PlatformModelSpec)
    pose_step: tuple[float, ...] = (0.02, 0.02, 0.01, 0.02, 0.02, 0.1)
    v_max_c: float = 20.0
    a_max_c: float = 100.0

    ACTION_MODES = ("mover", "pose")
    POSITIVE = (*MagBotConfig.POSITIVE, "v_max_c", "a_max_c")

    def _check(self) -> None:
        self._set("pose_step", as_vector(self.pose_step, "pose_step", 6, "(x, y, z, roll, pitch, yaw)"))
        self._set("geometry", option_of(self.geometry, PlatformGeometry, "geometry"))
        self._set("model", option_of(self.model, PlatformModelSpec, "model"))


@dataclass(frozen=True)
class PlatformPoseConfig(PlatformConfig):
    """The options of :class:`PlatformPoseEnv`: :class:`PlatformConfig`'s and the pose goals' ``position_tolerance``
    (m), ``angle_tolerance`` (rad) and ``sample_margin`` (in [0, 1): the share of the height and tilt ranges kept
    clear when starts and goals are drawn)."""

    max_episode_steps: int = 50
    position_tolerance: float = 0.01
    angle_tolerance: float = 0.03
    sample_margin: float = 0.2

    POSITIVE = ("position_tolerance", "angle_tolerance", *PlatformConfig.POSITIVE)
    FINITE = ("sample_margin", *PlatformConfig.FINITE)

    def _check(self) -> None:
        if not 0.0 <= self.sample_margin < 1.0:
            raise ValueError(f"sample_margin must lie in [0, 1), got {self.sample_margin!r}")
        super()._check()


class PlatformPoseEnv(MagBotTask, MagwarpVecEnv):
    """Batched 6D-platform pose tracking; see the module docstring. ``layout`` (a :class:`Layout` or 0/1 array,
    default 5 x 5 tiles) must leave room for the platform; the task's options: ``config`` (a
    :class:`PlatformPoseConfig` or a dict of its fields) and its fields as keyword options on top (``geometry`` and
    ``model`` set the mechanism, ``action_mode``, ...)."""

    metadata = {**MagwarpVecEnv.metadata, "render_modes": ["rgb_array", "rgb_array_3d"]}
    #: benchmark metric tracker (:func:`magwarp.metrics.Metrics` attaches one); adds ``info["metrics"]``
    benchmark_metrics = None
    num_movers = 2

    #: the options (:class:`PlatformPoseConfig`; each field is also a keyword option)
    config_class = PlatformPoseConfig

    def __init__(self, num_envs: int = 1, layout: Layout | np.ndarray | None = None, *,
                 config: PlatformPoseConfig | dict | None = None, device: str | None = None, seed: int | None = None,
                 render_mode: str | None = None, autoreset: bool = True, check_inputs: bool = True, **options):
        #: the env's options (``config`` with the keyword ``options`` on top)
        self.config = cfg = self.config_class.build(config, **options)
        self._take_options(cfg)
        layout = Layout(np.ones(self._default_tiles, dtype=np.int32)) if layout is None else layout
        self.layout = layout if isinstance(layout, Layout) else Layout(layout)
        self.action_mode = cfg.action_mode
        self.geometry = cfg.geometry
        self.gains = cfg.gains
        self.success_reward, self.per_step_penalty = cfg.success_reward, cfg.per_step_penalty
        self.collision_penalty = cfg.collision_penalty
        self.max_episode_steps = cfg.max_episode_steps
        self.mover = self._mover_spec()
        self.model_spec = cfg.model
        g = self.geometry

        # Workspace of the platform centre: both movers (at the widest spread, any yaw) stay on the tiles.
        ext = np.asarray(self.layout.extent)
        reach = 0.5 * g.max_mover_distance + self.mover.bounding_radius(self.mover.wall_margin) + 0.01
        self.xy_low, self.xy_high = np.full(2, reach), ext - reach
        if np.any(self.xy_high <= self.xy_low) or not self.layout.tiles.all():
            raise ValueError(f"layout of shape {self.layout.shape} leaves no room for the platform (a full grid at "
                             f"least {2 * reach:.3f} m wide in x and y is needed)")
        device = warp_device(device).alias
        centre = 0.5 * ext
        self.xml = self._generate_xml(centre, cfg.solver)
        control = ControlParams(v_max=cfg.v_max, a_max=cfg.a_max, num_cycles=cfg.num_cycles, rotation=True,
                                v_max_c=cfg.v_max_c, a_max_c=cfg.a_max_c)
        nconmax, njmax = self._contact_capacity
        self.backend = MjwBackend(self.xml, int(num_envs), control=control, nconmax=nconmax, njmax=njmax,
                                  device=device)
        self.joints = PlatformJoints(self.backend.mjm, g, self.model_spec)
        self.mover_z = float(self.backend.hover_z.mean())
        self.checks = MoverChecks(self.backend, self.layout, self.mover)
        super().__init__(num_envs, self.backend.torch_device, seed=seed, render_mode=render_mode, autoreset=autoreset,
                         check_inputs=check_inputs)
        n, dev = self.num_envs, self.device
        lo, hi = g.height_range
        self._target_low = torch.tensor([*self.xy_low, self.mover_z + lo, -g.max_tilt, -g.max_tilt], device=dev)
        self._target_high = torch.tensor([*self.xy_high, self.mover_z + hi, g.max_tilt, g.max_tilt], device=dev)
        self.pose_step = torch.as_tensor(np.asarray(cfg.pose_step), dtype=torch.float32, device=dev)
        #: goal and (pose mode) commanded target poses ``[W, 6]``
        self.goal_pose = torch.zeros(n, 6, device=dev)
        self.target_pose = torch.zeros(n, 6, device=dev)
        self.target_clipped = torch.zeros(n, dtype=torch.bool, device=dev)
        self.num_steps = torch.zeros(n, dtype=torch.int64, device=dev)
        self._init_task()
        self._set_spaces(self._observation_space(), self._action_space())
        self.reset()

    # ------------------------------------------------------------------ model hooks (tasks on the platform override)
    #: mujoco-warp's contacts and constraint rows per world (the bare platform has no contacts)
    _contact_capacity = (1, 24)

    #: the default layout: a full grid of this many tiles
    _default_tiles = (5, 5)

    def _take_options(self, cfg: PlatformConfig) -> None:
        """The task's own options as attributes, before the model is built (default: none)."""

    def _mover_spec(self) -> MoverSpec:
        return MoverSpec()

    def _generate_xml(self, centre: np.ndarray, solver: str) -> str:
        """The model's MJCF: one platform whose model pose is at ``centre``."""
        return generate_platform_mjcf(self.layout, [centre], geometry=self.geometry, spec=self.model_spec,
                                      mover=self.mover, solver=solver)

    def _init_task(self) -> None:
        """Task state allocated before the spaces are set and the first reset: here the pose goals' tolerances and
        the range that starts and goals are drawn from (``sample_margin``)."""
        cfg, g = self.config, self.geometry
        self.position_tolerance, self.angle_tolerance = cfg.position_tolerance, cfg.angle_tolerance
        lo, hi = g.height_range
        span = 0.5 * cfg.sample_margin * (hi - lo)
        tilt = (1.0 - cfg.sample_margin) * g.max_tilt
        dev = self.device
        self._sample_low = torch.tensor([*self.xy_low, self.mover_z + lo + span, -tilt, -tilt, -math.pi], device=dev)
        self._sample_high = torch.tensor([*self.xy_high, self.mover_z + hi - span, tilt, tilt, math.pi], device=dev)

    # ------------------------------------------------------------------ spaces
    def _observation_space(self) -> gym.spaces.Dict:
        dim = 8 + 6 + 7 + (7 if self.action_mode == "pose" else 0)
        goal = gym.spaces.Box(-np.inf, np.inf, (7,), np.float32)
        return gym.spaces.Dict({"observation": gym.spaces.Box(-np.inf, np.inf, (dim,), np.float32),
                                "achieved_goal": goal, "desired_goal": goal})

    def _action_space(self) -> gym.spaces.Box:
        if self.action_mode == "pose":
            return gym.spaces.Box(-1.0, 1.0, (6,), np.float32)
        c = self.backend.control
        high = np.tile(np.array([c.a_max, c.a_max, c.a_max_c], np.float32), 2)
        return gym.spaces.Box(-high, high, dtype=np.float32)

    # ------------------------------------------------------------------ state
    def platform_pose(self) -> torch.Tensor:
        """Current platform poses ``[W, 6]`` (x, y, z, roll, pitch, yaw of the top centre)."""
        return self.joints.pose(self.backend.qpos_t)[:, 0]

    def mover_state(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Mover (x, y, yaw) ``[W, 2, 3]`` and (vx, vy, yaw rate) ``[W, 2, 3]``."""
        b = self.backend
        q = b.mover_qpos
        pos = torch.cat([q[..., :2], _yaw(q[..., 3:])[..., None]], -1)
        return pos, b.mover_qvel[..., [0, 1, 5]]

    def _sample_poses(self) -> torch.Tensor:
        return self._sample_low + (self._sample_high - self._sample_low) * self._rand(self.num_envs, 6)

    # ------------------------------------------------------------------ task hooks
    def _reset_envs(self, mask: torch.Tensor) -> None:
        b = self.backend
        start = self._sample_poses()
        q = b.init_qpos_t.clone()
        self.joints.write_qpos(q, start[:, None], self.mover_z, check=False)
        b.init_qpos_t.copy_(torch.where(mask[:, None], q, b.init_qpos_t))
        b.init_qvel_t.masked_fill_(mask[:, None], 0.0)
        b.reset(mask)
        self.goal_pose.copy_(torch.where(mask[:, None], self._sample_poses(), self.goal_pose))
        self.target_pose.copy_(torch.where(mask[:, None], start, self.target_pose))
        self.target_clipped.masked_fill_(mask, False)
        self.num_steps.masked_fill_(mask, 0)
        if self.benchmark_metrics is not None:
            self.benchmark_metrics.episode_reset(mask)

    def scripted_policy(self):
        """The scripted baseline (:class:`magwarp.policies.platform.PlatformIKPolicy`), as ``magwarp eval`` uses it."""
        from magwarp.policies.platform import PlatformIKPolicy

        return PlatformIKPolicy(self)

    def _apply_action(self, action: torch.Tensor) -> None:
        self.checks.clear()
        n = self.num_envs
        if self.action_mode == "pose":
            want = self.target_pose + action * self.pose_step
            held = torch.cat([torch.maximum(torch.minimum(want[:, :5], self._target_high), self._target_low),
                              wrap_to_pi(want[:, 5:])], 1)
            self.target_clipped.copy_((held[:, :5] != want[:, :5]).any(-1))
            self.target_pose.copy_(held)
            movers = platform_ik(held, self.mover_z, self.geometry, check=False)  # [W, 2, 4]
            pos, vel = self.mover_state()
            action = track_movers(pos, vel, movers[..., [0, 1, 3]], self.gains)
        self.backend.step(action.reshape(n, 2, 3), check_finite=False)

    def _get_obs(self) -> dict[str, torch.Tensor]:
        pos, vel = self.mover_state()
        n = self.num_envs
        achieved = pose_to_goal(self.platform_pose())
        movers = torch.cat([pos[..., :2], torch.sin(pos[..., 2:]), torch.cos(pos[..., 2:])], -1).reshape(n, 8)
        parts = [movers, vel.reshape(n, 6), achieved]
        if self.action_mode == "pose":
            parts.append(pose_to_goal(self.target_pose))
        return {"observation": torch.cat(parts, 1), "achieved_goal": achieved.clone(),
                "desired_goal": pose_to_goal(self.goal_pose)}

    def _failure_info(self) -> dict[str, Any]:
        """This step's failure flags ``[W]``: wall and mover collisions, limit violations (any, and per limit)."""
        viol = platform_limit_violations(self.platform_pose(), self.mover_z, self.geometry)
        limit = viol["roll"] | viol["pitch"] | viol["height_min"] | viol["height_max"] | viol["non_finite"]
        info: dict[str, Any] = {
            "mover_collision": self.checks.mover_collision.clone(),
            "wall_collision": self.checks.wall_collision.clone(),
            "limit_violation": limit,
        }
        info.update({f"limit_{k}": v for k, v in viol.items()})
        return info

    def _evaluate(self, obs):
        info = self._failure_info()
        pos_err, ang_err = goal_errors(obs["achieved_goal"], obs["desired_goal"])
        reached = (pos_err <= self.position_tolerance) & (ang_err <= self.angle_tolerance)
        failed = self._failed(info, reached.shape)
        reward = self._reward(reached, failed)
        self.num_steps += 1
        info.update({"is_success": reached & ~failed, "position_error": pos_err, "angle_error": ang_err})
        return self._step_result(obs, reward, reached | failed, info)


    def goal_ghosts(self, world: int) -> list[tuple]:
        """The goal pose's plate (x, y, z, yaw; drawn level) for the 3D view."""
        from magwarp.render.mujoco3d import GOAL_RGBA

        x, y, z, _, _, yaw = (float(v) for v in self.goal_pose[world].tolist())
        hx, hy, hz = self.model_spec.platform_half_size
        return [((x, y, z - hz), yaw, (hx, hy, hz), GOAL_RGBA, "box")]

    def _render_frame(self) -> torch.Tensor:
        """Top-down view: tiles, the movers (red after a collision), the platform plate and its goal (x, y, yaw)."""
        if self.render_mode == "rgb_array_3d":
            return self._render_3d()
        hx, hy, _ = self.model_spec.platform_half_size
        renderer = self._top_down([[(0.0, 0.0, hx, hy)]])
        pos, _ = self.mover_state()
        pose = self.platform_pose()
        return renderer.draw(pos[..., :2], pos[..., 2], flags=self.checks.flags_t[:, None].expand(-1, 2),
                             object_poses=pose[:, [0, 1, 5]], object_goals=self.goal_pose[:, [0, 1, 5]])

    def compute_reward(self, achieved_goal, desired_goal, info) -> torch.Tensor:
        """Reward for a batch ``(..., 7)``; ``info`` holds the failure flags of the batch shape (or is None)."""
        achieved_goal = torch.as_tensor(achieved_goal)
        desired_goal = torch.as_tensor(desired_goal, device=achieved_goal.device)
        pos_err, ang_err = goal_errors(achieved_goal, desired_goal)
        reached = (pos_err <= self.position_tolerance) & (ang_err <= self.angle_tolerance)
        return self._reward(reached, self._failed(info, reached.shape, reached.device))
