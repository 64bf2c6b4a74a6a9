"""Shared by the MagBot envs (:mod:`magwarp.envs.platform_pose`, :mod:`magwarp.envs.platform_pick_place`,
:mod:`magwarp.envs.gripper_pick_place`): option checks, failure flags, the sparse reward, the top-down renderer and
what the 3D renderer reads (``render_mode="rgb_array_3d"``)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from magwarp._checks import as_count, as_finite, check_magnitude

__all__ = ["MagBotTask", "check_options", "option_of"]


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
