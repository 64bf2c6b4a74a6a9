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
