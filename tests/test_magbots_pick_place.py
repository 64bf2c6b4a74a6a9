"""MagBot pick and place: magwarp/PlatformPickPlace-v0 and magwarp/GripperPickPlace-v0 (make/make_vec, check_env,
placement and drop semantics, the scripted baselines, eval tables, bad options, trajectories vs float64 MuJoCo C).

One env of each per module (mujoco-warp compiles once per process; WARP_CACHE_PATH keeps it warm)."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
import torch
import warp as wp
from gymnasium.utils.env_checker import check_env

import magwarp  # noqa: F401  (registers the env ids)
from magwarp.envs.gripper_pick_place import GripperPickPlaceEnv
from magwarp.envs.platform_pick_place import PICK_PLACE_PLATFORM, PickPlaceScene, PlatformPickPlaceEnv
from magwarp.envs.single import SingleEnv
from magwarp.magbots.gripper import GripperJoints
from magwarp.magbots.mjcf import PlatformJoints, PlatformModelSpec
from magwarp.mjcf import ObjectSpec
from magwarp.physics import ControlParams, MjwBackend

from magbots_helpers import load_magbots_benchmark, rollout_vs_mujoco_c  # noqa: E402  (tests/ is on sys.path)

wp.config.quiet = True


@pytest.fixture(scope="module")
def platform_env():
    return PlatformPickPlaceEnv(4, device="cpu", seed=0)


@pytest.fixture(scope="module")
def gripper_env():
    return GripperPickPlaceEnv(8, device="cpu", seed=0)


def _first_episodes(env, steps: int, seed: int) -> tuple[torch.Tensor, torch.Tensor, dict]:
    """Run the scripted baseline from a fresh reset; per world, whether its first episode succeeded / failed."""
    policy = env.scripted_policy()
    obs, _ = env.reset(seed=seed)
    done = torch.zeros(env.num_envs, dtype=torch.bool)
    succ = torch.zeros(env.num_envs, dtype=torch.bool)
    fail = torch.zeros(env.num_envs, dtype=torch.bool)
    last = {}
    for _ in range(steps):
        obs, reward, term, trunc, info = env.step(policy(obs))
        new = (term | trunc) & ~done
        succ |= new & info["is_success"]
        fail |= new & term & ~info["is_success"]
        done |= new
        if bool((new & info["is_success"]).any()):
            last = {"reward": reward[new & info["is_success"]], "info": info, "mask": new & info["is_success"]}
        if bool(done.all()):
            break
    return succ, fail, last


def test_make_check_env_and_make_vec():
    for env_id, cls, obs_dim in (("magwarp/PlatformPickPlace-v0", PlatformPickPlaceEnv, 41),
                                 ("magwarp/GripperPickPlace-v0", GripperPickPlaceEnv, 21)):
        single = gym.make(env_id, device="cpu").unwrapped
        assert isinstance(single, SingleEnv)
        check_env(single, skip_render_check=True)
        vec = gym.make_vec(env_id, num_envs=2, device="cpu")
        assert isinstance(vec, cls) and vec.num_envs == 2
        space = vec.single_observation_space
        shape = space.shape if isinstance(space, gym.spaces.Box) else space["observation"].shape
        assert shape == (obs_dim,), env_id
    pose = gym.make_vec("magwarp/PlatformPickPlace-v0", num_envs=1, device="cpu", action_mode="pose")
    assert pose.single_observation_space.shape == (48,) and pose.single_action_space.high.max() == 1.0
    grip = gym.make_vec("magwarp/GripperPickPlace-v0", num_envs=1, device="cpu", action_mode="gripper")
    assert grip.single_observation_space["observation"].shape == (26,)


def test_platform_baseline_places_the_products(platform_env):
    env = platform_env
    succ, fail, last = _first_episodes(env, 220, seed=1)
    assert int(succ.sum()) >= 3 and not bool(fail.any()), (succ, fail)
    # the successful step's reward is the placement's, and its product lay in the container
    assert bool((last["reward"] == env.place_reward).all())
    final = last["info"]["final_obs"][last["mask"]]
    assert bool(env.in_container(final[:, 21:24]).all())
    assert bool((last["info"]["products_placed"][last["mask"]] == 1).all())


def test_platform_idle_places_nothing_and_breaks_nothing(platform_env):
    env = platform_env
    env.reset(seed=2)
    for _ in range(10):
        obs, reward, term, trunc, info = env.step(torch.zeros(env.num_envs, 6))
        assert not bool(term.any()) and not bool(info["placed"].any()) and not bool(info["dropped"].any())
    # the products still rest on the rack
    p, _ = env.product_pose()
    np.testing.assert_allclose(p[:, 2].numpy(), env.supply[2].item(), atol=2e-3)


def test_platform_placing_and_dropping_count_and_respawn(platform_env):
    env = platform_env
    env.reset(seed=3)
    b = env.backend
    q = b.object_qpos[:, 0].clone()
    c = env.container
    q[0, :3] = torch.tensor([c[0], c[1], env.scene.product.depth + 0.001])  # world 0: in the container
    q[1, :3] = torch.tensor([0.5, 0.5, env.scene.product.depth + 0.001])  # world 1: on the tiles
    b.object_qpos[:, 0].copy_(q)
    obs, reward, term, trunc, info = env.step(torch.zeros(env.num_envs, 6))
    assert info["placed"].tolist() == [True, False, False, False]
    assert info["dropped"].tolist() == [False, True, False, False]
    assert reward[:2].tolist() == [env.place_reward, env.drop_penalty]
    assert info["is_success"].tolist() == [True, False, False, False]  # one product is the default episode's goal
    assert term.tolist() == [True, False, False, False]
    assert int(info["products_dropped"][1]) == 1
    # world 1's next product lies on the rack (world 0 started a new episode)
    p, _ = env.product_pose()
    assert float((p[1, :2] - env.supply[:2]).norm()) < 0.02 and abs(float(p[1, 2] - env.supply[2])) < 2e-3


def test_platform_success_counts_the_products_placed():
    env = PlatformPickPlaceEnv(1, device="cpu", seed=0, products=2)
    env.reset(seed=0)
    c = env.container
    for k in range(2):
        q = env.backend.object_qpos[:, 0].clone()
        q[0, :3] = torch.tensor([c[0] - 0.05 + 0.1 * k, c[1], env.scene.product.depth + 0.001])
        env.backend.object_qpos[:, 0].copy_(q)
        obs, reward, term, trunc, info = env.step(torch.zeros(1, 6))
        assert bool(info["placed"][0]) and int(info["products_placed"][0]) == k + 1
        assert bool(info["is_success"][0]) == bool(term[0]) == (k == 1)  # the second product ends the episode
        if k == 0:  # the next product waits on the rack, and the observation says one of two is placed
            p, _ = env.product_pose()
            assert float((p[0, :2] - env.supply[:2]).norm()) < 0.02
            assert float(obs[0, 40]) == pytest.approx(0.5)


def test_gripper_baseline_places_most_objects(gripper_env):
    env = gripper_env
    succ, fail, last = _first_episodes(env, 200, seed=1)
    assert int(succ.sum()) >= 6 and int(fail.sum()) <= 1, (succ, fail)
    info = last["info"]
    final = info["final_obs"]
    m = last["mask"]
    # at success the object lies at its goal and the jaw is open (released); the reward is compute_reward's
    err = (final["achieved_goal"][m, :2] - final["desired_goal"][m, :2]).norm(dim=-1)
    assert bool((err <= env.goal_tolerance).all()) and bool((final["achieved_goal"][m, 2] == 1.0).all())
    want = env.compute_reward(final["achieved_goal"], final["desired_goal"], info)
    assert bool((want[m] == env.success_reward).all()) and bool((last["reward"] == env.success_reward).all())


def test_gripper_reward_needs_release_and_goal(gripper_env):
    env = gripper_env
    goal = torch.tensor([[0.5, 0.5, 1.0]] * 3)
    achieved = torch.tensor([[0.5, 0.51, 1.0], [0.5, 0.51, 0.0], [0.5, 0.55, 1.0]])
    want = [env.success_reward, env.per_step_penalty, env.per_step_penalty]
    assert env.compute_reward(achieved, goal, None).tolist() == pytest.approx(want)
    r = env.compute_reward(achieved[:2], goal[:2], {"object_lost": torch.tensor([True, False])})
    assert r.tolist() == pytest.approx([env.collision_penalty, env.per_step_penalty])


def test_renders_show_the_scene(platform_env, gripper_env):
    from magwarp.render import mujoco3d

    try:
        mujoco3d.gl_backend()
        modes = ("rgb_array", "rgb_array_3d")
    except mujoco3d.GLUnavailableError:
        modes = ("rgb_array",)  # no headless OpenGL here: the top-down view only
    for env, zeros in ((platform_env, torch.zeros(4, 6)), (gripper_env, torch.zeros(8, 4))):
        env.reset(seed=0)
        env.step(zeros)
        for mode in modes:
            env.render_mode = mode
            env.set_render_worlds(1)
            try:
                img = env.render()
            finally:
                env.render_mode = None
            assert img.dtype == np.uint8 and img.ndim == 3 and np.unique(img.reshape(-1, 3), axis=0).shape[0] > 4
    # the 3D view draws the gripper's goal as a ghost box at the goal
    (pos, yaw, half, rgba, kind), = gripper_env.goal_ghosts(0)
    assert pos[:2] == pytest.approx(gripper_env.goal[0].tolist()) and kind == "box" and rgba[3] < 1


def test_magwarp_eval_reports_the_pick_place_tables():
    from magwarp.evaluate import evaluate, format_table

    res = evaluate("PlatformPickPlace", episodes=2, repeats=1, steps=200, device="cpu", progress=False)
    rows = {r.key: r for r in res.rows}
    assert res.family == "pick_place" and rows["success_rate"].n == 2
    assert rows["success_rate"].mean >= 50.0, format_table(res)
    assert 0.0 < rows["placement_rate"].mean and rows["products_placed"].mean >= 0.5
    assert {"time_to_success_s", "collisions", "limit_violations", "products_dropped", "process_time_ms"} <= set(rows)
    res = evaluate("GripperPickPlace", episodes=4, repeats=1, device="cpu", progress=False)
    rows = {r.key: r for r in res.rows}
    assert rows["success_rate"].mean >= 50.0, format_table(res)
    assert {"objects_lost", "final_position_error_mm", "time_to_success_s", "collisions"} <= set(rows)


def test_bad_options_raise_clear_errors():
    with pytest.raises(ValueError, match="products"):
        PlatformPickPlaceEnv(1, device="cpu", products=0)
    with pytest.raises(ValueError, match="no pose goals"):
        PlatformPickPlaceEnv(1, device="cpu", position_tolerance=0.1)
    with pytest.raises(ValueError, match="do not hold the product"):
        PickPlaceScene(rail_gap=0.2)
    with pytest.raises(ValueError, match="does not fit between the rails"):
        PlatformPickPlaceEnv(1, device="cpu", model=PlatformModelSpec(platform_half_size=(0.08, 0.1, 0.004),
                                                                      plate_friction=0.15))
    with pytest.raises(ValueError, match="plate_friction is None"):
        PlatformPickPlaceEnv(1, device="cpu", model=PlatformModelSpec(platform_half_size=(0.04, 0.1, 0.004)))
    with pytest.raises(ValueError, match="dock height"):
        PlatformPickPlaceEnv(1, device="cpu", scene=PickPlaceScene(rail_height=0.4))
    with pytest.raises(ValueError, match="product_jitter"):
        PlatformPickPlaceEnv(1, device="cpu", product_jitter=(0.01, -1.0, 0.0))
    with pytest.raises(ValueError, match="action_mode"):
        GripperPickPlaceEnv(1, device="cpu", action_mode="pose")
    with pytest.raises(ValueError, match="must fit the jaw"):
        GripperPickPlaceEnv(1, device="cpu", obj=ObjectSpec(shape="square_box", width=0.1))
    with pytest.raises(ValueError, match="no room for the gripper"):
        GripperPickPlaceEnv(1, device="cpu", layout=np.ones((3, 3)))
    with pytest.raises(ValueError, match="gripper_step"):
        GripperPickPlaceEnv(1, device="cpu", gripper_step=(0.1, 0.1))


def test_pick_place_trajectories_match_mujoco_c():
    """The platform carrying a product (and sliding under one on the rack), and the gripper closing its jaw on the
    object: 300 cycles of mujoco-warp (float32) against MuJoCo C (float64) on the same MJCF and actions."""
    env = PlatformPickPlaceEnv(1, device="cpu")
    b = MjwBackend(env.xml, 2, control=ControlParams(num_cycles=10, rotation=True), nconmax=24, njmax=128,
                   device="cpu")
    pj = PlatformJoints(b.mjm, env.geometry, PICK_PLACE_PLATFORM)
    q = b.init_qpos_t.double().clone()
    mover_z = float(b.hover_z.mean())
    pj.write_qpos(q, torch.tensor([[[0.34, 0.36, 0.27, 0, 0, 0]], [[0.34, 0.14, 0.25, 0, 0, 0]]], dtype=torch.float64),
                  mover_z)
    oq, s = int(b.object_qadr[0]), env.scene
    q[0, oq:oq + 7] = torch.tensor([0.34, 0.36, 0.27 + s.product.depth, 1, 0, 0, 0], dtype=torch.float64)
    q[1, oq:oq + 7] = torch.tensor([*s.supply_position(), 1, 0, 0, 0], dtype=torch.float64)
    b.init_qpos_t.copy_(q)
    b.reset()
    acts = np.zeros((30, 2, 2, 3))
    acts[:10, 0, :, :2], acts[10:20, 0, :, :2] = 0.5, -0.5  # world 0: carry the product, brake, then tilt
    acts[20:, 0, 0, 2] = -20.0
    acts[:15, 1, :, 1], acts[15:, 1, :, 1] = 0.3, -0.3  # world 1: slide below the product on the rack
    got, errors = rollout_vs_mujoco_c(b, env.xml, acts)
    assert max(errors) < 1e-4, f"platform: max |qpos - MuJoCo C| per world: {errors}"
    assert float(got[-1, 0, oq + 2]) > 0.26 and abs(float(got[-1, 0, oq] - 0.34)) > 1e-3  # it rode along
    np.testing.assert_allclose(got[-1, 1, oq:oq + 3], s.supply_position(), atol=2e-3)  # it stayed on the rack

    genv = GripperPickPlaceEnv(1, device="cpu")
    b = MjwBackend(genv.xml, 2, control=ControlParams(num_cycles=10), nconmax=16, njmax=96, device="cpu")
    gj = GripperJoints(b.mjm)
    q = b.init_qpos_t.double().clone()
    state = torch.tensor([[[0.6, 0.6, 0.0, 0.06]], [[0.6, 0.5, 0.5, 0.12]]], dtype=torch.float64)
    gj.write_qpos(q, state, float(b.hover_z.mean()))
    oq = int(b.object_qadr[0])
    for w in range(2):  # the object inside the open jaw
        x, y, yaw = (float(v) for v in state[w, 0, :3])
        q[w, oq:oq + 7] = torch.tensor([x - genv.grip_offset * math.cos(yaw), y - genv.grip_offset * math.sin(yaw),
                                        genv.obj.depth, math.cos(yaw / 2), 0, 0, math.sin(yaw / 2)])
    b.init_qpos_t.copy_(q)
    b.reset()
    acts = np.zeros((30, 2, 2, 2))
    acts[:10, 0, 0] = [0.6, 0.0]  # world 0: mover A runs into the jaw's close (the pads meet the object)
    acts[20:, 0] = [0.0, 0.3]
    u = np.array([math.cos(0.5), math.sin(0.5)])
    acts[:10, 1, 1], acts[10:20, 1, 1], acts[20:, 1] = -0.8 * u, 0.8 * u, -0.5 * u  # world 1: B closes in
    got, errors = rollout_vs_mujoco_c(b, genv.xml, acts)
    assert max(errors) < 1e-4, f"gripper: max |qpos - MuJoCo C| per world: {errors}"
    width = gj.state(torch.as_tensor(got).reshape(60, -1)).reshape(30, 2, 4)[..., 3]
    # world 0's jaw stops on the object (4 cm wide) instead of closing further; world 1's closed by 3 cm
    assert 0.035 < float(width[:, 0].min()) < genv.object_width + 1e-3
    assert float(width[0, 1] - width[:, 1].min()) > 0.025


def test_benchmark_script_times_the_pick_place_envs(tmp_path):
    import json

    mod = load_magbots_benchmark()
    out = tmp_path / "mb.json"
    assert mod.main(["--device", "cpu", "--num-envs", "2", "--steps", "2", "--envs", "pickplace,gripper",
                     "--no-magbotsim", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())
    assert [r["env"] for r in rows] == ["magwarp/PlatformPickPlace-v0", "magwarp/GripperPickPlace-v0"]
    assert all(r["num_envs"] == 2 and r["env_steps_per_s"] > 0 and r["raw_mjw_ms"] > 0 for r in rows)
    with pytest.raises(SystemExit):
        mod.main(["--envs", "swarm", "--no-magbotsim"])
