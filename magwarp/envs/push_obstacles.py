"""PushWithObstacles (MagBotSim's ``StateBasedStaticObstaclePushingEnv``): pushing a box through the gap between two
static walls, with MagBotSim's obstacle modes (fixed, random per episode, or a curriculum), the walls varying per
world without a model rebuild."""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import mujoco
import numpy as np
import torch
from warp import to_torch as wp_to_torch

from magwarp._checks import as_count
from magwarp.envs.base import _where
from magwarp.envs.episode import fmt_xy
from magwarp.envs.push import _CANDIDATES, PushEnv
from magwarp.envs.push_config import PushConfig, check_object_type
from magwarp.mjcf import ObstacleSpec


# MagBotSim's static obstacle modes: obstacle half length in y (obstacle 0 sits at y = that, obstacle 1 at the top
# edge of the 0.72 m tall layout minus it, so the gap between them narrows as they grow).
_OBSTACLE_HALF_Y = {"simple": 0.1, "medium": 0.115, "hard": 0.13}
_OBSTACLE_MODES = (*_OBSTACLE_HALF_Y, "random", "curriculum")
_MIX_MODES = (*_OBSTACLE_HALF_Y, "random")  # what a mix of modes may draw from at each reset
WALL_X, WALL_HALF_X, LAYOUT_TOP = 0.48, 0.03, 0.72  # the walls' centre x and half thickness, the layout's top (m)


def _mix_probabilities(mix) -> dict[str, float]:
    """``{mode: probability}`` of an ``obstacle_mode`` mapping, normalised; a bad key or weight raises, naming it."""
    unknown = [k for k in mix if k not in _MIX_MODES]
    if unknown or not mix:
        raise ValueError(f"an obstacle_mode mapping draws from {list(_MIX_MODES)}, got {dict(mix)!r}")
    weights = {}
    for mode, w in mix.items():
        try:
            weights[mode] = float(w)
        except (TypeError, ValueError):
            raise ValueError(f"obstacle_mode[{mode!r}] must be a number, got {w!r}") from None
        if not np.isfinite(weights[mode]) or weights[mode] < 0:
            raise ValueError(f"obstacle_mode[{mode!r}] must be a finite weight >= 0, got {w!r}")
    total = sum(weights.values())
    if total <= 0:
        raise ValueError(f"an obstacle_mode mapping needs a positive weight, got {dict(mix)!r}")
    return {mode: w / total for mode, w in weights.items()}


@dataclass(frozen=True)
class PushWithObstaclesConfig(PushConfig):
    """Options of :class:`PushWithObstaclesEnv`: :class:`~magwarp.envs.push_config.PushConfig`'s with MagBotSim's
    task values as defaults (a square box of half sizes 3.5 x 3.5 x 2 cm and 30 g, hover gap 2 mm, rewards -50 / -1 /
    0), and its own options:

    ``obstacle_mode`` sets the gap, as in MagBotSim: ``simple``, ``medium`` or ``hard`` (fixed walls of half length
    0.1, 0.115 or 0.13 m), ``random`` (a half length drawn uniformly from [0.1, 0.13] per world at every reset) or
    ``curriculum`` (each world starts ``simple`` and moves to ``medium``, then ``hard``, every
    ``curriculum_episodes`` episodes; MagBotSim: 800). A mapping of the fixed modes and ``random`` to weights, such
    as ``{"random": 0.5, "hard": 0.5}``, draws a mode per world at every reset (not in MagBotSim: a training mix
    that keeps easier gaps in every batch while half the episodes face the walls a policy is evaluated on). In the
    last three cases the walls change per world without a model rebuild: the obstacle geoms' pose and size are
    per-world model arrays in mujoco-warp (:meth:`MjwBackend.batch_model_fields`).

    ``curriculum_success_rate`` (curriculum mode only; default ``None``: MagBotSim's fixed schedule) also holds a
    world at its level until its running success rate there (an exponential average over about
    ``curriculum_episodes`` episodes, restarted at each level) reaches this value. A fixed schedule counts
    episodes, and an untrained policy crashes within a few steps, so it can reach the hard walls before it has
    learned anything on the simple ones.

    ``threshold_pos`` (m, MagBotSim's name) is the goal distance (the push envs' ``max_position_err``, which stays
    None here: give ``threshold_pos``). The walls are the task's (from ``obstacle_mode``; ``obstacles`` stays
    empty) and so is the object (``object_type`` stays ``"square_box"``)."""

    object_width: float = 0.035
    object_height: float = 0.035
    object_mass: float = 0.03
    max_position_err: float | None = None
    collision_penalty: float = -50.0
    per_step_penalty: float = -1.0
    object_at_goal_reward: float = 0.0
    initial_mover_zpos: float = 0.002
    obstacle_mode: str | dict[str, float] = "simple"
    threshold_pos: float = 0.05
    curriculum_episodes: int = 800
    curriculum_success_rate: float | None = None

    def __post_init__(self):
        mode = self.obstacle_mode
        if self.mix() is None and mode not in _OBSTACLE_MODES:
            raise ValueError(f"obstacle_mode must be one of {list(_OBSTACLE_MODES)}, got {mode!r}")
        as_count(self.curriculum_episodes, "curriculum_episodes")
        rate = self.curriculum_success_rate
        if rate is not None:
            if mode != "curriculum":
                raise ValueError(f"curriculum_success_rate needs obstacle_mode='curriculum', got {mode!r}")
            if not 0.0 <= float(rate) <= 1.0:
                raise ValueError(f"curriculum_success_rate must lie in [0, 1], got {rate!r}")
        if self.max_position_err is not None:
            raise ValueError(f"PushWithObstaclesEnv's goal distance is threshold_pos (MagBotSim's name); give "
                             f"threshold_pos={self.max_position_err!r}, not max_position_err")
        if not isinstance(self.obstacles, (tuple, list)) or len(self.obstacles):
            raise ValueError(f"PushWithObstaclesEnv places its own walls (obstacle_mode); obstacles must stay empty, "
                             f"got {self.obstacles!r}")
        super().__post_init__()
        check_object_type(self)

    def mix(self) -> dict[str, float] | None:
        """``{mode: probability}`` of a mapping ``obstacle_mode`` (normalised; a bad key or weight raises), else
        None."""
        return _mix_probabilities(self.obstacle_mode) if isinstance(self.obstacle_mode, dict) else None

    def walls(self) -> tuple[ObstacleSpec, ObstacleSpec]:
        """The two walls the model is built with: ``obstacle_mode``'s, or the ``simple`` ones where resets draw them
        (random, curriculum and mixed walls start simple)."""
        mode = self.obstacle_mode if not isinstance(self.obstacle_mode, dict) else "simple"
        size_y = _OBSTACLE_HALF_Y.get(mode, _OBSTACLE_HALF_Y["simple"])
        return (ObstacleSpec((WALL_X, size_y), (WALL_HALF_X, size_y, 0.03)),
                ObstacleSpec((WALL_X, LAYOUT_TOP - size_y), (WALL_HALF_X, size_y, 0.03)))

    def as_push_config(self) -> PushConfig:
        return PushConfig(**{**self.push_fields(), "max_position_err": self.threshold_pos, "obstacles": self.walls()})


class PushWithObstaclesEnv(PushEnv):
    """Pushing past two static obstacles (MagBotSim ``StateBasedStaticObstaclePushingEnv``), 25 steps.

    4 x 3 tiles, one mover, a 7 x 7 x 4 cm box of 30 g; two walls at x = 0.48 leave a gap the box must pass to reach
    a goal behind them. Observation adds the obstacles' corner x/y (8 numbers each). Reward: -50 on a wall
    collision or any mover/object contact with an obstacle (and the episode terminates), 0 at the goal
    (distance <= ``threshold_pos``), else -1. Options: :class:`PushWithObstaclesConfig` (``obstacle_mode``, the
    curriculum, and every :class:`~magwarp.envs.push.PushEnv` option), as a config and/or keywords.

    Chosen episodes (``reset(options=...)``, see :class:`~magwarp.envs.push.PushEnv`) must also keep the movers, the
    object and the goal clear of the walls (of the longest walls where a reset draws them).
    """

    config_type = PushWithObstaclesConfig

    def _init_options(self, opts: PushConfig) -> None:
        super()._init_options(opts)
        cfg = self.config
        self._mix = cfg.mix()
        self.obstacle_mode = dict(cfg.obstacle_mode) if self._mix is not None else cfg.obstacle_mode
        self.curriculum_episodes = int(cfg.curriculum_episodes)
        rate = cfg.curriculum_success_rate
        self.curriculum_success_rate = None if rate is None else float(rate)
        self.obstacle_x, self.obstacle_size_x, self.layout_top = WALL_X, WALL_HALF_X, LAYOUT_TOP

    def _varying_walls(self) -> bool:
        return self._mix is not None or self.obstacle_mode in ("random", "curriculum")

    def _reset_envs(self, mask: torch.Tensor) -> None:
        if self._varying_walls():
            self._resize_walls(mask)
        super()._reset_envs(mask)
        if self._varying_walls():
            # mujoco-warp computes world-attached (static) geom poses once, when the data is made: place the walls'
            # world positions too (the world body sits at the origin, unrotated, so they equal geom_pos)
            xpos = wp_to_torch(self.backend.data.geom_xpos)
            g = self._wall_geoms
            xpos[:, g] = _where(mask, self._geom_fields["geom_pos"][:, g], xpos[:, g])

    def _check_episode(self, chosen: dict[str, torch.Tensor], mask: torch.Tensor) -> None:
        """Also keeps chosen movers (their bodies' bounding circles), objects and goals (the object's bounding circle)
        clear of the walls: this episode's walls where they are fixed, the longest (``hard``) ones where a reset
        draws them."""
        super()._check_episode(chosen, mask)
        boxes = self.obstacle_boxes.clone()
        if self._varying_walls():
            h = _OBSTACLE_HALF_Y["hard"]
            boxes[:, 0, 1], boxes[:, 1, 1], boxes[:, :, 3] = h, self.layout_top - h, h
        body = float(np.hypot(*self.mover.size[:2])) / 2
        for key, reach in (("mover_xy", body), ("object_xy", self._object_reach()), ("goal_xy", self._object_reach())):
            if key not in chosen:
                continue
            pts = chosen[key].reshape(self.num_envs, -1, 1, 2)  # [n, K, 1, 2] against the walls [n, 1, 2, 2]
            gap = ((pts - boxes[:, None, :, :2]).abs() - boxes[:, None, :, 2:4]).clamp(min=0).norm(dim=-1)
            self._raise_first((gap < reach) & mask[:, None, None], lambda i, key=key: (
                f"options[{key!r}] puts {'mover ' + str(i[1]) if key == 'mover_xy' else 'the object'} of env {i[0]} "
                f"at {fmt_xy(chosen[key].reshape(self.num_envs, -1, 2)[i[0], i[1]])}, into obstacle {i[2]}"))

    def _resize_walls(self, mask: torch.Tensor) -> None:
        """New wall half lengths for the worlds in ``mask``, written into the per-world obstacle geoms."""
        if not hasattr(self, "_geom_fields"):
            self._geom_fields = self.backend.batch_model_fields(["geom_pos", "geom_size", "geom_aabb", "geom_rbound"])
            self._wall_geoms = torch.tensor(
                [mujoco.mj_name2id(self.backend.mjm, mujoco.mjtObj.mjOBJ_GEOM, f"obstacle_geom_{k}") for k in range(2)],
                device=self.device)
            self.curriculum_level = torch.zeros(self.num_envs, dtype=torch.int64, device=self.device)
            # -1: the reset inside the constructor is not an episode (MagBotSim counts the user's resets)
            self._episodes_at_level = torch.full((self.num_envs,), -1, dtype=torch.int64, device=self.device)
            self.curriculum_success = torch.zeros(self.num_envs, device=self.device)  # running rate at the level
            self._last_success = torch.zeros(self.num_envs, dtype=torch.bool, device=self.device)
        n = self.num_envs
        if self._mix is not None:
            half_y = self._mixed_half_y(n)
        elif self.obstacle_mode == "random":
            half_y = self._uniform(_OBSTACLE_HALF_Y["simple"], _OBSTACLE_HALF_Y["hard"], n)[:, 0]
        else:
            # MagBotSim counts resets and moves up a level once a level has had curriculum_episodes of them
            count = self._episodes_at_level + mask.long()
            up = mask & (count > self.curriculum_episodes) & (self.curriculum_level < 2)
            if self.curriculum_success_rate is not None:
                # the episode ending now (counted once a reset at this level started it) updates its world's rate
                ended = mask & (self._episodes_at_level >= 1)
                rate = torch.lerp(self.curriculum_success, self._last_success.float(), 1.0 / self.curriculum_episodes)
                self.curriculum_success.copy_(torch.where(ended, rate, self.curriculum_success))
                up &= self.curriculum_success >= self.curriculum_success_rate
                self.curriculum_success.masked_fill_(up, 0.0)
            self.curriculum_level += up.long()
            self._episodes_at_level.copy_(torch.where(up, torch.ones_like(count), count))
            levels = self._const(np.array(list(_OBSTACLE_HALF_Y.values()), np.float32))
            half_y = levels[self.curriculum_level]
        boxes = self.obstacle_boxes.clone()
        boxes[:, 0, 1] = half_y
        boxes[:, 1, 1] = self.layout_top - half_y
        boxes[:, :, 3] = half_y[:, None]
        self.obstacle_boxes.copy_(_where(mask, boxes, self.obstacle_boxes))
        g, f = self._wall_geoms, self._geom_fields
        # geom_pos/geom_size [W, ngeom, 3]; geom_aabb [W, ngeom, 2, 3] (centre, half size); geom_rbound [W, ngeom]
        pos, size = f["geom_pos"][:, g], f["geom_size"][:, g]
        new_pos = torch.cat([self.obstacle_boxes[:, :, :2], pos[..., 2:]], -1)
        new_size = torch.cat([self.obstacle_boxes[:, :, 2:4], size[..., 2:]], -1)
        f["geom_pos"][:, g] = _where(mask, new_pos, pos)
        f["geom_size"][:, g] = _where(mask, new_size, size)
        f["geom_aabb"][:, g] = _where(mask, torch.stack([torch.zeros_like(new_size), new_size], 2),
                                      f["geom_aabb"][:, g])
        f["geom_rbound"][:, g] = _where(mask, new_size.norm(dim=-1), f["geom_rbound"][:, g])

    def _mixed_half_y(self, n: int) -> torch.Tensor:
        """Wall half lengths of ``n`` worlds: each picks a mode of the mix by weight, then a length uniform in that
        mode's interval (a fixed level's is the level alone; ``random``'s is [simple, hard])."""
        modes = list(self._mix)
        cdf = self._const(np.cumsum([self._mix[m] for m in modes], dtype=np.float32))
        pick = torch.searchsorted(cdf, self._rand(n), right=True).clamp_(max=len(modes) - 1)
        lo = self._const(np.array([_OBSTACLE_HALF_Y.get(m, _OBSTACLE_HALF_Y["simple"]) for m in modes], np.float32))
        hi = self._const(np.array([_OBSTACLE_HALF_Y.get(m, _OBSTACLE_HALF_Y["hard"]) for m in modes], np.float32))
        return lo[pick] + (hi - lo)[pick] * self._rand(n)

    def _end_step(self, obs, info) -> None:
        super()._end_step(obs, info)
        if self.curriculum_success_rate is not None:  # each world's last step: its episode's success, if it ends now
            self._last_success = info["is_success"]

    def _init_sampling_ranges(self) -> None:
        super()._init_sampling_ranges()
        c = self._c_size_xy()[0] + self.collision_offset + self.mover.wall_margin
        top = float(self.layout.tile_centers()[:, 1].max() + self.layout.tile.half)
        right = float(self.layout.tile_centers()[:, 0].max() + self.layout.tile.half)
        small, obj_half = 0.1, self.object.width
        self.object_min_xy = np.full(2, c + small + 0.05)
        self.object_max_xy = np.array([self.obstacle_x - self.obstacle_size_x - obj_half - 0.05,
                                       top - (c + small + 0.05)])
        self.min_xy = np.full(2, c + 0.05)
        self.max_xy = np.array([self.obstacle_x - self.obstacle_size_x, top]) - c - 0.05
        self.goal_min_xy = np.array([self.obstacle_x + max(self.obstacle_size_x, obj_half), 0.0]) + small
        self.goal_max_xy = np.array([right, top]) - small
        mover_half = 0.5 * np.asarray(self.mover.size[:2])
        self.min_mover_object_dist = max(float(np.linalg.norm(obj_half + mover_half)), c)

    def _sample_episode(self, n: int) -> dict[str, torch.Tensor]:
        k = _CANDIDATES
        movers = self._uniform(self.min_xy, self.max_xy, n, 1, self.num_movers).expand(n, k, self.num_movers, 2)
        obj = self._uniform(self.object_min_xy, self.object_max_xy, n, k)
        ok = (movers - obj[:, :, None, :]).norm(dim=-1).gt(self.min_mover_object_dist).all(-1)
        first = torch.argmax(ok.to(torch.int8), dim=1)
        rows = torch.arange(n, device=self.device)
        return {
            "mover_xy": movers[rows, first],
            "object_xy": obj[rows, first],
            "goal_xy": self._uniform(self.goal_min_xy, self.goal_max_xy, n),
            "object_yaw": torch.zeros(n, device=self.device),  # MagBotSim's obstacle task starts the box unrotated
            "goal_yaw": torch.zeros(n, device=self.device),
        }

    def _observation_space(self) -> gym.spaces.Dict:
        space = super()._observation_space()
        dim = space["observation"].shape[0] + 16
        space["observation"] = gym.spaces.Box(-np.inf, np.inf, (dim,), np.float32)
        return space

    def obstacle_vertices(self) -> torch.Tensor:
        """``[W, 16]``: each wall's corners (x, y) in MagBotSim's order (+x+y, +x-y, -x-y, -x+y), wall 0 first."""
        c, h = self.obstacle_boxes[..., :2], self.obstacle_boxes[..., 2:4]
        signs = self._const(np.array([[1.0, 1.0], [1.0, -1.0], [-1.0, -1.0], [-1.0, 1.0]], np.float32))
        return (c[:, :, None, :] + signs * h[:, :, None, :]).reshape(self.num_envs, -1)

    def _get_obs(self) -> dict[str, torch.Tensor]:
        obs = super()._get_obs()
        obs["observation"] = torch.cat([obs["observation"], self.obstacle_vertices()], dim=1)
        return obs

    def _collision_info(self) -> dict[str, torch.Tensor]:
        info = super()._collision_info()
        info["obstacle_mover_collision"] = self.contacts.pair("mover", "obstacle").clone()
        info["obstacle_object_collision"] = self.contacts.pair("object", "obstacle").clone()
        return info

    def _any_collision(self, info, batch=None, device=None) -> torch.Tensor:
        out = super()._any_collision(info, batch, device)
        for key in ("obstacle_mover_collision", "obstacle_object_collision"):
            if info is not None and key in info:
                v = torch.as_tensor(info[key], device=device).bool()
                out = out | (v.reshape(batch) if batch is not None else v)
        return out
