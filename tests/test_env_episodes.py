"""Chosen episodes through ``env.reset(seed=..., options={...})`` (trajectory planning and pushing), and per-mover
collision sizes in the trajectory env."""

from __future__ import annotations

import re

import numpy as np
import pytest
import torch

from magwarp.envs.trajectory import TrajectoryPlanningEnv

START = [[0.12, 0.12], [0.6, 0.12], [0.36, 0.6]]  # B0: 4 x 3 tiles (0.96 x 0.72 m), radius 0.11
GOALS = [[0.8, 0.5], [0.2, 0.5], [0.5, 0.3]]


@pytest.fixture(scope="module")
def env():
    return TrajectoryPlanningEnv(num_envs=3, layout="B0", device="cpu", seed=0)


def test_trajectory_reset_sets_the_chosen_episode(env):
    obs, _ = env.reset(seed=1, options={"start_xy": START, "goals": GOALS})
    np.testing.assert_allclose(env.sim.pos[..., :2].numpy(), np.broadcast_to(START, (3, 3, 2)), atol=1e-7)
    np.testing.assert_allclose(obs["desired_goal"].numpy(), np.broadcast_to(np.ravel(GOALS), (3, 6)), atol=1e-7)
    np.testing.assert_allclose(obs["achieved_goal"].numpy(), np.broadcast_to(np.ravel(START), (3, 6)), atol=1e-7)
    assert not env.sim.vel.any() and not env.sim.flags.any()
    # per env, one env only (the others keep their state), with headings
    per_env = torch.tensor(START).repeat(3, 1, 1)
    per_env[1, 0] = torch.tensor([0.15, 0.2])
    before = env.sim.pos.clone()
    yaw = torch.tensor([0.3, -0.2, 1.0])
    env.reset(options={"start_xy": per_env, "start_yaw": yaw, "reset_mask": torch.tensor([False, True, False])})
    np.testing.assert_allclose(env.sim.pos[1, 0, :2].numpy(), [0.15, 0.2], atol=1e-7)
    np.testing.assert_allclose(env.sim.yaw[1].numpy(), yaw.numpy(), atol=1e-6)
    assert torch.equal(env.sim.pos[[0, 2]], before[[0, 2]])
    # a later sampled reset starts level again and is collision free
    env.reset(seed=2)
    assert not env.sim.yaw.any() and not env.sim.flags.any()
    assert not torch.allclose(env.sim.pos[..., :2], torch.tensor(START).expand(3, 3, 2))


def test_trajectory_chosen_episode_replays_the_same_steps(env):
    acts = torch.rand(5, 3, 6, generator=torch.Generator().manual_seed(0)) * 4 - 2
    runs = []
    for _ in range(2):
        env.reset(seed=3, options={"start_xy": START, "goals": GOALS})
        runs.append(torch.stack([env.step(a)[0]["achieved_goal"] for a in acts]))
    assert torch.equal(runs[0], runs[1])


@pytest.mark.parametrize("options, match", [
    ({"start_xy": [[0.12, 0.12]]}, r"options\['start_xy'\] must have shape \(3, 2\) .* or \(3, 3, 2\)"),
    ({"start_xy": [[0.12, float("nan")], [0.6, 0.12], [0.36, 0.6]]},
     re.escape("options['start_xy'] contains a non-finite value at index [0, 0, 1]: nan")),
    ({"start_xy": [[0.05, 0.12], [0.6, 0.12], [0.36, 0.6]]},
     re.escape("options['start_xy'] puts mover 0 of env 0 at (0.05, 0.12), off the tiles")),
    ({"start_xy": [[0.12, 0.12], [0.3, 0.12], [0.36, 0.6]]},
     re.escape("options['start_xy'] puts movers 0 and 1 of env 0 in collision, at (0.12, 0.12) and (0.3, 0.12)")),
    ({"goals": [[0.8, 0.5], [0.9, 0.5], [0.5, 0.3]]},
     re.escape("options['goals'] puts the goal of mover 1 of env 0 at (0.9, 0.5), where the mover would be off")),
    ({"start_yaw": [0.0, 0.0, 0.0]}, "needs options\\['start_xy'\\]"),
])
def test_trajectory_bad_episode_names_the_value_and_changes_nothing(env, options, match):
    env.reset(seed=4)
    before = (env.sim.pos.clone(), env.goals.clone())
    with pytest.raises(ValueError, match=match):
        env.reset(options=options)
    assert torch.equal(env.sim.pos, before[0]) and torch.equal(env.goals, before[1])


def test_unknown_option_is_named_in_a_warning(env):
    with pytest.warns(UserWarning, match=r"unknown option\(s\) \['start'\]"):
        env.reset(options={"start": START})


def test_trajectory_per_mover_collision_sizes():
    radii = [0.05, 0.08, 0.11]
    env = TrajectoryPlanningEnv(num_envs=2, layout="B0", device="cpu", collision_size=radii, seed=0)
    np.testing.assert_allclose(env.sim.radii.numpy(), [radii, radii], atol=1e-7)  # per world
    # movers 0 and 1 are 0.14 m apart: free with radii 0.05 + 0.08, a collision with one radius of 0.11
    start = [[0.12, 0.3], [0.26, 0.3], [0.7, 0.4]]
    env.reset(options={"start_xy": start})
    env.step(torch.zeros(2, 6))
    assert not env.sim.flags_any.any()
    # the per-mover sizes decide: mover 2 (0.11) is too close to the wall where mover 0 (0.05) is not
    with pytest.raises(ValueError, match="mover 2 of env 0 at \\(0.08, 0.4\\)"):
        env.reset(options={"start_xy": [[0.12, 0.3], [0.26, 0.3], [0.08, 0.4]]})
    env.reset(options={"start_xy": [[0.06, 0.3], [0.26, 0.3], [0.7, 0.4]]})
    uniform = TrajectoryPlanningEnv(num_envs=1, layout="B0", device="cpu", collision_size=0.11, seed=0)
    with pytest.raises(ValueError, match="movers 0 and 1 of env 0 in collision"):
        uniform.reset(options={"start_xy": start})
    box = TrajectoryPlanningEnv(num_envs=1, layout="B0", device="cpu", collision_shape="box",
                                collision_size=[[0.05, 0.05], [0.08, 0.06], [0.07, 0.07]], seed=0)
    np.testing.assert_allclose(box.sim.half_sizes.numpy()[0], [[0.05, 0.05], [0.08, 0.06], [0.07, 0.07]], atol=1e-7)
    with pytest.raises(ValueError, match=r"collision_size for a circle .* got \[0.1, 0.1\]"):
        TrajectoryPlanningEnv(num_envs=1, layout="B0", device="cpu", collision_size=[0.1, 0.1])


# ---------------------------------------------------------------------------------------------- pushing
@pytest.fixture(scope="module")
def push_env():
    from magwarp.envs.push import PushTEnv

    return PushTEnv(2, device="cpu", seed=0, layout=np.ones((4, 4)))


def test_push_reset_sets_mover_object_and_goal(push_env):
    env = push_env
    opts = {"mover_xy": [[0.2, 0.2]], "object_xy": [0.5, 0.5], "object_yaw": 0.7, "goal_xy": [0.7, 0.3],
            "goal_yaw": -1.2}
    obs, _ = env.reset(seed=0, options=opts)
    b = env.backend
    np.testing.assert_allclose(b.mover_qpos[..., :2].cpu().numpy(), [[[0.2, 0.2]], [[0.2, 0.2]]], atol=1e-6)
    obj = b.object_qpos[:, 0]
    np.testing.assert_allclose(obj[:, :2].cpu().numpy(), [[0.5, 0.5]] * 2, atol=1e-6)
    yaw = torch.atan2(2 * obj[:, 3] * obj[:, 6], 1 - 2 * obj[:, 6] ** 2)
    np.testing.assert_allclose(yaw.cpu().numpy(), [0.7, 0.7], atol=1e-5)
    np.testing.assert_allclose(env.goal_xy.cpu().numpy(), [[0.7, 0.3]] * 2, atol=1e-7)
    np.testing.assert_allclose(env.goal_yaw.cpu().numpy(), [-1.2, -1.2], atol=1e-7)
    # per env, one env reset
    env.reset(options={"goal_xy": torch.tensor([[0.3, 0.3], [0.6, 0.7]]), "reset_mask": torch.tensor([False, True])})
    np.testing.assert_allclose(env.goal_xy.cpu().numpy(), [[0.7, 0.3], [0.6, 0.7]], atol=1e-7)


@pytest.mark.parametrize("options, match", [
    ({"mover_xy": [[0.05, 0.2]], "object_xy": [0.5, 0.5]}, "options\\['mover_xy'\\] puts mover 0 of env 0 at "
                                                             "\\(0.05, 0.2\\), off the tiles"),
    ({"mover_xy": [[0.5, 0.45]], "object_xy": [0.5, 0.5]}, "the object of env 0 at \\(0.5, 0.5\\) \\(yaw sampled\\) "
                                                             "under mover 0"),
    ({"mover_xy": [[0.2, 0.2]], "object_xy": [0.5, 0.5], "object_yaw": float("inf")},
     "options\\['object_yaw'\\] contains a non-finite value at index \\[0\\]: inf"),
    ({"goal_xy": [0.95, 0.5]}, "options\\['goal_xy'\\] puts the object of env 0 at \\(0.95, 0.5\\), off the tiles"),
    ({"object_xy": [0.5, 0.5]}, "go together"),
    ({"goal_xy": [[0.5, 0.5]]}, "options\\['goal_xy'\\] must have shape \\(2,\\)"),
])
def test_push_bad_episode_names_the_value_and_changes_nothing(push_env, options, match):
    env = push_env
    env.reset(seed=5)
    before = (env.backend.mover_qpos.clone(), env.backend.object_qpos.clone(), env.goal_xy.clone())
    with pytest.raises(ValueError, match=match):
        env.reset(options=options)
    assert torch.equal(env.backend.mover_qpos, before[0]) and torch.equal(env.backend.object_qpos, before[1])
    assert torch.equal(env.goal_xy, before[2])


def test_push_with_obstacles_keeps_chosen_poses_clear_of_the_walls():
    from magwarp.envs.push_obstacles import PushWithObstaclesEnv

    env = PushWithObstaclesEnv(1, device="cpu", seed=0)  # simple walls at x = 0.48, y in [0, 0.2] and [0.52, 0.72]
    env.reset(options={"mover_xy": [[0.2, 0.36]], "object_xy": [0.33, 0.36], "goal_xy": [0.7, 0.36]})
    np.testing.assert_allclose(env.goal_xy.cpu().numpy(), [[0.7, 0.36]], atol=1e-7)
    with pytest.raises(ValueError, match=re.escape("options['goal_xy'] puts the object of env 0 at (0.48, 0.1), into "
                                                   "obstacle 0")):
        env.reset(options={"goal_xy": [0.48, 0.1]})
    with pytest.raises(ValueError, match=re.escape("options['mover_xy'] puts mover 0 of env 0 at (0.5, 0.58), into "
                                                   "obstacle 1")):
        env.reset(options={"mover_xy": [[0.5, 0.58]], "object_xy": [0.3, 0.36]})
