"""Benchmark metrics of trajectory planning (the paper's Table 2), for :class:`~magwarp.envs.TrajectoryPlanningEnv`.

Per cycle (kernel, inside the step graph): smoothness, goal-region entry time, corrective movements per mover,
mover-mover and mover-wall collision events, simulated time. Per env step (torch, no sync): goals reached (the
env's rule: within ``threshold_pos`` at the end of the step), the time of each mover's ``makespan_goals``-th goal,
and goals lost when an episode ends (collision or timeout: every mover's pending goal fails).
"""

from __future__ import annotations

import torch
import warp as wp

from magwarp.kernels import metrics as km
from magwarp.metrics._common import Tracker, group_sum

__all__ = ["TrajectoryMetrics"]


class TrajectoryMetrics(Tracker):
    """Device-side accumulators for a :class:`TrajectoryPlanningEnv` (switches its simulator to per-cycle launches).

    ``makespan_goals``: the makespan is the time (ms) at which the slowest mover of a world reached this many goals.
    """

    ROWS = (
        ("success_rate", "Success Rate (%)", "goals"),
        ("makespan_ms", "Makespan (ms)", "makespan_worlds"),
        ("throughput", "Throughput (goals/s)", "goals_reached"),
        ("collisions_per_1k", "Collisions (per 1000 goals)", "goals"),
        ("mover_mover_per_1k", "Mover-Mover Collisions (per 1000 goals)", "goals"),
        ("mover_obstacle_per_1k", "Mover-Obstacle Collisions (per 1000 goals)", "goals"),
        ("smoothness", "Smoothness (per 1000 ms)", "time_s"),
    )

    def __init__(self, env, makespan_goals: int = 1):
        sim = env.sim
        super().__init__(env, sim.device)
        if int(makespan_goals) < 1:
            raise ValueError(f"makespan_goals must be >= 1, got {makespan_goals!r}")
        self.makespan_goals = int(makespan_goals)
        self.sim = sim
        self.dt = float(sim.model.limits.dt)
        W, M = env.num_envs, env.num_movers
        s = self.state
        for name, dtype, fill in (("prev_acc", wp.vec2, 0), ("in_since", int, -1), ("success_last", int, 0),
                                  ("last_dist", float, float("inf")), ("increased", int, 0)):
            s.add(name, (W, M), dtype, fill=fill, episode=True)
        s.add("prev", (W, km.NUM_EVENTS), int, episode=True)
        s.add("elapsed", (W,), int)
        s.add("smooth", (W, M), wp.float64)
        s.add("overshoots", (W, M), int)
        s.add("corrections", (W, M), int)
        s.add("events", (W, km.NUM_EVENTS), int)
        dev = self.torch_device
        s.add_torch("goals_reached", (W, M), torch.int32, dev)
        s.add_torch("goals_failed", (W,), torch.int32, dev)
        s.add_torch("episodes", (W,), torch.int32, dev)
        s.add_torch("nth_goal_cycle", (W, M), torch.int32, dev, fill=-1)
        self._goals = wp.from_torch(env.goals, dtype=wp.vec2)  # the env resamples goals in place
        sim.add_cycle_hook(self._launch)
        env.benchmark_metrics = self

    def _launch(self, sim) -> None:
        a, st = self.state.arrays, sim.state
        W, M = self.num_worlds, self.env.num_movers
        wp.launch(km.trajectory_movers_kernel, dim=(W, M), device=sim.device,
                  inputs=[self.dt, self.env.threshold_pos, a["active"], st.halted, a["elapsed"], st.pos, st.vel,
                          st.acc, self._goals, a["prev_acc"], a["in_since"], a["success_last"], a["last_dist"],
                          a["increased"], a["smooth"], a["overshoots"], a["corrections"]])
        wp.launch(km.trajectory_world_kernel, dim=W, device=sim.device,
                  inputs=[a["active"], st.world_pairs, st.world_walls, a["prev"], a["elapsed"], a["events"]])

    def on_step(self, obs, info, terminated: torch.Tensor, truncated: torch.Tensor) -> dict[str, torch.Tensor]:
        """Per env step, before the env resamples reached goals: count goals and failed goals (torch, no sync)."""
        t, env = self.t, self.env
        active = t["active"].bool()
        reached = (env.goal_distance(obs["achieved_goal"], obs["desired_goal"]) <= env.threshold_pos) & active[:, None]
        t["goals_reached"] += reached
        # Reach time: the cycle the mover entered the goal region (the step's end if float rounding disagrees).
        since = torch.where(t["in_since"] > 0, t["in_since"], t["elapsed"][:, None].expand_as(t["in_since"]))
        nth = reached & (t["goals_reached"] == self.makespan_goals)
        t["nth_goal_cycle"].copy_(torch.where(nth, since.to(torch.int32), t["nth_goal_cycle"]))
        # A reached goal is replaced: the per-mover distance history starts again.
        for name in ("in_since", "success_last", "last_dist", "increased"):
            t[name].masked_fill_(reached, self.state._fill[name])
        done = (terminated | truncated) & active
        lost = (env.num_movers - reached.sum(1)).to(torch.int32)
        t["goals_failed"] += torch.where(done, lost, torch.zeros_like(lost))
        t["episodes"] += done
        return {
            "goals_reached": t["goals_reached"].sum(1),
            "goals_failed": t["goals_failed"].clone(),
            "episodes": t["episodes"].clone(),
            "collisions": t["events"].clone(),
            "smoothness": t["smooth"].sum(1),
            "cycles": t["elapsed"].clone(),
        }

    def summary(self, num_groups: int = 1) -> dict[str, torch.Tensor]:
        """Per group of consecutive worlds (e.g. one repeat each): ``[G]`` float64 tensors, still on the device."""
        t, G = self.t, num_groups
        reached = group_sum(t["goals_reached"], G)
        goals = reached + group_sum(t["goals_failed"], G)
        time_s = group_sum(t["elapsed"], G) * self.dt
        ev = t["events"]
        per_1k = 1000.0 / goals
        nth = t["nth_goal_cycle"]
        valid = (nth >= 0).all(1)
        makespan = (nth.amax(1).to(torch.float64) * self.dt * 1000.0) * valid  # ms; worlds without it count 0
        worlds = group_sum(valid, G)
        return {
            "goals": goals,
            "goals_reached": reached,
            "time_s": time_s,
            "success_rate": 100.0 * reached / goals,
            "throughput": reached / time_s,
            "makespan_ms": group_sum(makespan, G) / worlds,
            "makespan_worlds": worlds,
            "collisions_per_1k": group_sum(ev, G) * per_1k,
            "mover_mover_per_1k": group_sum(ev[:, km.EV_MOVER_MOVER], G) * per_1k,
            "mover_obstacle_per_1k": group_sum(ev[:, km.EV_MOVER_WALL:], G) * per_1k,
            "smoothness": group_sum(t["smooth"], G) / time_s,
            "overshoot_corrections": group_sum(t["overshoots"], G) / reached,
            "distance_corrections": group_sum(t["corrections"], G) / reached,
        }
