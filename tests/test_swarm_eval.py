"""Swarm metrics in ``magwarp eval``: the tracker against a plain numpy re-count of recorded steps (per repeat group),
``evaluate`` against the env's own goal counters with a module:callable and a TorchScript policy, the CLI's table,
and one-line errors for bad options."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from magwarp import cli
from magwarp.evaluate import evaluate
from magwarp.metrics import Metrics
from magwarp.swarm import SwarmEnv, SwarmPlanner

STEP_S = 0.04


@pytest.mark.parametrize("stations", [None, "auto"])
def test_tracker_matches_a_plain_recount(rng, stations):
    W, M, T, G = 4, 8, 30, 2
    env = SwarmEnv(W, num_movers=M, layout=np.ones((6, 6)), k=3, num_rays=4, stations=stations, device="cpu",
                   seed=int(rng.integers(1 << 30)))
    metrics = Metrics(env, makespan_goals=1, deadlock_steps=3)
    planner = SwarmPlanner(env)
    rec = []
    for t in range(T):
        action = planner()
        # random pushes (collisions) and holds (stuck movers), more holds at the end
        push = torch.from_numpy(rng.random((W, M)) < 0.3)  # 0.1 let one seed in ~50 end without a collision
        hold = torch.from_numpy(rng.random((W, M)) < (0.9 if t > 20 else 0.1))
        action = torch.where(push[..., None], torch.from_numpy(rng.uniform(-10, 10, (W, M, 2))).float(), action)
        action = torch.where(hold[..., None], -env.sim.vel[..., :2] / STEP_S, action)
        _, _, _, _, info = env.step(action)
        assert "metrics" in info
        rec.append({k: info[k].numpy().copy() for k in ("goal_reached", "mover_collision", "wall_collision",
                                                         "respawn_pending", "agent_terminated")}
                   | {"job_done": info.get("job_done", torch.zeros(W, M, dtype=torch.bool)).numpy().copy(),
                      "speed": env.sim.vel[..., :2].norm(dim=-1).numpy().copy(),
                      "dist": (env.goals - env.sim.pos[..., :2]).norm(dim=-1).numpy().copy()})
    got = {k: v.numpy() for k, v in metrics.summary(G).items()}
    stack = {k: np.stack([r[k] for r in rec]) for k in rec[0]}  # [T, W, M]
    per_group = lambda x: x.reshape(x.shape[0], G, -1).sum(axis=(0, 2)) if x.ndim == 3 else x  # noqa: E731
    goals = per_group(stack["goal_reached"])
    collided = stack["agent_terminated"]  # respawn mode: the collided movers
    assert collided.sum() > 0
    time_s = W // G * T * STEP_S
    np.testing.assert_array_equal(got["goals"], goals)
    np.testing.assert_allclose(got["throughput"], goals / time_s)
    np.testing.assert_allclose(got["throughput_per_mover"], goals / time_s / M)
    np.testing.assert_array_equal(got["collisions"], per_group(collided))
    mm = per_group(collided & stack["mover_collision"])
    mw = per_group(collided & stack["wall_collision"] & ~stack["mover_collision"])
    with np.errstate(divide="ignore", invalid="ignore"):
        np.testing.assert_allclose(got["collisions_per_1k"], 1000 * per_group(collided) / goals)
        np.testing.assert_allclose(got["mover_mover_per_1k"], 1000 * mm / goals)
        np.testing.assert_allclose(got["mover_wall_per_1k"], 1000 * mw / goals)
    jobs = per_group(stack["job_done"])
    np.testing.assert_array_equal(got["jobs"], jobs)
    np.testing.assert_allclose(got["jobs_per_s"], jobs / time_s)
    if stations is not None:
        assert ("jobs_per_s", "Throughput (jobs/s per world)", "jobs") in metrics.ROWS
    stuck = np.zeros((W, M), int)
    for r in rec:
        now = (r["speed"] < 0.05) & (r["dist"] > env.config.threshold_pos) & ~r["respawn_pending"]
        stuck = np.where(now, stuck + 1, 0)
    dead = (stuck >= 3).reshape(G, -1).sum(1) / (W // G)
    np.testing.assert_allclose(got["deadlocked"], dead)
    assert dead.sum() > 0
    first = np.full((W, M), -1)
    for t, r in enumerate(rec):
        first = np.where((first < 0) & r["goal_reached"], t + 1, first)
    valid = (first >= 0).all(1)
    makespan = np.where(valid, first.max(1) * STEP_S, 0.0)
    np.testing.assert_array_equal(got["makespan_worlds"], valid.reshape(G, -1).sum(1))
    with np.errstate(divide="ignore", invalid="ignore"):
        np.testing.assert_allclose(got["makespan_s"], makespan.reshape(G, -1).sum(1) / valid.reshape(G, -1).sum(1))


class CountingPlanner(SwarmPlanner):
    """The scripted planner, remembering its env (to read the env's own goal counters after ``evaluate``)."""

    last = None

    def __init__(self, env):
        super().__init__(env)
        CountingPlanner.last = self


def test_evaluate_matches_the_envs_goal_counters():
    res = evaluate("magwarp/Swarm-v0", f"{__name__}:CountingPlanner", episodes=2, repeats=2, steps=25, device="cpu",
                   env_kwargs={"num_movers": 16, "layout": np.ones((8, 8))})
    assert res.family == "swarm" and res.steps_per_world == 25
    env = CountingPlanner.last.env
    goals = env.collected_goals.reshape(2, -1).sum(1).numpy()  # the last batch holds both repeats
    rows = {r.key: r for r in res.rows}
    assert goals.sum() > 0
    np.testing.assert_allclose(rows["throughput"].values, goals / (2 * 25 * STEP_S))
    np.testing.assert_allclose(rows["throughput_per_mover"].values, goals / (2 * 25 * STEP_S) / 16)
    assert rows["throughput"].n == goals.mean()
    assert rows["deadlocked"].n == 2


def test_evaluate_a_torchscript_policy_file(tmp_path):
    class Still(torch.nn.Module):  # parameter-shared: [N, M, D] observations -> [N, M, 2] actions
        def forward(self, obs: torch.Tensor) -> torch.Tensor:
            return torch.zeros(obs.shape[0], obs.shape[1], 2)

    path = tmp_path / "still.pt"
    torch.jit.script(Still()).save(str(path))
    res = evaluate("Swarm", str(path), episodes=1, repeats=2, steps=5, device="cpu", env_kwargs={"num_movers": 8})
    rows = {r.key: r for r in res.rows}
    # movers that stand still never collide; a streamed goal may fall under a still mover (a goal now and then)
    assert len(rows["throughput"].values) == 2 and max(rows["throughput"].values) <= 8 / (5 * STEP_S)
    assert all(v == 0 or math.isnan(v) for v in rows["collisions_per_1k"].values)


def run_cli(capsys, *argv):
    rc = cli.main(list(argv))
    out, err = capsys.readouterr()
    return rc, out, err


def test_cli_prints_the_swarm_table(capsys, tmp_path):
    path = tmp_path / "swarm.json"
    rc, out, err = run_cli(capsys, "eval", "magwarp/Swarm-v0", "--policy", "scripted", "--episodes", "1", "--repeats",
                           "2", "--steps", "8", "--device", "cpu", "--env-kwargs", '{"num_movers": 64}', "--json",
                           str(path))
    assert rc == 0, err
    assert "2 repeats x 1 worlds x 8 steps" in out
    for label in ("Throughput (goals/s per world)", "Throughput per Mover (goals/s)",
                  "Collisions (movers per 1000 goals)", "Deadlocked Movers (per world, at the end)",
                  "Makespan (s, 5 goals per mover)", "Process Time (ms per goal, batched)"):
        assert f"| {label}" in out, out
    data = json.loads(path.read_text())
    assert data["family"] == "swarm" and len(data["rows"][0]["values"]) == 2


@pytest.mark.parametrize("argv, words", [
    (["--env-kwargs", '{"num_movers": 0}'], "num_movers must be an integer >= 1, got 0"),
    (["--env-kwargs", '{"num_movers": 900, "layout": [[1, 1], [1, 1]]}'], "cannot place 900 movers"),
    (["--env-kwargs", '{"movers": 8}'], "unknown SwarmEnv options ['movers']"),
    (["--steps", "0"], "--steps must be a positive integer"),
])
def test_cli_bad_options_are_one_line(capsys, argv, words):
    rc, out, err = run_cli(capsys, "eval", "magwarp/Swarm-v0", "--episodes", "1", "--repeats", "1", "--device", "cpu",
                           *argv)
    assert rc == 2 and words in err, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
