"""The batched, torch-native env base class.

:class:`MagwarpVecEnv` is a :class:`gymnasium.vector.VectorEnv` whose observations, rewards, flags and actions are
torch tensors on the simulator's device, shaped ``[num_envs, ...]``. A task implements five small hooks:

* ``_reset_envs(mask)`` — new episodes for the envs where ``mask`` is true (start poses, goals, counters);
* ``_apply_action(action)`` — write the validated ``[num_envs, *single_action_space.shape]`` action and simulate;
* ``_get_obs()`` — the observation (a dict of tensors for goal-conditioned tasks);
* ``_evaluate(obs)`` — ``reward, terminated, truncated, info`` for the step just simulated;
* ``_end_step(obs, info)`` — bookkeeping after evaluation (e.g. resampling reached goals).

Autoreset happens inside :meth:`step` in the *same step* (``metadata["autoreset_mode"]``): for envs that finished,
the returned observation is the first one of the next episode, and the last observation of the finished episode is
kept in ``info["final_obs"]`` (valid where ``info["_final_obs"]`` is true; the final ``info`` values are the ones
returned). Nothing in a step synchronises with the host except the optional input check (``check_inputs``).

NaN guard (on by default, no host sync): a world whose state turns non-finite is terminated (so autoreset replaces
it) with reward 0, and flagged in ``info["nonfinite"]`` (``[num_envs]`` bool: the world) and
``info["nonfinite_step"]`` (the env step, counted from construction, at which it was found; -1 elsewhere). With
``nan_dump="PATH"`` the env also checks on the host after every step (one sync per step, for debugging) and writes
the flagged worlds' state and action to ``PATH`` (``.npz``, :meth:`dump_state`) before they are reset, with a warning.
"""

from __future__ import annotations

import os
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from magwarp._checks import as_count, as_seed

__all__ = ["MagwarpVecEnv"]

Obs = dict[str, torch.Tensor] | torch.Tensor


def _where(mask: torch.Tensor, new: Obs, old: Obs) -> Obs:
    """Per env: ``new`` where ``mask`` (``[num_envs]``) is true, else ``old`` (tensors or dicts of tensors)."""
    if isinstance(new, dict):
        return {k: _where(mask, v, old[k]) for k, v in new.items()}
    return torch.where(mask.view(-1, *([1] * (new.dim() - 1))), new, old)


class MagwarpVecEnv(VectorEnv):
    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": ["rgb_array"], "render_fps": 25}

    def __init__(self, num_envs: int, device: torch.device, *, seed: int | None = None, render_mode: str | None = None,
                 autoreset: bool = True, check_inputs: bool = True, nan_dump: str | None = None):
        num_envs = as_count(num_envs, "num_envs")
        seed = None if seed is None else as_seed(seed)
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}")
        self.num_envs = int(num_envs)
        self.device = torch.device(device)
        self.render_mode = render_mode
        self.autoreset = autoreset
        self.check_inputs = check_inputs
        self._generator = torch.Generator(device=self.device)
        self._generator.manual_seed(0 if seed is None else int(seed))
        self._all = torch.ones(self.num_envs, dtype=torch.bool, device=self.device)
        if nan_dump is not None and not isinstance(nan_dump, (str, os.PathLike)):
            raise TypeError(f"nan_dump must be None or a file path, got {nan_dump!r}")
        self.nan_dump = None if nan_dump is None else os.fspath(nan_dump)
        self._step_count = 0  # env steps since construction (host count: no sync)

    def _set_spaces(self, single_observation_space: gym.Space, single_action_space: gym.Space) -> None:
        self.single_observation_space = single_observation_space
        self.single_action_space = single_action_space
        self.observation_space = batch_space(single_observation_space, self.num_envs)
        self.action_space = batch_space(single_action_space, self.num_envs)

    # ------------------------------------------------------------------ hooks for tasks
    def _reset_envs(self, mask: torch.Tensor) -> None:
        raise NotImplementedError

    def _apply_action(self, action: torch.Tensor) -> None:
        raise NotImplementedError

    def _get_obs(self) -> Obs:
        raise NotImplementedError

    def _evaluate(self, obs: Obs) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, dict[str, Any]]:
        raise NotImplementedError

    def _end_step(self, obs: Obs, info: dict[str, Any]) -> None:
        """Bookkeeping after the step's reward is computed (default: nothing)."""

    # ------------------------------------------------------------------ gymnasium API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Obs, dict[str, Any]]:
        """Reset all envs, or those in ``options["reset_mask"]`` (a ``[num_envs]`` bool tensor)."""
        if seed is not None:
            self._reseed(as_seed(seed))
        mask = self._all
        if options and options.get("reset_mask") is not None:
            mask = self._check_mask(options["reset_mask"])
        self._reset_envs(mask)
        return self._get_obs(), {}

    def _reseed(self, seed: int) -> None:
        """``reset(seed=...)``: everything random from here on follows ``seed`` (tasks with more generators extend
        it)."""
        self._generator.manual_seed(seed)

    def step(self, action) -> tuple[Obs, torch.Tensor, torch.Tensor, torch.Tensor, dict[str, Any]]:
        action = self._check_action(action)
        self._apply_action(action)
        self._step_count += 1
        obs = self._get_obs()
        reward, terminated, truncated, info = self._evaluate(obs)
        self._end_step(obs, info)
        reward, terminated = self._guard_nonfinite(obs, reward, terminated, info, action)
        return self._autoreset(obs, reward, terminated, truncated, info)

    def _autoreset(self, obs, reward, terminated, truncated, info):
        """The end of :meth:`step`: with ``autoreset``, finished envs start their next episode and show its first
        observation (the last one goes to ``info["final_obs"]``); returns the step's 5-tuple."""
        if self.autoreset:
            done = terminated | truncated
            info["final_obs"] = obs
            info["_final_obs"] = done
            self._reset_envs(done)
            # Only finished envs show their new episode; the others keep the observation the reward was computed for.
            obs = _where(done, self._get_obs(), obs)
        return obs, reward, terminated, truncated, info

    def render(self):
        """``None`` without a render mode; with ``"rgb_array"``, a top-down ``uint8 [H, W, 3]`` numpy image of the
        worlds chosen by :meth:`set_render_worlds` (default: up to 16 worlds as a mosaic); the levitation envs, which
        have no mover-level view, show their coil currents (:meth:`render_coils`)."""
        if self.render_mode is None:
            return None
        from magwarp.render import to_numpy_image

        return to_numpy_image(self._render_frame())

    def set_render_worlds(self, worlds) -> None:
        """Choose the worlds ``render()`` draws: a count (worlds ``0..n-1``) or a list of indices."""
        self._render_worlds = worlds
        self._renderer = None
        self._coil_renderer = None

    def _render_frame(self) -> torch.Tensor:
        # envs without a top-down view of their own (the levitation envs) show their coil currents when they have them
        if self.coil_source() is not None:
            return self.render_coils()
        raise NotImplementedError(f"{type(self).__name__} does not implement rendering")

    # ------------------------------------------------------------------ coil currents (magnetic model)
    def coil_source(self):
        """The magnetic model that drives the movers: the env's coil actuator (levitation envs) or its simulator's
        magnetic drive (``force_model="magnetic"``); None with the ideal model."""
        actuator = getattr(self, "actuator", None)
        if actuator is not None and hasattr(actuator, "coil_ids"):
            return actuator
        return getattr(getattr(self, "sim", None), "magnetic_drive", None)

    def render_coils(self) -> np.ndarray:
        """The coil currents of the last control cycle seen from above (:mod:`magwarp.render.coils`: one row of
        coil-layer panels per world of :meth:`set_render_worlds`, default up to 4; the movers' outlines on top; the
        colour bar below), as a numpy ``uint8 [H, W, 3]`` image. Needs a magnetic model: a ValueError otherwise
        (the ideal model has no coils)."""
        source = self.coil_source()
        if source is None:
            raise ValueError(f"{type(self).__name__} has no magnetic model, so no coil currents to draw: build it "
                             f"with force_model='magnetic' (or use a magwarp/Levitation-v0 env)")
        from magwarp.render.coils import CoilCurrentRenderer, drive_currents
        from magwarp.render.legend import with_legend

        if getattr(self, "_coil_renderer", None) is None or self._coil_renderer[0] is not source:
            worlds = getattr(self, "_render_worlds", None) or min(self.num_envs, 4)
            r = CoilCurrentRenderer(source.model.coilset, self.sim.mover, worlds=worlds, device=self.sim.device)
            self._coil_renderer = (source, r, r.colorbar())
        _, r, strip = self._coil_renderer
        currents, _ = drive_currents(source)
        return with_legend(r.draw(currents, self.sim.pos, self.sim.quat), strip)

    def compute_reward(self, achieved_goal, desired_goal, info) -> torch.Tensor:
        """Batched reward for hindsight relabelling; tasks with goals override it."""
        raise NotImplementedError(f"{type(self).__name__} has no goal-conditioned reward")

    # ------------------------------------------------------------------ NaN guard
    def _nonfinite_worlds(self, obs: Obs) -> torch.Tensor:
        """``[num_envs]`` bool: worlds whose state is not finite (default: any non-finite observation entry)."""
        parts = obs.values() if isinstance(obs, dict) else (obs,)
        bad = torch.zeros(self.num_envs, dtype=torch.bool, device=self.device)
        for x in parts:
            bad = bad | ~torch.isfinite(x.reshape(self.num_envs, -1)).all(dim=1)
        return bad

    def _guard_nonfinite(self, obs, reward, terminated, info, action):
        bad = self._nonfinite_worlds(obs)
        info["nonfinite"] = bad
        info["nonfinite_step"] = torch.where(bad, self._step_count, -1)
        if self.nan_dump is not None and bool(bad.any()):  # debugging mode: one sync per step
            import warnings

            path = self.dump_state(self.nan_dump, torch.nonzero(bad).flatten().tolist(), action=action)
            warnings.warn(f"{type(self).__name__}: world(s) {torch.nonzero(bad).flatten().tolist()} turned non-finite "
                          f"at step {self._step_count}; their state is in {path}", RuntimeWarning, stacklevel=3)
        reward = torch.where(bad, torch.zeros_like(reward), reward)
        return reward, terminated | bad

    def state_arrays(self, worlds) -> dict[str, Any]:
        """Host copies of the worlds' state for a bug report (tasks add their simulator's arrays)."""
        from magwarp.envs.single import to_numpy

        obs = to_numpy(self._get_obs())
        obs = obs if isinstance(obs, dict) else {"observation": obs}
        return {f"obs_{k}": v[worlds] for k, v in obs.items()}

    def dump_state(self, path: str, worlds=None, action=None) -> str:
        """Write ``worlds``' state (default: all) and, if given, the action to ``path`` (``.npz``); returns the path."""
        idx = list(range(self.num_envs)) if worlds is None else [int(w) for w in worlds]
        arrays = self.state_arrays(idx)
        if action is not None:
            arrays["action"] = action.detach().cpu().numpy()[idx]
        np.savez(path, env=np.array(type(self).__name__), step=np.array(self._step_count), world=np.array(idx),
                 **arrays)
        return path if str(path).endswith(".npz") else f"{path}.npz"

    # ------------------------------------------------------------------ input checks
    def _check_action(self, action) -> torch.Tensor:
        if isinstance(action, np.ndarray):
            action = torch.from_numpy(action).to(self.device)
        if not isinstance(action, torch.Tensor):
            raise TypeError(f"action must be a torch tensor or numpy array, got {type(action).__name__}")
        expected = (self.num_envs, *self.single_action_space.shape)
        if tuple(action.shape) != expected:
            raise ValueError(f"action must have shape {expected}, got {tuple(action.shape)}")
        if not action.is_floating_point():
            raise TypeError(f"action must be a floating point tensor, got dtype {action.dtype}")
        if action.device != self.device:
            raise ValueError(f"action is on device {action.device}, but the env runs on {self.device}")
        # Check what the simulation will see: a finite float64 such as 1e40 overflows to inf in float32.
        stored = action.to(torch.float32)
        if self.check_inputs and not bool(torch.isfinite(stored).all()):
            bad = torch.nonzero(~torch.isfinite(stored))[0].tolist()
            raise ValueError(f"action contains a non-finite value (in float32, what the simulation runs in) at index "
                             f"{bad}: {action[tuple(bad)].item()!r}")
        return stored

    def _check_mask(self, mask) -> torch.Tensor:
        mask = torch.as_tensor(mask, device=self.device)
        if mask.shape != (self.num_envs,) or mask.dtype != torch.bool:
            raise ValueError(f"reset_mask must be a bool tensor of shape ({self.num_envs},), got {mask.dtype} {tuple(mask.shape)}")
        return mask

    # ------------------------------------------------------------------ helpers for tasks
    def _rand(self, *shape: int) -> torch.Tensor:
        return torch.rand(shape, generator=self._generator, device=self.device)

    def _randint(self, high: int, *shape: int) -> torch.Tensor:
        return torch.randint(high, shape, generator=self._generator, device=self.device)

    def _noisy(self, x: torch.Tensor, std: float) -> torch.Tensor:
        """``x`` plus zero-mean Gaussian noise of standard deviation ``std`` (``x`` itself when ``std`` is 0)."""
        if std == 0.0:
            return x
        return x + std * torch.randn(x.shape, generator=self._generator, device=x.device, dtype=x.dtype)
