"""The material-flow variant of the swarm env: goals alternate between pick-up and drop-off stations, deliveries
count as jobs, stations are checked against the wall rule; ``magwarp/SwarmMaterialFlow-v0`` is registered."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

import magwarp  # noqa: F401  (registers the env ids)
from magwarp.swarm import SwarmEnv, SwarmPlanner
from magwarp.swarm.metrics import SwarmMetrics

PICKUP = [[0.4, 0.4], [0.4, 1.5]]
DROPOFF = [[2.0, 0.6], [2.0, 1.6], [1.2, 1.7]]


def test_jobs_alternate_between_stations(rng):
    env = SwarmEnv(2, num_movers=6, layout=np.ones((10, 8)), stations={"pickup": PICKUP, "dropoff": DROPOFF},
                   device="cpu", seed=int(rng.integers(1 << 30)))
    planner = SwarmPlanner(env)
    metrics = SwarmMetrics(env)
    pick, drop = torch.tensor(PICKUP), torch.tensor(DROPOFF)

    def at(goals, sites):
        return (goals[..., None, :] - sites).norm(dim=-1).min(dim=-1).values < 1e-5

    jobs = 0
    obs, _ = env.reset()
    assert not env.carrying.any() and at(env.goals, pick).all()
    for _ in range(150):
        carrying = env.carrying.clone()
        obs, reward, _, _, info = env.step(planner())
        metrics.update(info)
        reached = info["goal_reached"]
        assert torch.equal(info["job_done"], reached & carrying)
        assert torch.equal(env.carrying, carrying ^ reached)
        assert at(env.goals[env.carrying], drop).all() and at(env.goals[~env.carrying], pick).all()
        assert torch.equal(obs[..., 4], env.carrying.float())  # the carrying flag is part of the observation
        jobs += int(info["job_done"].sum())
    assert jobs > 0, f"{rng}: no job was delivered"
    assert int(env.jobs.sum()) == jobs and metrics.result()["jobs"] == jobs


def test_stations_are_checked_and_auto_stations_split_by_side():
    with pytest.raises(ValueError, match=r"dropoff station 1 at \(2\.35"):
        SwarmEnv(1, num_movers=2, layout=np.ones((10, 8)), device="cpu",
                 stations={"pickup": PICKUP, "dropoff": [[2.0, 0.6], [2.35, 1.0]]})
    with pytest.raises(ValueError, match="stations must be"):
        SwarmEnv(1, num_movers=2, layout=np.ones((10, 8)), device="cpu", stations="somewhere")
    env = gym.make_vec("magwarp/SwarmMaterialFlow-v0", num_envs=1, num_movers=8, layout=np.ones((12, 6)),
                       num_stations=3, device="cpu")
    st = env.stations
    assert len(st.pickup) == 3 and len(st.dropoff) == 3 and st.pickup[:, 0].max() <= st.dropoff[:, 0].min()
