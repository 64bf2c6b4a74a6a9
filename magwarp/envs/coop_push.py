"""Cooperative pushing (``magwarp/CoopPush-v0``): two to four movers jointly push an object too heavy for one.

A :class:`~magwarp.envs.push.PushEnv` on the mujoco-warp backend, batched over worlds, whose object is heavy: the
Coulomb friction of the object on the tiles exceeds what one mover can push, but not what two can. A mover's drive
applies the generalized force ``m_mover * a`` with ``|a| <= a_max`` (:mod:`magwarp.physics.control`), so one mover
pushes with at most ``F_1 = m_mover * a_max`` (12.4 N for the default 1.24 kg mover at 10 m/s^2). The object's
friction on the tiles is ``F_f = mu * m_object * g``; by default its mass is chosen so that ``F_f = force_ratio * F_1``
with ``force_ratio = 1.5``: with ``mu = 0.6`` and ``g = 9.81 m/s^2`` that is ``m_object = 1.5 * 12.4 / (0.6 * 9.81)
= 3.16 kg`` and ``F_f = 18.6 N``. One mover at its acceleration limit cannot move it (``F_1 < F_f``); two pushing
together can (``2 F_1 = 24.8 N > F_f``) and accelerate the object with the movers at up to ``(2 F_1 - F_f) / (m_object
+ 2 m_mover) = 1.1 m/s^2``. Released, the object stops at ``mu g = 5.9 m/s^2``. tests/test_coop_push.py checks
both: one mover pushing at full force for 1 s moves it less than 5 mm, two move it more than 5 cm.

Defaults: two movers (``num_movers`` 2 to 4), a square box of half-size (``object_width`` = ``object_height``) 0.05 m
per mover (0.2 m wide for two movers: all of them fit behind one face; its mass does not depend on the mover count:
``force_ratio=2.5`` makes one that needs three), a 6 x 6 tile layout,
box-shaped mover collision checks (half-size 0.08 m: movers side by side behind the object are not a collision),
position goals (``max_position_err`` = 0.05 m; ``learn_pose=True`` gives pose goals scored by coverage as
in Push-T), 100 steps of 40 ms. The object starts, and its goal lies, at least one mover length plus a margin further
from the layout's edge than in the push envs, so that the movers can get behind it from any side. Reward, success,
termination and ``info`` are the push env's (``PushEnv`` docstring): the reward is shared by all movers.

Observations: the push env's goal dict, with the object's state appended to ``"observation"``::

    observation = [mover x/y positions (2 M), mover x/y velocities (2 M), (x/y accelerations (2 M), jerk mode),
                   object x, y, sin yaw, cos yaw, object vx, vy]

and a per-agent view (:meth:`CoopPushEnv.agent_observations`, used by the PettingZoo and TorchRL multi-agent adapters
of :mod:`magwarp.envs.adapters`): for mover ``i`` (``obs_mode="flat"``)::

    [p_i (2), v_i (2), (a_i (2), jerk mode), object - p_i (2), object sin/cos yaw (2), object velocity (2),
     goal x/y - p_i (2), (goal sin/cos yaw (2), pose goals), p_j - p_i for the other movers j in index order (2 (M-1)),
     v_j for the other movers (2 (M-1))]

``obs_mode="dict"`` gives the same without the goal terms as ``observation`` and the shared ``achieved_goal`` /
``desired_goal`` (ready for hindsight relabelling). Per-agent action: the mover's x/y acceleration (or jerk).
"""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import numpy as np
import torch

from magwarp._checks import as_count, as_flag, check_finite
from magwarp.envs.push import PushEnv
from magwarp.envs.push_config import PushConfig
from magwarp.layout import Layout, MoverSpec, mover_params_kwargs

__all__ = ["CoopPushConfig", "CoopPushEnv", "CoopAgentObservations", "heavy_object_mass", "GRAVITY"]

GRAVITY = 9.81  # m/s^2, MuJoCo's default gravity (the model's)
_OBJECT_OBS = 6  # object x, y, sin yaw, cos yaw, vx, vy


def heavy_object_mass(mover_mass: float, a_max: float, friction: float, force_ratio: float) -> float:
    """Object mass (kg) whose sliding friction ``friction * m * g`` is ``force_ratio`` times one mover's largest push
    ``mover_mass * a_max`` (N): with ``1 < force_ratio < 2`` one mover cannot move it and two can."""
    for name, value in (("mover_mass", mover_mass), ("a_max", a_max), ("friction", friction),
                        ("force_ratio", force_ratio)):
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive number, got {value!r}")
    return float(force_ratio * mover_mass * a_max / (friction * GRAVITY))


@dataclass(frozen=True)
class CoopPushConfig(PushConfig):
    """Options of :class:`CoopPushEnv`: :class:`~magwarp.envs.push_config.PushConfig`'s with the cooperative task's
    defaults (the module docstring): ``num_movers`` 2 (2 to 4), a 6 x 6 tile layout (``layout`` None), box-shaped
    mover collision checks of half size 0.08 m, 100 steps; ``object_width`` and ``object_height`` (None: 0.05 m per
    mover) and ``object_mass`` (None: the mass whose sliding friction is ``force_ratio`` times one mover's largest
    push, :func:`heavy_object_mass` from the mover mass, ``a_max`` and ``object_sliding_friction``). The movers are
    driven in x/y only (``learn_mover_c_rotation`` stays False)."""

    num_movers: int = 2
    object_width: float | None = None
    object_height: float | None = None
    object_mass: float | None = None
    max_episode_steps: int = 100
    collision_shape: str = "box"
    collision_size: float | tuple[float, float] | None = 0.08
    force_ratio: float = 1.5

    def __post_init__(self):
        num_movers = as_count(self.num_movers, "num_movers")
        if not 2 <= num_movers <= 4:
            raise ValueError(f"CoopPush takes 2 to 4 movers, got num_movers={self.num_movers!r}")
        check_finite(a_max=self.a_max, object_sliding_friction=self.object_sliding_friction,
                     force_ratio=self.force_ratio, object_mass=self.object_mass, allow_none=("object_mass",))
        for name in ("a_max", "object_sliding_friction", "force_ratio", "object_mass"):
            value = getattr(self, name)
            if value is not None and not value > 0:
                raise ValueError(f"{name} must be positive, got {value!r}")
        if as_flag(self.learn_mover_c_rotation, "learn_mover_c_rotation"):
            raise ValueError("CoopPush drives the movers' x/y only: learn_mover_c_rotation=True is not supported")
        super().__post_init__()

    def mover_mass(self) -> float:
        """One mover's mass (kg): ``mover_params``' or the default mover's."""
        return float(mover_params_kwargs(self.mover_params).get("mass", MoverSpec.mass))

    def heavy_mass(self) -> float:
        """The object's mass (kg): ``object_mass``, or :func:`heavy_object_mass` of ``force_ratio``."""
        if self.object_mass is not None:
            return self.object_mass
        return heavy_object_mass(self.mover_mass(), self.a_max, self.object_sliding_friction, self.force_ratio)

    def as_push_config(self) -> PushConfig:
        size = 0.05 * int(self.num_movers)  # half-size: 5 cm per mover
        return PushConfig(**{
            **self.push_fields(),
            "layout": Layout(np.ones((6, 6), dtype=np.int32)) if self.layout is None else self.layout,
            "object_width": size if self.object_width is None else self.object_width,
            "object_height": size if self.object_height is None else self.object_height,
            "object_mass": self.heavy_mass(),
        })


class CoopPushEnv(PushEnv):
    """Batched cooperative pushing of a heavy object by ``num_movers`` (2 to 4) movers; see the module docstring.

    Options: :class:`CoopPushConfig` (a config and/or keywords). ``force_ratio`` sets the object's mass from the
    mover mass, ``a_max`` and ``object_sliding_friction`` (see :func:`heavy_object_mass`) unless ``object_mass`` is
    given; ``movers_needed`` is the least number of movers whose combined push exceeds the object's friction. Every
    other option is :class:`~magwarp.envs.push.PushEnv`'s."""

    config_type = CoopPushConfig

    def _init_options(self, opts: PushConfig) -> None:
        super()._init_options(opts)
        self.mover_force = self.config.mover_mass() * float(opts.a_max)  # N, one mover's largest push
        self.friction_force = float(opts.object_sliding_friction) * float(opts.object_mass) * GRAVITY  # N
        #: the least number of movers whose combined largest push exceeds the object's sliding friction
        self.movers_needed = int(self.friction_force // self.mover_force) + 1

    # ------------------------------------------------------------------ definitions
    def _init_sampling_ranges(self) -> None:
        """The push env's ranges, with the object's start range shrunk by one mover length (movers fit behind it)."""
        super()._init_sampling_ranges()
        room = float(max(self.mover.size[:2])) + 0.02
        lo, hi = self.object_min_xy + room, self.object_max_xy - room
        if np.any(hi < lo):
            raise ValueError(f"layout of shape {self.layout.shape} is too small for cooperative pushing: the object's "
                             f"start range leaves no room for a mover behind it (use a larger layout)")
        self.object_min_xy, self.object_max_xy = lo, hi

    def _observation_space(self) -> gym.spaces.Dict:
        space = super()._observation_space()
        dim = space["observation"].shape[0] + _OBJECT_OBS
        return gym.spaces.Dict({**space.spaces, "observation": gym.spaces.Box(-np.inf, np.inf, (dim,), np.float32)})

    def _object_obs(self) -> torch.Tensor:
        """``[N, 6]``: object x, y, sin yaw, cos yaw, vx, vy (``object_noise`` on the position and yaw)."""
        from magwarp.envs.push import _yaw_from_quat

        b = self.backend
        q = b.object_qpos[:, 0]
        yaw = self._noisy(_yaw_from_quat(q[:, 3:]), self.object_noise)
        xy = self._noisy(q[:, :2], self.object_noise)
        return torch.cat([xy, torch.sin(yaw)[:, None], torch.cos(yaw)[:, None], b.object_qvel[:, 0, :2]], 1)

    def _get_obs(self) -> dict[str, torch.Tensor]:
        obs = super()._get_obs()
        obs["observation"] = torch.cat([obs["observation"], self._object_obs()], 1)
        return obs

    # ------------------------------------------------------------------ multi-agent view, baseline
    def agent_observations(self, obs_mode: str = "flat") -> CoopAgentObservations:
        """The per-agent view of this env's observations (one agent per mover), for the multi-agent adapters."""
        return CoopAgentObservations(self, obs_mode)

    def scripted_policy(self):
        """The built-in baseline: the movers line up behind the object opposite the goal and push together."""
        from magwarp.policies.coop_push import CoopPushPolicy

        return CoopPushPolicy(self)


class CoopAgentObservations:
    """Splits :class:`CoopPushEnv` goal-dict observations ``[..., ...]`` into per-mover ones ``[..., M, D]`` (layout in
    the module docstring); batched tensor ops, no loop over worlds or movers. ``action_dim``: per-agent action size."""

    def __init__(self, env: CoopPushEnv, obs_mode: str = "flat"):
        if obs_mode not in ("flat", "dict"):
            raise ValueError(f"obs_mode must be one of ('flat', 'dict'), got {obs_mode!r}")
        self.num_movers = m = env.num_movers
        self.obs_mode = obs_mode
        self.learn_jerk = env.learn_jerk
        self.action_dim = 2
        self.goal_dim = 4 if env.learn_pose else 2
        others = [[j for j in range(m) if j != i] for i in range(m)]
        self._others = torch.tensor(others, dtype=torch.long, device=env.device).reshape(m, m - 1)
        own = 6 if self.learn_jerk else 4
        self.dim_dict_obs = own + _OBJECT_OBS + 4 * (m - 1)
        self.dim_flat = self.dim_dict_obs + self.goal_dim

    def spaces(self) -> gym.Space:
        """The observation space of one agent."""
        if self.obs_mode == "flat":
            return gym.spaces.Box(-np.inf, np.inf, (self.dim_flat,), np.float32)
        goal = gym.spaces.Box(-np.inf, np.inf, (self.goal_dim,), np.float32)
        return gym.spaces.Dict({"observation": gym.spaces.Box(-np.inf, np.inf, (self.dim_dict_obs,), np.float32),
                                "achieved_goal": goal, "desired_goal": goal})

    def __call__(self, obs: dict[str, torch.Tensor], state: torch.Tensor | None = None):
        """Per-agent observations from a goal-dict observation (``state`` is accepted for the adapters, unused)."""
        o = obs["observation"]
        lead, m = o.shape[:-1], self.num_movers
        groups = 3 if self.learn_jerk else 2
        movers = o[..., :2 * m * groups].reshape(*lead, groups, m, 2).movedim(-3, -2)  # (..., M, groups, 2)
        pos, vel = movers[..., 0, :], movers[..., 1, :]
        own = movers.flatten(-2)  # p, v(, a)
        obj = o[..., 2 * m * groups:][..., None, :].expand(*lead, m, _OBJECT_OBS)
        others = self._others.to(o.device)
        rel = (pos[..., others, :] - pos[..., None, :]).flatten(-2)  # (..., M, 2 (M-1))
        vel_o = vel[..., others, :].flatten(-2)
        obj_rel = torch.cat([obj[..., :2] - pos, obj[..., 2:]], -1)
        if self.obs_mode == "dict":
            goal_shape = (*lead, m, self.goal_dim)
            return {"observation": torch.cat([own, obj_rel, rel, vel_o], -1),
                    "achieved_goal": obs["achieved_goal"][..., None, :].expand(goal_shape).clone(),
                    "desired_goal": obs["desired_goal"][..., None, :].expand(goal_shape).clone()}
        goal = obs["desired_goal"][..., None, :].expand(*lead, m, self.goal_dim)
        goal = torch.cat([goal[..., :2] - pos, goal[..., 2:]], -1)
        return torch.cat([own, obj_rel, goal, rel, vel_o], -1)
