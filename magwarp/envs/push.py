"""Object pushing on mujoco-warp (MagBotSim's ``StateBasedGlobalPushingEnv`` family), batched and torch-native.

One or more movers push an object (box, square box, cylinder, T, L, X) to a goal position (``learn_pose=False``)
or a goal pose (``learn_pose=True``). Per env step (``num_cycles`` control cycles of 1 ms, the same action held; the
physics steps at ``physics_dt``, 1 ms by default, see :class:`~magwarp.envs.push_config.PushConfig`):

* observation: mover x/y positions then x/y velocities (then x/y accelerations when learning jerk), each flattened
  mover by mover (with ``learn_mover_c_rotation``: x, y, sin and cos of the yaw, then x/y/yaw rates, as MagBotSim;
  each mover's action is then x, y and yaw, see :mod:`magwarp.physics.control` for the yaw limits); achieved_goal:
  object x/y (plus sin/cos of its yaw for poses); desired_goal: the goal likewise;
* success: distance <= ``max_position_err`` (position goals) or coverage = area(object ∩ goal) / area(goal) >=
  ``min_coverage`` (pose goals; the paper's 0.7 by default, MagBotSim's library uses 0.95), and no collision;
* reward: ``collision_penalty`` on a mover-mover or wall collision, else ``object_at_goal_reward`` at the goal
  (position goals, or ``use_sparse_pose_reward``), else the coverage where it is positive (dense pose reward), else
  ``per_step_penalty``;
* terminated on a collision (or after ``early_termination_steps`` consecutive steps at the goal, if set);
  truncated after ``max_episode_steps`` (25 for Push-Box, 50 for Push-T/L/X, as MagBotSim registers them).

Start sampling follows MagBotSim's definition (start and goal ranges with its safety margins, mover-object distance
above the sum of their half-extents, object-goal distance above 0.15 m, uniform start and goal yaw), drawn on the
device with a fixed number of candidates per reset instead of a Python rejection loop (start and goal are drawn
together, so goals whose neighbourhood leaves no valid start are slightly less likely than in MagBotSim).

Differences from MagBotSim, on purpose: observations are float32 and noise-free unless ``std_noise`` (mover positions
and velocities) or ``object_noise`` (achieved goal) > 0 (MagBotSim's defaults: 1e-5 each); the mover controller is the
physically right impedance law of :mod:`magwarp.physics.control`; collisions are checked after every cycle inside
the step graph but a world is not frozen at its collision cycle (the episode ends at the step either way);
coverage rotates the object about its body origin (MagBotSim's shapely code rotates the L about its bounding-box
centre); jerk-mode observations use mujoco-warp's ``qacc`` as MagBotSim does.

Options: every one is a field of :class:`~magwarp.envs.push_config.PushConfig` (documented there); the env takes a
config and/or the same names as keywords: ``PushEnv(num_envs, config=None, *, device=..., seed=..., **options)``.
"""

from __future__ import annotations

import math
import warnings
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from magwarp._checks import as_count, as_flag, warp_device
from magwarp.collision import CollisionQuery
from magwarp.envs.base import MagwarpVecEnv, _where
from magwarp.envs.config import resolve_config
from magwarp.envs.episode import ChosenEpisodes, fmt_xy
from magwarp.envs.object_variants import MODEL_FIELDS, build_variants
from magwarp.envs.push_config import (PUSH_BENCHMARKS, PushBoxConfig, PushConfig, PushLConfig, PushTConfig,
                                      PushXConfig, push_benchmark)
from magwarp.envs.randomization import Randomizer
from magwarp.envs.sim2real import PushSim2Real
from magwarp.mjcf import ObjectSpec, generate_mjcf
from magwarp.physics import ContactFlags, MjwBackend, coverage
from magwarp.physics.coverage import ShapeTable
from magwarp.physics.mover_checks import MoverChecks
from magwarp.physics.push_metrics import PushMetrics

__all__ = ["PUSH_BENCHMARKS", "PushConfig", "PushBoxConfig", "PushTConfig", "PushLConfig", "PushXConfig", "PushEnv",
           "PushBoxEnv", "PushTEnv", "PushLEnv", "PushXEnv", "push_benchmark"]

_CANDIDATES = 256  # start configurations drawn per env and reset; the first valid one is used. With 64, the
# default Push-Box ranges (about 13% of candidates valid) left one env in ~8000 without a valid start per reset.


def _parts(obj: ObjectSpec) -> list[tuple[float, float, float, float]]:
    """Drawing parts ``(cx, cy, hx, hy)`` of an object in its body frame (a disc: ``hy = 0``)."""
    if obj.shape == "cylinder":
        return [(0.0, 0.0, float(obj.radius), 0.0)]
    return [tuple(float(v) for v in r) for r in obj.rects()]


def _yaw_from_quat(q: torch.Tensor) -> torch.Tensor:
    """Yaw of MuJoCo quaternions ``[..., 4]`` (w, x, y, z)."""
    w, x, y, z = q.unbind(-1)
    return torch.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


class PushEnv(PushSim2Real, ChosenEpisodes, MagwarpVecEnv):
    """Batched object pushing: ``PushEnv(num_envs, config=None, *, device=None, seed=None, render_mode=None,
    autoreset=True, check_inputs=True, nan_dump=None, **options)``. Every option (scene, object, goals, rewards,
    physics, randomisation, sim2real) is a field of :class:`~magwarp.envs.push_config.PushConfig`, documented there;
    give a config, the same names as keywords (``PushEnv(8, object_type="t_shape", learn_pose=True)``), or both
    (the keywords replace the config's fields). Unknown options and a config of another type raise a ``TypeError``,
    bad values a ``ValueError`` naming them, before anything is built. :attr:`config` is the resolved config; a
    subclass env (Push-Box, Push-T, ...) has its own :attr:`config_type` with its defaults.

    Rendering: ``render_mode="rgb_array"`` draws the worlds of :meth:`set_render_worlds` from above (tiles, movers,
    the object, its goal and obstacles); ``"rgb_array_3d"`` renders them in 3D through MuJoCo's offscreen renderer
    (:mod:`magwarp.render.mujoco3d`; needs EGL or OSMesa).

    Chosen episodes (e.g. a MagBotSim episode or a real-system log replayed): ``reset(seed=..., options={...})`` with
    any of ``"mover_xy"`` (mover start positions ``[M, 2]``; movers start hovering, level, at rest), ``"object_xy"``
    ``[2]`` and ``"object_yaw"`` ``[]`` (the object's start pose), ``"goal_xy"`` ``[2]`` and ``"goal_yaw"`` ``[]``
    (its goal), each for every reset env or per env with a leading ``num_envs`` axis, and ``"reset_mask"``
    (``[num_envs]`` bool). ``"mover_xy"`` and ``"object_xy"`` go together. Movers must be on the tiles (wall rule,
    wall margin included) and clear of each other; the object and the goal must lie on the tiles (the object's
    bounding circle) and the object must not overlap a mover's body (at any yaw when its yaw is sampled). A value
    that is not raises a ``ValueError`` naming it, and nothing is reset; keys not given are sampled as usual.
    """

    EPISODE_OPTIONS = {"mover_xy": ("M", 2), "object_xy": (2,), "object_yaw": (), "goal_xy": (2,), "goal_yaw": ()}

    #: benchmark metric tracker (:func:`magwarp.metrics.Metrics` attaches one); adds ``info["metrics"]``
    benchmark_metrics = None
    #: domain randomisation (:mod:`magwarp.envs.randomization`); None without ``randomization`` terms
    randomizer = None

    metadata = {**MagwarpVecEnv.metadata, "render_modes": ["rgb_array", "rgb_array_3d"]}

    #: the options' dataclass (a subclass env with other defaults or more options has its own subclass)
    config_type = PushConfig

    def __init__(self, num_envs: int = 1, config: PushConfig | None = None, *, device: str | None = None,
                 seed: int | None = None, render_mode: str | None = None, autoreset: bool = True,
                 check_inputs: bool = True, nan_dump: str | None = None, **options):
        #: the options (a :attr:`config_type`); :meth:`PushConfig.as_push_config` gives the push options it stands for
        self.config = resolve_config(type(self), config, options)  # every option checked before anything is built
        opts = self.config.as_push_config()
        num_envs = as_count(num_envs, "num_envs")
        self._init_options(opts)
        # Start ranges, and whether the mover and the object fit in them, before anything is built.
        self._init_sampling_ranges()
        self._check_sizes_fit()
        self._build_backend(num_envs, warp_device(device).alias, opts, seed)
        super().__init__(num_envs, self.backend.torch_device, seed=seed, render_mode=render_mode, autoreset=autoreset,
                         check_inputs=check_inputs, nan_dump=nan_dump)
        self._init_task_state()
        self._set_spaces(self._observation_space(), self._action_space())
        terms = opts.randomization_terms()[0]
        self.randomizer = Randomizer(self, terms) if terms else None
        self._init_sim2real(opts.actuation, opts.sensors)
        self.reset()

    # ------------------------------------------------------------------ construction
    def _init_options(self, opts: PushConfig) -> None:
        """The task's settings the env reads, from the (checked) push options ``opts``; a subclass adds its own (from
        :attr:`config`) before the sampling ranges and the model are made."""
        self.layout = opts.make_layout()
        self.num_movers = opts.mover_count()
        self.learn_pose = as_flag(opts.learn_pose, "learn_pose")
        self.learn_jerk = as_flag(opts.learn_jerk, "learn_jerk")
        self.learn_mover_c_rotation = as_flag(opts.learn_mover_c_rotation, "learn_mover_c_rotation")
        self.std_noise, self.object_noise = float(opts.std_noise), float(opts.object_noise)
        self.num_cycles = int(opts.num_cycles)  # control cycles (1 ms) per env step
        self.physics_dt = float(opts.physics_dt)  # mujoco-warp timestep and control period (s)
        self.substeps = opts.substeps()  # physics steps per env step
        self.max_position_err = float(opts.max_position_err)
        self.min_coverage = float(opts.min_coverage)
        self.use_sparse_pose_reward = as_flag(opts.use_sparse_pose_reward, "use_sparse_pose_reward")
        self.collision_penalty = float(opts.collision_penalty)
        self.per_step_penalty = float(opts.per_step_penalty)
        self.object_at_goal_reward = float(opts.object_at_goal_reward)
        e = opts.early_termination_steps
        self.early_termination_steps = None if e is None else int(e)
        self.max_episode_steps = int(opts.max_episode_steps)
        self.object = opts.make_object()
        self.mover = opts.make_mover()
        self.collision_offset = float(opts.collision_offset)
        self.obstacles = tuple(opts.obstacles)

    def _build_backend(self, num_envs: int, device: str, opts: PushConfig, seed: int | None) -> None:
        """The mujoco-warp model, built once (starts and goals change per world without a rebuild), its object
        variants, and the collision and contact checks on it."""
        solver = opts.solver
        if solver == "auto":
            solver = "Newton" if str(device).startswith("cuda") else "CG"

        def scene(spec):
            return generate_mjcf(self.layout, self.num_movers, self.mover, mover_xy=self._placeholder_starts(),
                                 objects=[spec], obstacles=self.obstacles, solver=solver,
                                 iterations=int(opts.solver_iterations), ls_iterations=int(opts.ls_iterations),
                                 timestep=self.physics_dt)

        self.xml = scene(self.object)
        # Contacts per world: up to 8 per colliding geom pair (MuJoCo's box-box and plane-box tests return at most 8):
        # every object part with the support, each mover and each obstacle, and each mover with each obstacle. An
        # elliptic-cone contact (condim 3) is 3 constraint rows. mujoco-warp's solver kernels run over njmax rows
        # per world, so a tight bound is speed (Push-Box: 48 rows, not a generous 96).
        parts = max(len(self.object.rects()), 1)
        n_obs = len(self.obstacles)
        ncon = int(opts.nconmax or 8 * (parts * (1 + self.num_movers + n_obs) + self.num_movers * n_obs))
        self.backend = MjwBackend(self.xml, num_envs, control=opts.control_params(), nconmax=ncon,
                                  njmax=int(opts.njmax or 3 * ncon), device=device)
        self.variants = None
        varying = opts.varying_ranges()
        if varying:
            self.variants = build_variants(self.object, varying, opts.object_variants, scene,
                                           np.random.default_rng(seed), self.backend.torch_device)
            self._variant_fields = self.backend.batch_model_fields(MODEL_FIELDS)
        self.checks = MoverChecks(self.backend, self.layout, self.mover)
        self.contacts = None
        if self.obstacles:
            self.contacts = ContactFlags(
                self.backend,
                {"mover": ["mover_geom_"], "object": ["object_0_geom_"], "obstacle": ["obstacle_geom_"]},
                [("mover", "obstacle"), ("object", "obstacle")],
            )
        self.backend.add_step_hook(self._clear_step_flags)

    def _clear_step_flags(self) -> None:
        """Per-step collision and contact flags start at zero: memsets at the head of the physics graph."""
        self.checks.flags.zero_()
        if self.contacts is not None:
            self.contacts.flags.zero_()

    def _init_task_state(self) -> None:
        """Per-world task tensors (goals, step counters, object variants, obstacle boxes) and the step metrics."""
        #: ``[W, K, 5]`` (cx, cy, hx, hy, yaw) of each world's static obstacles (the same in every world unless a
        #: subclass changes them per episode)
        self.obstacle_boxes = torch.as_tensor(
            np.array([[o.xy[0], o.xy[1], o.half_size[0], o.half_size[1], o.yaw] for o in self.obstacles],
                     dtype=np.float32).reshape(1, -1, 5), device=self.device).repeat(self.num_envs, 1, 1)

        n, dev = self.num_envs, self.device
        self.goal_xy = torch.zeros(n, 2, device=dev)
        self.goal_yaw = torch.zeros(n, device=dev)
        self.num_steps = torch.zeros(n, dtype=torch.int64, device=dev)
        self.steps_at_goal = torch.zeros(n, dtype=torch.int64, device=dev)
        self._step_count_t = torch.zeros((), dtype=torch.int64, device=dev)  # env steps since construction
        #: which object variant each world has (0 without ``object_ranges``); ``shapes`` their outlines (coverage)
        self.object_variant = torch.zeros(n, dtype=torch.int32, device=dev)
        self.shapes = ShapeTable(self.variants.specs if self.variants else [self.object], self.backend.device)
        self.metrics = PushMetrics(self.backend, self.shapes, self.goal_xy, self.goal_yaw,
                                   threshold=self.max_position_err, learn_pose=self.learn_pose,
                                   min_coverage=self.min_coverage, shape_index=self.object_variant)

    # ------------------------------------------------------------------ definitions (MagBotSim's)
    def _placeholder_starts(self) -> np.ndarray:
        # Any positions do for the model's qpos0 (every reset overrides them); spread them so the XML is sensible.
        ext = np.asarray(self.layout.extent)
        return np.stack([np.linspace(0.2, 0.8, self.num_movers) * ext[0], np.full(self.num_movers, 0.2 * ext[1])], 1)

    def _c_size_xy(self) -> np.ndarray:
        m = self.mover
        return np.full(2, m.collision_radius) if m.collision_shape == "circle" else np.asarray(m.collision_half_size)

    def _init_sampling_ranges(self) -> None:
        """Start/goal ranges and distances of MagBotSim's global pushing env (its definition, in its units)."""
        tile_half = self.layout.tile.half
        centres = self.layout.tile_centers()
        margin = self._c_size_xy() + self.mover.wall_margin + self.collision_offset + 0.03
        # MagBotSim bounds the range by the outermost tile centres plus half of the tile's *half* size.
        self.min_xy = margin
        self.max_xy = centres.max(axis=0) + tile_half / 2 - margin
        obj_margin = margin + 0.02
        self.object_min_xy = self.min_xy + obj_margin
        self.object_max_xy = self.max_xy - obj_margin
        if np.any(self.object_max_xy < self.object_min_xy) or np.any(self.max_xy < self.min_xy):
            raise ValueError(f"layout of shape {self.layout.shape} is too small for pushing with these margins")
        obj = self.object
        side = obj.radius if obj.shape == "cylinder" else max(obj.width, obj.height)
        mover_half = 0.5 * np.asarray(self.mover.size[:2])
        c = self._c_size_xy() + self.collision_offset
        c_offset = c[0] if self.mover.collision_shape == "circle" else float(np.linalg.norm(c))
        self.min_mover_object_dist = max(float(np.linalg.norm(side + mover_half)), c_offset)
        self.min_object_goal_dist = 0.15
        self.mover_pair_dist = 2 * float(np.linalg.norm(c)) if self.mover.collision_shape == "box" else 2 * c[0]
        self._continuous = bool(self.layout.tiles.all())
        reach = float(np.linalg.norm(self.object_max_xy - self.object_min_xy))
        if self._continuous and reach <= self.min_object_goal_dist:
            # MagBotSim's own rejection loop never ends here (it logs "Consider choosing more tiles" forever); a
            # batched draw cannot wait either, so episodes start with the object nearer its goal than 0.15 m.
            warnings.warn(f"the object range of layout {self.layout.shape} spans at most {reach:.3f} m, so no start is "
                          f"{self.min_object_goal_dist} m from its goal as MagBotSim requires (MagBotSim loops forever "
                          "here); episodes start nearer", stacklevel=3)

    def _check_sizes_fit(self) -> None:
        """The mover's body and the (largest) object must stay on the layout anywhere in their start ranges: a body
        that overhangs the tiles there is not levitated and goes unflagged (its collision shape is what is checked)."""
        extent = np.asarray(self.layout.extent)
        room = float(np.min(np.minimum(self.min_xy, extent - self.max_xy)))  # closest start to the layout's edge
        half = 0.5 * np.asarray(self.mover.size[:2])
        reach = float(np.hypot(*half)) if self.learn_mover_c_rotation else float(half.max())
        if reach > room:
            size, halves = tuple(round(v, 4) for v in self.mover.size), tuple(float(v) for v in half.round(4))
            raise ValueError(f"mover of size {size} m (mover_params['size'] = half sizes {halves}) does not fit the "
                             f"layout: its start range comes within {room:.3f} m of the tiles' edge (collision size + "
                             f"margins + 0.03 m), so its body would overhang the tiles; the largest half size that "
                             f"fits is {room:.3f} m (or enlarge collision_size)")
        obj = self.object
        parts = np.asarray(_parts(obj))
        radius = float(np.max(np.hypot(np.abs(parts[:, 0]) + parts[:, 2], np.abs(parts[:, 1]) + parts[:, 3])))
        obj_room = float(np.min(np.minimum(self.object_min_xy, extent - self.object_max_xy)))
        if radius > obj_room:
            size = f"radius {obj.radius:g} m" if obj.shape == "cylinder" else (
                f"half sizes width {obj.width:g}, height {obj.height:g} m")
            raise ValueError(f"the {obj.shape} object ({size}; with object_ranges, the largest) does not fit the "
                             f"layout {self.layout.shape}: it reaches {radius:.3f} m from its centre at any yaw, but "
                             f"its start range comes within {obj_room:.3f} m of the tiles' edge; the largest that fits "
                             f"reaches {obj_room:.3f} m")

    def _nonfinite_worlds(self, obs) -> torch.Tensor:
        b = self.backend
        state_bad = ~torch.isfinite(b.qpos_t).all(dim=1) | ~torch.isfinite(b.qvel_t).all(dim=1)
        return state_bad | super()._nonfinite_worlds(obs)

    def state_arrays(self, worlds) -> dict[str, Any]:
        b = self.backend
        return {**super().state_arrays(worlds), "qpos": b.qpos_t.cpu().numpy()[worlds],
                "qvel": b.qvel_t.cpu().numpy()[worlds], "goal_xy": self.goal_xy.cpu().numpy()[worlds],
                "goal_yaw": self.goal_yaw.cpu().numpy()[worlds]}

    def _observation_space(self) -> gym.spaces.Dict:
        m, c = self.num_movers, int(self.learn_mover_c_rotation)
        obs_dim = m * ((2 + int(self.learn_jerk)) * (2 + c) + c)  # MagBotSim's count
        ext = np.asarray(self.layout.extent, dtype=np.float32)
        if self.learn_pose:
            lo, hi = np.array([0, 0, -1, -1], np.float32), np.array([ext[0], ext[1], 1, 1], np.float32)
        else:
            lo, hi = np.zeros(2, np.float32), ext
        return gym.spaces.Dict({
            "observation": gym.spaces.Box(-np.inf, np.inf, (obs_dim,), np.float32),
            "achieved_goal": gym.spaces.Box(lo, hi, dtype=np.float32),
            "desired_goal": gym.spaces.Box(lo, hi, dtype=np.float32),
        })

    def _action_space(self) -> gym.spaces.Box:
        c = self.backend.control
        limit = c.j_max if c.jerk else c.a_max
        if not c.rotation:
            return gym.spaces.Box(-limit, limit, (self.num_movers * 2,), np.float32)
        limit_c = c.j_max_c if c.jerk else c.a_max_c
        high = np.tile(np.array([limit, limit, limit_c], np.float32), self.num_movers)
        return gym.spaces.Box(-high, high, dtype=np.float32)

    # ------------------------------------------------------------------ sampling (device, batched)
    def _const(self, value, dtype=torch.float32) -> torch.Tensor:
        """A device copy of a constant array, made once (resets then issue no host-to-device copies)."""
        arr = np.ascontiguousarray(value)
        key = (arr.tobytes(), arr.shape, dtype)
        cache = self.__dict__.setdefault("_consts", {})
        if key not in cache:
            cache[key] = torch.as_tensor(arr.copy(), device=self.device).to(dtype)  # a writable copy
        return cache[key]

    def _uniform(self, lo, hi, *shape: int) -> torch.Tensor:
        lo_t, hi_t = self._const(np.asarray(lo, np.float32)), self._const(np.asarray(hi, np.float32))
        return lo_t + (hi_t - lo_t) * self._rand(*shape, lo_t.shape[-1] if lo_t.ndim else 1)

    def _on_tiles(self, xy: torch.Tensor, radius: float) -> torch.Tensor:
        """Circle of ``radius`` at ``xy`` ``[..., 2]`` lies on present tiles (conservative for box footprints)."""
        size = self.layout.tile.size
        tiles = self._const(self.layout.tiles, torch.int32)
        nx, ny = tiles.shape
        reach = int(math.ceil(radius / size))
        base = torch.floor(xy / size).long()
        ok = torch.ones(xy.shape[:-1], dtype=torch.bool, device=self.device)
        for di in range(-reach, reach + 1):
            for dj in range(-reach, reach + 1):
                cell = torch.stack([base[..., 0] + di, base[..., 1] + dj], dim=-1)
                inside = (cell[..., 0] >= 0) & (cell[..., 0] < nx) & (cell[..., 1] >= 0) & (cell[..., 1] < ny)
                present = inside & (tiles[cell[..., 0].clamp(0, nx - 1), cell[..., 1].clamp(0, ny - 1)] == 1)
                lo = cell.to(xy.dtype) * size
                nearest = torch.maximum(torch.minimum(xy, lo + size), lo)
                hits = (xy - nearest).norm(dim=-1) < radius
                ok &= present | ~hits
        return ok

    def _tile_points(self, *shape: int) -> torch.Tensor:
        """MagBotSim's ``_sample_position_on_tile``: a random present tile, offset towards present neighbours."""
        t = self.layout.tiles
        ii, jj = np.nonzero(t)
        nx, ny = t.shape
        h = self.layout.tile.half
        lo = np.stack([np.where((ii > 0) & (t[np.maximum(ii - 1, 0), jj] == 1), -h, 0.0),
                       np.where((jj > 0) & (t[ii, np.maximum(jj - 1, 0)] == 1), -h, 0.0)], 1)
        hi = np.stack([np.where((ii < nx - 1) & (t[np.minimum(ii + 1, nx - 1), jj] == 1), h, 0.0),
                       np.where((jj < ny - 1) & (t[ii, np.minimum(jj + 1, ny - 1)] == 1), h, 0.0)], 1)
        centres, lo_t, hi_t = self._const(self.layout.tile_centers()), self._const(lo), self._const(hi)
        k = self._randint(len(ii), *shape)
        return centres[k] + lo_t[k] + (hi_t[k] - lo_t[k]) * self._rand(*shape, 2)

    def _sample_episode(self, n: int) -> dict[str, torch.Tensor]:
        """Starts and goals for ``n`` envs: ``_CANDIDATES`` candidates each, the first valid one chosen."""
        k, m = _CANDIDATES, self.num_movers
        movers = self._uniform(self.min_xy, self.max_xy, n, k, m)
        if self._continuous:
            # Goals are drawn per candidate: MagBotSim draws one goal and loops over starts, which can take very long
            # for goals in the middle of its narrow default range (4 x 3 tiles: 0.30 x 0.06 m).
            goal = self._uniform(self.object_min_xy, self.object_max_xy, n, k)
            obj = self._uniform(self.object_min_xy, self.object_max_xy, n, k)
        else:
            goal, obj = self._tile_points(n, k), self._tile_points(n, k)
        ok = (movers - obj[:, :, None, :]).norm(dim=-1).gt(self.min_mover_object_dist).all(-1)
        ok &= (obj - goal).norm(dim=-1) > self.min_object_goal_dist
        reach = self.mover.bounding_radius(self.mover.wall_margin + self.collision_offset)
        if not self._continuous:
            ok &= self._on_tiles(movers, reach).all(-1)
        if m > 1:
            d = (movers[:, :, :, None, :] - movers[:, :, None, :, :]).norm(dim=-1)
            d = d + torch.eye(m, device=self.device) * 1e9
            ok &= (d > self.mover_pair_dist).flatten(2).all(-1)
        first = torch.argmax(ok.to(torch.int8), dim=1)  # first valid candidate (0 if none: p ~ 1e-16 here)
        rows = torch.arange(n, device=self.device)
        two_pi = 2 * math.pi
        return {
            "mover_xy": movers[rows, first],
            "object_xy": obj[rows, first],
            "goal_xy": goal[rows, first],
            "object_yaw": self._rand(n) * two_pi - math.pi,
            "goal_yaw": self._rand(n) * two_pi - math.pi,
        }

    # ------------------------------------------------------------------ task hooks
    def _assign_variants(self, mask: torch.Tensor) -> None:
        """Give the worlds in ``mask`` a random object variant: its rows of the object-dependent model arrays."""
        v = self.variants
        pick = self._randint(v.count, self.num_envs).to(torch.int32)
        self.object_variant.copy_(torch.where(mask, pick, self.object_variant))
        idx = self.object_variant.long()
        for name, bank in v.fields.items():
            field = self._variant_fields[name]
            field.copy_(_where(mask, bank[idx], field))

    def _reset_envs(self, mask: torch.Tensor) -> None:
        b = self.backend
        if self.variants is not None:
            self._assign_variants(mask)
        if self.randomizer is not None:
            self.randomizer.reset(mask)
        self._sim2real_reset(mask)
        s = {key: self._chosen_or(key, value) for key, value in self._sample_episode(self.num_envs).items()}
        m3 = mask[:, None, None]
        mover_q = b.init_mover_qpos
        new_mover = mover_q.clone()
        new_mover[..., :2] = s["mover_xy"]
        new_mover[..., 2] = float(b.hover_z[0])
        new_mover[..., 3:] = self._const(np.array([1.0, 0.0, 0.0, 0.0]))
        mover_q.copy_(torch.where(m3, new_mover, mover_q))
        obj_q = b.init_object_qpos
        half = 0.5 * s["object_yaw"]
        new_obj = torch.zeros_like(obj_q)
        new_obj[:, 0, :2] = s["object_xy"]
        # 10 um into the support: a contact at exactly zero distance flips between float32 and float64 rounding
        depth = self.variants.depth[self.object_variant.long()] if self.variants is not None else self.object.depth
        new_obj[:, 0, 2] = depth - 1e-5
        new_obj[:, 0, 3] = torch.cos(half)
        new_obj[:, 0, 6] = torch.sin(half)
        obj_q.copy_(torch.where(m3, new_obj, obj_q))
        b.init_qvel_t.masked_fill_(mask[:, None], 0.0)
        b.reset(mask)
        self.goal_xy.copy_(torch.where(mask[:, None], s["goal_xy"], self.goal_xy))
        self.goal_yaw.copy_(torch.where(mask, s["goal_yaw"], self.goal_yaw))
        self.num_steps.masked_fill_(mask, 0)
        self.steps_at_goal.masked_fill_(mask, 0)
        self.metrics.reset(mask)
        if self.benchmark_metrics is not None:
            self.benchmark_metrics.episode_reset(mask)

    def _object_reach(self) -> float:
        """Radius of a circle around the object (its largest variant) about its centre."""
        parts = _parts(self.object)
        return max(math.hypot(abs(cx) + hx, abs(cy) + (hx if hy == 0 else hy)) for cx, cy, hx, hy in parts)

    def _check_episode(self, chosen: dict[str, torch.Tensor], mask: torch.Tensor) -> None:
        n, m, dev = self.num_envs, self.num_movers, self.device
        circle = self.mover.collision_shape == "circle"
        if getattr(self, "_episode_queries", None) is None:
            self._episode_queries = (
                CollisionQuery(self.layout, self.mover.collision_shape, offset_wall=self.mover.wall_margin,
                               device=str(dev)),
                CollisionQuery(self.layout, "circle", device=str(dev)),
                CollisionQuery(self.layout, "box", device=str(dev)),
            )
        movers_q, circle_q, box_q = self._episode_queries
        if ("mover_xy" in chosen) != ("object_xy" in chosen):
            raise ValueError("options['mover_xy'] and options['object_xy'] go together (the sampler keeps movers and "
                             "object apart only among sampled values)")
        if "object_yaw" in chosen and "object_xy" not in chosen:
            raise ValueError("options['object_yaw'] needs options['object_xy']")
        size = torch.tensor(self.mover.collision_radius if circle else self.mover.collision_half_size, device=dev)
        if "mover_xy" in chosen:
            poses = torch.cat([chosen["mover_xy"], torch.zeros(n, m, 1, device=dev)], -1)
            self._check_movers(movers_q, "mover_xy", poses, size + self.mover.margin, size, mask)
        parts = _parts(self.object)
        reach = self._object_reach()
        for key in ("object_xy", "goal_xy"):
            if key in chosen:
                on = circle_q(torch.cat([chosen[key], torch.zeros(n, 1, device=dev)], -1)[:, None], reach).wall_valid
                self._raise_first(~on[:, 0] & mask, lambda i, key=key: (
                    f"options[{key!r}] puts the object of env {i[0]} at {fmt_xy(chosen[key][i[0]])}, off the tiles "
                    f"(its bounding circle, radius {reach:.4g} m, must lie on them)"))
        if "mover_xy" in chosen:
            # the object's parts as boxes (a disc as its square); with a sampled yaw, the square around its bounding
            # circle (clear of the movers at any yaw)
            mover_xy, obj_xy = chosen["mover_xy"], chosen["object_xy"]
            obj_yaw = chosen.get("object_yaw", torch.zeros(n, device=dev))
            if "object_yaw" not in chosen:
                parts = [(0.0, 0.0, reach, reach)]
            c, si = torch.cos(obj_yaw), torch.sin(obj_yaw)
            half_body = torch.tensor(self.mover.size[:2], device=dev) / 2
            body = torch.cat([mover_xy, torch.zeros(n, m, 1, device=dev)], -1)
            for cx, cy, hx, hy in parts:
                centre = obj_xy + torch.stack([c * cx - si * cy, si * cx + c * cy], -1)
                part = torch.cat([centre, obj_yaw[:, None]], -1)[:, None].expand(n, m, 3)
                part_half = torch.tensor([hx, hy if hy > 0 else hx], device=dev)
                sizes = torch.stack([half_body.expand(n, m, 2), part_half.expand(n, m, 2)], -2)
                hit = box_q(torch.stack([body, part], -2), sizes).pair_collision[..., 0, 1] & mask[:, None]
                self._raise_first(hit, lambda i: (
                    f"options put the object of env {i[0]} at {fmt_xy(obj_xy[i[0]])} (yaw "
                    f"{'sampled' if 'object_yaw' not in chosen else format(obj_yaw[i[0]].item(), '.4g')}) under "
                    f"mover {i[1]} at {fmt_xy(mover_xy[i[0], i[1]])}"))

    def _apply_action(self, action: torch.Tensor) -> None:
        # the collision and contact flags are cleared inside the physics graph (_clear_step_flags)
        if self.randomizer is not None:
            self.randomizer.step()
        self._step_backend(action.reshape(self.num_envs, self.num_movers, -1))

    # ------------------------------------------------------------------ the step
    #: on CUDA, record the task work after the physics as one CUDA graph (:mod:`magwarp.envs.step_graph`); False runs
    #: it eagerly (the same results, bit for bit)
    use_step_graph = True
    _task_graph = None

    def step(self, action):
        """One env step: the action is checked (a host sync only with ``check_inputs``), written into the physics
        graph's command buffer and the physics graph replayed (``substeps`` physics steps, collision checks and
        metrics per physics step); then observations, rewards, terminations, goal resampling and autoreset run as
        one more graph on CUDA (a torch CUDA graph with the reset's Warp kernels inside), eagerly on the CPU. No
        host sync; randomness follows the env's seeded generator either way. With ``nan_dump``, a randomizer, a sensor
        model or benchmark metrics attached the task work runs eagerly (they keep host-side state)."""
        if self.nan_dump is not None:  # debugging mode: the base class's step, one host sync per step
            out = super().step(action)
            self._step_count_t += 1
            return out
        action = self._check_action(action)
        self._apply_action(action)
        self._step_count += 1
        graph = self._task_graph_for_step()
        return graph() if graph is not None else self._finish_step()

    def _task_graph_for_step(self):
        if not self.use_step_graph or self.device.type != "cuda" or self.randomizer is not None \
                or self.benchmark_metrics is not None or self.sensors is not None:
            return None
        if self._task_graph is None:
            from magwarp.envs.step_graph import TaskGraph

            self._task_graph = TaskGraph(self._finish_step, self.device, generators=[self._generator],
                                         recorders=[self.backend.recording])
        return None if self._task_graph.failed else self._task_graph

    def _finish_step(self):
        """The step after the physics (the base class's step from its observation on): observation, reward,
        termination, NaN guard, autoreset. The step count is a device counter here, so a graph replays it right."""
        self._step_count_t += 1
        obs = self._get_obs()
        reward, terminated, truncated, info = self._evaluate(obs)
        self._end_step(obs, info)
        reward, terminated = self._guard_nonfinite(obs, reward, terminated, info, None)
        info["nonfinite_step"] = torch.where(info["nonfinite"], self._step_count_t, -1)
        return self._autoreset(obs, reward, terminated, truncated, info)

    def _mover_obs(self) -> torch.Tensor:
        b, n = self.backend, self.num_envs
        if self.learn_mover_c_rotation:
            # MagBotSim's layout: per mover (x, y, sin yaw, cos yaw), then (vx, vy, yaw rate)[, (ax, ay, yaw acc)]
            yaw = self._noisy(_yaw_from_quat(b.mover_qpos[..., 3:]), self.std_noise)
            xy = self._noisy(b.mover_qpos[..., :2], self.std_noise)
            pos = torch.cat([xy, torch.sin(yaw)[..., None], torch.cos(yaw)[..., None]], -1)
            parts = [pos.reshape(n, -1), self._noisy(b.mover_qvel[..., [0, 1, 5]], self.std_noise).reshape(n, -1)]
            if self.learn_jerk:
                parts.append(b.mover_qacc[..., [0, 1, 5]].reshape(n, -1))
            return torch.cat(parts, dim=1)
        parts = list(self._sense_movers(b.mover_qpos[..., :2], b.mover_qvel[..., :2]))
        if self.learn_jerk:
            parts.append(b.mover_qacc[..., :2].reshape(n, -1))
        return torch.cat(parts, dim=1)

    def _goals(self) -> tuple[torch.Tensor, torch.Tensor]:
        q = self.backend.object_qpos[:, 0]
        achieved = self._noisy(q[:, :2], self.object_noise)
        desired = self.goal_xy
        if self.learn_pose:
            yaw = self._noisy(_yaw_from_quat(q[:, 3:]), self.object_noise)
            achieved = torch.cat([achieved, torch.sin(yaw)[:, None], torch.cos(yaw)[:, None]], 1)
            desired = torch.cat([desired, torch.sin(self.goal_yaw)[:, None], torch.cos(self.goal_yaw)[:, None]], 1)
        return achieved.clone(), desired.clone()

    def _get_obs(self) -> dict[str, torch.Tensor]:
        achieved, desired = self._goals()
        return self._hold_obs({"observation": self._mover_obs(), "achieved_goal": achieved, "desired_goal": desired})

    def _collision_info(self) -> dict[str, torch.Tensor]:
        return {"mover_collision": self.checks.mover_collision.clone(),
                "wall_collision": self.checks.wall_collision.clone()}

    def _evaluate(self, obs):
        info = self._collision_info()
        if self.variants is not None:
            info["object_variant"] = self.object_variant.clone()
        reached, metric = self.goal_reached(obs["achieved_goal"], obs["desired_goal"], info)
        collision = self._any_collision(info)
        self.num_steps += 1
        self.steps_at_goal.copy_(torch.where(reached, self.steps_at_goal + 1, torch.zeros_like(self.steps_at_goal)))
        reward = self._reward(reached, metric, info)
        terminated = collision.clone()
        if self.early_termination_steps is not None:
            terminated |= self.steps_at_goal >= self.early_termination_steps
        truncated = self.num_steps >= self.max_episode_steps
        info.update({
            "is_success": reached & ~collision,
            "goal_metric": metric,
            "steps_at_goal": self.steps_at_goal.clone(),
            "num_overshoot_corrections": self.metrics.t["overshoots"].clone(),
            "num_distance_corrections": self.metrics.t["dist_corrections"].clone(),
            "time_to_success_s": self.metrics.t["time_to_success"].clone(),
        })
        if self.benchmark_metrics is not None:
            info["metrics"] = self.benchmark_metrics.on_step(obs, info, terminated, truncated)
        return reward, terminated, truncated, info

    # ------------------------------------------------------------------ reward (batched, for HER)
    def goal_reached(self, achieved_goal: torch.Tensor, desired_goal: torch.Tensor,
                     info: dict[str, Any] | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """(reached, metric): metric is the distance (position goals) or the coverage (pose goals).

        With ``object_ranges`` the coverage needs each pose pair's object variant: ``info["object_variant"]`` (of the
        batch shape; every step's ``info`` has it), or the env's current variants for a batch of ``num_envs``."""
        if self.learn_pose:
            index = None
            if self.variants is not None:
                if info is not None and "object_variant" in info:
                    index = torch.as_tensor(info["object_variant"], device=achieved_goal.device)
                elif achieved_goal.shape[:-1] == (self.num_envs,):
                    index = self.object_variant
                else:
                    raise ValueError("pose goals with object_ranges: pass info['object_variant'] (from the step's "
                                     f"info) for a batch of shape {tuple(achieved_goal.shape[:-1])}")
            cov = coverage(achieved_goal, desired_goal, self.shapes, index)
            return cov >= self.min_coverage, cov
        dist = (achieved_goal[..., :2] - desired_goal[..., :2]).norm(dim=-1)
        return dist <= self.max_position_err, dist

    def _any_collision(self, info: dict[str, Any] | None, batch=None, device=None) -> torch.Tensor:
        keys = ("mover_collision", "wall_collision")
        out = None
        for key in keys:
            if info is not None and key in info:
                v = torch.as_tensor(info[key], device=device).bool()
                v = v.reshape(batch) if batch is not None else v
                out = v if out is None else out | v
        if out is None:
            out = torch.zeros(batch if batch is not None else (self.num_envs,), dtype=torch.bool,
                              device=device or self.device)
        return out

    def _reward(self, reached: torch.Tensor, metric: torch.Tensor, info: dict[str, Any] | None) -> torch.Tensor:
        collision = self._any_collision(info, reached.shape, reached.device)
        reward = torch.full(reached.shape, self.per_step_penalty, device=reached.device)
        if self.learn_pose and not self.use_sparse_pose_reward:
            reward = torch.where(metric > 0, metric.to(reward.dtype), reward)
        else:
            reward = torch.where(reached, torch.full_like(reward, self.object_at_goal_reward), reward)
        return torch.where(collision, torch.full_like(reward, self.collision_penalty), reward)

    def compute_reward(self, achieved_goal, desired_goal, info) -> torch.Tensor:
        """Reward for a batch ``(..., goal_dim)``; ``info`` holds collision flags of the batch shape (or is None)."""
        achieved_goal = torch.as_tensor(achieved_goal)
        desired_goal = torch.as_tensor(desired_goal, device=achieved_goal.device)
        reached, metric = self.goal_reached(achieved_goal, desired_goal, info)
        return self._reward(reached, metric, info)

    # ------------------------------------------------------------------ rendering
    def object_parts(self, world: int = 0) -> list[tuple[float, float, float, float]]:
        """World ``world``'s object footprint as drawing parts ``(cx, cy, hx, hy)`` in its body frame (a disc:
        ``hy = 0``); with ``object_ranges`` this reads the world's variant (one device-to-host copy)."""
        if self.variants is None:
            return _parts(self.object)
        return _parts(self.variants.specs[int(self.object_variant[world])])

    def render_state(self) -> dict[str, torch.Tensor]:
        """What a frame shows, as device tensors (shared by the top-down renderer and the 3D viewers): mover
        ``pos [W, M, 3]`` and ``yaw [W, M]``, collision ``flags [W, M]`` (the world's flags, per mover), object
        ``object_poses`` and goal ``object_goals`` ``[W, 1, 3]`` (x, y, yaw; position goals are drawn unrotated)
        and static ``obstacles [W, K, 5]`` (cx, cy, hx, hy, yaw)."""
        b, n, m = self.backend, self.num_envs, self.num_movers
        q = b.mover_qpos
        flags = self.checks.flags_t
        if self.contacts is not None:  # touching an obstacle counts as a collision in this task
            flags = flags | self.contacts.pair("mover", "obstacle").to(flags.dtype)
        obj = b.object_qpos[:, 0]
        goal_yaw = self.goal_yaw if self.learn_pose else torch.zeros_like(self.goal_yaw)
        out = {
            "pos": q[..., :3],
            "yaw": _yaw_from_quat(q[..., 3:]),
            "flags": flags[:, None].expand(n, m),
            "object_poses": torch.cat([obj[:, :2], _yaw_from_quat(obj[:, 3:])[:, None]], 1)[:, None],
            "object_goals": torch.cat([self.goal_xy, goal_yaw[:, None]], 1)[:, None],
        }
        if self.obstacles:
            out["obstacles"] = self.obstacle_boxes
        return out

    def _render_frame(self):
        worlds = getattr(self, "_render_worlds", None) or min(self.num_envs, 16)
        if self.render_mode == "rgb_array_3d":
            from magwarp.render.mujoco3d import render_worlds

            return render_worlds(self, worlds)
        if getattr(self, "_renderer", None) is None:
            from magwarp.render import TopDownRenderer

            count = worlds if np.ndim(worlds) == 0 else len(worlds)
            ppt = 96 if count == 1 else 48 if count <= 4 else 32
            specs = self.variants.specs if self.variants is not None else [self.object]
            self._renderer = TopDownRenderer(self.layout, self.mover, worlds=worlds, px_per_tile=ppt,
                                             object_shapes=[_parts(o) for o in specs], device=self.backend.device)
        s = self.render_state()
        return self._renderer.draw(s["pos"], s["yaw"], flags=s["flags"], object_poses=s["object_poses"],
                                   object_goals=s["object_goals"], obstacles=s.get("obstacles"),
                                   object_shape=self.object_variant)


class PushBoxEnv(PushEnv):
    """Push-Box (MagBotSim ``StateBasedPushBoxEnv``): a square box to a goal position, 25 steps
    (:class:`~magwarp.envs.push_config.PushBoxConfig`)."""

    config_type = PushBoxConfig


class PushTEnv(PushEnv):
    """Push-T (MagBotSim ``StateBasedPushTEnv``): a T to a goal pose (coverage >= ``min_coverage``), 50 steps
    (:class:`~magwarp.envs.push_config.PushTConfig`)."""

    config_type = PushTConfig


class PushLEnv(PushTEnv):
    """Push-L: like Push-T with an L-shaped object (:class:`~magwarp.envs.push_config.PushLConfig`)."""

    config_type = PushLConfig


class PushXEnv(PushTEnv):
    """Push-X: like Push-T with an X (plus) shaped object (:class:`~magwarp.envs.push_config.PushXConfig`)."""

    config_type = PushXConfig
