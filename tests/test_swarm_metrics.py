"""Swarm metrics against a plain re-count over recorded steps (goals, collisions, throughput, stuck movers,
makespan), and the planner's run through :func:`run_policy`."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from magwarp.swarm import SwarmEnv
from magwarp.swarm.metrics import SwarmMetrics, run_policy
from magwarp.swarm.planner import SwarmPlanner


def test_metrics_match_a_plain_recount(rng):
    env = SwarmEnv(2, num_movers=6, layout=np.ones((5, 5)), k=2, num_rays=4, device="cpu",
                   seed=int(rng.integers(1 << 30)))
    metrics = SwarmMetrics(env, deadlock_steps=3)
    planner = SwarmPlanner(env)
    rec = []
    for t in range(40):
        # the planner, with some movers held still now and then (so that some get stuck away from their goals)
        action = planner()
        hold = torch.from_numpy(rng.random((2, 6)) < (0.9 if t > 30 else 0.1))
        action = torch.where(hold[..., None], -env.sim.vel[..., :2] / 0.04, action)
        _, _, _, _, info = env.step(action)
        metrics.update(info)
        rec.append({k: v.clone().numpy() for k, v in info.items() if k in ("goal_reached", "agent_terminated",
                                                                          "respawn_pending")}
                   | {"speed": env.sim.vel[..., :2].norm(dim=-1).numpy().copy(),
                      "dist": (env.goals - env.sim.pos[..., :2]).norm(dim=-1).numpy().copy()})
    res = metrics.result()
    goals = sum(int(r["goal_reached"].sum()) for r in rec)
    collisions = sum(int(r["agent_terminated"].sum()) for r in rec)
    assert res["goals"] == goals and res["collisions"] == collisions
    seconds = 40 * 0.04
    assert math.isclose(res["throughput"], goals / seconds / 2) and math.isclose(res["seconds"], seconds)
    stuck = np.zeros((2, 6), int)
    for r in rec:
        now = (r["speed"] < 0.05) & (r["dist"] > 0.1) & ~r["respawn_pending"]
        stuck = np.where(now, stuck + 1, 0)
    assert res["deadlocked"] == int((stuck >= 3).sum()) and res["deadlocked"] > 0
    first = np.full((2, 6), -1)
    for t, r in enumerate(rec):
        first = np.where((first < 0) & r["goal_reached"], t + 1, first)
    want = first.max() * 0.04 if (first >= 0).all() else math.nan
    assert (math.isnan(want) and math.isnan(res["makespan"])) or math.isclose(res["makespan"], want)


def test_run_policy_with_the_planner():
    env = SwarmEnv(1, num_movers=16, layout=np.ones((8, 8)), device="cpu", seed=2)
    res = run_policy(env, lambda obs: SwarmPlanner(env)(), 60)
    assert res["steps"] == 60 and res["goals"] > 10 and res["throughput_per_mover"] > 0


def test_run_policy_counts_goals_per_window():
    """``window``: the goals of each run of ``window`` steps (the last one shorter), summing to the run's goals; the
    run's other numbers are those of a run without windows on a twin env."""
    def run(window):
        env = SwarmEnv(2, num_movers=16, layout=np.ones((8, 8)), device="cpu", seed=5)
        planner = SwarmPlanner(env)
        return run_policy(env, lambda obs: planner(), 60, window=window)

    plain, windowed = run(0), run(25)
    assert "goals_per_window" not in plain and windowed["window_s"] == 25 * 0.04
    assert len(windowed["goals_per_window"]) == 3 and sum(windowed["goals_per_window"]) == windowed["goals"]
    assert windowed["goals"] == plain["goals"] > 10 and min(windowed["goals_per_window"]) > 0
    with pytest.raises(ValueError, match="window must be a number of steps >= 0, got -1"):
        run(-1)
