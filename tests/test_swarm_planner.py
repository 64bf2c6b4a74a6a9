"""The scripted swarm planner: its ORCA lines against the geometry they promise (a relative velocity moved by
``u`` grazes the safe disc within the horizon: closest approach = the radius), the braking shield's stop speed
against the held-then-braked kinematics, a head-on pass, a swarm where it collides far less and reaches more goals
than straight goal seeking, and its quality on a small seeded swarm at 25% occupancy (goals, collisions per 1000
goals, deadlocks, share of first goals reached)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from magwarp.swarm import SwarmEnv
from magwarp.swarm.metrics import SwarmMetrics
from magwarp.swarm.planner import SwarmPlanner, orca_lines, stop_speed


def closest_approach(d: np.ndarray, u: np.ndarray, horizon: float) -> np.ndarray:
    """min over t in [0, horizon] of |d - u t| (relative position d of j from i, relative velocity u = v_i - v_j)."""
    t = np.clip((d * u).sum(-1) / np.maximum((u * u).sum(-1), 1e-12), 0.0, horizon)
    return np.linalg.norm(d - u * t[..., None], axis=-1)


def test_orca_change_puts_the_relative_velocity_on_the_obstacle_boundary(rng):
    radius, horizon = 0.26, 1.0
    n = 2000
    ang = rng.uniform(0, 2 * np.pi, n)
    d = np.stack([np.cos(ang), np.sin(ang)], -1) * rng.uniform(radius * 1.05, 4 * radius, (n, 1))
    rel = rng.normal(0, 1.0, (n, 2))
    direction, u = orca_lines(torch.tensor(d, dtype=torch.float64), torch.tensor(rel, dtype=torch.float64), radius,
                              horizon, 0.04)
    new = rel + u.numpy()
    np.testing.assert_allclose(closest_approach(d, new, horizon), radius, atol=1e-6, err_msg=str(rng))
    # the line runs through the new relative velocity along the boundary: unit direction, normal to u
    np.testing.assert_allclose(np.linalg.norm(direction.numpy(), axis=-1), 1.0, atol=1e-9)
    un = np.linalg.norm(u.numpy(), axis=-1)
    cos = np.abs((direction.numpy() * u.numpy()).sum(-1)) / np.maximum(un, 1e-12)
    assert (cos[un > 1e-6] < 1e-6).all(), f"{rng}: u is not normal to its line"
    # already overlapping: u leaves the disc within one step
    inside = rng.normal(0, 1, (50, 2)) * 0.05
    _, u_in = orca_lines(torch.tensor(inside), torch.tensor(rel[:50]), radius, horizon, 0.04)
    after = inside - (rel[:50] + u_in.numpy()) * 0.04
    np.testing.assert_allclose(np.linalg.norm(after, axis=-1), radius, atol=1e-6)


def test_head_on_movers_pass_each_other():
    env = SwarmEnv(1, num_movers=2, layout=np.ones((20, 12)), device="cpu", seed=0)
    env.sim.pos[0, :, :2] = torch.tensor([[1.0, 1.5], [3.0, 1.5]])
    env.goals[0] = torch.tensor([[3.0, 1.5], [1.0, 1.5]])
    env._get_obs()
    planner = SwarmPlanner(env)
    reached = torch.zeros(2, dtype=torch.bool)
    for _ in range(80):
        _, _, _, _, info = env.step(planner())
        assert not info["agent_terminated"].any(), "the movers collided"
        reached |= info["goal_reached"][0]
    assert reached.all()


def test_swarm_planner_beats_straight_seeking():
    results = {}
    for name in ("seek", "planner"):
        env = SwarmEnv(2, num_movers=64, device="cpu", seed=3)
        planner = SwarmPlanner(env, safe=False)  # the steering rules alone (the filter makes collisions 0)
        collisions = goals = 0
        for _ in range(100):
            if name == "planner":
                action = planner()
            else:  # straight at the goal, braking on arrival, no avoidance
                action = 2.0 * (2.0 * (env.goals - env.sim.pos[..., :2]) - 2.0 * env.sim.vel[..., :2])
            _, _, _, _, info = env.step(action)
            collisions += int(info["agent_terminated"].sum())
            goals += int(info["goal_reached"].sum())
        results[name] = (collisions, goals)
    (c_seek, g_seek), (c_plan, g_plan) = results["seek"], results["planner"]
    assert c_plan * 5 < c_seek and g_plan > g_seek, results


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_solve_lines_finds_the_closest_feasible_velocity(rng, dtype):
    """ORCA's incremental LP against a brute-force search over a fine grid of velocities in the speed disc: the torch
    form (float64) and the Warp kernel (float32, a thread per mover)."""
    from magwarp.swarm.planner import solve_lines

    tol = 1e-9 if dtype == torch.float64 else 1e-5

    g = np.linspace(-1.0, 1.0, 401)
    grid = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    grid = grid[np.linalg.norm(grid, axis=-1) <= 1.0]
    checked = 0
    for _ in range(40):
        k = int(rng.integers(1, 6))
        ang = rng.uniform(0, 2 * np.pi, k)
        direction = np.stack([np.cos(ang), np.sin(ang)], -1)
        point = rng.uniform(-0.8, 0.8, (k, 2))
        live = rng.random(k) < 0.8
        v_pref = rng.uniform(-1.2, 1.2, 2)
        lines = [(torch.tensor(point[i], dtype=dtype), torch.tensor(direction[i], dtype=dtype),
                  torch.tensor(bool(live[i]))) for i in range(k)]
        v, ok = solve_lines(lines, torch.tensor(v_pref, dtype=dtype), 1.0)
        det = direction[:, 0, None] * (point[:, 1, None] - grid[None, :, 1]) - \
            direction[:, 1, None] * (point[:, 0, None] - grid[None, :, 0])
        feasible = grid[((det <= 0) | ~live[:, None]).all(axis=0)]
        if len(feasible) == 0:
            continue  # (the LP may still find a sliver the grid misses; nothing to compare)
        checked += 1
        assert bool(ok), f"{rng}: a feasible set was reported empty"
        v = v.double().numpy()
        best = np.linalg.norm(feasible - v_pref, axis=-1).min()
        assert np.linalg.norm(v - v_pref) <= best + tol, f"{rng}: not the closest feasible velocity"
        assert np.linalg.norm(v) <= 1.0 + tol
        vdet = direction[:, 0] * (point[:, 1] - v[1]) - direction[:, 1] * (point[:, 0] - v[0])
        assert (vdet[live] <= tol).all(), f"{rng}: the velocity violates a line"
    assert checked >= 10


@pytest.mark.parametrize("skip, device", [(False, "cpu"), (True, "cpu"), pytest.param(
    True, "cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device"))])
def test_solve_lines_kernel_matches_the_torch_form(rng, skip, device):
    """The Warp kernel (float32, a thread per mover) against the torch form on the same float32 lines: 2,000 movers,
    each with 8 lines (walls, shields and ORCA lines alike: random, some dead, one parallel to an earlier one; about
    a quarter of the programs feasible), with
    and without dropping the lines that leave no room. The same velocities but for rounding (a few movers at a line's
    boundary may step differently), the same feasibility."""
    from magwarp.swarm.planner import solve_lines, solve_lines_torch

    g = torch.Generator().manual_seed(int(rng.integers(1 << 30)))
    rows, k = 2000, 8
    ang = torch.rand(rows, k, generator=g) * 6.2832
    ang[:, 5] = ang[:, 2]  # parallel to an earlier line
    direction = torch.stack([ang.cos(), ang.sin()], -1)
    point = (torch.rand(rows, k, 2, generator=g) - 0.5) * 1.6
    live = torch.rand(rows, k, generator=g) < 0.8
    v_pref = (torch.rand(rows, 2, generator=g) - 0.5) * 2.4
    point, direction, live, v_pref = (t.to(device) for t in (point, direction, live, v_pref))
    lines = [(point[:, i], direction[:, i], live[:, i]) for i in range(k)]
    v, ok = solve_lines(lines, v_pref, 1.0, skip=skip)
    v_ref, ok_ref = solve_lines_torch(lines, v_pref, 1.0, skip=skip)
    close = (v - v_ref).norm(dim=-1) <= 1e-4
    assert close.float().mean() >= 0.99 and (ok == ok_ref).float().mean() >= 0.99, \
        f"{rng}: {int((~close).sum())} velocities, {int((ok != ok_ref).sum())} flags differ"
    assert 0.05 < ok.float().mean() < 0.95, f"{rng}: the test needs feasible and infeasible programs"
    assert (v.norm(dim=-1) <= 1.0 + 1e-5).all()


def test_planner_options_keep_commands_within_limits():
    env = SwarmEnv(1, num_movers=24, layout=np.ones((8, 8)), device="cpu", seed=5)
    for options in (dict(relax=0.1), dict(reachable=True), dict(brake_factor=1.0, yield_share=0.8),
                    dict(greedy=False, relax=1.0), dict(greedy=False, shield=0.0), dict(reachable=True, greedy=True)):
        planner = SwarmPlanner(env, **options)
        for _ in range(10):
            action = planner()
            assert action.shape == (1, 24, 2) and torch.isfinite(action).all()
            assert float(action.norm(dim=-1).max()) <= env.config.a_max * (1 + 1e-5)
            env.step(action)
    for bad in (dict(relax=-1.0), dict(yield_share=1.5), dict(brake_factor=2.0), dict(cruise=0.0), dict(shield=1.5),
                dict(margin=-0.01)):
        with pytest.raises(ValueError):
            SwarmPlanner(env, **bad)


def test_stop_speed_matches_the_held_then_braked_kinematics(rng):
    """At the stop speed the gap closes by exactly ``room``: the closing speed moves linearly from ``c0`` to ``c``
    within the step, then brakes at ``decel`` to rest (numerical integration of that profile)."""
    n, step, decel = 400, 0.04, 8.0
    room = rng.uniform(0.0, 0.5, n)
    c0 = rng.uniform(-1.0, 2.0, n)
    c = stop_speed(torch.tensor(room), torch.tensor(c0), decel, step).numpy()
    fits = room - 0.5 * step * c0 >= 0
    # the closed-form distance: the step's trapezoid, then c^2 / (2 decel) while braking (c >= 0 where room is left)
    assert (c[fits] >= -1e-12).all(), str(rng)
    travelled = 0.5 * step * (c0 + c) + np.where(c > 0, c * c / (2 * decel), 0.0)
    np.testing.assert_allclose(travelled[fits], room[fits], atol=1e-9, err_msg=str(rng))
    # fine time steps of the same profile
    t = np.linspace(0.0, step, 2001)
    hold = np.trapezoid(c0[:, None] + (c - c0)[:, None] * t / step, t, axis=1)
    tb = np.linspace(0.0, 1.0, 20001)[None, :] * (np.maximum(c, 0.0) / decel)[:, None]
    brake = np.trapezoid(np.maximum(c, 0.0)[:, None] - decel * tb, tb, axis=1)
    np.testing.assert_allclose((hold + brake)[fits], room[fits], atol=1e-6, err_msg=str(rng))
    # no room left: open the gap back within one step
    np.testing.assert_allclose(c[~fits], 2.0 * (room[~fits] - 0.5 * step * c0[~fits]) / step, atol=1e-9)


@pytest.mark.parametrize("seed", [3, 4])
def test_planner_quality_on_a_small_dense_swarm(seed):
    """64 movers on 16 x 16 tiles (25% occupancy), 2 worlds, 100 steps (4 s): the planner as shipped (with its
    safety filter) never collides, keeps moving (no deadlocked mover) and reaches goals. Measured with these seeds:
    76 / 88 goals, 0 collisions, 0 deadlocked, 44-56% of the first goals reached; the planner without the filter
    (``safe=False``) reached 62 / 75 goals at 113 / 200 collided movers per 1000 goals."""
    env = SwarmEnv(2, num_movers=64, layout=np.ones((16, 16)), device="cpu", seed=seed, check_inputs=False)
    planner = SwarmPlanner(env)
    metrics = SwarmMetrics(env)
    env.reset()
    for _ in range(100):
        _, _, _, _, info = env.step(planner())
        metrics.update(info)
    r = metrics.result()
    first = float((metrics.tracker.t["nth_goal_step"] >= 0).float().mean())  # movers that reached a first goal
    assert r["collisions"] == 0, r
    assert r["goals"] >= 55, r
    assert r["deadlocked"] <= 2, r
    assert first >= 0.3, (first, r)


def test_safe_planner_options_are_checked():
    env = SwarmEnv(1, num_movers=8, layout=np.ones((6, 6)), device="cpu", seed=0, obs_radius=0.5)
    planner = SwarmPlanner(env)  # its own neighbour search sees the filter's reach radius, whatever the view's
    assert planner.near.radius == planner.safety.reach_radius > 0.5 and planner.near.k == 24
    with pytest.raises(ValueError, match="v_max"):
        SwarmPlanner(SwarmEnv(1, num_movers=8, layout=np.ones((6, 6)), device="cpu", seed=0), cruise=3.0)
    for bad in (dict(patience=-1), dict(patience=1.5), dict(commit_brake=0.0), dict(commit_brake=1.5),
                dict(safe_k=0)):
        with pytest.raises(ValueError):
            SwarmPlanner(env, cruise=0.8, **bad)


@pytest.mark.parametrize("options", [{}, {"safe": False}])
def test_planner_kernels_command_as_the_torch_forms(rng, options):
    """The planner with its Warp kernels (the lines built on the device, the linear program and the safety filter, a
    thread per mover) against the same planner in torch ops, from the same states of a crowded world with holes
    (lanes off: every mover steers by ORCA), with the filter, and without it (the braking shield's lines then): the
    same commands but for float rounding at a boundary, for nearly every mover; the filtered planner keeps the movers
    apart over the steps (no collision)."""
    tiles = np.ones((12, 12))
    tiles[rng.integers(0, 12, 4), rng.integers(0, 12, 4)] = 0
    env = SwarmEnv(3, num_movers=40, layout=tiles, device="cpu", seed=int(rng.integers(1 << 20)))
    fast, ref = SwarmPlanner(env, **options), SwarmPlanner(env, kernels=False, **options)
    assert fast.kernels and not ref.kernels and (fast.shield > 0) == ("safe" in options)
    if fast.safety is not None:
        assert fast.safety.kernel and not ref.safety.kernel
    env.reset(seed=int(rng.integers(1 << 20)))
    close = total = 0
    for _ in range(12):
        a, b = fast(), ref()
        d = (a - b).norm(dim=-1)
        close += int((d <= 1e-3).sum())
        total += d.numel()
        _, _, _, _, info = env.step(a)
        assert fast.safety is None or not info["collided"].any(), f"{rng}: the planner's movers collided"
    assert close >= 0.97 * total, f"{rng}: {total - close} of {total} commands differ"
