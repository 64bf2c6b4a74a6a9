"""6D-platform pick and place (``magwarp/PlatformPickPlace-v0``): MagBotSim's application example, batched.

A 6D-platform MagBot (:mod:`magwarp.magbots`) takes a product from a supply rack and places it in a container, on
the mujoco-warp backend, batched over worlds. The scene (:class:`PickPlaceScene`; world frame, tile tops at z = 0,
default 4 x 4 tiles):

* **supply rack**: two static rails (boxes along y) cantilevered over the tiles from a post beyond the ``y = 0``
  edge; the product (a box, :attr:`PickPlaceScene.product`) rests across them, its centre at ``supply_xy``. The
  rails are further apart than the platform plate is wide, so the platform can **dock** under the product at
  ``dock_height`` (the plate's top below the rails), lift it off at ``lift_height``, and back out;
* **container**: an open box beyond the far edge (``y`` = the layout's extent), its floor at tile level, centred on
  ``container_x``. The platform **places** the product by carrying it to the edge and tilting (roll toward the
  container, MagBotSim's way): the product slides off the plate and falls in.

The plate is a contact geom (:class:`~magwarp.magbots.mjcf.PlatformModelSpec` ``plate_friction``); the product's
friction (``priority`` 1, so it rules its contacts) is low enough that it slides at most of the tilt limit
(``tan(14 deg) = 0.25``) and high enough that it rides along at moderate accelerations (``mu g``).

Per env step (``num_cycles`` control cycles of 1 ms), actions are :class:`~magwarp.envs.platform_pose.PlatformPoseEnv`'s
(``action_mode="mover"``: the movers' x/y and yaw accelerations; ``"pose"``: platform-pose increments through the
IK). Observation (a flat vector)::

    [mover x, y, sin yaw, cos yaw (A then B: 8), mover x/y/yaw rates (6), platform pose (x, y, z, roll, pitch,
     sin yaw, cos yaw: 7), product position (3), product quaternion (w, x, y, z: 4), product velocity (3),
     product - platform top (3), supply position (3), container centre (3), products placed / products (1),
     (pose mode: the commanded target pose, 7)]

A product counts as **placed** when its centre is inside the container's walls below ``placed_height``; it is
**dropped** when it is that low anywhere else (on the tiles). Either way the next product appears on the rack
(``_end_step``: the step's observation still shows where the product ended up). Reward: ``place_reward`` per placed
product, ``drop_penalty`` per dropped one, ``collision_penalty`` on a wall or mover collision or a platform limit
violation (these terminate the episode), else ``per_step_penalty``. The episode is a success (``is_success``,
terminated) when ``products`` products are placed; it is truncated after ``max_episode_steps``. ``info`` has
``products_placed`` and ``products_dropped`` (this episode, so far), ``placed`` / ``dropped`` (this step), the
collision and limit flags of :class:`PlatformPoseEnv`. The observation's count includes the step's placement.

Starts: the platform level, at ``start_height``, its yaw within ``start_yaw`` of 0, anywhere in the middle of the
tiles (:attr:`PickPlaceScene.start_low` / ``start_high``); the product on the rack with a small random offset
(``product_jitter``: x, y in m, yaw in rad).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import gymnasium as gym
import numpy as np
import torch

from magwarp.envs.magbot_task import as_vector, option_of
from magwarp.envs.platform_pose import PlatformConfig, PlatformPoseEnv, pose_to_goal
from magwarp.layout import Layout
from magwarp.magbots.mjcf import PlatformModelSpec, generate_platform_mjcf
from magwarp.mjcf import ObjectSpec, XmlHooks

__all__ = ["PickPlaceScene", "PlatformPickPlaceConfig", "PlatformPickPlaceEnv"]

#: the plate of the pick-and-place platform: narrow in x (it passes between the rack's rails), long in y
PICK_PLACE_PLATFORM = PlatformModelSpec(platform_half_size=(0.04, 0.1, 0.004), plate_friction=0.15)


def _f(x) -> str:
    return format(float(x), ".10g")


def _box(name: str, centre, half, rgba: str, visual: bool = False) -> str:
    bits = ' contype="0" conaffinity="0" group="1"' if visual else ""
    return (f'<geom name="{name}" type="box" pos="{_f(centre[0])} {_f(centre[1])} {_f(centre[2])}" '
            f'size="{_f(half[0])} {_f(half[1])} {_f(half[2])}" rgba="{rgba}"{bits}/>')


@dataclass(frozen=True)
class PickPlaceScene:
    """Where the supply rack, the product and the container are (metres; see the module docstring).

    ``supply_xy``: the product's centre on the rack; ``rail_height``: top of the rails; ``rail_gap``: half the
    distance between the rails' centres; ``container_x``: the container's centre in x, ``container_half``: its inner
    half extents (x, y), ``container_wall``: wall heights (near, other); ``drop_y``: the platform's y when it tilts
    the product off (default: the layout's far edge minus ``drop_margin``); ``placed_height``: a product below it
    has landed. ``product``: the product's shape, mass and friction.
    """

    supply_xy: tuple[float, float] = (0.34, 0.14)
    rail_height: float = 0.265
    rail_gap: float = 0.064
    rail_half: tuple[float, float] = (0.006, 0.006)
    container_x: float = 0.62
    container_half: tuple[float, float] = (0.16, 0.1)
    container_wall: tuple[float, float] = (0.04, 0.12)
    drop_margin: float = 0.12
    placed_height: float = 0.1
    dock_clearance: float = 0.015
    lift_clearance: float = 0.015
    product: ObjectSpec = field(default_factory=lambda: ObjectSpec(shape="box", width=0.075, height=0.04,
                                                                   depth=0.012, mass=0.06,
                                                                   friction=(0.15, 0.005, 0.0001)))

    def __post_init__(self):
        for name in ("rail_height", "rail_gap", "container_x", "drop_margin", "placed_height", "dock_clearance",
                     "lift_clearance"):
            v = float(getattr(self, name))
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"PickPlaceScene.{name} must be a positive number, got {v!r}")
            object.__setattr__(self, name, v)
        for name, n in (("supply_xy", 2), ("rail_half", 2), ("container_half", 2), ("container_wall", 2)):
            v = tuple(float(x) for x in getattr(self, name))
            if len(v) != n or not all(math.isfinite(x) for x in v) or (name != "supply_xy" and min(v) <= 0):
                raise ValueError(f"PickPlaceScene.{name} must be {n} finite (positive) numbers, got {v!r}")
            object.__setattr__(self, name, v)
        if not isinstance(self.product, ObjectSpec) or self.product.shape != "box":
            raise ValueError(f"PickPlaceScene.product must be a box ObjectSpec, got {self.product!r}")
        if self.rail_gap - self.rail_half[0] >= self.product.width:
            raise ValueError(f"PickPlaceScene: the rails (inner edges {self.rail_gap - self.rail_half[0]:.4g} m from "
                             f"the centre) do not hold the product (half width {self.product.width:.4g} m)")

    @property
    def dock_height(self) -> float:
        """Platform top height under the product on the rack."""
        return self.rail_height - self.dock_clearance

    @property
    def lift_height(self) -> float:
        """Platform top height with the product lifted clear of the rails."""
        return self.rail_height + self.lift_clearance

    def supply_position(self) -> tuple[float, float, float]:
        """The product's centre on the rack."""
        return (*self.supply_xy, self.rail_height + self.product.depth)

    def container_centre(self, layout: Layout) -> tuple[float, float, float]:
        """The container's inner centre (floor level)."""
        y0 = float(layout.extent[1]) + 0.005
        return (self.container_x, y0 + 0.005 + self.container_half[1], 0.0)

    def check(self, layout: Layout, plate_half_x: float) -> None:
        """Refuse a scene that the layout cannot hold or the platform cannot pass (clear errors)."""
        ext = np.asarray(layout.extent, dtype=float)
        inner = self.rail_gap - self.rail_half[0]
        if plate_half_x >= inner:
            raise ValueError(f"PickPlaceScene: the platform plate (half width {plate_half_x:.4g} m) does not fit "
                             f"between the rails (inner edges {inner:.4g} m from the centre)")
        x, y = self.supply_xy
        if not (0 < x < ext[0] and 0 < y < ext[1]):
            raise ValueError(f"PickPlaceScene.supply_xy {self.supply_xy} is not over the tiles (extent {ext.tolist()})")
        cx, hx = self.container_x, self.container_half[0]
        if not (0 <= cx - hx and cx + hx <= ext[0]):
            raise ValueError(f"PickPlaceScene: the container (x {cx - hx:.4g} .. {cx + hx:.4g}) is not along the "
                             f"layout's far edge (x 0 .. {ext[0]:.4g})")

    def boxes(self, layout: Layout) -> list[tuple[str, tuple, tuple, bool]]:
        """The static boxes ``(name, centre, half sizes, visual only)``: the rack's rails (they collide) and post
        (visual), the container's walls (they collide)."""
        x, y = self.supply_xy
        rh = self.rail_height
        hx, hz = self.rail_half
        y_start = -0.05
        ry = 0.5 * (y + self.product.height + 0.02 - y_start)
        out = [(f"rack_rail_{k}", (x + s * self.rail_gap, y_start + ry, rh - hz), (hx, ry, hz), False)
               for k, s in enumerate((-1.0, 1.0))]
        out.append(("rack_post", (x, y_start - 0.01, 0.5 * rh), (self.rail_gap + hx, 0.01, 0.5 * rh), True))
        cx, cy, _ = self.container_centre(layout)
        ix, iy = self.container_half
        near, other = self.container_wall
        t = 0.005
        out += [
            ("container_near", (cx, cy - iy - t, 0.5 * near), (ix + 2 * t, t, 0.5 * near), False),
            ("container_far", (cx, cy + iy + t, 0.5 * other), (ix + 2 * t, t, 0.5 * other), False),
            ("container_left", (cx - ix - t, cy, 0.5 * other), (t, iy, 0.5 * other), False),
            ("container_right", (cx + ix + t, cy, 0.5 * other), (t, iy, 0.5 * other), False),
        ]
        return out

    def hooks(self, layout: Layout) -> XmlHooks:
        """:meth:`boxes` as static geoms of the world body."""
        rgba = {"rack": "0.1 0.1 0.1 1", "container": "0.2 0.2 0.25 1"}
        return XmlHooks(worldbody="\n".join(_box(name, centre, half, rgba[name.split("_")[0]], visual)
                                            for name, centre, half, visual in self.boxes(layout)))


#: PlatformPose-v0's pose-goal options, refused by name (PlatformPickPlace's goal is the container)
_POSE_GOAL_OPTIONS = ("position_tolerance", "angle_tolerance", "sample_margin")


@dataclass(frozen=True)
class PlatformPickPlaceConfig(PlatformConfig):
    """The options of :class:`PlatformPickPlaceEnv` (see the module docstring): those of the 6D-platform envs
    (:class:`~magwarp.envs.platform_pose.PlatformConfig`: ``action_mode``, ``gains``, ``pose_step``, limits,
    ``num_cycles``, ...; ``model`` defaults to :data:`PICK_PLACE_PLATFORM`) and ``scene`` (the rack and the
    container, :class:`PickPlaceScene`), ``products`` (how many to place for a success), ``place_reward``,
    ``drop_penalty``, ``start_height`` (m), ``start_yaw`` (rad), ``product_jitter`` (x, y in m, yaw in rad)."""

    model: PlatformModelSpec = field(default_factory=lambda: PICK_PLACE_PLATFORM)
    per_step_penalty: float = -0.001
    max_episode_steps: int = 300
    scene: PickPlaceScene = field(default_factory=PickPlaceScene)
    products: int = 1
    place_reward: float = 1.0
    drop_penalty: float = -1.0
    start_height: float = 0.255
    start_yaw: float = 0.2
    product_jitter: tuple[float, float, float] = (0.004, 0.01, 0.05)

    COUNTS = ("products", *PlatformConfig.COUNTS)
    POSITIVE = ("start_height", *PlatformConfig.POSITIVE)
    FINITE = ("place_reward", "drop_penalty", "start_yaw", *PlatformConfig.FINITE)

    @classmethod
    def build(cls, config: PlatformPickPlaceConfig | dict | None = None, /, **options) -> PlatformPickPlaceConfig:
        """:meth:`MagBotConfig.build <magwarp.envs.magbot_task.MagBotConfig.build>`; PlatformPose-v0's pose-goal
        options are refused with the reason."""
        given = [*options, *(config if isinstance(config, dict) else ())]
        if any(k in given for k in _POSE_GOAL_OPTIONS):
            raise ValueError("PlatformPickPlace has no pose goals: position_tolerance, angle_tolerance and "
                             "sample_margin are PlatformPose-v0 options")
        return super().build(config, **options)

    def _check(self) -> None:
        self._set("product_jitter", as_vector(self.product_jitter, "product_jitter", 3, "(x, y, yaw)",
                                              positive=False))
        self._set("scene", option_of(self.scene, PickPlaceScene, "scene"))
        if self.model is None:
            self._set("model", PICK_PLACE_PLATFORM)
        super()._check()


class PlatformPickPlaceEnv(PlatformPoseEnv):
    """Batched pick and place with a 6D platform; see the module docstring. The task's options: ``config`` (a
    :class:`PlatformPickPlaceConfig` or a dict of its fields) and its fields as keyword options on top (``scene``
    places the rack and the container, ``products`` is the number to place for a success, ``action_mode``,
    ``gains``, ``pose_step``, limits, ``num_cycles``, ...); ``device``, ``seed``, ``render_mode``, ``autoreset`` and
    ``check_inputs`` are :class:`~magwarp.envs.platform_pose.PlatformPoseEnv`'s."""

    _contact_capacity = (24, 128)

    #: the options (:class:`PlatformPickPlaceConfig`; each field is also a keyword option)
    config_class = PlatformPickPlaceConfig
    _default_tiles = (4, 4)

    def _take_options(self, cfg: PlatformPickPlaceConfig) -> None:
        self.scene = cfg.scene
        self.products = cfg.products
        self.place_reward, self.drop_penalty = cfg.place_reward, cfg.drop_penalty
        self.start_height, self.start_yaw = cfg.start_height, cfg.start_yaw
        self._jitter = np.asarray(cfg.product_jitter, dtype=np.float64)

    # ------------------------------------------------------------------ model
    def _generate_xml(self, centre: np.ndarray, solver: str) -> str:
        s = self.scene
        if self.model_spec.plate_friction is None:
            raise ValueError("PlatformPickPlace needs a plate that carries the product: model.plate_friction is None")
        s.check(self.layout, self.model_spec.platform_half_size[0])
        return generate_platform_mjcf(self.layout, [centre], geometry=self.geometry, spec=self.model_spec,
                                      mover=self.mover, solver=solver, hooks=s.hooks(self.layout),
                                      objects=[s.product], object_xy=[s.supply_xy])

    def _init_task(self) -> None:
        s, g, dev, n = self.scene, self.geometry, self.device, self.num_envs
        lo, hi = g.height_range
        for name, h in (("dock", s.dock_height), ("lift", s.lift_height), ("start", self.start_height)):
            if not self.mover_z + lo <= h <= self.mover_z + hi:
                raise ValueError(f"PickPlaceScene: the {name} height {h:.4g} m is outside the platform's height range "
                                 f"[{self.mover_z + lo:.4g}, {self.mover_z + hi:.4g}] m")
        ext = np.asarray(self.layout.extent, dtype=float)
        #: the platform's y when it tilts the product into the container
        self.drop_y = float(ext[1] - s.drop_margin)
        self._jitter_t = torch.as_tensor(self._jitter, dtype=torch.float32, device=dev)
        self.supply = torch.tensor(s.supply_position(), device=dev)
        self.container = torch.tensor(s.container_centre(self.layout), device=dev)
        self._container_half = torch.tensor(s.container_half, device=dev)
        margin = 0.5 * g.max_mover_distance + self.mover.bounding_radius(self.mover.wall_margin) + 0.01
        self.start_low = torch.tensor([margin, 0.3, self.start_height], device=dev)
        self.start_high = torch.tensor([ext[0] - margin, ext[1] - 0.3, self.start_height], device=dev)
        # pose mode: the commanded platform centre may come as close to an edge as a mover's footprint (the rack
        # and the container lie near the edges; the wall check still fails a mover that leaves the tiles)
        r = self.mover.bounding_radius(self.mover.wall_margin)
        self._target_low[:2] = r
        self._target_high[:2] = torch.as_tensor(ext - r, dtype=self._target_high.dtype, device=dev)
        self.products_placed = torch.zeros(n, dtype=torch.int64, device=dev)
        self.products_dropped = torch.zeros(n, dtype=torch.int64, device=dev)
        self._placed = torch.zeros(n, dtype=torch.bool, device=dev)
        self._dropped = torch.zeros(n, dtype=torch.bool, device=dev)

    # ------------------------------------------------------------------ spaces
    def _observation_space(self) -> gym.spaces.Box:
        dim = 8 + 6 + 7 + 3 + 4 + 3 + 3 + 3 + 3 + 1 + (7 if self.action_mode == "pose" else 0)
        return gym.spaces.Box(-np.inf, np.inf, (dim,), np.float32)

    # ------------------------------------------------------------------ state
    def product_pose(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The product's position ``[W, 3]`` and quaternion (w, x, y, z) ``[W, 4]``."""
        q = self.backend.object_qpos[:, 0]
        return q[:, :3], q[:, 3:]

    def _product_start(self, mask: torch.Tensor) -> None:
        """Put a product on the rack (with the jitter) in the worlds of ``mask``, at rest."""
        b, n = self.backend, self.num_envs
        off = (2 * self._rand(n, 3) - 1) * self._jitter_t
        yaw = off[:, 2]
        q = torch.cat([self.supply + torch.nn.functional.pad(off[:, :2], (0, 1)),
                       torch.stack([torch.cos(0.5 * yaw), torch.zeros_like(yaw), torch.zeros_like(yaw),
                                    torch.sin(0.5 * yaw)], 1)], 1).to(b.qpos_t.dtype)
        for view in (b.object_qpos, b.init_object_qpos):
            view[:, 0].copy_(torch.where(mask[:, None], q, view[:, 0]))
        for view in (b.object_qvel, b.init_object_qvel):
            view[:, 0].masked_fill_(mask[:, None], 0.0)

    def _reset_envs(self, mask: torch.Tensor) -> None:
        b, n = self.backend, self.num_envs
        start = torch.zeros(n, 6, device=self.device)
        start[:, :3] = self.start_low + (self.start_high - self.start_low) * self._rand(n, 3)
        start[:, 5] = self.start_yaw * (2 * self._rand(n) - 1)
        q = b.init_qpos_t.clone()
        self.joints.write_qpos(q, start[:, None], self.mover_z, check=False)
        b.init_qpos_t.copy_(torch.where(mask[:, None], q, b.init_qpos_t))
        b.init_qvel_t.masked_fill_(mask[:, None], 0.0)
        self._product_start(mask)
        b.reset(mask)
        self.goal_pose.copy_(torch.where(mask[:, None], start, self.goal_pose))
        self.target_pose.copy_(torch.where(mask[:, None], start, self.target_pose))
        self.target_clipped.masked_fill_(mask, False)
        self.num_steps.masked_fill_(mask, 0)
        self.products_placed.masked_fill_(mask, 0)
        self.products_dropped.masked_fill_(mask, 0)
        if self.benchmark_metrics is not None:
            self.benchmark_metrics.episode_reset(mask)

    def scripted_policy(self):
        """The scripted baseline (:class:`magwarp.policies.platform_pick_place.PickPlacePolicy`)."""
        from magwarp.policies.platform_pick_place import PickPlacePolicy

        return PickPlacePolicy(self)

    def _get_obs(self) -> torch.Tensor:
        pos, vel = self.mover_state()
        n = self.num_envs
        pose = self.platform_pose()
        p, quat = self.product_pose()
        movers = torch.cat([pos[..., :2], torch.sin(pos[..., 2:]), torch.cos(pos[..., 2:])], -1).reshape(n, 8)
        parts = [movers, vel.reshape(n, 6), pose_to_goal(pose), p, quat, self.backend.object_qvel[:, 0, :3],
                 p - pose[:, :3], self.supply.expand(n, 3), self.container.expand(n, 3),
                 (self.products_placed.float() / self.products)[:, None]]
        if self.action_mode == "pose":
            parts.append(pose_to_goal(self.target_pose))
        return torch.cat(parts, 1).float()

    def in_container(self, p: torch.Tensor) -> torch.Tensor:
        """``[W]`` bool: product positions ``p`` ``[W, 3]`` inside the container's walls, below ``placed_height``."""
        inside = ((p[:, :2] - self.container[:2]).abs() <= self._container_half).all(-1)
        return inside & (p[:, 2] < self.scene.placed_height)

    def _evaluate(self, obs):
        info = self._failure_info()
        placed, dropped = self._placed, self._dropped
        failed = self._failed(info, placed.shape)
        done = self.products_placed >= self.products
        reward = torch.where(placed, self.place_reward, torch.where(dropped, self.drop_penalty,
                                                                     self.per_step_penalty))
        reward = torch.where(failed, torch.full_like(reward, self.collision_penalty), reward).float()
        self.num_steps += 1
        info.update({"is_success": done & ~failed, "placed": placed.clone(), "dropped": dropped.clone(),
                     "products_placed": self.products_placed.clone(),
                     "products_dropped": self.products_dropped.clone()})
        return self._step_result(obs, reward, done | failed, info)

    def _apply_action(self, action: torch.Tensor) -> None:
        """Simulate, then count the products that landed in the container or elsewhere (before the observation,
        so that it shows this step's count)."""
        super()._apply_action(action)
        p, _ = self.product_pose()
        placed = self.in_container(p)
        self._placed.copy_(placed)
        self._dropped.copy_(~placed & ((p[:, 2] < self.scene.placed_height) | ~torch.isfinite(p).all(-1)))
        self.products_placed += self._placed
        self.products_dropped += self._dropped

    def _end_step(self, obs, info) -> None:
        """The next product appears on the rack where one was placed or dropped."""
        self._product_start(self._placed | self._dropped)

    def compute_reward(self, achieved_goal, desired_goal, info) -> torch.Tensor:
        raise NotImplementedError("PlatformPickPlace has no goal-conditioned reward (its goal is the container)")

    def goal_ghosts(self, world: int) -> list[tuple]:
        """No ghost in the 3D view: the goal is the container, drawn as it is."""
        return []

    def _render_frame(self) -> torch.Tensor:
        """Top-down view: tiles, the movers, the platform plate and the product (objects), the rack's rails and the
        container's walls (obstacles)."""
        if self.render_mode == "rgb_array_3d":
            return self._render_3d()
        hx, hy, _ = self.model_spec.platform_half_size
        o = self.scene.product
        renderer = self._top_down([[(0.0, 0.0, hx, hy)], [(0.0, 0.0, o.width, o.height)]])
        if getattr(self, "_scene_rects", None) is None:  # the rails and the container's walls, seen from above
            self._scene_rects = torch.tensor([[c[0], c[1], h[0], h[1]] for _, c, h, visual in
                                              self.scene.boxes(self.layout) if not visual])
        pos, _ = self.mover_state()
        pose = self.platform_pose()
        p, q = self.product_pose()
        w, z = q[:, 0], q[:, 3]
        yaw = 2 * torch.atan2(z, w)
        objects = torch.stack([pose[:, [0, 1, 5]], torch.stack([p[:, 0], p[:, 1], yaw], 1)], 1)
        return renderer.draw(pos[..., :2], pos[..., 2], flags=self.checks.flags_t[:, None].expand(-1, 2),
                             object_poses=objects, obstacles=self._scene_rects)
