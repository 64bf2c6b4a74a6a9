"""Swarm metrics, accumulated on the device step by step (no host synchronisation until :meth:`SwarmMetrics.result`).

Per world, over the steps recorded since :meth:`SwarmMetrics.reset`:

* ``goals``: goals reached; ``throughput``: goals per second of simulated time, in total and per mover;
* ``collisions``: movers that collided (each collided mover of a step counts once), and ``collisions_per_1000_goals``;
* ``deadlocked``: movers stuck at the end: slower than ``stuck_speed`` and away from their goal (farther than the
  goal threshold) for at least ``deadlock_steps`` consecutive steps, not counting movers waiting for a respawn;
* ``makespan``: seconds until every mover had reached at least one goal (``nan`` while some never did);
* ``jobs`` / ``jobs_per_s`` (material flow): deliveries, and deliveries per second per world.

Numbers are summed over worlds in :meth:`SwarmMetrics.result` (worlds are independent samples of one setting).
"""

from __future__ import annotations

import math

import torch

from magwarp.swarm.env import SwarmEnv

__all__ = ["SwarmMetrics", "run_policy"]


class SwarmMetrics:
    """Tracks the metrics of a :class:`SwarmEnv`; call :meth:`update` with each step's ``info``."""

    def __init__(self, env: SwarmEnv, *, deadlock_steps: int = 25, stuck_speed: float = 0.05):
        if int(deadlock_steps) < 1 or not stuck_speed > 0:
            raise ValueError(f"deadlock_steps must be >= 1 and stuck_speed > 0, got {deadlock_steps!r}, "
                             f"{stuck_speed!r}")
        self.env = env
        self.deadlock_steps, self.stuck_speed = int(deadlock_steps), float(stuck_speed)
        self.step_time = env.num_cycles * float(env.sim.model.limits.dt)
        n, m, dev = env.num_envs, env.num_movers, env.device
        self.goals = torch.zeros(n, m, dtype=torch.int64, device=dev)
        self.jobs = torch.zeros(n, m, dtype=torch.int64, device=dev)
        self.collisions = torch.zeros(n, m, dtype=torch.int64, device=dev)
        self.stuck = torch.zeros(n, m, dtype=torch.int64, device=dev)
        self.first_goal_step = torch.full((n, m), -1, dtype=torch.int64, device=dev)
        self.steps = 0

    def reset(self) -> None:
        for t in (self.goals, self.jobs, self.collisions, self.stuck):
            t.zero_()
        self.first_goal_step.fill_(-1)
        self.steps = 0

    def update(self, info: dict) -> None:
        env = self.env
        self.steps += 1
        reached = info["goal_reached"]
        self.goals += reached
        self.collisions += info["agent_terminated"]
        if "job_done" in info:
            self.jobs += info["job_done"]
        first = (self.first_goal_step < 0) & reached
        self.first_goal_step.masked_fill_(first, self.steps)
        speed = env.sim.vel[..., :2].norm(dim=-1)
        away = (env.goals - env.sim.pos[..., :2]).norm(dim=-1) > env.config.threshold_pos
        stuck = (speed < self.stuck_speed) & away & ~env.respawn_pending
        self.stuck.copy_(torch.where(stuck, self.stuck + 1, 0))

    def result(self) -> dict:
        """The metrics over every world (one host synchronisation)."""
        n, m = self.env.num_envs, self.env.num_movers
        seconds = self.steps * self.step_time
        goals = int(self.goals.sum())
        collisions = int(self.collisions.sum())
        done = self.first_goal_step.min() >= 0 if self.steps else False
        makespan = float(self.first_goal_step.max()) * self.step_time if done else math.nan
        throughput = goals / (seconds * n) if seconds else 0.0  # per world
        return {
            "worlds": n, "movers": m, "steps": self.steps, "seconds": seconds, "goals": goals,
            "throughput": throughput, "throughput_per_mover": throughput / m, "collisions": collisions,
            "collisions_per_1000_goals": 1000.0 * collisions / goals if goals else math.inf if collisions else 0.0,
            "deadlocked": int((self.stuck >= self.deadlock_steps).sum()), "makespan": makespan,
            "jobs": int(self.jobs.sum()), "jobs_per_s": int(self.jobs.sum()) / (seconds * n) if seconds else 0.0,
        }


def run_policy(env: SwarmEnv, policy, steps: int, **metric_options) -> dict:
    """Run ``policy`` (called with the observation, returns ``[N, M, 2]`` actions) for ``steps`` steps from a fresh
    reset and return the :class:`SwarmMetrics` result."""
    metrics = SwarmMetrics(env, **metric_options)
    obs, _ = env.reset()
    for _ in range(int(steps)):
        obs, _, _, _, info = env.step(policy(obs))
        metrics.update(info)
    return metrics.result()
