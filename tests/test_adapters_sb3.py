"""Stable-Baselines3 adapter: VecEnv API, terminal observations, HER's compute_reward, SAC+HER, SB3's check_env."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
import torch

pytest.importorskip("stable_baselines3")

from magwarp.envs import TrajectoryPlanningEnv  # noqa: E402
from magwarp.envs.adapters import SB3VecEnv  # noqa: E402


def test_sb3_check_env_on_single_env_view():
    from stable_baselines3.common.env_checker import check_env

    # SB3 2.9's goal-env check calls env.compute_reward on the outermost wrapper, which gymnasium 1.x wrappers no
    # longer forward (its _is_goal_env looks at env.unwrapped), so the check runs on the single-env view itself.
    env = gym.make("magwarp/TrajectoryPlanning-v0")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # the [-10, 10] m/s² action box is MagBotSim's, not normalised
        check_env(env.unwrapped)
    env.close()


def test_vec_env_api(rng):
    n = 6
    venv = SB3VecEnv("magwarp/TrajectoryPlanningB0-v0", num_envs=n, seed=1)
    assert venv.num_envs == n and isinstance(venv.env, TrajectoryPlanningEnv)
    assert venv.observation_space == venv.env.single_observation_space
    assert venv.action_space == venv.env.single_action_space
    assert venv.render_mode is None
    venv.seed(5)
    obs = venv.reset()
    assert set(obs) == {"observation", "achieved_goal", "desired_goal"}
    assert all(isinstance(v, np.ndarray) and v.shape == (n, 6) and v.dtype == np.float32 for v in obs.values())
    finished = 0
    for _ in range(40):
        act = rng.uniform(-10, 10, (n, 6)).astype(np.float32)
        goals = venv.env.goals.numpy().copy()
        obs, rew, done, infos = venv.step(act)
        assert rew.shape == (n,) and rew.dtype == np.float32 and done.dtype == bool and len(infos) == n
        for i, info in enumerate(infos):
            assert ("terminal_observation" in info) == bool(done[i])
            if done[i]:
                term = info["terminal_observation"]
                # the terminal observation is the last one of the episode: its goals are the ones the step started with
                np.testing.assert_array_equal(term["desired_goal"], goals[i].reshape(-1))
                assert not np.array_equal(term["achieved_goal"], obs["achieved_goal"][i])
                assert (obs["observation"][i] == 0).all()
                assert info["TimeLimit.truncated"] == (not (info["mover_collision"] or info["wall_collision"]))
                finished += 1
            else:
                assert info["TimeLimit.truncated"] is False
        # stored (next_obs or terminal_observation, infos) reproduce the rewards through HER's call
        nxt = {k: np.stack([infos[i]["terminal_observation"][k] if done[i] else obs[k][i] for i in range(n)]) for k in obs}
        again = venv.env_method("compute_reward", nxt["achieved_goal"], nxt["desired_goal"], infos, indices=[0])
        assert len(again) == 1
        np.testing.assert_array_equal(again[0], rew)
    assert finished > 0
    assert venv.get_attr("num_movers") == [3] * n
    assert venv.get_attr("threshold_pos", indices=[0, 2]) == [0.1, 0.1]
    venv.set_attr("reward_per_step", -2.0)
    assert venv.env.reward_per_step == -2.0
    assert venv.env_is_wrapped(gym.Wrapper) == [False] * n
    assert venv.env_method("goal_distance", torch.zeros(6), torch.ones(6), indices=1)[0].shape == (3,)
    assert venv.has_attr("sim") and not venv.has_attr("no_such_attribute")
    # HER without stored infos: empty dicts mean no collision
    r = venv.env_method("compute_reward", np.zeros((4, 6)), np.zeros((4, 6)), [{}] * 4, indices=[0])[0]
    np.testing.assert_array_equal(r, [60.0] * 4)
    venv.close()


def test_seed_makes_resets_reproducible(rng):
    venv = SB3VecEnv(TrajectoryPlanningEnv(num_envs=4, seed=0))
    acts = rng.uniform(-10, 10, (15, 4, 6)).astype(np.float32)

    def run():
        venv.seed(123)
        out = [venv.reset()["achieved_goal"].copy()]
        for a in acts:
            o, r, d, _ = venv.step(a)
            out += [o["achieved_goal"].copy(), r.copy()]
        return out

    for x, y in zip(run(), run()):
        np.testing.assert_array_equal(x, y)


def test_adapter_argument_errors():
    with pytest.raises(ValueError, match="autoreset"):
        SB3VecEnv(TrajectoryPlanningEnv(num_envs=2, autoreset=False))
    with pytest.raises(TypeError, match="instance"):
        SB3VecEnv(TrajectoryPlanningEnv(num_envs=2), num_envs=3)
    venv = SB3VecEnv(TrajectoryPlanningEnv, num_envs=2)
    venv.reset()
    with pytest.raises(ValueError, match=r"\(2, 6\)"):
        venv.step(np.zeros((2, 5), np.float32))
    with pytest.raises(RuntimeError, match="step_async"):
        venv.step_wait()


def test_sac_her_runs(rng):
    from stable_baselines3 import SAC, HerReplayBuffer

    venv = SB3VecEnv("magwarp/TrajectoryPlanningB0-v0", num_envs=4, seed=int(rng.integers(1 << 30)))
    model = SAC(
        "MultiInputPolicy", venv, replay_buffer_class=HerReplayBuffer,
        replay_buffer_kwargs=dict(n_sampled_goal=4, goal_selection_strategy="future", copy_info_dict=True),
        learning_starts=64, batch_size=32, buffer_size=2000, policy_kwargs=dict(net_arch=[16, 16]),
        train_freq=1, gradient_steps=1, seed=0, device="cpu",
    )
    model.learn(total_timesteps=300)
    assert model.num_timesteps >= 300
    action, _ = model.predict(venv.reset(), deterministic=True)
    assert action.shape == (4, 6)
