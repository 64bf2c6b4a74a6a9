"""Benchmark metric accumulators vs numpy re-implementations of their definitions on recorded random trajectories,
and vs MagBotSim's own ``benchmark_utils`` (where installed) for the corrective movements."""

import numpy as np
import pytest
import torch

from magwarp.envs.push import PushBoxEnv
from magwarp.envs.push_obstacles import PushWithObstaclesEnv
from magwarp.envs.trajectory import TrajectoryPlanningEnv
from magwarp.metrics import Metrics, PushTaskMetrics, TrajectoryMetrics

EPS = 2e-5


# ---------------------------------------------------------------------------------------------- numpy references
def ref_corrections(dist: np.ndarray, threshold: float, restart: np.ndarray) -> tuple[int, int]:
    """Overshoot and distance corrections of one distance sequence (per cycle); ``restart[t]``: history cleared
    before cycle t (a new goal or a new episode)."""
    over = corr = 0
    last_in, last, inc = False, np.inf, False
    for d, r in zip(dist, restart):
        if r:
            last_in, last, inc = False, np.inf, False
        now_in = d < threshold
        if last_in and not now_in and abs(d - threshold) > EPS:
            over += 1
        last_in = now_in
        if last < d and abs(last - d) > EPS:
            inc = True
        elif inc and d < last and abs(last - d) > EPS:
            inc = False
            corr += 1
        last = d
    return over, corr


def ref_smoothness(vel: np.ndarray, acc: np.ndarray, restart: np.ndarray, skip: np.ndarray, dt: float) -> float:
    """Sum over cycles of 15|jerk|_1 + 5|acc|_1 + |vel|_1 for one mover (x/y), jerk over the real dt."""
    total, prev = 0.0, np.zeros(2)
    for v, a, r, s in zip(vel, acc, restart, skip):
        if r:
            prev = np.zeros(2)
        if not s:
            total += 15 * np.abs((a - prev) / dt).sum() + 5 * np.abs(a).sum() + np.abs(v).sum()
        prev = a
    return total


def ref_events(counts: np.ndarray, restart: np.ndarray) -> int:
    """Collision events: rises of a per-cycle count (pairs, movers over a wall, contacts)."""
    events, prev = 0, 0
    for c, r in zip(counts, restart):
        if r:
            prev = 0
        events += max(0, int(c) - prev)
        prev = int(c)
    return events


# ---------------------------------------------------------------------------------------------- trajectory planning
def _record_trajectory_run(rng, steps=40, num_envs=4):
    env = TrajectoryPlanningEnv(num_envs, "B0", num_cycles=10, timeout_steps=8, threshold_pos=0.12, device="cpu",
                                seed=int(rng.integers(1 << 30)))
    m = Metrics(env, makespan_goals=1)
    env.sim._use_graph = False  # hooks run eagerly, so the recorder below can copy the state every cycle
    rec = {k: [] for k in ("pos", "vel", "acc", "goals", "pairs", "walls", "halted")}
    sim = env.sim

    def record(s):
        rec["pos"].append(s.pos[..., :2].clone())
        rec["vel"].append(s.vel[..., :2].clone())
        rec["acc"].append(s.acc.clone())
        rec["goals"].append(env.goals.clone())
        rec["pairs"].append(s.world_pairs.clone())
        rec["walls"].append(s.world_walls.clone())
        rec["halted"].append(s.halted.clone())

    sim.add_cycle_hook(record)
    env.reset(seed=int(rng.integers(1 << 30)))
    gen = torch.Generator().manual_seed(int(rng.integers(1 << 30)))
    done_steps, reached_steps = [], []
    for _ in range(steps):
        # toward the goals with noise: goals get reached, movers collide and time out
        to_goal = (env.goals - sim.pos[..., :2])
        act = 40 * to_goal - 4 * sim.vel[..., :2] + 6 * torch.randn(to_goal.shape, generator=gen)
        obs, _, term, trunc, info = env.step(act.reshape(num_envs, -1))
        done_steps.append((term | trunc).clone())
        reached_steps.append(info["goals_reached"].clone())
    stack = {k: torch.stack(v).numpy() for k, v in rec.items()}
    return env, m, stack, torch.stack(done_steps).numpy(), torch.stack(reached_steps).numpy()


def test_trajectory_metrics_match_numpy_definitions(rng):
    env, m, rec, done, reached = _record_trajectory_run(rng)
    W, M, C = env.num_envs, env.num_movers, env.num_cycles
    T = rec["pos"].shape[0]
    dt = env.sim.model.limits.dt
    # per-cycle restarts: a new episode after a done step; a new goal after a reached step (per mover)
    ep_restart = np.zeros((T, W), bool)
    goal_restart = np.zeros((T, W, M), bool)
    for s in range(done.shape[0] - 1):
        ep_restart[(s + 1) * C] |= done[s]
        goal_restart[(s + 1) * C] |= reached[s]
    assert done.any() and reached.any(), f"the random run must contain episode ends and reached goals ({rng})"
    t = m.t
    dist = np.linalg.norm(rec["pos"] - rec["goals"], axis=-1).astype(np.float32)
    for w in range(W):
        pairs = rec["pairs"][:, w]
        walls = rec["walls"][:, w]
        assert t["events"][w, 0] == ref_events(pairs, ep_restart[:, w]), f"world {w} mover-mover ({rng})"
        assert t["events"][w, 1] == ref_events(walls, ep_restart[:, w]), f"world {w} walls ({rng})"
        assert t["elapsed"][w] == T
        for k in range(M):
            smooth = ref_smoothness(rec["vel"][:, w, k].astype(np.float64), rec["acc"][:, w, k].astype(np.float64),
                                    ep_restart[:, w], rec["halted"][:, w] != 0, dt)
            np.testing.assert_allclose(float(t["smooth"][w, k]), smooth, rtol=1e-5, err_msg=f"world {w} mover {k} ({rng})")
            restart = ep_restart[:, w] | goal_restart[:, w, k]
            over, corr = ref_corrections(dist[:, w, k], env.threshold_pos, restart)
            assert (int(t["overshoots"][w, k]), int(t["corrections"][w, k])) == (over, corr), f"world {w} mover {k} ({rng})"
        # goals: the env's own count; failed goals: every mover's pending goal at an episode end
        assert int(t["goals_reached"][w].sum()) == int(reached[:, w].sum())
        lost = sum(M - int(reached[s, w].sum()) for s in range(done.shape[0]) if done[s, w])
        assert int(t["goals_failed"][w]) == lost
        assert int(t["episodes"][w]) == int(done[:, w].sum())
    # makespan_goals=1: the cycle each mover entered the region of its first reached goal
    for w in range(W):
        for k in range(M):
            steps = np.nonzero(reached[:, w, k])[0]
            if len(steps) == 0:
                assert t["nth_goal_cycle"][w, k] == -1
                continue
            s = steps[0]
            end = (s + 1) * C  # cycles 0..end-1 simulated so far; the mover is inside from its entry cycle on
            inside = dist[:end, w, k] <= env.threshold_pos
            entry = end - np.argmin(inside[::-1]) if not inside.all() else 0
            assert int(t["nth_goal_cycle"][w, k]) == entry + 1, f"world {w} mover {k} ({rng})"


def test_trajectory_summary_and_info(rng):
    env, m, rec, done, reached = _record_trajectory_run(rng, steps=20)
    s = m.summary(2)
    assert all(v.shape == (2,) for v in s.values())
    W = env.num_envs
    goals = m.t["goals_reached"].sum(1).double() + m.t["goals_failed"].double()
    np.testing.assert_allclose(s["goals"].numpy(), goals.view(2, -1).sum(1).numpy())
    np.testing.assert_allclose(s["success_rate"].numpy(), 100 * s["goals_reached"].numpy() / s["goals"].numpy())
    time_s = 20 * env.num_cycles * 1e-3 * W / 2
    np.testing.assert_allclose(s["throughput"].numpy(), s["goals_reached"].numpy() / time_s)
    obs, _, _, _, info = env.step(torch.zeros(W, env.num_movers * 2))
    assert set(info["metrics"]) >= {"goals_reached", "goals_failed", "collisions", "smoothness", "cycles"}


def test_reset_and_freeze_are_per_world():
    env = TrajectoryPlanningEnv(4, "B0", num_cycles=5, device="cpu", seed=0)
    m = Metrics(env)
    env.reset(seed=0)
    act = torch.full((4, env.num_movers * 2), 3.0)
    env.step(act)
    m.freeze(torch.tensor([False, True, False, False]))
    frozen = m.t["elapsed"][1].item()
    env.step(act)
    assert m.t["elapsed"][1].item() == frozen and m.t["elapsed"][0].item() == 10
    m.reset(torch.tensor([True, False, False, False]))
    assert m.t["elapsed"][0].item() == 0 and m.t["smooth"][0].sum().item() == 0 and m.t["elapsed"][2].item() == 10
    assert m.t["active"].tolist() == [1, 0, 1, 1]
    with pytest.raises(ValueError, match="already has a metrics tracker"):
        Metrics(env)
    with pytest.raises(TypeError, match="no benchmark metrics"):
        Metrics(object())


# ---------------------------------------------------------------------------------------------- pushing
def _record_push_run(cls, rng, steps=40, num_envs=6):
    env = cls(num_envs, device="cpu", seed=int(rng.integers(1 << 30)), num_cycles=20, max_episode_steps=30)
    m = Metrics(env)
    assert isinstance(m, PushTaskMetrics)
    b = env.backend
    b.use_graph = False
    rec = {k: [] for k in ("mover", "vel", "acc", "obj", "goal", "contact")}

    def record():
        rec["mover"].append(b.mover_qpos[..., :2].clone())
        rec["vel"].append(b.mover_qvel[..., :2].clone())
        rec["acc"].append(b.acc_t.clone())
        rec["obj"].append(b.object_qpos[:, 0, :2].clone())
        rec["goal"].append(env.goal_xy.clone())
        if env.contacts is not None:
            rec["contact"].append(env.contacts.flags_t.clone())  # OR over the step so far: rises are the same

    b.add_cycle_hook(record)
    env.reset(seed=int(rng.integers(1 << 30)))
    gen = torch.Generator().manual_seed(int(rng.integers(1 << 30)))
    done_steps, infos = [], []
    # per world a steady drift in one of six directions: most worlds reach a wall within the run
    dirs = torch.tensor([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0], [0.7, 0.7], [-0.7, -0.7]])
    drift = 9 * dirs[torch.arange(num_envs) % 6] * (0.8 + 0.2 * torch.rand(num_envs, 1, generator=gen))
    for _ in range(steps):
        # toward the object with noise and drift: pushes, wall hits and (with obstacles) contacts happen
        to_obj = b.object_qpos[:, 0, :2] - b.mover_qpos[:, 0, :2]
        act = 10 * to_obj - 3 * b.mover_qvel[:, 0, :2] + drift + 3 * torch.randn(to_obj.shape, generator=gen)
        _, _, term, trunc, info = env.step(act.reshape(num_envs, -1))
        done_steps.append((term | trunc).clone())
        infos.append(info)
    return env, m, {k: torch.stack(v).numpy() for k, v in rec.items() if v}, torch.stack(done_steps).numpy(), infos


def _push_restarts(done, T, C):
    restart = np.zeros((T, done.shape[1]), bool)
    for s in range(done.shape[0] - 1):
        restart[(s + 1) * C] |= done[s]
    return restart


def test_push_metrics_match_numpy_definitions(rng):
    env, m, rec, done, infos = _record_push_run(PushBoxEnv, rng)
    T, C, W = rec["obj"].shape[0], env.backend.control.num_cycles, env.num_envs
    restart = _push_restarts(done, T, C)
    ext = np.asarray(env.layout.extent)
    r = env.mover.collision_radius
    off = (rec["mover"][..., 0] - r < 0) | (rec["mover"][..., 1] - r < 0) | (rec["mover"][..., 0] + r > ext[0]) | (
        rec["mover"][..., 1] + r > ext[1])
    assert off.any(), f"the random run must hit a wall ({rng})"
    t = m.t
    dt = env.backend.dt
    for w in range(W):
        assert t["events"][w, 1] == ref_events(off[:, w].sum(-1), restart[:, w]), f"world {w} ({rng})"
        smooth = ref_smoothness(rec["vel"][:, w, 0].astype(np.float64), rec["acc"][:, w, 0].astype(np.float64),
                                restart[:, w], np.zeros(T, bool), dt)
        np.testing.assert_allclose(float(t["smooth"][w]), smooth, rtol=1e-5)
    # corrective movements of the env's per-cycle PushMetrics (episode of each world up to its end)
    dist = np.linalg.norm(rec["obj"] - rec["goal"], axis=-1).astype(np.float32)
    last = infos[-1]
    for w in range(W):
        start = np.nonzero(restart[:, w])[0]
        s0 = start[-1] if len(start) else 0
        over, corr = ref_corrections(dist[s0:, w], env.max_position_err, np.zeros(T - s0, bool))
        assert (int(last["num_overshoot_corrections"][w]), int(last["num_distance_corrections"][w])) == (over, corr)
    # episodes and successes recorded at episode ends
    ends = done.sum(0)
    np.testing.assert_array_equal(t["episodes"].numpy(), ends)
    succ = sum((info["is_success"] & d).numpy().astype(int) for info, d in zip(infos, torch.as_tensor(done)))
    np.testing.assert_array_equal(t["successes"].numpy(), succ)


def test_push_obstacle_contact_events(rng):
    env, m, rec, done, _ = _record_push_run(PushWithObstaclesEnv, rng, steps=25)
    # per world: contact events exactly where the env saw mover-obstacle / object-obstacle contacts
    for w in range(env.num_envs):
        for col, k in ((2, 0), (3, 1)):
            touched = bool(rec["contact"][:, w, k].any())
            assert (int(m.t["events"][w, col]) > 0) == touched, f"world {w} column {col} ({rng})"


def test_corrections_match_magbotsim_benchmark_utils(rng):
    bu = pytest.importorskip("magbotsim.utils.benchmark_utils")
    env, m, rec, done, infos = _record_push_run(PushBoxEnv, rng)
    dist_func = lambda a, b: np.linalg.norm(np.asarray(a) - np.asarray(b), axis=-1).reshape(1)  # noqa: E731
    T, C = rec["obj"].shape[0], env.backend.control.num_cycles
    restart = _push_restarts(done, T, C)
    for w in range(env.num_envs):
        start = np.nonzero(restart[:, w])[0]
        s0 = start[-1] if len(start) else 0
        oracle = bu.CorrectiveMovementMeasurement(dist_func, threshold=env.max_position_err)
        for t in range(s0, T):
            oracle.update_distance_corrections(rec["obj"][t, w], rec["goal"][t, w])
            oracle.update_overshoot_corrections(rec["obj"][t, w], rec["goal"][t, w])
        got = (int(infos[-1]["num_overshoot_corrections"][w]), int(infos[-1]["num_distance_corrections"][w]))
        assert got == (oracle.get_current_num_overshoot_corrections(), oracle.get_current_num_distance_corrections())
    # the trajectory tracker's per-mover totals: the oracle restarted at every new goal or episode, summed
    tenv, tm, trec, tdone, treached = _record_trajectory_run(rng)
    Tt, Ct = trec["pos"].shape[0], tenv.num_cycles
    for w in range(tenv.num_envs):
        for k in range(tenv.num_movers):
            oracle = bu.CorrectiveMovementMeasurement(dist_func, threshold=tenv.threshold_pos)
            total = np.zeros(2, int)
            for t in range(Tt):
                s = t // Ct
                if t % Ct == 0 and s > 0 and (tdone[s - 1, w] or treached[s - 1, w, k]):
                    total += (oracle.get_current_num_overshoot_corrections(), oracle.get_current_num_distance_corrections())
                    oracle.reset()
                oracle.update_distance_corrections(trec["pos"][t, w, k], trec["goals"][t, w, k])
                oracle.update_overshoot_corrections(trec["pos"][t, w, k], trec["goals"][t, w, k])
            total += (oracle.get_current_num_overshoot_corrections(), oracle.get_current_num_distance_corrections())
            got = (int(tm.t["overshoots"][w, k]), int(tm.t["corrections"][w, k]))
            assert got == tuple(total), f"world {w} mover {k} ({rng})"


def test_metrics_factory_picks_the_family():
    env = TrajectoryPlanningEnv(2, "B0", device="cpu", seed=0)
    assert isinstance(Metrics(env), TrajectoryMetrics)
