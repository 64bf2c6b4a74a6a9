"""magwarp/PlatformPose-v0: gymnasium make/make_vec and check_env, spaces, rewards, limits, the scripted baseline."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env

import magwarp  # noqa: F401  (registers the env ids)
from magwarp.envs.platform_pose import PlatformPoseEnv, goal_errors, pose_to_goal
from magwarp.envs.single import SingleEnv
from magwarp.magbots import platform_fk
from magwarp.policies.platform import PlatformIKPolicy

from magbots_helpers import load_magbots_benchmark  # noqa: E402  (tests/ is on sys.path)


@pytest.fixture(scope="module")
def env():
    return PlatformPoseEnv(8, device="cpu", seed=0)


def _run(env, policy, steps: int) -> tuple[int, int]:
    """(successful episodes, failed episodes: collision or limit) over ``steps`` steps from a fresh reset."""
    obs, _ = env.reset(seed=3)
    succ = fail = 0
    for _ in range(steps):
        obs, reward, term, trunc, info = env.step(policy(obs))
        succ += int(info["is_success"].sum())
        fail += int((term & ~info["is_success"]).sum())
        # rewards are the batched compute_reward of the step's goals and flags
        final = info["final_obs"]
        want = env.compute_reward(final["achieved_goal"], final["desired_goal"], info)
        assert torch.equal(reward, want)
    return succ, fail


def test_make_check_env_and_make_vec():
    single = gym.make("magwarp/PlatformPose-v0", device="cpu").unwrapped
    assert isinstance(single, SingleEnv)
    check_env(single, skip_render_check=True)
    vec = gym.make_vec("magwarp/PlatformPose-v0", num_envs=3, device="cpu", action_mode="pose")
    assert isinstance(vec, PlatformPoseEnv) and vec.num_envs == 3
    assert vec.single_action_space.shape == (6,) and vec.single_action_space.high.max() == 1.0
    assert vec.single_observation_space["observation"].shape == (28,)
    obs, _ = vec.reset(seed=0)
    assert obs["observation"].shape == (3, 28) and obs["desired_goal"].shape == (3, 7)


def test_top_down_render_shows_movers_and_platform():
    env = PlatformPoseEnv(2, device="cpu", seed=0, render_mode="rgb_array")
    img = env.render()
    assert isinstance(img, np.ndarray) and img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3
    env.step(torch.zeros(2, 6))
    assert not np.array_equal(img, np.zeros_like(img)) and np.unique(img.reshape(-1, 3), axis=0).shape[0] > 4


def test_observation_is_the_state(env):
    obs, _ = env.reset(seed=5)
    pose = env.platform_pose()
    np.testing.assert_allclose(obs["achieved_goal"].numpy(), pose_to_goal(pose).numpy(), atol=1e-6)
    pos, _ = env.mover_state()
    movers = torch.cat([pos[..., :2], torch.full_like(pos[..., :1], env.mover_z), pos[..., 2:]], -1)
    # the mechanism's joints and the movers agree through the forward kinematics (float32 state)
    np.testing.assert_allclose(platform_fk(movers.double()).numpy(), pose.double().numpy(), atol=2e-4)
    lo, hi = env._sample_low.numpy(), env._sample_high.numpy()
    assert np.all(pose.numpy() >= lo - 1e-4) and np.all(pose.numpy() <= hi + 1e-4)
    assert env.single_action_space.shape == (6,) and env.single_observation_space["observation"].shape == (21,)


def test_scripted_baseline_solves_most_goals(env):
    succ, fail = _run(env, PlatformIKPolicy(env), 60)
    assert succ >= 8 and fail <= 0.1 * (succ + fail), (succ, fail)
    idle, idle_fail = _run(env, lambda obs: torch.zeros(env.num_envs, 6), 10)
    assert idle == 0 and idle_fail == 0  # holding still reaches no random goal and breaks nothing


def test_pose_mode_baseline_and_target_limits():
    env = PlatformPoseEnv(4, device="cpu", seed=1, action_mode="pose")
    succ, fail = _run(env, PlatformIKPolicy(env), 50)
    assert succ >= 4 and fail == 0, (succ, fail)
    env.reset(seed=0)
    up = torch.zeros(4, 6)
    up[:, 3] = 1.0  # keep asking for more roll: the target stops at the tilt limit and says so
    for _ in range(30):
        *_, info = env.step(up)
    assert bool(info["target_clipped"].all())
    assert float(env.target_pose[:, 3].max()) == pytest.approx(env.geometry.max_tilt, abs=1e-6)


def test_limit_violation_fails_the_episode(env):
    env.reset(seed=0)
    flags = []
    for _ in range(8):
        pos, _ = env.mover_state()
        axis = torch.nn.functional.normalize(pos[:, 1, :2] - pos[:, 0, :2], dim=-1)
        a = torch.zeros(env.num_envs, 2, 3)
        a[:, 0, :2], a[:, 1, :2] = -10.0 * axis, 10.0 * axis  # pull the movers apart: the linkage's distance limit
        _, reward, term, _, info = env.step(a.reshape(env.num_envs, 6))
        flags.append(info["limit_height_min"] & term)
        if bool(info["limit_violation"].any()):
            assert bool((reward[info["limit_violation"]] == env.collision_penalty).all())
    assert bool(torch.stack(flags).any(0).all())
    r = env.compute_reward(torch.zeros(2, 7), torch.zeros(2, 7), {"limit_violation": torch.tensor([True, False])})
    assert r.tolist() == [env.collision_penalty, env.success_reward]


def test_goal_errors_wrap_the_yaw():
    a = pose_to_goal(torch.tensor([[0.0, 0.0, 0.2, 0.0, 0.0, 3.1]]))
    b = pose_to_goal(torch.tensor([[0.0, 0.0, 0.2, 0.0, 0.0, -3.1]]))
    pos, ang = goal_errors(a, b)
    assert float(pos) == 0.0 and float(ang) == pytest.approx(2 * np.pi - 6.2, abs=1e-5)


def test_bad_options_raise_clear_errors():
    with pytest.raises(ValueError, match="action_mode"):
        PlatformPoseEnv(1, device="cpu", action_mode="joint")
    with pytest.raises(ValueError, match="no room"):
        PlatformPoseEnv(1, device="cpu", layout=np.ones((2, 4)))
    holes = np.ones((5, 5))
    holes[2, 2] = 0
    with pytest.raises(ValueError, match="full grid"):
        PlatformPoseEnv(1, device="cpu", layout=holes)
    with pytest.raises(ValueError, match="pose_step"):
        PlatformPoseEnv(1, device="cpu", pose_step=(0.1, 0.1))


def test_magwarp_eval_reports_the_platform_table():
    from magwarp.evaluate import evaluate, format_table

    res = evaluate("PlatformPose", episodes=6, repeats=2, device="cpu", progress=False)
    rows = {r.key: r for r in res.rows}
    assert res.family == "platform" and rows["success_rate"].n == 6
    assert rows["success_rate"].mean >= 50.0, format_table(res)
    assert 0.0 < rows["time_to_success_s"].mean <= 2.0  # within the 50-step (2 s) episode
    assert {"limit_violations", "collisions", "final_position_error_mm", "process_time_ms"} <= set(rows)


def test_benchmark_script_smoke(tmp_path):
    import json

    mod = load_magbots_benchmark()
    out = tmp_path / "mb.json"
    assert mod.main(["--device", "cpu", "--num-envs", "2", "--steps", "2", "--envs", "pose", "--action-modes", "pose",
                     "--no-magbotsim", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())
    assert len(rows) == 1 and rows[0]["num_envs"] == 2 and rows[0]["env_steps_per_s"] > 0
    assert {"date_utc", "versions", "command", "device_name"} <= set(rows[0])
