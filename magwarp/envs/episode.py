"""Chosen episodes: ``env.reset(seed=..., options={...})`` sets the start state of the reset worlds (Gymnasium's way),
e.g. to replay a MagBotSim episode or a real-system log.

A task lists its option keys with the per-env shape of each (:attr:`ChosenEpisodes.EPISODE_OPTIONS`). A value may
be given for one env (that shape, then shared by every reset env) or for all of them (``[num_envs, *shape]``; rows
of envs outside ``options["reset_mask"]`` are ignored). Every value is checked before anything changes: a wrong
shape or a NaN/inf raises a ``ValueError`` naming it (an unknown key is named in a warning), and the task checks the
poses themselves (on the tiles, collision free) in :meth:`ChosenEpisodes._check_episode`. Keys not given are sampled
as usual.
"""

from __future__ import annotations

import warnings
from typing import Any

import torch

from magwarp.collision import CollisionQuery, float32_tensor

__all__ = ["ChosenEpisodes", "fmt_xy"]


def fmt_xy(v: torch.Tensor) -> str:
    """A short text of a small tensor for error messages, e.g. ``(0.12, 0.36)``."""
    vals = v.detach().cpu().reshape(-1).tolist()
    return "(" + ", ".join(f"{x:.4g}" for x in vals) + ")"


class ChosenEpisodes:
    """Mixin for :class:`~magwarp.envs.base.MagwarpVecEnv` tasks (listed first in the bases)."""

    #: option key -> per-env shape (``M`` stands for the number of movers)
    EPISODE_OPTIONS: dict[str, tuple[int | str, ...]] = {}

    _chosen: dict[str, torch.Tensor] = {}

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Reset all envs, or those in ``options["reset_mask"]``; the other keys of ``options`` (see the task's
        docstring) set chosen episodes. Nothing changes when a value is refused."""
        options = dict(options or {})
        known = ("reset_mask", *self.EPISODE_OPTIONS)
        unknown = sorted(set(options) - set(known))
        if unknown:  # a warning, not an error: API checkers (PettingZoo's) pass made-up options and expect a reset
            warnings.warn(f"reset ignores unknown option(s) {unknown}; known: {list(known)}", stacklevel=2)
        mask = self._all if options.get("reset_mask") is None else self._check_mask(options["reset_mask"])
        chosen = {key: self._option_tensor(key, options[key]) for key in self.EPISODE_OPTIONS if key in options}
        if chosen:
            self._check_episode(chosen, mask)
        self._chosen = chosen
        try:
            return super().reset(seed=seed, options={"reset_mask": options.get("reset_mask")})
        finally:
            self._chosen = {}

    def _option_tensor(self, key: str, value) -> torch.Tensor:
        shape = tuple(self.num_movers if s == "M" else s for s in self.EPISODE_OPTIONS[key])
        t = float32_tensor(f"options[{key!r}]", value, self.device, check_finite=False)
        if tuple(t.shape) == shape:
            t = t.expand(self.num_envs, *shape)
        elif tuple(t.shape) != (self.num_envs, *shape):
            raise ValueError(f"options[{key!r}] must have shape {shape} (every reset env) or {(self.num_envs, *shape)} "
                             f"(per env), got {tuple(t.shape)}")
        return float32_tensor(f"options[{key!r}]", t.contiguous(), self.device)

    def _chosen_or(self, key: str, sampled: torch.Tensor) -> torch.Tensor:
        """The chosen value of ``key`` where given, else the sampled one (same shape)."""
        return self._chosen[key] if key in self._chosen else sampled

    # ------------------------------------------------------------------ checks
    def _check_episode(self, chosen: dict[str, torch.Tensor], mask: torch.Tensor) -> None:
        """Task-specific checks of the chosen poses (the reset envs only); raise ``ValueError`` naming the value."""

    @staticmethod
    def _raise_first(bad: torch.Tensor, message) -> None:
        """``bad`` ``[num_envs, ...]`` (already masked): raise ``ValueError(message(index))`` at its first entry."""
        if bool(bad.any()):
            raise ValueError(message(tuple(torch.nonzero(bad)[0].tolist())))

    def _check_movers(self, query: CollisionQuery, key: str, poses: torch.Tensor, pair_size, wall_size,
                      mask: torch.Tensor, pairs: bool = True) -> None:
        """Mover poses ``[num_envs, M, 3]`` (x, y, yaw) on the tiles (``wall_size``: per-mover sizes for the wall
        rule) and, with ``pairs``, not colliding (``pair_size``: sizes for the mover-mover rule)."""
        walls = query(poses, wall_size)
        self._raise_first(~walls.wall_valid & mask[:, None], lambda i: (
            f"options[{key!r}] puts mover {i[1]} of env {i[0]} at {fmt_xy(poses[i[0], i[1], :2])}, off the tiles or "
            "too close to an edge"))
        if pairs and poses.shape[1] > 1:
            hit = query(poses, pair_size).pair_collision & mask[:, None, None]
            self._raise_first(hit, lambda i: (
                f"options[{key!r}] puts movers {i[1]} and {i[2]} of env {i[0]} in collision, at "
                f"{fmt_xy(poses[i[0], i[1], :2])} and {fmt_xy(poses[i[0], i[2], :2])}"))
