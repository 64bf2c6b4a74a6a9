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
    """Tracks the metrics of a :class:`SwarmEnv`; call :meth:`update` with each step's ``info``. The counting is
    :class:`~magwarp.metrics.swarm.SwarmTaskMetrics` (what ``magwarp eval`` reports per repeat), here summed over
    every world, with the makespan of the first goal."""

    def __init__(self, env: SwarmEnv, *, deadlock_steps: int = 25, stuck_speed: float = 0.05):
        from magwarp.metrics.swarm import SwarmTaskMetrics

        self.env = env
        self.tracker = SwarmTaskMetrics(env, 1, deadlock_steps=deadlock_steps, stuck_speed=stuck_speed, attach=False)
        self.deadlock_steps, self.stuck_speed = self.tracker.deadlock_steps, self.tracker.stuck_speed
        self.step_time = self.tracker.step_time
        self.steps = 0

    def reset(self) -> None:
        self.tracker.reset()
        self.steps = 0

    def update(self, info: dict) -> None:
        self.steps += 1
        none = torch.zeros(self.env.num_envs, dtype=torch.bool, device=self.env.device)
        self.tracker.on_step(None, info, none, none)

    def result(self) -> dict:
        """The metrics over every world (one host synchronisation)."""
        n, m = self.env.num_envs, self.env.num_movers
        s = {k: float(v) for k, v in self.tracker.summary(1).items()}
        seconds = self.steps * self.step_time
        goals, collisions, jobs = int(s["goals"]), int(s["collisions"]), int(s["jobs"])
        first = self.tracker.t["nth_goal_step"]
        done = bool(first.min() >= 0) if self.steps else False
        makespan = float(first.max()) * self.step_time if done else math.nan
        throughput = goals / (seconds * n) if seconds else 0.0  # per world
        return {
            "worlds": n, "movers": m, "steps": self.steps, "seconds": seconds, "goals": goals,
            "throughput": throughput, "throughput_per_mover": throughput / m, "collisions": collisions,
            "collisions_per_1000_goals": 1000.0 * collisions / goals if goals else math.inf if collisions else 0.0,
            "deadlocked": int(round(s["deadlocked"] * n)), "makespan": makespan,
            "jobs": jobs, "jobs_per_s": jobs / (seconds * n) if seconds else 0.0,
        }


def run_policy(env: SwarmEnv, policy, steps: int, window: int = 0, **metric_options) -> dict:
    """Run ``policy`` (called with the observation, returns ``[N, M, 2]`` actions) for ``steps`` steps from a fresh
    reset and return the :class:`SwarmMetrics` result. ``window`` > 0: also ``goals_per_window``, the goals reached
    in each run of ``window`` consecutive steps (summed over worlds; whether the throughput holds over time), counted
    on the device and read once at the end."""
    metrics = SwarmMetrics(env, **metric_options)
    window = int(window)
    if window < 0:
        raise ValueError(f"window must be a number of steps >= 0, got {window}")
    per_window = torch.zeros(-(-int(steps) // window) if window else 0, dtype=torch.int64, device=env.device)
    obs, _ = env.reset()
    for i in range(int(steps)):
        obs, _, _, _, info = env.step(policy(obs))
        metrics.update(info)
        if window:
            per_window[i // window] += info["goal_reached"].sum()
    out = metrics.result()
    if window:
        out["goals_per_window"] = per_window.tolist()
        out["window_s"] = window * metrics.step_time
    return out
