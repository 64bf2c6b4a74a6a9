"""Benchmark metrics of the MagBot pick-and-place tasks (``PlatformPickPlace-v0``, ``GripperPickPlace-v0``).

Per finished episode (torch, once per env step, no sync), as the paper's pushing table counts them: episodes,
successes (the episode's products all placed, or the object released at its goal), the time to success of the
successful ones, collisions (wall or mover) and limit violations (the mechanism's range) of the failed ones.
The platform adds the products placed and dropped per episode and the placement rate (products per minute of
simulated time); the gripper adds the objects pushed off the tiles and the final distance of the object to its
goal.
"""

from __future__ import annotations

import torch

from magwarp.metrics._common import Tracker, group_sum

__all__ = ["GripperPickPlaceMetrics", "PlatformPickPlaceMetrics"]


class _EpisodeMetrics(Tracker):
    """Shared accumulators: episodes, successes, time to success, collisions, limit violations, elapsed time."""

    _COMMON = (
        ("success_rate", "Success Rate (%)", "episodes"),
        ("time_to_success_s", "Time to Success (s)", "successes"),
        ("collisions", "Collisions", "episodes"),
        ("limit_violations", "Limit Violations", "episodes"),
    )

    def __init__(self, env, extra_int: tuple[str, ...] = (), extra_float: tuple[str, ...] = ()):
        super().__init__(env, env.backend.device)
        W, dev = env.num_envs, self.torch_device
        for name in ("episodes", "successes", "limits", "collisions", *extra_int):
            self.state.add_torch(name, (W,), torch.int32, dev)
        for name in ("time_to_success_sum", "elapsed_s", *extra_float):
            self.state.add_torch(name, (W,), torch.float64, dev)
        self._step_s = env.backend.control.num_cycles * env.backend.dt
        env.benchmark_metrics = self

    def _count(self, info, terminated, truncated) -> tuple[torch.Tensor, torch.Tensor]:
        t = self.t
        active = t["active"].bool()
        done = (terminated | truncated) & active
        success = info["is_success"] & done
        t["episodes"] += done
        t["successes"] += success
        t["limits"] += info["limit_violation"] & done
        t["collisions"] += (info["wall_collision"] | info["mover_collision"]) & done
        t["elapsed_s"] += torch.where(active, self._step_s, 0.0)
        steps = self.env.num_steps.to(torch.float64)
        t["time_to_success_sum"] += torch.where(success, steps * self._step_s, torch.zeros_like(steps))
        return done, active

    def _summary(self, G: int) -> dict[str, torch.Tensor]:
        t = self.t
        episodes, successes = group_sum(t["episodes"], G), group_sum(t["successes"], G)
        return {
            "episodes": episodes,
            "successes": successes,
            "success_rate": 100.0 * successes / episodes,
            "time_to_success_s": group_sum(t["time_to_success_sum"], G) / successes,
            "collisions": group_sum(t["collisions"], G) / episodes,
            "limit_violations": group_sum(t["limits"], G) / episodes,
        }


class PlatformPickPlaceMetrics(_EpisodeMetrics):
    """Step-level accumulators for a :class:`~magwarp.envs.platform_pick_place.PlatformPickPlaceEnv`."""

    ROWS = _EpisodeMetrics._COMMON + (
        ("products_placed", "Products Placed (per episode)", "episodes"),
        ("products_dropped", "Products Dropped (per episode)", "episodes"),
        ("placement_rate", "Placement Rate (products/min)", "episodes"),
    )

    def __init__(self, env):
        super().__init__(env, extra_int=("placed", "dropped"))

    def on_step(self, obs, info, terminated: torch.Tensor, truncated: torch.Tensor) -> dict[str, torch.Tensor]:
        t = self.t
        _, active = self._count(info, terminated, truncated)
        t["placed"] += info["placed"] & active
        t["dropped"] += info["dropped"] & active
        return {"episodes": t["episodes"].clone(), "successes": t["successes"].clone()}

    def summary(self, num_groups: int = 1) -> dict[str, torch.Tensor]:
        """Per group of consecutive worlds: ``[G]`` float64 tensors, still on the device."""
        t, G = self.t, num_groups
        out = self._summary(G)
        placed = group_sum(t["placed"], G)
        out.update({"products_placed": placed / out["episodes"],
                    "products_dropped": group_sum(t["dropped"], G) / out["episodes"],
                    "placement_rate": 60.0 * placed / group_sum(t["elapsed_s"], G)})
        return out


class GripperPickPlaceMetrics(_EpisodeMetrics):
    """Step-level accumulators for a :class:`~magwarp.envs.gripper_pick_place.GripperPickPlaceEnv`."""

    ROWS = _EpisodeMetrics._COMMON + (
        ("objects_lost", "Objects Lost", "episodes"),
        ("final_position_error_mm", "Final Position Error (mm)", "episodes"),
    )

    def __init__(self, env):
        super().__init__(env, extra_int=("lost",), extra_float=("position_error_sum",))

    def on_step(self, obs, info, terminated: torch.Tensor, truncated: torch.Tensor) -> dict[str, torch.Tensor]:
        t = self.t
        done, _ = self._count(info, terminated, truncated)
        t["lost"] += info["object_lost"] & done
        zero = torch.zeros((), dtype=torch.float64, device=done.device)
        t["position_error_sum"] += torch.where(done, info["position_error"].to(torch.float64), zero)
        return {"episodes": t["episodes"].clone(), "successes": t["successes"].clone()}

    def summary(self, num_groups: int = 1) -> dict[str, torch.Tensor]:
        """Per group of consecutive worlds: ``[G]`` float64 tensors, still on the device."""
        t, G = self.t, num_groups
        out = self._summary(G)
        out.update({"objects_lost": group_sum(t["lost"], G) / out["episodes"],
                    "final_position_error_mm": 1e3 * group_sum(t["position_error_sum"], G) / out["episodes"]})
        return out
