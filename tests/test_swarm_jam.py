"""benchmarks/swarm_jam.py: the planner's throughput and slow movers per window of time, and where they are."""

from __future__ import annotations

import os
import sys

import numpy as np
import pytest
import torch

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "benchmarks"))

import swarm_jam  # noqa: E402


def test_occupancy_map_matches_numpy():
    gen = np.random.default_rng(5)
    side = 3.84
    xy = gen.uniform(0.0, side, (500, 2))
    xy[:3] = [[0.0, 0.0], [side, side], [side - 1e-6, 0.0]]  # the edges fall in the edge cells
    got = np.array(swarm_jam.occupancy_map(torch.as_tensor(xy, dtype=torch.float32), side, cells=6))
    ref, _, _ = np.histogram2d(xy[:, 1], xy[:, 0], bins=6, range=[[0, side], [0, side]])
    assert got.sum() == 500
    np.testing.assert_array_equal(got, ref[::-1].astype(int))


def test_run_counts_every_goal_once_and_maps_every_mover():
    row = swarm_jam.run(16, 0.25, 1.0, 0.4, "cpu", "outer", seed=3)
    assert [w["end_s"] for w in row["windows"]] == pytest.approx([0.4, 0.8, 1.0])
    assert row["goals"] == sum(w["goals"] for w in row["windows"]) and row["goals"] > 0
    assert np.sum(row["movers_map"]) == 16 and np.sum(row["slow_map"]) == row["slow_at_end"]
    for w in row["windows"]:
        assert 0.0 <= w["slow_share"] <= 1.0 and 0.0 <= w["escape_share"] <= 1.0 and w["mean_speed"] >= 0.0


def test_x_first_routes_need_the_lanes():
    with pytest.raises(ValueError, match="needs the planner's lanes"):
        swarm_jam.run(16, 0.25, 0.2, 0.1, "cpu", "x", seed=0)


def test_slow_pairs_match_a_pair_by_pair_count():
    gen = np.random.default_rng(11)
    xy = torch.as_tensor(gen.uniform(0.0, 2.0, (60, 2)), dtype=torch.float32)
    goals = torch.as_tensor(gen.uniform(0.0, 2.0, (60, 2)), dtype=torch.float32)
    slow = torch.as_tensor(gen.random(60) < 0.5)
    got = swarm_jam.slow_pairs(xy, goals, slow, radius=0.5)
    idx = np.flatnonzero(slow.numpy())
    p, g = xy.numpy().astype(float)[idx], goals.numpy().astype(float)[idx]
    u = (g - p) / np.linalg.norm(g - p, axis=1, keepdims=True)
    paired = opposed = aligned = 0
    for i in range(len(idx)):
        nb = [j for j in range(len(idx)) if j != i and np.linalg.norm(p[i] - p[j]) < 0.5]
        paired += bool(nb)
        opposed += any(u[i] @ u[j] < -0.5 for j in nb)
        aligned += any(u[i] @ u[j] > 0.5 for j in nb)
    assert got["slow"] == len(idx) and got["with_slow_neighbour"] == paired > 0
    assert got["opposed_share"] == pytest.approx(opposed / paired) and got["aligned_share"] == pytest.approx(
        aligned / paired)
    assert 0.0 < got["opposed_share"] < 1.0  # the draw has both kinds of pair


def test_a_trained_policy_runs_in_place_of_the_planner():
    row = swarm_jam.run(16, 0.25, 0.4, 0.2, "cpu", "outer", seed=3, policy="pretrained:swarm_residual_1024_gate_ep")
    planner = swarm_jam.run(16, 0.25, 0.4, 0.2, "cpu", "outer", seed=3)
    assert row["policy"] == "pretrained:swarm_residual_1024_gate_ep" and planner["policy"] is None
    assert row["goals"] == sum(w["goals"] for w in row["windows"]) and len(row["windows"]) == 2
    assert np.sum(row["movers_map"]) == 16 and row["slow_pairs"]["slow"] == row["slow_at_end"]
    # the same starts (the seed), another controller: the gated correction acts once the movers run
    assert row["windows"][0]["mean_speed"] != planner["windows"][0]["mean_speed"]


def test_x_first_routes_need_a_planner(monkeypatch):
    """A policy that runs on no planner (a plain swarm policy, not a residual) has no routes to set."""
    real = swarm_jam.controller

    def no_planner(*args):
        env, act, _ = real(16, 8, "cpu", 0, None)
        return env, act, None

    monkeypatch.setattr(swarm_jam, "controller", no_planner)
    with pytest.raises(ValueError, match="'plain.pt' runs on no planner"):
        swarm_jam.run(16, 0.25, 0.2, 0.1, "cpu", "x", seed=0, policy="plain.pt")
