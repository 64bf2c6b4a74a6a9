"""The env API surface: gymnasium registration (make / make_vec), the VectorEnv contract of the batched env (spaces,
dtypes, devices, autoreset metadata) and the single-env numpy view (reset/step types, HER-style compute_reward)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.vector import AutoresetMode, VectorEnv

import magwarp  # noqa: F401  (registers the env ids)
from magwarp.envs import MagwarpVecEnv, SingleEnv, TrajectoryPlanningEnv
from magwarp.layout import BENCHMARK_LAYOUTS

IDS = ["magwarp/TrajectoryPlanning-v0"] + [f"magwarp/TrajectoryPlanning{b}-v0" for b in BENCHMARK_LAYOUTS]


def test_all_ids_registered():
    for env_id in IDS:
        assert env_id in gym.registry, env_id


@pytest.mark.parametrize("env_id, movers", [("magwarp/TrajectoryPlanning-v0", 3), ("magwarp/TrajectoryPlanningB8-v0", 5)])
def test_make_gives_single_numpy_view(env_id, movers):
    env = gym.make(env_id)
    single = env.unwrapped
    assert isinstance(single, SingleEnv) and single.render_mode is None and single.render() is None
    assert env.action_space.shape == (2 * movers,)
    obs, info = env.reset(seed=0)
    assert isinstance(obs, dict) and all(isinstance(v, np.ndarray) and v.dtype == np.float32 for v in obs.values())
    assert env.observation_space.contains(obs)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    assert isinstance(reward, float) and isinstance(terminated, bool) and isinstance(truncated, bool)
    assert {"mover_collision", "wall_collision", "steps_since_goal", "collected_goals"} <= set(info)
    env.close()


def test_make_vec_gives_batched_torch_env():
    env = gym.make_vec("magwarp/TrajectoryPlanningB2-v0", num_envs=5, learn_jerk=True)
    assert isinstance(env, TrajectoryPlanningEnv) and isinstance(env, VectorEnv) and isinstance(env, MagwarpVecEnv)
    assert env.num_envs == 5 and env.layout_name == "B2" and env.learn_jerk and env.num_movers == 4
    assert env.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    assert env.render_mode is None and env.render() is None
    for k, space in env.single_observation_space.items():
        assert env.observation_space[k].shape == (5, *space.shape)
    assert env.action_space.shape == (5, *env.single_action_space.shape)
    obs, info = env.reset(seed=1)
    obs, reward, terminated, truncated, info = env.step(torch.zeros(env.action_space.shape))
    for k, v in obs.items():
        assert isinstance(v, torch.Tensor) and v.device == env.device and v.dtype == torch.float32
        assert v.shape == env.observation_space[k].shape
    assert reward.shape == (5,) and reward.dtype == torch.float32
    assert terminated.dtype == torch.bool and truncated.dtype == torch.bool
    assert info["_final_obs"].shape == (5,) and set(info["final_obs"]) == set(obs)
    # numpy actions of any float dtype are accepted
    env.step(np.zeros(env.action_space.shape, np.float64))


def test_single_env_compute_reward_for_her():
    env = gym.make("magwarp/TrajectoryPlanning-v0").unwrapped
    obs, _ = env.reset(seed=2)
    obs, reward, *_, info = env.step(np.zeros(6, np.float32))
    assert env.compute_reward(obs["achieved_goal"], obs["desired_goal"], info) == reward
    batch_a = np.stack([obs["achieved_goal"]] * 4)
    batch_d = np.stack([obs["achieved_goal"], obs["desired_goal"], obs["achieved_goal"], obs["desired_goal"]])
    infos = np.array([{"mover_collision": False, "wall_collision": False}, {}, {"mover_collision": True}, {}])
    r = env.compute_reward(batch_a, batch_d, infos)
    assert r.shape == (4,)
    np.testing.assert_array_equal(r, [60.0, reward, -20.0, reward])


def test_single_env_rejects_bad_actions():
    env = gym.make("magwarp/TrajectoryPlanning-v0").unwrapped
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"\(6,\).*\(5,\)"):
        env.step(np.zeros(5))
    with pytest.raises(ValueError, match="nan"):
        env.step(np.full(6, np.nan))


def test_rgb_render_of_the_batched_env():
    pytest.importorskip("magwarp.render")
    env = TrajectoryPlanningEnv(num_envs=2, render_mode="rgb_array", seed=0)
    img = env.render()
    assert isinstance(img, np.ndarray) and img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3


# ---------------------------------------------------------------------------------------------------- the tutorial
def _tutorial():
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parent.parent / "examples" / "custom_env_tutorial.py"
    spec = importlib.util.spec_from_file_location("custom_env_tutorial", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_custom_env_tutorial_runs():
    tut = _tutorial()
    stats = tut.main(["--envs", "8", "--steps", "40", "--device", "cpu"])
    assert stats["episodes"] == stats["successes"] + stats["collisions"] + stats["timeouts"] > 0
    env = tut.ParkingEnv(num_envs=4, device="cpu", seed=1, max_steps=5)
    assert isinstance(env, VectorEnv) and env.single_action_space.shape == (6,)
    obs, _ = env.reset(seed=3)
    assert env.single_observation_space.contains(obs[0].numpy())
    # slots: the last tile column, assigned by start y rank
    np.testing.assert_allclose(env.slots[..., 0].numpy(), 0.84, rtol=1e-6)
    y = env.sim.pos[..., 1]
    assert (y.argsort(dim=1) == env.slots[..., 1].argsort(dim=1)).all()
    # the base class's machinery works for it unchanged: bad input checks, autoreset with final_obs, partial reset
    with pytest.raises(ValueError, match=r"\(4, 6\)"):
        env.step(torch.zeros(4, 5))
    for _ in range(5):
        obs, reward, terminated, truncated, info = env.step(tut.pd_policy(obs, env.num_movers))
    assert (terminated | truncated).all() and info["_final_obs"].all()
    assert (obs.view(4, 3, 4)[..., 2:] == 0).all()  # new episodes start at rest
    keep = env.sim.pos.clone()
    env.reset(options={"reset_mask": torch.tensor([True, False, False, False])})
    assert torch.equal(env.sim.pos[1:], keep[1:])


def test_custom_env_with_adapters():
    tut = _tutorial()
    pytest.importorskip("stable_baselines3")
    from magwarp.envs.adapters import SB3VecEnv

    venv = SB3VecEnv(tut.ParkingEnv(num_envs=3, device="cpu", seed=0, max_steps=3))
    obs = venv.reset()
    for _ in range(3):  # max_steps=3: the third step truncates every env
        obs, rew, done, infos = venv.step(np.zeros((3, 6), np.float32))
    assert obs.shape == (3, 12) and done.any() and all("terminal_observation" in i for i, d in zip(infos, done) if d)
    pytest.importorskip("torchrl")
    from torchrl.envs.utils import check_env_specs

    from magwarp.envs.adapters import TorchRLEnv

    check_env_specs(TorchRLEnv(tut.ParkingEnv(num_envs=3, device="cpu", seed=0)))


def test_random_agents_example_runs():
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parent.parent / "examples" / "random_agents.py"
    spec = importlib.util.spec_from_file_location("random_agents", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    out = module.main(["--envs", "4", "--steps", "15", "--device", "cpu"])
    assert out["batched"]["episodes"] >= out["batched"]["collisions"]
    assert set(out) == {"batched", "multi_agent", "pettingzoo", "sb3", "torchrl", "rsl_rl", "skrl"}
