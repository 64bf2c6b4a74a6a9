"""Shared by the MagBot envs (:mod:`magwarp.envs.platform_pose`, :mod:`magwarp.envs.platform_pick_place`,
:mod:`magwarp.envs.gripper_pick_place`): their typed options (:class:`MagBotConfig`, which each env extends), option
checks, failure flags, the sparse reward, the top-down renderer and what the 3D renderer reads
(``render_mode="rgb_array_3d"``)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, fields, replace
from typing import Any, ClassVar

import numpy as np
import torch

from magwarp._checks import as_count, as_finite, check_finite, check_magnitude
from magwarp.magbots.control import TrackingGains

__all__ = ["MagBotConfig", "MagBotTask", "as_vector", "check_options", "option_of"]


def option_of(value, cls: type, name: str):
    """``value`` if it is a ``cls`` (None: ``cls()``, its defaults); anything else is a TypeError naming it."""
    if value is None:
        return cls()
    if not isinstance(value, cls):
        raise TypeError(f"{name} must be a {cls.__name__} (or None), got {value!r}")
    return value


def check_options(action_mode: str, action_modes: Sequence[str], *, counts: dict[str, Any],
                  positive: dict[str, Any] = {}, finite: dict[str, Any] = {}) -> None:  # noqa: B006 (read only)
    """Refuse, naming the option: an unknown ``action_mode``, ``counts`` that are not positive integers, ``positive``
    values that are not positive finite numbers (at most :data:`magwarp._checks.MAGNITUDE_MAX`), ``finite`` values
    that are not finite numbers (likewise bounded)."""
    if not isinstance(action_mode, str) or action_mode not in action_modes:
        raise ValueError(f"action_mode must be one of {tuple(action_modes)}, got {action_mode!r}")
    for name, value in counts.items():
        as_count(value, name)
    for name, value in positive.items():
        if not as_finite(value, name) > 0:
            raise ValueError(f"{name} must be a positive number, got {value!r}")
    for name, value in finite.items():
        as_finite(value, name)
    check_magnitude(**positive, **finite)


def as_vector(value, name: str, length: int, what: str, *, positive: bool = True) -> tuple[float, ...]:
    """``value`` as a tuple of ``length`` floats, each positive (``positive=False``: non-negative); anything else is
    an error naming it and saying ``what`` the numbers are (e.g. ``"(x, y, yaw)"``)."""
    check_finite(**{name: value}, vectors=(name,))
    arr = np.asarray(value, dtype=np.float64)
    ok = (arr > 0) if positive else (arr >= 0)
    if arr.shape != (length,) or not np.all(np.isfinite(arr) & ok):
        words = {3: "three", 4: "four", 6: "six"}.get(length, str(length))
        raise ValueError(f"{name} must be {words} {'positive' if positive else 'non-negative'} numbers {what}, "
                         f"got {value!r}")
    return tuple(float(v) for v in arr)


@dataclass(frozen=True)
class MagBotConfig:
    """The options every MagBot env takes; each env extends it with its own (e.g.
    :class:`~magwarp.envs.gripper_pick_place.GripperPickPlaceConfig`). An env takes its config as ``config=`` and
    each field as a keyword option of the same name, on top of it (``Env(config=cfg, max_episode_steps=10)``,
    ``gymnasium.make(id, max_episode_steps=10)``); :meth:`build` merges the two.

    Checked on construction (frozen afterwards): a bad value raises naming the option and the value. Numbers are
    stored as ``float`` (counts as ``int``), option objects left as None get their defaults.

    ``action_mode``: one of the env's :attr:`ACTION_MODES`; ``gains``: the tracking gains of the target action modes
    (:class:`~magwarp.magbots.control.TrackingGains`); ``success_reward``, ``per_step_penalty``,
    ``collision_penalty``: the sparse reward; ``max_episode_steps``: truncation; ``num_cycles``: control cycles of 1
    ms per env step; ``v_max`` (m/s), ``a_max`` (m/s^2): the movers' x/y limits; ``solver``: MuJoCo's solver."""

    action_mode: str = "mover"
    gains: TrackingGains = field(default_factory=TrackingGains)
    success_reward: float = 1.0
    per_step_penalty: float = -0.01
    collision_penalty: float = -10.0
    max_episode_steps: int = 200
    num_cycles: int = 40
    v_max: float = 2.0
    a_max: float = 10.0
    solver: str = "Newton"

    #: the action modes the env takes
    ACTION_MODES: ClassVar[tuple[str, ...]] = ("mover",)
    #: the fields checked (in this order) as positive integers, positive numbers and finite numbers
    COUNTS: ClassVar[tuple[str, ...]] = ("num_cycles", "max_episode_steps")
    POSITIVE: ClassVar[tuple[str, ...]] = ("v_max", "a_max")
    FINITE: ClassVar[tuple[str, ...]] = ("success_reward", "per_step_penalty", "collision_penalty")

    def __post_init__(self):
        check_options(self.action_mode, self.ACTION_MODES, counts={n: getattr(self, n) for n in self.COUNTS},
                      positive={n: getattr(self, n) for n in self.POSITIVE},
                      finite={n: getattr(self, n) for n in self.FINITE})
        for name in self.COUNTS:
            self._set(name, int(getattr(self, name)))
        for name in (*self.POSITIVE, *self.FINITE):
            self._set(name, float(getattr(self, name)))
        self._set("gains", option_of(self.gains, TrackingGains, "gains"))
        self._check()

    def _check(self) -> None:
        """The env's own checks and conversions (after the shared ones; :meth:`_set` stores a converted value)."""

    def _set(self, name: str, value) -> None:
        object.__setattr__(self, name, value)

    @classmethod
    def build(cls, config: MagBotConfig | dict | None = None, /, **options) -> MagBotConfig:
        """A ``cls`` from ``config`` (a ``cls``, a dict of its fields, e.g. JSON env kwargs, or None: the defaults)
        with the keyword ``options`` (fields by name) on top. An unknown name is a TypeError naming it."""
        if config is not None and not isinstance(config, (cls, dict)):
            raise TypeError(f"config must be a {cls.__name__}, a dict of its fields or None, got {config!r}")
        known = [f.name for f in fields(cls)]
        unknown = [k for k in (*(config if isinstance(config, dict) else ()), *options) if k not in known]
        if unknown:
            raise TypeError(f"unknown {cls.__name__} option(s) {', '.join(map(repr, unknown))} (the options: "
                            f"{', '.join(known)})")
        if isinstance(config, cls):
            return replace(config, **options) if options else config
        return cls(**{**(config or {}), **options})


class MagBotTask:
    """Mixin of a :class:`~magwarp.envs.base.MagwarpVecEnv` MagBot task with ``success_reward``,
    ``per_step_penalty``, ``collision_penalty``, ``layout``, ``mover`` and ``backend``."""

    #: the ``info`` flags that fail an episode (the reward is then ``collision_penalty``)
    FAILURE_KEYS: tuple[str, ...] = ("mover_collision", "wall_collision", "limit_violation")

    def _failed(self, info: dict[str, Any] | None, shape, device=None) -> torch.Tensor:
        out = torch.zeros(shape, dtype=torch.bool, device=device or self.device)
        for key in self.FAILURE_KEYS:
            if info is not None and key in info:
                out = out | torch.as_tensor(info[key], device=out.device).bool().reshape(shape)
        return out

    def _reward(self, reached: torch.Tensor, failed: torch.Tensor) -> torch.Tensor:
        reward = torch.where(reached, self.success_reward, self.per_step_penalty)
        return torch.where(failed, torch.full_like(reward, self.collision_penalty), reward).float()

    def _step_result(self, obs, reward: torch.Tensor, terminated: torch.Tensor, info: dict[str, Any]):
        """``(reward, terminated, truncated, info)`` of a step: truncated after ``max_episode_steps``; the target
        clip flag of the target action modes (``"pose"``, ``"gripper"``); the benchmark metrics when attached."""
        if self.action_mode != "mover":
            info["target_clipped"] = self.target_clipped.clone()
        truncated = self.num_steps >= self.max_episode_steps
        if self.benchmark_metrics is not None:
            info["metrics"] = self.benchmark_metrics.on_step(obs, info, terminated, truncated)
        return reward, terminated, truncated, info

    @property
    def num_cycles(self) -> int:
        """Control cycles of 1 ms per env step (the backend's)."""
        return self.backend.control.num_cycles

    def render_state(self) -> dict[str, torch.Tensor]:
        """What the 3D renderer reads: the movers' collision flags ``[W, M]`` of the last step."""
        return {"flags": self.checks.flags_t[:, None].expand(-1, self.num_movers)}

    def goal_ghosts(self, world: int) -> list[tuple]:
        """The goal of ``world`` as translucent boxes for the 3D view: ``(pos, yaw, half sizes, rgba, "box")``
        (default: none)."""
        return []

    def _render_3d(self):
        """The worlds :meth:`set_render_worlds` chose, in 3D (:mod:`magwarp.render.mujoco3d`)."""
        from magwarp.render.mujoco3d import render_worlds

        return render_worlds(self, getattr(self, "_render_worlds", None) or min(self.num_envs, 16))

    def _top_down(self, object_shapes):
        """The top-down renderer of the worlds :meth:`set_render_worlds` chose (built once, then reused)."""
        if getattr(self, "_renderer", None) is None:
            from magwarp.render import TopDownRenderer

            worlds = getattr(self, "_render_worlds", None) or min(self.num_envs, 16)
            count = worlds if np.ndim(worlds) == 0 else len(worlds)
            self._renderer = TopDownRenderer(self.layout, self.mover, worlds=worlds,
                                             px_per_tile=96 if count == 1 else 48 if count <= 4 else 32,
                                             object_shapes=object_shapes, device=self.backend.device)
        return self._renderer
