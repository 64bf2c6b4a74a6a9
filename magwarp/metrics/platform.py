"""Benchmark metrics of 6D-platform pose tracking (:class:`~magwarp.envs.platform_pose.PlatformPoseEnv`).

Per finished episode (torch, once per env step, no sync): episodes, successes, the time to success of the
successful ones, limit violations (tilt or mover distance beyond the linkage's limits) and wall/mover collisions
of the failed ones, and the final position and angle errors. Episodes are the paper's pushing-table episodes: one
goal each, ending at the goal, on a failure or at the step limit.
"""

from __future__ import annotations

import torch

from magwarp.metrics._common import Tracker, group_sum

__all__ = ["PlatformMetrics"]


class PlatformMetrics(Tracker):
    """Step-level accumulators for a :class:`PlatformPoseEnv`."""

    ROWS = (
        ("success_rate", "Success Rate (%)", "episodes"),
        ("throughput", "Throughput (goals/s)", "successes"),
        ("time_to_success_s", "Time to Success (s)", "successes"),
        ("limit_violations", "Limit Violations", "episodes"),
        ("collisions", "Collisions", "episodes"),
        ("final_position_error_mm", "Final Position Error (mm)", "episodes"),
        ("final_angle_error_deg", "Final Angle Error (deg)", "episodes"),
    )

    def __init__(self, env):
        super().__init__(env, env.backend.device)
        W, dev = env.num_envs, self.torch_device
        s = self.state
        for name in ("episodes", "successes", "limits", "collisions"):
            s.add_torch(name, (W,), torch.int32, dev)
        for name in ("time_to_success_sum", "position_error_sum", "angle_error_sum"):
            s.add_torch(name, (W,), torch.float64, dev)
        self._step_s = env.backend.control.num_cycles * env.backend.dt
        env.benchmark_metrics = self

    def on_step(self, obs, info, terminated: torch.Tensor, truncated: torch.Tensor) -> dict[str, torch.Tensor]:
        t = self.t
        done = (terminated | truncated) & t["active"].bool()
        success = info["is_success"] & done
        t["episodes"] += done
        t["successes"] += success
        t["limits"] += info["limit_violation"] & done
        t["collisions"] += (info["wall_collision"] | info["mover_collision"]) & done
        zero = torch.zeros((), dtype=torch.float64, device=done.device)
        steps = self.env.num_steps.to(torch.float64)
        t["time_to_success_sum"] += torch.where(success, steps * self._step_s, zero)
        t["position_error_sum"] += torch.where(done, info["position_error"].to(torch.float64), zero)
        t["angle_error_sum"] += torch.where(done, info["angle_error"].to(torch.float64), zero)
        return {"episodes": t["episodes"].clone(), "successes": t["successes"].clone()}

    def summary(self, num_groups: int = 1) -> dict[str, torch.Tensor]:
        """Per group of consecutive worlds: ``[G]`` float64 tensors, still on the device."""
        t, G = self.t, num_groups
        episodes = group_sum(t["episodes"], G)
        successes = group_sum(t["successes"], G)
        return {
            "episodes": episodes,
            "successes": successes,
            "success_rate": 100.0 * successes / episodes,
            "throughput": successes / group_sum(t["time_to_success_sum"], G),
            "time_to_success_s": group_sum(t["time_to_success_sum"], G) / successes,
            "limit_violations": group_sum(t["limits"], G) / episodes,
            "collisions": group_sum(t["collisions"], G) / episodes,
            "final_position_error_mm": 1e3 * group_sum(t["position_error_sum"], G) / episodes,
            "final_angle_error_deg": torch.rad2deg(group_sum(t["angle_error_sum"], G) / episodes),
        }
