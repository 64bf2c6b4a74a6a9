"""Batched pushing envs: gymnasium check_env, MagBotSim's start/goal definitions, rewards, terminations."""

import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env

from magwarp.envs.push import PushBoxEnv, PushEnv, PushLEnv, PushTEnv, PushXEnv
from magwarp.envs.push_obstacles import PushWithObstaclesEnv
from magwarp.envs.single import SingleEnv

ALL = [PushBoxEnv, PushTEnv, PushLEnv, PushXEnv, PushWithObstaclesEnv]


@pytest.mark.parametrize("cls", ALL)
def test_check_env_single_view(cls):
    env = SingleEnv(cls, device="cpu", seed=0)
    check_env(env, skip_render_check=True)
    obs, _ = env.reset(seed=1)
    assert env.observation_space.contains(obs)


def test_spaces_match_magbotsim_layout_of_observations():
    box = PushBoxEnv(2, device="cpu", seed=0)
    assert box.single_observation_space["observation"].shape == (4,)
    assert box.single_observation_space["desired_goal"].shape == (2,)
    assert box.single_action_space.shape == (2,) and box.single_action_space.high[0] == 10.0
    t = PushTEnv(2, device="cpu", seed=0, learn_jerk=True, num_movers=2, layout=np.ones((5, 4)))
    assert t.single_observation_space["observation"].shape == (12,)  # pos, vel, acc of 2 movers
    assert t.single_observation_space["achieved_goal"].shape == (4,)  # x, y, sin, cos
    assert t.single_action_space.high[0] == 100.0
    assert t.max_episode_steps == 50 and box.max_episode_steps == 25
    obs = PushWithObstaclesEnv(1, device="cpu", seed=0)._get_obs()["observation"]
    np.testing.assert_allclose(obs[0, 4:12].numpy(), [0.51, 0.2, 0.51, 0.0, 0.45, 0.0, 0.45, 0.2], atol=1e-6)


def test_reset_sampling_follows_magbotsim_definition(rng):
    env = PushBoxEnv(128, device="cpu", seed=int(rng.integers(1 << 30)))
    # 4 x 3 tiles, circle 0.11: margin 0.14; mover range [0.14, 0.76] x [0.14, 0.52]; object/goal [0.30, 0.60] x [0.30, 0.36]
    np.testing.assert_allclose(env.min_xy, [0.14, 0.14])
    np.testing.assert_allclose(env.max_xy, [0.76, 0.52])
    np.testing.assert_allclose(env.object_min_xy, [0.30, 0.30])
    np.testing.assert_allclose(env.object_max_xy, [0.60, 0.36])
    assert env.min_mover_object_dist == pytest.approx(np.hypot(0.1375, 0.1375))
    for _ in range(2):
        obs, _ = env.reset()
        mover = obs["observation"][:, :2]
        obj, goal = obs["achieved_goal"], obs["desired_goal"]
        assert torch.all(mover >= 0.14 - 1e-6) and torch.all(mover <= torch.tensor([0.76, 0.52]) + 1e-6), rng
        assert torch.all(obj >= 0.30 - 1e-4) and torch.all(obj <= torch.tensor([0.60, 0.36]) + 1e-4), rng
        assert torch.all((mover - obj).norm(dim=1) > env.min_mover_object_dist - 1e-4), rng
        assert torch.all((obj - goal).norm(dim=1) > 0.15), rng
        yaw = 2 * torch.atan2(env.backend.object_qpos[:, 0, 6], env.backend.object_qpos[:, 0, 3])
        assert yaw.std() > 1.0  # uniform start yaw in (-pi, pi)
        assert torch.all(obs["observation"][:, 2:] == 0)


def test_mover_params_set_the_body_and_magbotsim_sampling_distances(rng):
    # MagBotSim's published Push-Box run: 3 x 3 tiles, a 113 mm mover of 0.639 kg with its own square as the
    # collision box. MagBotSim: min_mover_object_dist = |object half side (0.06 m) + mover half size| (both axes).
    import mujoco

    box = [0.113 / 2 + 1e-6] * 2
    env = PushBoxEnv(64, layout=np.ones((3, 3)), collision_shape="box", collision_size=box,
                     mover_params={"size": [0.113 / 2, 0.113 / 2, 0.006], "mass": 0.639}, device="cpu",
                     seed=int(rng.integers(1 << 30)))
    m = env.backend.mjm
    geom = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "mover_geom_0")
    np.testing.assert_allclose(m.geom_size[geom], [0.0565, 0.0565, 0.006])
    assert m.body_mass[m.geom_bodyid[geom]] == pytest.approx(0.639)
    assert env.min_mover_object_dist == pytest.approx(np.hypot(0.06 + 0.0565, 0.06 + 0.0565))
    # margin: box half size + 0.03; the range ends half a tile half size past the outer tile centres (0.60 m)
    np.testing.assert_allclose(env.min_xy, [0.0865 + 1e-6] * 2, atol=1e-9)
    np.testing.assert_allclose(env.max_xy, [0.66 - 0.0865 - 1e-6] * 2, atol=1e-9)
    obs, _ = env.reset()
    mover, obj = obs["observation"][:, :2], obs["achieved_goal"]
    assert torch.all((mover - obj).norm(dim=1) > env.min_mover_object_dist - 1e-4), rng
    with pytest.raises(ValueError, match="'sphere'"):
        PushBoxEnv(1, mover_params={"shape": "sphere"}, device="cpu")


def test_layout_with_holes_samples_on_tiles(rng):
    tiles = np.array([[1, 1, 1, 1], [1, 1, 0, 1], [1, 1, 1, 1], [1, 1, 1, 1], [0, 1, 1, 1]])
    env = PushTEnv(64, layout=tiles, device="cpu", seed=int(rng.integers(1 << 30)))
    obs, _ = env.reset()
    for key in ("achieved_goal", "desired_goal"):
        cells = torch.floor(obs[key][:, :2] / 0.24).long()
        assert torch.all(torch.as_tensor(tiles)[cells[:, 0], cells[:, 1]] == 1), rng
    # mover footprints (circle 0.11) clear of holes and the border
    assert not env.checks.wall_collision.any()
    mover = obs["observation"][:, :2]
    assert env._on_tiles(mover, 0.11).all(), rng


def _place(env: PushEnv, mover_xy, object_xy, goal_xy, object_yaw=0.0, goal_yaw=0.0):
    """Put world 0 into a chosen configuration (test helper; the env's own reset samples these)."""
    b = env.backend
    b.init_mover_qpos[0, 0, :2] = torch.tensor(mover_xy)
    b.init_object_qpos[0, 0, :2] = torch.tensor(object_xy)
    b.init_object_qpos[0, 0, 3] = float(np.cos(object_yaw / 2))
    b.init_object_qpos[0, 0, 6] = float(np.sin(object_yaw / 2))
    mask = torch.zeros(env.num_envs, dtype=torch.bool)
    mask[0] = True
    b.reset(mask)
    env.goal_xy[0] = torch.tensor(goal_xy)
    env.goal_yaw[0] = goal_yaw
    env.num_steps[0] = 0


def test_push_box_to_goal_gives_success_and_reward():
    env = PushBoxEnv(1, device="cpu", seed=0, object_sliding_friction=0.3)
    env.reset()
    # mover just behind the box, goal 6 cm ahead: accelerate, then brake, pushing the box there
    _place(env, (0.20, 0.30), (0.34, 0.30), (0.40, 0.30))
    success = False
    for k in range(12):
        a = torch.tensor([[4.0, 0.0]]) if k < 2 else torch.tensor([[-1.5, 0.0]])
        obs, reward, term, trunc, info = env.step(a)
        if info["is_success"][0]:
            success = True
            assert reward[0] == 1.0 and not term[0]
            assert (obs["achieved_goal"][0] - obs["desired_goal"][0]).norm() <= 0.05
            break
        assert reward[0] == pytest.approx(-0.01)
    assert success, f"box ended at {obs['achieved_goal'][0].tolist()}"


def test_wall_collision_terminates_with_penalty_and_autoresets():
    env = PushBoxEnv(2, device="cpu", seed=0)
    env.reset()
    _place(env, (0.20, 0.30), (0.60, 0.30), (0.50, 0.30))
    for k in range(10):
        a = torch.tensor([[-10.0, 0.0], [0.0, 0.0]])
        obs, reward, term, trunc, info = env.step(a)
        if term[0]:
            break
    assert term[0] and info["wall_collision"][0] and reward[0] == -10.0
    assert not term[1] and reward[1] == pytest.approx(-0.01)
    # autoreset: the final observation shows the mover at the wall, the returned one a fresh start
    assert info["final_obs"]["observation"][0, 0] < 0.11 + 1e-3
    assert obs["observation"][0, 0] >= 0.14 - 1e-6 and env.num_steps[0] == 0


def test_truncation_after_max_episode_steps():
    env = PushTEnv(1, device="cpu", seed=0, max_episode_steps=3)
    env.reset()
    flags = [env.step(torch.zeros(1, 2))[3][0].item() for _ in range(4)]
    assert flags == [False, False, True, False]


def test_pose_reward_dense_sparse_and_threshold():
    env = PushTEnv(1, device="cpu", seed=0)
    goal = torch.tensor([[0.4, 0.3, 0.0, 1.0]])
    same = goal.clone()
    shifted = torch.tensor([[0.4, 0.3 + 0.01, 0.0, 1.0]])  # T: 6 x 12 cm outline; 1 cm shift keeps most of it
    far = torch.tensor([[0.9, 0.9, 0.0, 1.0]])
    batch_a, batch_g = torch.cat([same, shifted, far]), goal.expand(3, 4)
    cov = env.goal_reached(batch_a, batch_g)[1]
    assert cov[0] == pytest.approx(1.0, abs=1e-6) and 0.7 < cov[1] < 1.0 and cov[2] == 0
    torch.testing.assert_close(env.compute_reward(batch_a, batch_g, None), torch.tensor([cov[0], cov[1], -0.01]))
    info = {"mover_collision": torch.tensor([True, False, False]), "wall_collision": torch.tensor([False, False, True])}
    assert env.compute_reward(batch_a, batch_g, info).tolist() == pytest.approx([-10.0, float(cov[1]), -10.0])
    sparse = PushTEnv(1, device="cpu", seed=0, use_sparse_pose_reward=True, min_coverage=0.95)
    assert sparse.compute_reward(batch_a, batch_g, None).tolist() == pytest.approx([1.0, -0.01 if cov[1] < 0.95 else 1.0, -0.01])


def test_obstacle_contact_penalty_and_termination():
    env = PushWithObstaclesEnv(1, device="cpu", seed=0)
    env.reset()
    # mover in front of the lower obstacle (x = 0.45 .. 0.51, y <= 0.2), driven into it
    _place(env, (0.30, 0.14), (0.20, 0.40), (0.70, 0.40))
    for _ in range(10):
        obs, reward, term, trunc, info = env.step(torch.tensor([[10.0, 0.0]]))
        if term[0]:
            break
    assert term[0] and info["obstacle_mover_collision"][0] and reward[0] == -50.0
    assert not info["wall_collision"][0]


def test_curriculum_walls_differ_per_world_in_observation_and_physics():
    # curriculum_episodes=1: every masked reset after the first moves that world up a level (simple -> medium -> hard)
    env = PushWithObstaclesEnv(2, device="cpu", seed=0, obstacle_mode="curriculum", curriculum_episodes=1)
    env.reset()
    only_1 = torch.tensor([False, True])
    for _ in range(2):
        env.reset(options={"reset_mask": only_1})
    assert env.curriculum_level.tolist() == [0, 2]
    half = env.obstacle_boxes[:, 0, 3]
    assert torch.allclose(half, torch.tensor([0.10, 0.13]))
    verts = env._get_obs()["observation"][:, -16:].reshape(2, 2, 4, 2)
    assert torch.allclose(verts[:, 0, 0, 1], 2 * half) and torch.allclose(verts[:, 1, 2, 1], 0.72 - 2 * half)
    # a mover whose footprint starts at y = 0.2125 clears the simple wall (top at 0.2) but not the hard one (0.26)
    b = env.backend
    b.init_mover_qpos[:, 0, :2] = torch.tensor([0.30, 0.29])
    b.init_object_qpos[:, 0, :2] = torch.tensor([0.15, 0.55])
    b.reset(torch.ones(2, dtype=torch.bool))
    hit = torch.zeros(2, dtype=torch.bool)
    for _ in range(6):
        _, _, term, _, info = env.step(torch.tensor([[10.0, 0.0], [10.0, 0.0]]))
        hit |= info["obstacle_mover_collision"]
        if term.any():
            break
    assert hit.tolist() == [False, True]


def test_random_walls_are_drawn_per_world_within_magbotsim_range():
    env = PushWithObstaclesEnv(64, device="cpu", seed=1, obstacle_mode="random")
    half = env.obstacle_boxes[:, 0, 3]
    assert half.min() >= 0.1 and half.max() <= 0.13 and half.std() > 0.005
    assert torch.allclose(env.obstacle_boxes[:, 1, 1], 0.72 - half)
    sizes = env.backend.batched_fields["geom_size"][:, env._wall_geoms, 1]
    assert torch.allclose(sizes, env.obstacle_boxes[:, :, 3])


def test_mixed_walls_draw_each_mode_at_its_weight_per_world_and_reset():
    env = PushWithObstaclesEnv(512, device="cpu", seed=3, obstacle_mode={"random": 1, "hard": 1, "simple": 2})
    halves = []
    for _ in range(4):
        env.reset()
        half = env.obstacle_boxes[:, 0, 3].clone()
        assert half.min() >= 0.1 - 1e-7 and half.max() <= 0.13 + 1e-7
        sizes = env.backend.batched_fields["geom_size"][:, env._wall_geoms, 1]
        assert torch.allclose(sizes, env.obstacle_boxes[:, :, 3])
        halves.append(half)
    half = torch.cat(halves)
    hard, simple = (half == 0.13).float().mean(), (half == 0.1).float().mean()
    between = ((half > 0.1) & (half < 0.13)).float().mean()  # the random draws (a uniform one hits an end never)
    # weights 1:1:2 over 2048 draws: 0.25, 0.25, 0.5, each within 4 standard deviations (about 0.04)
    assert abs(hard - 0.25) < 0.04 and abs(between - 0.25) < 0.04 and abs(simple - 0.5) < 0.045
    assert not torch.equal(halves[0], halves[1])  # redrawn at every reset
    only_hard = PushWithObstaclesEnv(4, device="cpu", seed=0, obstacle_mode={"hard": 1.0, "medium": 0})
    only_hard.reset()
    assert torch.allclose(only_hard.obstacle_boxes[:, 0, 3], torch.full((4,), 0.13))
    assert only_hard.obstacle_mode == {"hard": 1.0, "medium": 0}


@pytest.mark.parametrize("mix, message", [
    ({"curriculum": 1}, "draws from"), ({}, "draws from"), ({"hard": -1}, r"obstacle_mode\['hard'\] must be a finite"),
    ({"hard": float("nan")}, "finite"), ({"hard": "x"}, "must be a number, got 'x'"), ({"hard": 0}, "positive weight")])
def test_bad_wall_mix_names_the_value(mix, message):
    with pytest.raises(ValueError, match=message):
        PushWithObstaclesEnv(1, device="cpu", obstacle_mode=mix)


@pytest.mark.parametrize("jerk", [False, True])
def test_yaw_actions_turn_the_mover_within_limits(jerk):
    env = PushBoxEnv(2, device="cpu", seed=0, learn_mover_c_rotation=True, learn_jerk=jerk, p_max_c=1.0)
    assert env.single_action_space.shape == (3,) and env.single_observation_space["observation"].shape == (10 if jerk else 7,)
    assert env.single_action_space.high[2] == pytest.approx(610.86524 if jerk else 122.17305)
    check_env(SingleEnv(PushBoxEnv, device="cpu", seed=0, learn_mover_c_rotation=True), skip_render_check=True)
    obs, _ = env.reset(seed=0)
    a = torch.zeros(2, 3)
    a[:, 2] = torch.tensor([1.0, -1.0]) * float(env.single_action_space.high[2])
    for _ in range(8):
        obs, *_ = env.step(a)
    sin_yaw, cos_yaw = obs["observation"][:, 2], obs["observation"][:, 3]
    yaw = torch.atan2(sin_yaw, cos_yaw)
    assert yaw[0] > 0.5 and yaw[1] < -0.5 and yaw.abs().max() <= 1.0 + 1e-3  # turned both ways, stopped at p_max_c
    assert torch.allclose(sin_yaw ** 2 + cos_yaw ** 2, torch.ones(2), atol=1e-5)
    with pytest.raises(ValueError, match="shape"):
        env.step(torch.zeros(2, 2))


def test_success_gated_curriculum_holds_worlds_that_do_not_succeed():
    # world 0 ends every episode with its box on the goal, world 1 never does: with a gate at 0.6 over a running
    # rate of about 2 episodes, world 0 moves up once its rate passes 0.6 (restarted at each level), world 1 stays
    env = PushWithObstaclesEnv(2, device="cpu", seed=0, obstacle_mode="curriculum", curriculum_episodes=2,
                               curriculum_success_rate=0.6)
    env.reset()
    b, both, levels = env.backend, torch.ones(2, dtype=torch.bool), []
    for _ in range(6):
        b.init_object_qpos[0, 0, :2] = env.goal_xy[0]  # world 0: the box starts on its goal
        b.reset(both)
        _, _, term, _, info = env.step(torch.zeros(2, 2))
        assert info["is_success"].tolist() == [True, False] and not term.any()
        env.reset(options={"reset_mask": both})
        levels.append(env.curriculum_level.tolist())
    # rate of world 0 after each episode at a level: 0.5, 0.75 (>= 0.6: up, restart) ...
    assert levels == [[0, 0], [1, 0], [1, 0], [2, 0], [2, 0], [2, 0]]
    assert env.curriculum_success[1] == 0.0 and torch.allclose(env.obstacle_boxes[:, 0, 3], torch.tensor([0.13, 0.10]))
    fixed = PushWithObstaclesEnv(2, device="cpu", seed=0, obstacle_mode="curriculum", curriculum_episodes=2)
    for _ in range(3):
        fixed.reset()
    assert fixed.curriculum_level.tolist() == [1, 1]  # MagBotSim's schedule: no gate


def test_bad_arguments_name_the_value():
    with pytest.raises(ValueError, match="min_coverage"):
        PushTEnv(1, device="cpu", min_coverage=1.5)
    with pytest.raises(ValueError, match="obstacle_mode"):
        PushWithObstaclesEnv(1, device="cpu", obstacle_mode="nightmare")
    with pytest.raises(ValueError, match="curriculum_episodes"):
        PushWithObstaclesEnv(1, device="cpu", obstacle_mode="curriculum", curriculum_episodes=0)
    with pytest.raises(ValueError, match=r"curriculum_success_rate must lie in \[0, 1\], got 1.5"):
        PushWithObstaclesEnv(1, device="cpu", obstacle_mode="curriculum", curriculum_success_rate=1.5)
    with pytest.raises(ValueError, match="curriculum_success_rate needs obstacle_mode='curriculum', got 'hard'"):
        PushWithObstaclesEnv(1, device="cpu", obstacle_mode="hard", curriculum_success_rate=0.5)
    with pytest.raises(Exception, match="hexagon"):
        PushEnv(1, object_type="hexagon", device="cpu")
    env = PushBoxEnv(2, device="cpu", seed=0)
    with pytest.raises(ValueError, match=r"shape \(2, 2\)"):
        env.step(torch.zeros(2, 3))
    with pytest.raises(ValueError, match="non-finite"):
        env.step(torch.tensor([[0.0, float("nan")], [0.0, 0.0]]))


@pytest.mark.parametrize("name", ["B0", "B1", "B3"])
def test_benchmark_variants(name, rng):
    from magwarp.envs.push import push_benchmark

    layout, movers = push_benchmark(name)
    if name == "B0":  # MagBotSim's B0 ranges cannot keep the object 0.15 m from its goal: said, not hidden
        with pytest.warns(UserWarning, match="loops forever"):
            env = PushBoxEnv(16, benchmark=name, device="cpu", seed=int(rng.integers(1 << 30)))
    else:
        env = PushBoxEnv(16, benchmark=name, device="cpu", seed=int(rng.integers(1 << 30)))
    assert env.num_movers == movers and env.layout.shape == layout.shape
    assert env.single_action_space.shape == (2 * movers,)
    obs, _ = env.reset()
    xy = obs["observation"][:, : 2 * movers].reshape(16, movers, 2)
    assert env._on_tiles(xy, 0.11).all(), rng
    if movers == 2:
        assert torch.all((xy[:, 0] - xy[:, 1]).norm(dim=1) > 0.22), rng
    env.step(torch.zeros(16, 2 * movers))
    assert not env.checks.flags_t.any()


def test_corrective_movement_metrics_match_magbotsim_per_cycle(rng):
    CorrectiveMovementMeasurement = pytest.importorskip("magbotsim.utils.benchmark_utils").CorrectiveMovementMeasurement
    env = PushBoxEnv(2, device="cpu", seed=0, num_cycles=1, max_episode_steps=1000)
    env.reset()
    obj = env.backend.object_qpos[:, 0, :2].clone()
    # The object rests; moving the goal every cycle scripts the distance sequence (crossing the 5 cm threshold,
    # rising and falling by more and by less than MagBotSim's 2e-5 tolerance).
    n = 300
    dists = 0.05 + 0.03 * np.sin(np.linspace(0, 6 * np.pi, n)) + rng.normal(0, 2e-5, n)
    dists[100:120] = 0.02  # a streak at the goal
    refs = [CorrectiveMovementMeasurement(lambda a, b: np.linalg.norm(np.atleast_2d(a - b), axis=1), 0.05) for _ in range(2)]
    # MagBotSim's throughput bookkeeping (its _after_mujoco_step_callback), re-implemented as the reference
    elapsed, streak, tts = [0, 0], [0, 0], [-1.0, -1.0]
    for t in range(n):
        offs = torch.tensor([[dists[t], 0.0], [0.0, dists[t] * (1 + 0.5 * (t % 2))]], dtype=torch.float32)
        env.goal_xy.copy_(obj + offs)
        env.step(torch.zeros(2, 2))
        q = env.backend.object_qpos[:, 0, :2].numpy().astype(np.float64)
        g = env.goal_xy.numpy().astype(np.float64)
        for w in range(2):
            refs[w].update_distance_corrections(q[w], g[w])
            refs[w].update_overshoot_corrections(q[w], g[w])
            if streak[w] < 150:
                elapsed[w] += 1
                if np.linalg.norm(q[w] - g[w]) <= 0.05:
                    tts[w] = elapsed[w] * 1e-3 if streak[w] == 0 else tts[w]
                    streak[w] += 1
                else:
                    streak[w] = 0
    got_over = env.metrics.t["overshoots"].tolist()
    got_dist = env.metrics.t["dist_corrections"].tolist()
    assert got_over == [r.get_current_num_overshoot_corrections() for r in refs], rng
    assert got_dist == [r.get_current_num_distance_corrections() for r in refs], rng
    assert min(got_over) > 0 and min(got_dist) > 0
    np.testing.assert_allclose(env.metrics.t["time_to_success"].numpy(), tts, rtol=1e-6, err_msg=str(rng))
    assert min(tts) > 0
    env.reset()
    assert env.metrics.t["overshoots"].tolist() == [0, 0] and env.metrics.t["time_to_success"].tolist() == [-1, -1]


def test_object_variants_behave_like_the_same_object_built_directly():
    # A world given variant k must move exactly like an env whose model was compiled with that object: every
    # size- and mass-dependent model array (inertia, centre of mass, contact geometry) was swapped in.
    ranges = {"width": (0.05, 0.08), "height": (0.05, 0.08), "mass": (0.1, 0.5)}
    env = PushTEnv(2, device="cpu", seed=0, object_ranges=ranges, object_variants=4)
    env.reset(seed=3)
    k = int(env.object_variant[0])
    spec = env.variants.specs[k]
    ref = PushTEnv(2, device="cpu", seed=0, object_width=spec.width, object_height=spec.height, object_mass=spec.mass)
    trajectories = []
    for e in (env, ref):
        e.reset(seed=3)
        _place(e, (0.20, 0.36), (0.42, 0.38), (0.6, 0.4))
        for _ in range(6):
            e.step(torch.tensor([[4.0, 0.0], [0.0, 0.0]]))
        trajectories.append(e.backend.object_qpos[0, 0].clone())
    moved = (trajectories[0][:2] - torch.tensor([0.42, 0.38])).norm()
    assert moved > 0.02  # the mover did push the object
    assert torch.allclose(trajectories[0], trajectories[1], atol=2e-5), trajectories
    # coverage uses each world's own outline: the variant at its own pose covers its goal fully
    pose = torch.tensor([[0.4, 0.4, 0.0, 1.0]] * 2)
    info = {"object_variant": env.object_variant}
    assert torch.allclose(env.goal_reached(pose, pose, info)[1], torch.ones(2))


def test_object_ranges_are_validated():
    with pytest.raises(ValueError, match="unknown key 'colour'"):
        PushBoxEnv(1, device="cpu", object_ranges={"colour": (1, 2)})
    with pytest.raises(ValueError, match="width"):
        PushBoxEnv(1, device="cpu", object_ranges={"width": (0.08, 0.05)})
    with pytest.raises(ValueError, match="object_variants"):
        PushBoxEnv(1, device="cpu", object_ranges={"width": (0.05, 0.08)}, object_variants=0)
    env = PushBoxEnv(1, device="cpu", object_ranges={"width": (0.05, 0.05)})  # fixed: just sets the value
    assert env.variants is None and env.object.width == pytest.approx(0.05)


def test_observation_noise_is_seeded_and_of_the_given_size():
    env = PushBoxEnv(512, device="cpu", seed=0, std_noise=1e-3, object_noise=2e-3)
    obs, _ = env.reset(seed=5)
    b = env.backend
    mover_err = obs["observation"][:, :2] - b.mover_qpos[:, 0, :2]
    object_err = obs["achieved_goal"] - b.object_qpos[:, 0, :2]
    assert mover_err.std().item() == pytest.approx(1e-3, rel=0.1)
    assert object_err.std().item() == pytest.approx(2e-3, rel=0.1)
    again, _ = env.reset(seed=5)
    assert torch.equal(obs["observation"], again["observation"])
    with pytest.raises(ValueError, match="std_noise"):
        PushBoxEnv(1, device="cpu", std_noise=-1.0)
