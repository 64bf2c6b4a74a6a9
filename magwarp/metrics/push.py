"""Benchmark metrics of object pushing (the paper's Table 1), for :class:`~magwarp.envs.PushEnv` and its variants.

Per cycle (kernel, a cycle hook of the mujoco-warp backend): mover-mover, mover-wall, mover-obstacle and
object-obstacle collision events, smoothness, simulated time. Corrective movements and the time to success come
from the env's own per-cycle :class:`~magwarp.physics.push_metrics.PushMetrics` (real cycle time); they are
recorded per finished episode here (torch, no sync): episodes, successes, and the corrections and time to success
of the successful ones.
"""

from __future__ import annotations

import torch
import warp as wp

from magwarp.kernels import metrics as km
from magwarp.metrics._common import Tracker, group_sum
from magwarp.physics import ContactFlags
from magwarp.physics.backend import CONTROL_CYCLE_S

__all__ = ["PushTaskMetrics"]


class PushTaskMetrics(Tracker):
    """Device-side accumulators for a :class:`PushEnv` (one more cycle hook on its backend)."""

    ROWS = (
        ("success_rate", "Success Rate (%)", "episodes"),
        ("throughput", "Throughput (goals/s)", "successes"),
        ("overshoot_corrections", "Overshoot Corrections", "successes"),
        ("distance_corrections", "Distance Corrections", "successes"),
        ("collisions", "Collisions", "episodes"),
        ("mover_mover", "Mover-Mover Collisions", "episodes"),
        ("mover_obstacle", "Mover-Obstacle Collisions", "episodes"),
    )

    def __init__(self, env):
        b = env.backend
        super().__init__(env, b.device)
        self.backend = b
        W, M = env.num_envs, env.num_movers
        s = self.state
        s.add("prev_acc", (W, M), wp.vec2, episode=True)
        s.add("prev", (W, km.NUM_EVENTS), int, episode=True)
        s.add("elapsed", (W,), int)
        s.add("smooth", (W,), wp.float64)
        s.add("events", (W, km.NUM_EVENTS), int)
        dev = self.torch_device
        for name in ("episodes", "successes"):
            s.add_torch(name, (W,), torch.int32, dev)
        for name in ("overshoot_sum", "correction_sum", "time_to_success_sum"):
            s.add_torch(name, (W,), torch.float64, dev)
        # This cycle's obstacle contacts: a second ContactFlags whose flags the metric kernel clears once read (the
        # env's own flags are OR-ed over the step).
        self.num_pairs = 0
        self._contacts = wp.zeros((W, 1), dtype=int, device=b.device)
        if env.obstacles:
            flags = ContactFlags(b, {"mover": ["mover_geom_"], "object": ["object_0_geom_"], "obstacle": ["obstacle_geom_"]},
                                 [("mover", "obstacle"), ("object", "obstacle")])
            self._contacts, self.num_pairs = flags.flags, 2
        self._checks = env.checks  # the env's collision geometry (shape, margins, tiles)
        b.add_cycle_hook(self._launch)
        env.benchmark_metrics = self

    @property
    def _geometry(self) -> list:
        """The env's collision geometry, read at every launch (randomisation may give each world its own sizes)."""
        c, b = self._checks, self.backend
        return [c._tiles, c._col, b._qadr, b._dadr, c._radius, c._half, c._margins]

    def _launch(self) -> None:
        a, b = self.state.arrays, self.backend
        wp.launch(km.push_world_kernel, dim=self.num_worlds, device=b.device,
                  inputs=[*self._geometry, float(b.dt), self.num_pairs, a["active"], b.data.qpos, b.data.qvel, b.acc,
                          self._contacts, a["prev_acc"], a["prev"], a["elapsed"], a["smooth"], a["events"]])

    def on_step(self, obs, info, terminated: torch.Tensor, truncated: torch.Tensor) -> dict[str, torch.Tensor]:
        """Per env step: record the episodes that just ended (torch, no sync)."""
        t = self.t
        done = (terminated | truncated) & t["active"].bool()
        success = info["is_success"] & done
        t["episodes"] += done
        t["successes"] += success
        zero = torch.zeros((), dtype=torch.float64, device=done.device)
        for key, name in (("num_overshoot_corrections", "overshoot_sum"), ("num_distance_corrections", "correction_sum"),
                          ("time_to_success_s", "time_to_success_sum")):
            t[name] += torch.where(success, info[key].to(torch.float64), zero)
        return {
            "episodes": t["episodes"].clone(),
            "successes": t["successes"].clone(),
            "collisions": t["events"].clone(),
            "smoothness": t["smooth"].clone(),
            "cycles": t["elapsed"].clone(),
        }

    def summary(self, num_groups: int = 1) -> dict[str, torch.Tensor]:
        """Per group of consecutive worlds (e.g. one repeat each): ``[G]`` float64 tensors, still on the device."""
        t, G = self.t, num_groups
        episodes = group_sum(t["episodes"], G)
        successes = group_sum(t["successes"], G)
        ev = t["events"]
        time_s = group_sum(t["elapsed"], G) * float(self.backend.dt)
        return {
            "episodes": episodes,
            "successes": successes,
            "time_s": time_s,
            "success_rate": 100.0 * successes / episodes,
            "throughput": successes / group_sum(t["time_to_success_sum"], G),
            "overshoot_corrections": group_sum(t["overshoot_sum"], G) / successes,
            "distance_corrections": group_sum(t["correction_sum"], G) / successes,
            "collisions": group_sum(ev, G) / episodes,
            "mover_mover": group_sum(ev[:, km.EV_MOVER_MOVER], G) / episodes,
            "mover_obstacle": group_sum(ev[:, km.EV_MOVER_WALL:km.EV_OBJECT_OBSTACLE], G) / episodes,
            "object_obstacle": group_sum(ev[:, km.EV_OBJECT_OBSTACLE], G) / episodes,
            # summed per physics step: scaled to 1 ms cycles (MagBotSim's), so a longer physics_dt reads the same
            "smoothness": group_sum(t["smooth"], G) * (float(self.backend.dt) / CONTROL_CYCLE_S) / time_s,
            "time_to_success_s": group_sum(t["time_to_success_sum"], G) / successes,
        }
