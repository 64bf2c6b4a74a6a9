"""Benchmark metrics of large swarms, for :class:`~magwarp.swarm.SwarmEnv` (``magwarp/Swarm-v0`` and its variants).

A swarm world has no episode end by default (goals stream, collided movers respawn): what is evaluated is a
*window* of env steps per world (``magwarp eval --steps``), from a fresh reset. Worlds that do end inside the
window (``on_collision="end"``, ``max_episode_steps``) restart and keep counting. Per env step (torch, no host
sync), per world, over the window:

* ``goals``: goals reached (the env's rule: within ``threshold_pos`` at the end of the step);
  ``throughput``: goals per second of simulated time per world (the whole swarm), and per mover;
* ``jobs`` (material flow, ``stations``): deliveries, per second per world and per mover;
* ``collisions``: collided movers (each mover that collided in a step counts once: a mover-mover collision counts
  both movers), split into mover-mover and mover-wall, per 1000 goals;
* ``deadlocked``: movers stuck at the end of the window: slower than ``stuck_speed`` and away from their goal
  (farther than the goal threshold) for at least ``deadlock_steps`` consecutive steps, not counting movers waiting
  for a respawn (the count restarts with a world's episode);
* ``makespan``: the time (step resolution) at which the slowest mover of a world had reached ``makespan_goals``
  goals (averaged over the worlds where every mover did).
"""

from __future__ import annotations

import torch

from magwarp.metrics._common import Tracker, group_sum

__all__ = ["SwarmTaskMetrics"]


class SwarmTaskMetrics(Tracker):
    """Step-level accumulators for a :class:`SwarmEnv`. ``attach=False``: not registered as the env's
    ``benchmark_metrics`` (the caller feeds :meth:`on_step` itself, as :class:`~magwarp.swarm.SwarmMetrics` does)."""

    def __init__(self, env, makespan_goals: int = 1, *, deadlock_steps: int = 25, stuck_speed: float = 0.05,
                 attach: bool = True):
        if attach:
            super().__init__(env, env.sim.device)
        else:  # a private tracker: the env's own slot stays free
            saved, env.benchmark_metrics = env.benchmark_metrics, None
            try:
                super().__init__(env, env.sim.device)
            finally:
                env.benchmark_metrics = saved
        if isinstance(makespan_goals, bool) or int(makespan_goals) != makespan_goals or makespan_goals < 1:
            raise ValueError(f"makespan_goals must be an integer >= 1, got {makespan_goals!r}")
        if isinstance(deadlock_steps, bool) or int(deadlock_steps) != deadlock_steps or deadlock_steps < 1:
            raise ValueError(f"deadlock_steps must be an integer >= 1, got {deadlock_steps!r}")
        if not stuck_speed > 0:
            raise ValueError(f"stuck_speed must be a positive speed (m/s), got {stuck_speed!r}")
        self.makespan_goals, self.deadlock_steps = int(makespan_goals), int(deadlock_steps)
        self.stuck_speed = float(stuck_speed)
        self.step_time = env.num_cycles * float(env.sim.model.limits.dt)
        self.material_flow = env.stations is not None
        W, M, dev = env.num_envs, env.num_movers, self.torch_device
        s = self.state
        for name in ("goals", "jobs", "mover_mover", "mover_wall", "collided"):
            s.add_torch(name, (W, M), torch.int64, dev)
        s.add_torch("steps", (W,), torch.int64, dev)
        s.add_torch("nth_goal_step", (W, M), torch.int64, dev, fill=-1)
        # consecutive stuck steps: restarts with the world's episode
        s.add_torch("stuck", (W, M), torch.int64, dev)
        s.episode.append(s.total.pop(s.total.index("stuck")))
        self.ROWS = self._rows_spec()
        if attach:
            env.benchmark_metrics = self

    def _rows_spec(self) -> tuple[tuple[str, str, str], ...]:
        rows = [("throughput", "Throughput (goals/s per world)", "goals"),
                ("throughput_per_mover", "Throughput per Mover (goals/s)", "goals")]
        if self.material_flow:
            rows += [("jobs_per_s", "Throughput (jobs/s per world)", "jobs"),
                     ("jobs_per_s_per_mover", "Throughput per Mover (jobs/s)", "jobs")]
        rows += [("collisions_per_1k", "Collisions (movers per 1000 goals)", "goals"),
                 ("mover_mover_per_1k", "Mover-Mover Collisions (per 1000 goals)", "goals"),
                 ("mover_wall_per_1k", "Mover-Wall Collisions (per 1000 goals)", "goals"),
                 ("deadlocked", "Deadlocked Movers (per world, at the end)", "worlds"),
                 ("makespan_s", f"Makespan (s, {self.makespan_goals} goal{'s' * (self.makespan_goals > 1)} per mover)",
                  "makespan_worlds")]
        return tuple(rows)

    def on_step(self, obs, info, terminated: torch.Tensor, truncated: torch.Tensor) -> dict[str, torch.Tensor]:
        """After the step's goal streaming and respawns, before any autoreset: count (torch, no sync)."""
        t, env = self.t, self.env
        active = t["active"].bool()
        act = active[:, None]
        t["steps"] += active
        reached = info["goal_reached"] & act
        t["goals"] += reached
        collided = info["collided"] & act
        t["collided"] += collided
        t["mover_mover"] += collided & info["mover_collision"]
        t["mover_wall"] += collided & info["wall_collision"] & ~info["mover_collision"]
        if self.material_flow:
            t["jobs"] += info["job_done"] & act
        nth = reached & (t["goals"] == self.makespan_goals)
        t["nth_goal_step"].copy_(torch.where(nth, t["steps"][:, None], t["nth_goal_step"]))
        sim = env.sim
        speed = sim.vel[..., :2].norm(dim=-1)
        away = (env.goals - sim.pos[..., :2]).norm(dim=-1) > env.config.threshold_pos
        stuck = (speed < self.stuck_speed) & away & ~env.respawn_pending & act
        t["stuck"].copy_(torch.where(stuck, t["stuck"] + 1, torch.where(act, 0, t["stuck"])))
        return {"goals": t["goals"].sum(1), "collided": t["collided"].sum(1), "jobs": t["jobs"].sum(1),
                "steps": t["steps"].clone()}

    def summary(self, num_groups: int = 1) -> dict[str, torch.Tensor]:
        """Per group of consecutive worlds (e.g. one repeat each): ``[G]`` float64 tensors, still on the device."""
        t, G, M = self.t, num_groups, self.env.num_movers
        goals = group_sum(t["goals"], G)
        jobs = group_sum(t["jobs"], G)
        time_s = group_sum(t["steps"], G) * self.step_time  # world-seconds
        per_1k = 1000.0 / goals
        nth = t["nth_goal_step"]
        valid = (nth >= 0).all(1)
        makespan = nth.amax(1).to(torch.float64) * self.step_time * valid  # worlds without it count 0
        worlds = group_sum(torch.ones_like(valid), G)
        makespan_worlds = group_sum(valid, G)
        return {
            "worlds": worlds,
            "goals": goals,
            "goals_reached": goals,
            "jobs": jobs,
            "time_s": time_s,
            "throughput": goals / time_s,
            "throughput_per_mover": goals / time_s / M,
            "jobs_per_s": jobs / time_s,
            "jobs_per_s_per_mover": jobs / time_s / M,
            "collisions": group_sum(t["collided"], G),
            "collisions_per_1k": group_sum(t["collided"], G) * per_1k,
            "mover_mover_per_1k": group_sum(t["mover_mover"], G) * per_1k,
            "mover_wall_per_1k": group_sum(t["mover_wall"], G) * per_1k,
            "deadlocked": group_sum(t["stuck"] >= self.deadlock_steps, G) / worlds,
            "makespan_s": group_sum(makespan, G) / makespan_worlds,
            "makespan_worlds": makespan_worlds,
        }
