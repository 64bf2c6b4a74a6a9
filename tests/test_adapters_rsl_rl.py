"""rsl_rl adapter: the VecEnv contract against a twin env stepped alone, and rsl_rl's own OnPolicyRunner training
trajectory planning (B0) and Push-Box for a few iterations on the CPU."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest
import torch

pytest.importorskip("rsl_rl")

from rsl_rl.env import VecEnv  # noqa: E402
from rsl_rl.runners import OnPolicyRunner  # noqa: E402
from tensordict import TensorDict  # noqa: E402

from magwarp.envs import PushBoxEnv, TrajectoryPlanningEnv  # noqa: E402
from magwarp.envs.adapters import RslRlVecEnv  # noqa: E402
from magwarp.training import flatten_obs  # noqa: E402


def _train_cfg(steps: int = 8) -> dict:
    mlp = {"class_name": "MLPModel", "hidden_dims": [32, 32], "activation": "elu", "obs_normalization": True}
    return {
        "num_steps_per_env": steps, "save_interval": 1000, "obs_groups": {"actor": ["policy"], "critic": ["policy"]},
        "algorithm": {"class_name": "PPO", "num_learning_epochs": 2, "num_mini_batches": 2, "learning_rate": 1e-3},
        "actor": {**mlp, "distribution_cfg": {"class_name": "GaussianDistribution", "init_std": 1.0}},
        "critic": mlp,
    }


def _params(runner) -> torch.Tensor:
    return torch.cat([p.detach().reshape(-1).clone() for p in runner.alg.get_policy().parameters()])


def test_contract_matches_the_env_stepped_alone(rng):
    n, kw = 8, dict(device="cpu", seed=int(rng.integers(1 << 30)), timeout_steps=6, max_episode_steps=9)
    env = RslRlVecEnv(TrajectoryPlanningEnv, num_envs=n, **kw)
    twin = TrajectoryPlanningEnv(n, **kw)
    assert isinstance(env, VecEnv) and env.num_envs == n and env.num_actions == 6 and env.device == twin.device
    assert env.max_episode_length == 9 and env.cfg["num_envs"] == n
    torch.testing.assert_close(env.action_scale, torch.full((6,), 10.0))
    obs = env.get_observations()
    assert isinstance(obs, TensorDict) and list(obs.keys()) == ["policy"] and obs.batch_size == (n,)
    assert obs["policy"].shape == (n, 18) and obs["policy"].dtype == torch.float32
    twin_obs, _ = twin.reset()
    torch.testing.assert_close(obs["policy"], flatten_obs(twin_obs), rtol=0, atol=0)
    seen = {"time_out": 0, "terminated": 0, "both": 0}
    for _ in range(30):
        action = torch.as_tensor(rng.uniform(-1.5, 1.5, (n, 6)), dtype=torch.float32)
        action[: n // 2] *= 0.02  # gentle worlds run into the time-outs (a CI seed crashed every world first)
        obs, reward, dones, extras = env.step(action)
        t_obs, t_reward, term, trunc, info = twin.step(action * 10.0)
        torch.testing.assert_close(obs["policy"], flatten_obs(t_obs), rtol=0, atol=0)
        torch.testing.assert_close(reward, t_reward, rtol=0, atol=0)
        assert reward.shape == (n,) and reward.dtype == torch.float32
        assert dones.dtype == torch.long and dones.tolist() == (term | trunc).long().tolist()
        assert extras["time_outs"].dtype == torch.bool
        assert extras["time_outs"].tolist() == (trunc & ~term).tolist()
        assert extras["log"]["Magwarp/mover_collision"].tolist() == info["mover_collision"].float().tolist()
        assert extras["log"]["Magwarp/goals_reached"].tolist() == info["goals_reached"].sum(1).float().tolist()
        assert "Magwarp/_final_obs" not in extras["log"]
        # reset on done: a finished env starts its next episode in the same step
        assert env.episode_length_buf[dones.bool()].eq(0).all()
        assert env.get_observations() is obs
        seen["time_out"] += int((trunc & ~term).sum())
        seen["terminated"] += int((term & ~trunc).sum())
    assert seen["time_out"] > 0 and seen["terminated"] > 0, seen


def test_episode_length_buf_moves_the_cut_not_the_timeout():
    env = RslRlVecEnv("magwarp/TrajectoryPlanningB0-v0", num_envs=3, device="cpu", seed=0, max_episode_steps=5,
                      timeout_steps=50)
    base = env.env
    zero = torch.zeros(3, 6)
    env.step(zero)
    since_goal = base.num_steps - base.last_goal_step
    env.episode_length_buf = torch.tensor([0, 2, 3])
    assert base.num_steps.tolist() == [0, 2, 3] and env.episode_length_buf is base.num_steps
    assert (base.num_steps - base.last_goal_step).tolist() == since_goal.tolist()
    _, _, d1, e1 = env.step(zero)
    _, _, d2, e2 = env.step(zero)
    assert d1.tolist() == [0, 0, 0] and d2.tolist() == [0, 0, 1] and e2["time_outs"].tolist() == [False, False, True]
    with pytest.raises(ValueError, match="integer tensor of shape"):
        env.episode_length_buf = torch.zeros(3)
    with pytest.raises(ValueError, match=">= 0"):
        env.episode_length_buf = torch.tensor([0, -1, 0])


def test_errors_name_the_bad_value():
    with pytest.raises(ValueError, match="obs_mode"):
        RslRlVecEnv(TrajectoryPlanningEnv, num_envs=1, device="cpu", obs_mode="stacked")
    with pytest.raises(ValueError, match="clip_actions"):
        RslRlVecEnv(TrajectoryPlanningEnv, num_envs=1, device="cpu", clip_actions=-1.0)
    with pytest.raises(ValueError, match="autoreset"):
        RslRlVecEnv(TrajectoryPlanningEnv(1, device="cpu", autoreset=False))
    with pytest.raises(TypeError, match="wraps a MagwarpVecEnv"):
        RslRlVecEnv(object())
    env = RslRlVecEnv(TrajectoryPlanningEnv(1, device="cpu"))
    with pytest.raises(ValueError, match="max_episode_steps=None"):
        env.max_episode_length  # noqa: B018


def test_dict_groups_and_clipping():
    env = RslRlVecEnv(TrajectoryPlanningEnv, num_envs=2, device="cpu", seed=3, obs_mode="dict", clip_actions=1.0)
    twin = TrajectoryPlanningEnv(2, device="cpu", seed=3)
    twin.reset()  # the adapter resets once
    assert sorted(env.get_observations().keys()) == ["achieved_goal", "desired_goal", "observation"]
    action = torch.tensor([[5.0, -5.0, 0.5, 0.0, 0.0, 0.0]] * 2)
    obs, reward, _, _ = env.step(action)
    t_obs, t_reward, *_ = twin.step(torch.tensor([[10.0, -10.0, 5.0, 0.0, 0.0, 0.0]] * 2))
    for k in t_obs:
        torch.testing.assert_close(obs[k], t_obs[k], rtol=0, atol=0)
    torch.testing.assert_close(reward, t_reward, rtol=0, atol=0)


def test_on_policy_runner_trains_b0(tmp_path):
    torch.manual_seed(0)
    env = RslRlVecEnv("magwarp/TrajectoryPlanningB0-v0", num_envs=16, device="cpu", seed=0, max_episode_steps=20)
    runner = OnPolicyRunner(env, _train_cfg(), log_dir=str(tmp_path), device="cpu")
    before = _params(runner)
    runner.learn(3, init_at_random_ep_len=True)
    assert not torch.equal(before, _params(runner))
    assert (tmp_path / "model_2.pt").exists() and len(runner.logger.rewbuffer) > 0
    policy = runner.get_inference_policy()
    with torch.inference_mode():
        action = policy(env.get_observations())
    assert action.shape == (16, 6) and torch.isfinite(action).all()
    env.step(action.clone())  # the trained policy drives the env


def _record_steps(base) -> list:
    """Make ``base.step`` append ``(action, outputs)`` of every call to the returned list."""
    calls, step = [], base.step

    def recording_step(action):
        out = step(action)
        calls.append((action.clone(), out))
        return out

    base.step = recording_step
    return calls


def test_on_policy_runner_trains_push_box(tmp_path):
    env = RslRlVecEnv(PushBoxEnv, num_envs=4, device="cpu", seed=0, max_episode_steps=3, num_cycles=10)
    calls = _record_steps(env.env)
    assert env.get_observations()["policy"].shape == (4, 8) and env.max_episode_length == 3
    for step in range(3):
        action = torch.full((4, 2), 0.3)
        obs, reward, dones, extras = env.step(action)
        sent, (t_obs, t_reward, term, trunc, _) = calls[-1]
        torch.testing.assert_close(sent, torch.full((4, 2), 3.0))
        torch.testing.assert_close(obs["policy"], flatten_obs(t_obs), rtol=0, atol=0)
        assert reward is t_reward and dones.tolist() == (term | trunc).long().tolist()
        assert extras["time_outs"].tolist() == (trunc & ~term).tolist() == [step == 2] * 4
    runner = OnPolicyRunner(env, _train_cfg(steps=3), log_dir=None, device="cpu")
    before = _params(runner)
    runner.learn(2, init_at_random_ep_len=True)
    assert not torch.equal(before, _params(runner)) and len(calls) == 3 + 2 * 3


def _example(name: str):
    path = Path(__file__).resolve().parent.parent / "examples" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_custom_env_with_box_observations():
    tut = _example("custom_env_tutorial")
    env = RslRlVecEnv(tut.ParkingEnv(num_envs=4, device="cpu", seed=0, max_steps=3))
    obs = env.get_observations()
    assert list(obs.keys()) == ["policy"] and obs["policy"].shape == (4, 12)
    for step in range(3):
        obs, reward, dones, extras = env.step(torch.zeros(4, 6))
        assert extras["time_outs"].tolist() == [step == 2] * 4
        assert extras["log"]["Magwarp/collision"].tolist() == [0.0] * 4 and "Magwarp/parked" not in extras["log"]
    with pytest.raises(AttributeError, match="no per-episode step counter"):
        env.episode_length_buf  # noqa: B018
    runner = OnPolicyRunner(env, _train_cfg(steps=3), log_dir=None, device="cpu")
    runner.learn(1)
    assert runner.current_learning_iteration == 0 and torch.isfinite(_params(runner)).all()


def test_train_rsl_rl_example(tmp_path):
    example = _example("train_rsl_rl")
    stats = example.main(["--device", "cpu", "--num-envs", "16", "--iterations", "2", "--steps-per-env", "4",
                          "--hidden", "16,16", "--eval-steps", "20", "--log-dir", str(tmp_path)])
    assert stats["episodes"] > 0 and 0.0 <= stats["success_rate"] <= 1.0
    assert (tmp_path / "model_1.pt").exists() and (tmp_path / "policy.pt").exists()
