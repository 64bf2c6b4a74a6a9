"""Trajectory planning env (batched, torch) against a plain numpy re-implementation of MagBotSim's task definition.

The reference (``_task_step``) restates LongHorizonGlobalTrajectoryPlanningEnv's rules from the env's own state
before and after each step: reward +reward_success per goal within threshold_pos, reward_collision on a mover or wall
collision (collision first), else reward_per_step; terminated on collision; truncated when steps_since_goal (counted
before the step's increment) exceeds timeout_steps; reached goals resampled after the reward, the step counter
incremented and the last-goal step set. Collisions are re-derived geometrically from the end-of-step positions: a
world stops at the cycle of its first collision, so it collides at the end of the step exactly when it collided
during the step.
"""

from __future__ import annotations

import dataclasses

import gymnasium as gym
import numpy as np
import pytest
import torch

from magwarp import reference
from magwarp.envs import TrajectoryPlanningEnv
from magwarp.layout import BENCHMARK_LAYOUTS, LayoutError

EPS = 1e-5  # positions within EPS of a collision or goal boundary are not judged (float32 vs float64)


def _np(x):
    return x.detach().cpu().numpy()


def _state(env) -> dict[str, np.ndarray]:
    s = env.sim
    return {
        "pos": _np(s.pos).copy(), "vel": _np(s.vel).copy(), "quat": _np(s.quat).copy(), "acc": _np(s.acc).copy(),
        "goals": _np(env.goals).copy(), "num_steps": _np(env.num_steps).copy(),
        "last_goal_step": _np(env.last_goal_step).copy(), "collected": _np(env.collected_goals).copy(),
        "generator": env._generator.get_state().clone(),
    }


def _assert_same_state(a, b):
    for k in a:
        if k == "generator":
            assert torch.equal(a[k], b[k]), "the random generator advanced"
        else:
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)


# ---------------------------------------------------------------------------------------------------- numpy oracle
def _collisions(env, xy: np.ndarray, yaw: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-world (mover_collision, wall_collision, ambiguous) for end-of-step positions ``(W, M, 2)``."""
    spec = env.sim.mover
    w, m = xy.shape[:2]
    yaw = np.zeros((w, m)) if yaw is None else yaw
    radii, half = env.sim._radii_np, env.sim._half_np

    def judge(grow: float):  # the shapes grown (or shrunk) by ``grow``
        r, h = radii + grow, half + grow
        wall = reference.wall_collisions(env.layout, spec, xy, yaw, r, h).any(axis=1)
        mover = np.array([len(reference.mover_collision_pairs(spec, xy[i], yaw[i], r, h)) > 0 for i in range(w)])
        return mover, wall

    mover, wall = judge(0.0)
    lo, hi = judge(-EPS), judge(EPS)
    ambiguous = (lo[0] != hi[0]) | (lo[1] != hi[1])
    return mover, wall, ambiguous


def _task_step(env, before, pos_xy, mover_col, wall_col):
    """MagBotSim's reward/termination/truncation/goal bookkeeping for one step, in numpy."""
    dist = np.linalg.norm(pos_xy.astype(np.float64) - before["goals"].astype(np.float64), axis=-1)  # (W, M)
    reached = dist <= env.threshold_pos
    near = np.abs(dist - env.threshold_pos) < 1e-5
    collision = mover_col | wall_col
    n_reached = reached.sum(axis=1)
    reward = np.where(n_reached > 0, env.reward_success * n_reached, env.reward_per_step).astype(np.float64)
    reward = np.where(collision, env.reward_collision, reward)
    steps_since = before["num_steps"] - before["last_goal_step"]
    truncated = steps_since > env.timeout_steps if env.timeout_steps is not None else np.zeros_like(collision)
    num_steps = before["num_steps"] + 1
    last = np.where(reached.any(axis=1), num_steps, before["last_goal_step"])
    return dict(reward=reward, terminated=collision, truncated=truncated, reached=reached, near=near.any(axis=1),
                steps_since=steps_since, num_steps=num_steps, last_goal_step=last,
                collected=before["collected"] + reached)


def _valid_goal(env, goals: np.ndarray) -> np.ndarray:
    """Goals ``(K, 2)`` inside MagBotSim's sampling box and with the yaw-0 footprint on the tiles."""
    r = float(env.sim._radii_np.max()) if env.sim.mover.collision_shape == "circle" else env.sim._half_np.max(axis=0)
    reach = r + env.sampler.offset + env.sim.mover.wall_margin
    ext = np.array(env.layout.extent)
    inside = ((goals >= reach - 1e-5) & (goals <= ext - reach + 1e-5)).all(axis=1)
    spec = dataclasses.replace(env.sim.mover, wall_margin=env.sim.mover.wall_margin + env.sampler.offset)
    m = len(goals)
    on = ~reference.wall_collisions(env.layout, spec, goals[None], np.zeros((1, m)),
                                    np.full(m, env.sim._radii_np.max()), np.tile(env.sim._half_np.max(axis=0), (m, 1)))[0]
    return inside & on


CONFIGS = {
    # strong random accelerations: many collisions and goals
    "B0-default": (dict(layout="B0"), 10.0),
    # a layout with a hole, custom task parameters, a short timeout and gentle actions: truncations
    "B1-custom": (dict(layout="B1", threshold_pos=0.15, reward_success=5.0, reward_collision=-7.0,
                       reward_per_step=-0.5, timeout_steps=3), 1.0),
}


@pytest.mark.parametrize("name", list(CONFIGS))
def test_steps_match_numpy_task_definition(rng, name):
    kwargs, scale = CONFIGS[name]
    n, steps = 16, 60
    env = TrajectoryPlanningEnv(num_envs=n, seed=int(rng.integers(1 << 30)), device="cpu", **kwargs)
    env.reset(seed=int(rng.integers(1 << 30)))
    m = env.num_movers
    counts = dict(reached=0, terminated=0, truncated=0, skipped=0, resampled=0)
    for t in range(steps):
        before = _state(env)
        action = torch.from_numpy(rng.uniform(-scale, scale, (n, 2 * m)).astype(np.float32))
        obs, reward, terminated, truncated, info = env.step(action)
        final = {k: _np(v) for k, v in info["final_obs"].items()}
        done = _np(info["_final_obs"])
        pos = final["achieved_goal"].reshape(n, m, 2)
        msg = f"{rng} config={name} step={t}"
        # the observation the reward was computed for shows the goals the step started with
        np.testing.assert_array_equal(final["desired_goal"].reshape(n, m, 2), before["goals"], err_msg=msg)
        mover_col, wall_col, ambiguous = _collisions(env, pos)
        ref = _task_step(env, before, pos, mover_col, wall_col)
        judge = ~(ambiguous | ref["near"])
        counts["skipped"] += int((~judge).sum())
        np.testing.assert_array_equal(_np(info["mover_collision"])[judge], mover_col[judge], err_msg=msg)
        np.testing.assert_array_equal(_np(info["wall_collision"])[judge], wall_col[judge], err_msg=msg)
        np.testing.assert_allclose(_np(reward)[judge], ref["reward"][judge], err_msg=msg)
        np.testing.assert_array_equal(_np(terminated)[judge], ref["terminated"][judge], err_msg=msg)
        np.testing.assert_array_equal(_np(truncated), ref["truncated"], err_msg=msg)
        np.testing.assert_array_equal(_np(info["steps_since_goal"]), ref["steps_since"], err_msg=msg)
        np.testing.assert_array_equal(_np(info["goals_reached"])[judge], ref["reached"][judge], err_msg=msg)
        np.testing.assert_array_equal(done, _np(terminated | truncated), err_msg=msg)

        after = _state(env)
        live = judge & ~done
        # envs that go on: counters, collected goals and goal resampling
        np.testing.assert_array_equal(after["num_steps"][~done], ref["num_steps"][~done], err_msg=msg)
        np.testing.assert_array_equal(after["last_goal_step"][live], ref["last_goal_step"][live], err_msg=msg)
        np.testing.assert_array_equal(after["collected"][live], ref["collected"][live], err_msg=msg)
        np.testing.assert_array_equal(_np(info["collected_goals"])[live], ref["collected"][live], err_msg=msg)
        keep = live[:, None] & ~ref["reached"]
        np.testing.assert_array_equal(after["goals"][keep], before["goals"][keep], err_msg=msg)
        new = live[:, None] & ref["reached"]
        assert (after["goals"][new] != before["goals"][new]).any(axis=-1).all(), msg
        assert _valid_goal(env, after["goals"][new]).all(), msg
        # returned observations: the step's observation for envs that go on ...
        o = {k: _np(v) for k, v in obs.items()}
        for k in o:
            np.testing.assert_array_equal(o[k][~done], final[k][~done], err_msg=f"{msg} key={k}")
        # ... and the first observation of a new episode for finished ones
        np.testing.assert_array_equal(after["num_steps"][done], 0, err_msg=msg)
        np.testing.assert_array_equal(after["last_goal_step"][done], 0, err_msg=msg)
        np.testing.assert_array_equal(after["collected"][done], 0, err_msg=msg)
        np.testing.assert_array_equal(o["observation"][done], 0, err_msg=msg)
        np.testing.assert_array_equal(o["achieved_goal"][done], after["pos"][done][..., :2].reshape(-1, 2 * m), err_msg=msg)
        np.testing.assert_array_equal(o["desired_goal"][done], after["goals"][done].reshape(-1, 2 * m), err_msg=msg)
        if done.any():
            start = after["pos"][done][..., :2]
            mc, wc, _ = _collisions(env, start)
            assert not (mc | wc).any(), f"{msg}: a new episode starts in collision"
            assert _valid_goal(env, after["goals"][done].reshape(-1, 2)).all(), msg
        counts["reached"] += int(ref["reached"][judge].sum())
        counts["terminated"] += int(ref["terminated"][judge].sum())
        counts["truncated"] += int(ref["truncated"].sum())
        counts["resampled"] += int(new.sum())
    print(name, counts)
    # the run must have exercised the rules it checks
    assert counts["skipped"] <= n * steps // 10, (counts, str(rng))
    if name == "B0-default":
        assert counts["reached"] > 0 and counts["terminated"] > 0 and counts["resampled"] > 0, (counts, str(rng))
    else:
        assert counts["truncated"] > 0, (counts, str(rng))


# ---------------------------------------------------------------------------------------------------- observations
@pytest.mark.parametrize("learn_jerk", [False, True])
def test_observation_layout(rng, learn_jerk):
    n = 3
    env = TrajectoryPlanningEnv(num_envs=n, seed=1, learn_jerk=learn_jerk, autoreset=False, device="cpu")
    m = env.num_movers
    limit = 100.0 if learn_jerk else 10.0
    obs_dim = m * 2 * (2 if learn_jerk else 1)
    assert env.single_observation_space["observation"].shape == (obs_dim,)
    assert env.single_action_space.shape == (2 * m,)
    np.testing.assert_array_equal(env.single_action_space.high, limit)
    obs, _ = env.reset(seed=int(rng.integers(1 << 30)))
    for _ in range(2):
        action = torch.from_numpy(rng.uniform(-0.3 * limit, 0.3 * limit, (n, 2 * m)).astype(np.float32))
        obs, *_ = env.step(action)
        s = env.sim
        vel = _np(s.vel)[..., :2].reshape(n, -1)
        expect = np.concatenate([vel, _np(s.acc).reshape(n, -1)], axis=1) if learn_jerk else vel
        np.testing.assert_array_equal(_np(obs["observation"]), expect)
        # mover by mover: (vx0, vy0, vx1, vy1, ...)
        np.testing.assert_array_equal(_np(obs["observation"])[:, 2:4], _np(s.vel)[:, 1, :2])
        np.testing.assert_array_equal(_np(obs["achieved_goal"]), _np(s.pos)[..., :2].reshape(n, -1))
        for k, v in obs.items():
            assert v.dtype == torch.float32 and v.shape == (n, *env.single_observation_space[k].shape), k
    assert np.abs(_np(obs["observation"])).max() > 0
    if learn_jerk:
        assert np.abs(_np(obs["observation"])[:, 2 * m:]).max() > 0, "accelerations missing in jerk mode"


def test_desired_goal_is_the_goal_state(rng):
    env = TrajectoryPlanningEnv(num_envs=4, seed=2, device="cpu")
    obs, _ = env.reset(seed=3)
    np.testing.assert_array_equal(_np(obs["desired_goal"]), _np(env.goals).reshape(4, -1))
    assert _valid_goal(env, _np(env.goals).reshape(-1, 2)).all()


# ---------------------------------------------------------------------------------------------------- resets, seeds
def test_partial_reset_leaves_other_envs_untouched(rng):
    n = 6
    env = TrajectoryPlanningEnv(num_envs=n, seed=4, autoreset=False, device="cpu")
    env.reset(seed=int(rng.integers(1 << 30)))
    for _ in range(3):
        env.step(torch.from_numpy(rng.uniform(-2, 2, (n, 6)).astype(np.float32)))
    before = _state(env)
    mask = torch.tensor([True, False, False, True, False, False])
    obs, _ = env.reset(options={"reset_mask": mask})
    after = _state(env)
    keep = ~mask.numpy()
    for k in ("pos", "vel", "quat", "acc", "goals", "num_steps", "last_goal_step", "collected"):
        np.testing.assert_array_equal(after[k][keep], before[k][keep], err_msg=k)
    assert (after["num_steps"][~keep] == 0).all()
    assert (after["vel"][~keep] == 0).all()
    assert not np.array_equal(after["goals"][~keep], before["goals"][~keep])
    assert (_np(obs["observation"])[~keep] == 0).all()
    np.testing.assert_array_equal(_np(obs["achieved_goal"])[keep], before["pos"][keep][..., :2].reshape(-1, 6))


def _rollout(env, seed, actions):
    obs, _ = env.reset(seed=seed)
    out = [_np(obs["achieved_goal"]).copy(), _np(obs["desired_goal"]).copy()]
    for a in actions:
        obs, r, te, tr, info = env.step(a)
        out += [_np(v).copy() for v in (*obs.values(), r, te, tr)]
    return out


def test_seeding_reproduces_trajectories(rng):
    n = 8
    actions = [torch.from_numpy(rng.uniform(-10, 10, (n, 6)).astype(np.float32)) for _ in range(30)]
    env = TrajectoryPlanningEnv(num_envs=n, seed=5, device="cpu")
    a = _rollout(env, 11, actions)
    b = _rollout(env, 11, actions)
    c = _rollout(TrajectoryPlanningEnv(num_envs=n, seed=5, device="cpu"), 11, actions)
    for x, y, z in zip(a, b, c):
        np.testing.assert_array_equal(x, y)
        np.testing.assert_array_equal(x, z)
    d = _rollout(env, 12, actions)
    assert not all(np.array_equal(x, y) for x, y in zip(a, d)), "a different seed gave the same run"


def test_autoreset_final_obs(rng):
    """Drive every mover into the wall: all envs collide, the final observation shows it, the returned one restarts."""
    n = 4
    env = TrajectoryPlanningEnv(num_envs=n, seed=6, device="cpu", timeout_steps=None)
    env.reset(seed=int(rng.integers(1 << 30)))
    push = torch.tensor([-10.0, 0.0]).repeat(n, env.num_movers)
    finished = np.zeros(n, bool)
    for _ in range(30):
        before = _state(env)
        obs, r, te, tr, info = env.step(push)
        done = _np(info["_final_obs"])
        assert (done == _np(te | tr)).all()
        final = {k: _np(v) for k, v in info["final_obs"].items()}
        if done.any():
            assert _np(info["wall_collision"])[done].all()
            assert (_np(r)[done] == env.reward_collision).all()
            # final obs: moving left at the wall; new obs: at rest at a fresh start
            assert (final["observation"][done][:, 0::2] < 0).all()
            np.testing.assert_array_equal(final["desired_goal"][done], before["goals"][done].reshape(-1, 2 * env.num_movers))
            assert (_np(obs["observation"])[done] == 0).all()
            assert not np.array_equal(_np(obs["achieved_goal"])[done], final["achieved_goal"][done])
        finished |= done
        if finished.all():
            break
    assert finished.all()


# ---------------------------------------------------------------------------------------------------- variants
@pytest.mark.parametrize("name", BENCHMARK_LAYOUTS)
def test_benchmark_variants_construct_and_step(rng, name):
    from magwarp.layout import benchmark_layout

    layout, movers = benchmark_layout(name)
    env = TrajectoryPlanningEnv(num_envs=2, layout=name, seed=7, device="cpu")
    assert env.num_movers == movers and env.layout.shape == layout.shape
    obs, _ = env.reset(seed=8)
    assert _valid_goal(env, _np(env.goals).reshape(-1, 2)).all()
    mc, wc, _ = _collisions(env, _np(env.sim.pos)[..., :2])
    assert not (mc | wc).any(), "start poses collide"
    for _ in range(3):
        obs, r, te, tr, info = env.step(torch.from_numpy(rng.uniform(-10, 10, (2, 2 * movers)).astype(np.float32)))
        assert obs["observation"].shape == (2, 2 * movers) and r.shape == (2,) and te.dtype == torch.bool


def test_box_collision_shape(rng):
    """Box shapes: collision flags agree with the separating-axis reference on the yawed boxes."""
    n = 8
    env = TrajectoryPlanningEnv(num_envs=n, collision_shape="box", collision_size=(0.08, 0.08), seed=9,
                                autoreset=False, device="cpu")
    assert env.sim.mover.collision_shape == "box"
    np.testing.assert_allclose(env.sim._half_np, 0.08)
    judged = 0
    for episode in range(3):
        env.reset(seed=int(rng.integers(1 << 30)))
        for _ in range(15):
            action = torch.from_numpy(rng.uniform(-10, 10, (n, 6)).astype(np.float32))
            obs, r, te, tr, info = env.step(action)
            pos, yaw = _np(env.sim.pos)[..., :2], _np(env.sim.yaw)
            mc, wc, amb = _collisions(env, pos, yaw)
            ok = ~amb
            judged += int(ok.sum())
            np.testing.assert_array_equal(_np(info["mover_collision"])[ok], mc[ok], err_msg=str(rng))
            np.testing.assert_array_equal(_np(info["wall_collision"])[ok], wc[ok], err_msg=str(rng))
            if (te | tr).all():
                break
            env.reset(options={"reset_mask": te | tr})
    assert judged > 0


def test_circle_size_and_offsets():
    env = TrajectoryPlanningEnv(num_envs=2, collision_size=0.09, collision_offset=0.01, collision_offset_wall=0.02,
                                safety_margin=0.005, seed=0, device="cpu")
    assert env.sim.mover.collision_radius == 0.09
    assert env.sim.mover.wall_margin == 0.02 and env.sim.mover.margin == 0.005
    goals = _np(env.goals).reshape(-1, 2)
    assert _valid_goal(env, goals).all()
    assert (goals >= 0.09 + 0.01 + 0.02 - 1e-6).all()


def test_jerk_mode_limits_acceleration(rng):
    env = TrajectoryPlanningEnv(num_envs=2, learn_jerk=True, seed=0, autoreset=False, device="cpu")
    assert env.single_action_space.high.max() == 100.0
    env.reset(seed=1)
    for _ in range(3):
        env.step(torch.full((2, 6), 100.0))
    acc = _np(env.sim.acc)
    assert np.linalg.norm(acc, axis=-1).max() <= 10.0 + 1e-4
    assert np.linalg.norm(acc, axis=-1).min() > 1.0


# ---------------------------------------------------------------------------------------------------- compute_reward
def test_compute_reward_batched_and_consistent_with_step(rng):
    n = 16
    env = TrajectoryPlanningEnv(num_envs=n, seed=10, device="cpu")
    env.reset(seed=int(rng.integers(1 << 30)))
    for _ in range(20):
        obs, r, te, tr, info = env.step(torch.from_numpy(rng.uniform(-10, 10, (n, 6)).astype(np.float32)))
        final = info["final_obs"]
        again = env.compute_reward(final["achieved_goal"], final["desired_goal"], info)
        torch.testing.assert_close(again, r, rtol=0, atol=0)
    # arbitrary leading shapes, with and without collision info, torch or numpy
    m2 = 2 * env.num_movers
    for lead in [(), (5,), (3, 4), (2, 3, 2)]:
        a = rng.uniform(0, 0.7, (*lead, m2)).astype(np.float32)
        d = a + rng.normal(0, 0.08, a.shape).astype(np.float32)
        col = rng.random(lead) < 0.3
        info = {"mover_collision": torch.from_numpy(np.asarray(col)), "wall_collision": torch.zeros(lead, dtype=torch.bool)}
        got = env.compute_reward(torch.from_numpy(a), torch.from_numpy(d), info)
        assert got.shape == lead
        dist = np.linalg.norm((a - d).reshape(*lead, -1, 2), axis=-1)
        k = (dist <= env.threshold_pos).sum(-1)
        ref = np.where(col, -20.0, np.where(k > 0, 20.0 * k, -1.0))
        np.testing.assert_allclose(_np(got), ref, err_msg=str(rng))
        none = env.compute_reward(a, d, None)
        np.testing.assert_allclose(_np(none), np.where(k > 0, 20.0 * k, -1.0))


# ---------------------------------------------------------------------------------------------------- bad inputs
def test_mover_params_set_the_simulated_body():
    # MagBotSim's published trajectory-planning run: a 113 mm mover of 0.63 kg (half sizes in mover_params)
    env = TrajectoryPlanningEnv(num_envs=2, seed=0, device="cpu",
                                mover_params={"size": [0.113 / 2, 0.113 / 2, 0.006], "mass": 0.63})
    assert env.sim.mover.size == pytest.approx((0.113, 0.113, 0.012)) and env.sim.mover.mass == 0.63
    assert env.sim.mover.collision_shape == "circle"  # the collision shape stays the env's own option
    bad = r"mover_params\['mass'\] must be one mass shared by every mover, got \[0.6, 0.7\]"
    with pytest.raises(LayoutError, match=bad):
        TrajectoryPlanningEnv(num_envs=1, device="cpu", mover_params={"mass": [0.6, 0.7]})


def test_bad_inputs_raise_clear_errors_without_state_change(rng):
    n = 3
    env = TrajectoryPlanningEnv(num_envs=n, seed=11, device="cpu")
    env.reset(seed=1)
    env.step(torch.zeros(n, 6))
    before = _state(env)
    good = torch.zeros(n, 6)
    nan = good.clone()
    nan[1, 3] = float("nan")
    inf = good.clone()
    inf[2, 0] = float("inf")
    cases = [
        (torch.zeros(n, 5), ValueError, r"\(3, 6\).*\(3, 5\)"),
        (torch.zeros(n + 1, 6), ValueError, r"\(4, 6\)"),
        (torch.zeros(n, 6, dtype=torch.int32), TypeError, "int32"),
        (nan, ValueError, r"non-finite.*\[1, 3\].*nan"),
        (inf, ValueError, r"non-finite.*\[2, 0\].*inf"),
        (torch.zeros(n, 6, device="meta"), ValueError, "meta"),
        ([[0.0] * 6] * n, TypeError, "list"),
    ]
    for action, exc, pattern in cases:
        with pytest.raises(exc, match=pattern):
            env.step(action)
        _assert_same_state(before, _state(env))
    for mask, pattern in [(torch.ones(n + 2, dtype=torch.bool), r"\(3,\).*\(5,\)"),
                          (torch.ones(n, dtype=torch.int64), "int64"),
                          (np.ones((n, 1), dtype=bool), r"\(3, 1\)")]:
        with pytest.raises(ValueError, match=pattern):
            env.reset(options={"reset_mask": mask})
        _assert_same_state(before, _state(env))
    # a numpy float64 action of the right shape is accepted
    env.step(np.zeros((n, 6)))


@pytest.mark.parametrize("kwargs, exc, pattern", [
    (dict(layout="B42"), LayoutError, "B42"),
    (dict(collision_shape="hexagon"), ValueError, "hexagon"),
    (dict(num_envs=0), ValueError, "num_envs"),
    (dict(layout=np.ones((2, 2)), num_movers=None), ValueError, "num_movers"),
    (dict(threshold_pos=-0.1), ValueError, "threshold_pos"),
    (dict(timeout_steps=0), ValueError, "timeout_steps"),
    (dict(max_episode_steps=0), ValueError, "max_episode_steps.*0"),
    (dict(max_episode_steps=2.5), ValueError, "max_episode_steps.*2.5"),
    (dict(max_episode_steps=True), ValueError, "max_episode_steps.*True"),
    (dict(num_cycles=0), ValueError, "num_cycles"),
    (dict(render_mode="human"), ValueError, "human"),
])
def test_bad_construction_arguments(kwargs, exc, pattern):
    with pytest.raises(exc, match=pattern):
        TrajectoryPlanningEnv(**{"device": "cpu", **kwargs})


@pytest.mark.parametrize("cut", [1, 5])
def test_episode_length_cut_truncates_resets_and_leaves_pending_goals_open(rng, cut):
    from magwarp.metrics import Metrics

    n, seed = 6, int(rng.integers(1 << 30))
    # a goal sampled within a tiny threshold of a resting mover has probability ~0: no goal is reached
    env = TrajectoryPlanningEnv(num_envs=n, seed=seed, device="cpu", timeout_steps=None, max_episode_steps=cut,
                                threshold_pos=1e-6)
    obs, _ = env.reset(seed=seed)
    # a goal drawn from the valid-point pool (the fallback where no uniform candidate was valid) can be a mover's own
    # start, also drawn from that pool: rare, but then it is reached at once (seed 489733446); reseed past it
    while bool((obs["desired_goal"] == obs["achieved_goal"]).reshape(n, -1, 2).all(-1).any()):
        seed += 1
        obs, _ = env.reset(seed=seed)
    metrics = Metrics(env)
    still = torch.zeros(n, 2 * env.num_movers)  # movers at rest never collide nor reach a goal (starts are clear)
    for step in range(1, 2 * cut + 1):
        start = env.sim.pos[..., :2].clone()
        obs, reward, terminated, truncated, info = env.step(still)
        cut_now = step % cut == 0
        assert not terminated.any() and not info["goals_reached"].any(), f"step {step} ({rng})"
        assert truncated.tolist() == [cut_now] * n, f"step {step} of a {cut}-step episode ({rng})"
        assert info["time_limit"].tolist() == [cut_now] * n, f"step {step}: the cut alone ended it ({rng})"
        np.testing.assert_array_equal(_np(info["final_obs"]["achieved_goal"]) if cut_now else _np(obs["achieved_goal"]),
                                      _np(start).reshape(n, -1), err_msg=f"the movers stood still ({rng})")
        assert env.num_steps.tolist() == [0 if cut_now else step % cut] * n
        if cut_now:  # autoreset: new starts
            assert not torch.equal(env.sim.pos[..., :2], start), f"no new starts after the cut ({rng})"
    # the pending goals were neither reached nor failed, and no benchmark episode ended
    summary = metrics.summary()
    assert metrics.t["goals_failed"].sum() == 0 and metrics.t["episodes"].sum() == 0
    assert summary["goals"].item() == 0


def test_timeout_still_fails_pending_goals_with_an_episode_length_cut(rng):
    from magwarp.metrics import Metrics

    n, seed = 4, int(rng.integers(1 << 30))
    env = TrajectoryPlanningEnv(num_envs=n, seed=seed, device="cpu", timeout_steps=2, max_episode_steps=50,
                                threshold_pos=1e-6)
    metrics = Metrics(env)
    env.reset(seed=seed)
    truncations = []
    for _ in range(4):  # steps_since_goal 0, 1, 2, 3: the fourth step times out (3 > 2)
        *_, truncated, info = env.step(torch.zeros(n, 2 * env.num_movers))
        truncations.append(truncated.tolist())
    assert truncations == [[False] * n] * 3 + [[True] * n], rng
    assert not info["time_limit"].any(), f"a timeout is not the episode-length cut ({rng})"
    assert metrics.t["goals_failed"].tolist() == [env.num_movers] * n
    assert metrics.t["episodes"].tolist() == [1] * n


# ---------------------------------------------------------------------------------------------------- gymnasium
@pytest.mark.parametrize("env_id", ["magwarp/TrajectoryPlanning-v0", "magwarp/TrajectoryPlanningB3-v0"])
def test_gymnasium_env_checker(env_id):
    from gymnasium.utils.env_checker import check_env

    env = gym.make(env_id)
    check_env(env.unwrapped, skip_render_check=True)
    env.close()


def test_observation_noise_is_seeded_and_of_the_given_size():
    env = TrajectoryPlanningEnv(256, "B0", std_noise=1e-3, device="cpu", seed=0)
    obs, _ = env.reset(seed=2)
    err = obs["achieved_goal"] - env.sim.pos[..., :2].reshape(256, -1)
    assert err.std().item() == pytest.approx(1e-3, rel=0.1)
    assert torch.equal(obs["achieved_goal"], env.reset(seed=2)[0]["achieved_goal"])
    with pytest.raises(ValueError, match="std_noise"):
        TrajectoryPlanningEnv(1, "B0", std_noise=float("nan"), device="cpu")


def test_replaced_generator_continues_the_draws_for_every_user():
    # After a failed CUDA graph capture the env swaps its generator (trajectory_fused's fallback): goals and starts
    # must move to the new one and continue the old stream exactly (the latency and sensor draws are counter-based).
    kw = dict(num_envs=4, seed=5, device="cpu", actuation={"latency_range": [0, 3]},
              sensors={"pos_noise_std": 0.001, "vel_bias_std": 0.01})
    a, b = TrajectoryPlanningEnv(**kw), TrajectoryPlanningEnv(**kw)
    a.reset(seed=5)
    b.reset(seed=5)
    gen = torch.Generator().manual_seed(1)
    actions = [torch.rand((4, 2 * a.num_movers), generator=gen) * 2 - 1 for _ in range(6)]
    for i, act in enumerate(actions):
        if i == 3:
            old = b._generator
            b._replace_generator()
            users = (b._generator, b.sampler.generator)
            assert all(u is b._generator for u in users) and b._generator is not old
        oa, ra, *_ = a.step(act)
        ob, rb, *_ = b.step(act)
        assert torch.equal(oa["observation"], ob["observation"]) and torch.equal(ra, rb), f"step {i}"
        assert torch.equal(a.goals, b.goals), f"step {i}"
