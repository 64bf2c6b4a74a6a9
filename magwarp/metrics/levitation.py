"""Benchmark metrics of low-level levitation control (:class:`~magwarp.envs.levitation.LevitationEnv`).

Per finished episode (torch, once per env step, no sync): episodes, successes (not failed and within the env's
``success_tol`` at the episode's end), failures, the tracking error (the position error averaged over the episode's
steps), the final position and rotation errors, and the copper energy the episode spent (J: the coils' loss, sum of
R i^2, over its steps). The energy per success is the point-to-point move's metric: energy per move at the arrival
accuracy ``success_tol``.
"""

from __future__ import annotations

import torch

from magwarp.metrics._common import Tracker, group_sum

__all__ = ["LevitationMetrics"]


class LevitationMetrics(Tracker):
    """Step-level accumulators for a :class:`LevitationEnv`."""

    ROWS = (
        ("success_rate", "Success Rate (%)", "episodes"),
        ("failure_rate", "Failures (%)", "episodes"),
        ("tracking_error_mm", "Tracking Error (mm, mean over steps)", "episodes"),
        ("final_position_error_mm", "Final Position Error (mm)", "episodes"),
        ("final_rotation_error_mrad", "Final Rotation Error (mrad)", "episodes"),
        ("episode_energy_j", "Copper Energy (J per episode)", "episodes"),
        ("success_energy_j", "Copper Energy (J per success)", "successes"),
        ("mean_copper_loss_w", "Copper Loss (W, mean)", "episodes"),
    )

    def __init__(self, env):
        super().__init__(env, env.sim.device)
        W, dev = env.num_envs, self.torch_device
        s = self.state
        for name in ("episodes", "successes", "failures", "ep_steps", "steps"):
            s.add_torch(name, (W,), torch.int32, dev)
        for name in ("ep_error", "ep_energy", "tracking_sum", "position_sum", "rotation_sum", "energy_sum",
                     "success_energy_sum"):
            s.add_torch(name, (W,), torch.float64, dev)
        self._step_s = env.step_dt
        env.benchmark_metrics = self

    def on_step(self, obs, info, terminated: torch.Tensor, truncated: torch.Tensor) -> dict[str, torch.Tensor]:
        t = self.t
        active = t["active"].bool()
        done = (terminated | truncated) & active
        success = info["is_success"] & done
        zero = torch.zeros((), dtype=torch.float64, device=done.device)
        t["ep_steps"] += active
        t["steps"] += active
        t["ep_error"] += torch.where(active, info["pos_error"].to(torch.float64), zero)
        t["ep_energy"] += torch.where(active, info["copper_loss"].to(torch.float64) * self._step_s, zero)
        t["episodes"] += done
        t["successes"] += success
        t["failures"] += info["failed"] & done
        t["tracking_sum"] += torch.where(done, t["ep_error"] / t["ep_steps"].clamp_min(1), zero)
        t["position_sum"] += torch.where(done, info["pos_error"].to(torch.float64), zero)
        t["rotation_sum"] += torch.where(done, info["rot_error"].to(torch.float64), zero)
        t["energy_sum"] += torch.where(done, t["ep_energy"], zero)
        t["success_energy_sum"] += torch.where(success, t["ep_energy"], zero)
        for name in ("ep_error", "ep_energy", "ep_steps"):
            t[name].masked_fill_(done, 0)
        return {"episodes": t["episodes"].clone(), "successes": t["successes"].clone()}

    def summary(self, num_groups: int = 1) -> dict[str, torch.Tensor]:
        """Per group of consecutive worlds: ``[G]`` float64 tensors, still on the device."""
        t, G = self.t, num_groups
        episodes = group_sum(t["episodes"], G)
        successes = group_sum(t["successes"], G)
        energy = group_sum(t["energy_sum"], G)
        return {
            "episodes": episodes,
            "successes": successes,
            "success_rate": 100.0 * successes / episodes,
            "failure_rate": 100.0 * group_sum(t["failures"], G) / episodes,
            "tracking_error_mm": 1e3 * group_sum(t["tracking_sum"], G) / episodes,
            "final_position_error_mm": 1e3 * group_sum(t["position_sum"], G) / episodes,
            "final_rotation_error_mrad": 1e3 * group_sum(t["rotation_sum"], G) / episodes,
            "episode_energy_j": energy / episodes,
            "success_energy_j": group_sum(t["success_energy_sum"], G) / successes,
            "mean_copper_loss_w": energy / (group_sum(t["steps"], G) * self._step_s),
        }
