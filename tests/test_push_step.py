"""The push env step: the fused step (task work after the physics in one body; one CUDA graph on GPUs) gives the base
class's eager step bit for bit, and the 2 ms physics step (``physics_dt=0.002``) keeps trajectories near the 1 ms
default. Small CPU worlds; the CUDA comparison runs where a GPU is present."""

from __future__ import annotations

import math

import pytest
import torch
import warp as wp

from magwarp.envs.base import MagwarpVecEnv
from magwarp.envs.push import PushBoxEnv, _yaw_from_quat
from magwarp.envs.push_obstacles import PushWithObstaclesEnv
from magwarp.physics.backend import PHYSICS_DT_MAX, PHYSICS_DT_MIN, PhysicsInputError, physics_substeps
from magwarp.policies.push import PushHeuristic

# Measured (CPU, scripted Push-Box actions replayed open-loop, 8 worlds, 1 s = 25 env steps): the 2 ms mode stays
# within 7.3 mm (mover x/y), 7.8 mm (box x/y) and 0.055 rad (box yaw) of the 1 ms default; Push-T within 7.1 mm,
# 11.5 mm and 0.17 rad. The mover's offset is the semi-implicit Euler term a t dt / 2 of its commanded motion.
MOVER_TOL_M, OBJECT_TOL_M, OBJECT_YAW_TOL = 0.01, 0.015, 0.1


def _leaves(out, prefix=""):
    if isinstance(out, dict):
        for k, v in out.items():
            yield from _leaves(v, f"{prefix}/{k}")
    elif isinstance(out, (tuple, list)):
        for i, v in enumerate(out):
            yield from _leaves(v, f"{prefix}/{i}")
    else:
        yield prefix, out


def _assert_same(a, b, step):
    la, lb = dict(_leaves(a)), dict(_leaves(b))
    assert la.keys() == lb.keys(), la.keys() ^ lb.keys()
    for k, v in la.items():
        if isinstance(v, torch.Tensor):
            assert v.dtype == lb[k].dtype and torch.equal(v, lb[k]), f"step {step}, {k}: {v} != {lb[k]}"


def _random_actions(env, steps, seed=0):
    g = torch.Generator(device=env.device).manual_seed(seed)
    space = env.single_action_space
    lo, hi = (torch.as_tensor(v, device=env.device) for v in (space.low, space.high))
    return [lo + (hi - lo) * torch.rand((env.num_envs, *space.shape), generator=g, device=env.device)
            for _ in range(steps)]


def _compare(make, step_b, steps=30, reseed_at=None, check_flags=True):
    """Steps two equally seeded envs with the same random actions: ``env.step`` against ``step_b(env, action)``
    (both reset with a new seed at step ``reseed_at``); returns how many episodes ended (autoresets) on the way."""
    a, b = make(), make()
    ended = 0
    for i, act in enumerate(_random_actions(a, steps)):
        if i == reseed_at:
            _assert_same(a.reset(seed=9), b.reset(seed=9), i)
        out_a, out_b = a.step(act), step_b(b, act)
        _assert_same(out_a, out_b, i)
        ended += int(out_a[4]["_final_obs"].sum())
    if not check_flags:
        return ended
    # the per-step flags are cleared inside the physics graph: stale bits are gone after a step at rest
    a.reset(seed=5)
    flags = [a.checks.flags_t] + ([a.contacts.flags_t] if a.contacts is not None else [])
    for f in flags:
        f.fill_(3)
    a.step(torch.zeros((a.num_envs, *a.single_action_space.shape), device=a.device))
    assert all(int(f.abs().sum()) == 0 for f in flags), flags
    return ended


@pytest.mark.parametrize("make", [
    lambda: PushBoxEnv(3, device="cpu", seed=1, std_noise=1e-3, object_noise=1e-3),
    lambda: PushWithObstaclesEnv(3, device="cpu", seed=2, obstacle_mode="curriculum", curriculum_episodes=1),
], ids=["PushBox", "PushWithObstacles"])
def test_fused_step_equals_the_base_class_step_on_cpu(make):
    # 30 steps: the 25-step episodes truncate, random actions collide, so autoresets run inside the compared steps
    ended = _compare(make, MagwarpVecEnv.step)
    assert ended >= 3


@pytest.mark.skipif(not wp.is_cuda_available() or not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_cuda_graph_step_equals_eager_step():
    from mujoco_warp._src.io import override_model  # mujoco-warp 4.0 does not export it

    def make():
        env = PushWithObstaclesEnv(64, device="cuda:0", seed=3, obstacle_mode="random", std_noise=1e-3)
        # mujoco-warp's GPU contacts are not bitwise reproducible run to run, even with opt.deterministic (measured on
        # an H100: two eager envs' qpos differ by 5e-9 after 2 steps, 7e-6 after 5): the physics is frozen (no
        # mujoco-warp step), so what is compared is the task work, graphed or eager (observations with noise draws,
        # rewards, truncations, autoresets with the backend's reset kernels inside the graph, a reseed)
        override_model(env.backend.model, {"opt.deterministic": True})
        env.backend._step_graph = None
        env._step_backend = lambda action: None
        return env

    def eager(env, act):
        env.use_step_graph = False
        return env.step(act)

    with torch.no_grad():
        # a reseed mid-way: the graph reads the new seed
        ended = _compare(make, eager, steps=40, reseed_at=30, check_flags=False)
    assert ended >= 64  # the 25-step episodes truncate inside the compared steps
    env = make()
    env.step(_random_actions(env, 1)[0])
    env.step(_random_actions(env, 1)[0])
    assert env._task_graph is not None and env._task_graph.graph is not None and not env._task_graph.failed


def test_physics_dt_substeps_and_refusals():
    assert physics_substeps(0.001, 40) == 40 and physics_substeps(0.002, 40) == 20
    assert physics_substeps(0.002, 160) == 80 and physics_substeps(PHYSICS_DT_MAX, 40) == 8
    assert physics_substeps(PHYSICS_DT_MIN, 40) == 400
    for bad, words in ((0.003, "does not divide"), (0.0015, "does not divide"), (0.0, "positive"), (-0.001, "positive"),
                       (math.nan, "finite"), (math.inf, "finite"), (0.01, "above 0.005"), (True, "number"),
                       ("0.002", "number"), (None, "number"), (1e-300, "below 0.0001"), (5e-5, "below 0.0001")):
        with pytest.raises(PhysicsInputError, match=words):
            physics_substeps(bad, 40)
    with pytest.raises(ValueError, match="physics_dt=0.004 s does not divide the env step of 50 control cycles"):
        PushBoxEnv(1, device="cpu", num_cycles=50, physics_dt=0.004)


def test_two_ms_physics_keeps_trajectories_of_one_ms():
    kw = dict(device="cpu", seed=3, autoreset=False, max_episode_steps=1000)
    fine, fast = PushBoxEnv(4, physics_dt=0.001, **kw), PushBoxEnv(4, physics_dt=0.002, **kw)
    assert (fine.substeps, fast.substeps, fast.backend.dt, fast.backend.control.num_cycles) == (40, 20, 0.002, 20)
    policy = PushHeuristic(fine)
    obs, _ = fine.reset(seed=3)
    fast.reset(seed=3)
    start = fine.backend.object_qpos[:, 0, :2].clone()
    worst = torch.zeros(3)
    for _ in range(25):  # 1 s of the same actions (chosen on the 1 ms env, replayed open-loop)
        action = policy(obs)
        obs, *_ = fine.step(action)
        fast.step(action)
        a, b = fine.backend, fast.backend
        mover = (a.mover_qpos[..., :2] - b.mover_qpos[..., :2]).norm(dim=-1).max()
        obj = (a.object_qpos[..., :2] - b.object_qpos[..., :2]).norm(dim=-1).max()
        dyaw = (_yaw_from_quat(a.object_qpos[:, 0, 3:]) - _yaw_from_quat(b.object_qpos[:, 0, 3:])).abs()
        dyaw = torch.minimum(dyaw, 2 * math.pi - dyaw).max()
        worst = torch.maximum(worst, torch.stack([mover, obj, dyaw]))
    pushed = (fine.backend.object_qpos[:, 0, :2] - start).norm(dim=-1)
    assert pushed.max() > 0.05, pushed  # the box was pushed: the comparison covers contact
    assert worst[0] <= MOVER_TOL_M and worst[1] <= OBJECT_TOL_M and worst[2] <= OBJECT_YAW_TOL, worst
    assert worst[0] > 0  # the two modes do differ (the option reached the physics)


def test_time_to_success_freezes_after_the_same_time_at_two_ms():
    # MagBotSim freezes time to success once the object stays 150 cycles (0.15 s) at the goal; at 2 ms that is 75
    env = PushBoxEnv(1, device="cpu", seed=0, num_cycles=2, physics_dt=0.002, max_episode_steps=1000)
    env.reset()
    assert env.substeps == 1 and env.metrics._streak_max == 75
    obj = env.backend.object_qpos[:, 0, :2].clone()
    at_goal = torch.zeros(140, dtype=torch.bool)
    at_goal[10:90] = True  # 80 steps (0.16 s) at the goal: frozen after 75
    at_goal[120:130] = True  # a later streak must not restart the clock
    for t in range(140):
        env.goal_xy.copy_(obj + torch.tensor([[0.02 if at_goal[t] else 0.2, 0.0]]))
        env.step(torch.zeros(1, 2))
    assert env.metrics.t["time_to_success"].item() == pytest.approx(11 * 0.002)  # the streak began at step 11
    assert env.metrics.t["streak"].item() == 75


@pytest.mark.skipif(not wp.is_cuda_available() or not torch.cuda.is_available(), reason="needs a CUDA GPU")
def test_push_t_step_is_recorded_as_a_graph():
    """Push-T's task work launches the coverage kernel on torch's stream: the capture must end on a registered stream
    (a temporary ``wp.stream_from_torch`` wrapper, once collected, unregistered it: "unknown capture stream")."""
    import warnings

    from magwarp._streams import torch_stream
    from magwarp.envs.push import PushTEnv

    assert torch_stream("cuda:0") is torch_stream("cuda:0")
    env = PushTEnv(8, device="cuda:0", seed=0)
    env.reset(seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        for act in _random_actions(env, 3):
            env.step(act)
    assert env._task_graph is not None and env._task_graph.graph is not None and not env._task_graph.failed


def test_task_graph_outputs_are_fresh_copies_and_cuda_only():
    from magwarp.envs.step_graph import TaskGraph, clone_outputs

    out = ({"a": torch.arange(3)}, torch.ones(2), [torch.zeros(1)], 5)
    copy = clone_outputs(out)
    assert copy[3] == 5 and isinstance(copy[2], list)
    for x, y in ((out[0]["a"], copy[0]["a"]), (out[1], copy[1]), (out[2][0], copy[2][0])):
        assert torch.equal(x, y) and x.data_ptr() != y.data_ptr()
    with pytest.raises(ValueError, match="not a CUDA device"):
        TaskGraph(lambda: None, torch.device("cpu"))
