"""skrl adapter: the wrapper contract against a twin env stepped alone, and skrl's own PPO agent with its
SequentialTrainer on trajectory planning (B0) for a few hundred timesteps on the CPU."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

pytest.importorskip("skrl")

from skrl import config  # noqa: E402
from skrl.envs.wrappers.torch import Wrapper  # noqa: E402
from skrl.utils.spaces.torch import unflatten_tensorized_space  # noqa: E402

from magwarp.envs import PushBoxEnv, TrajectoryPlanningEnv  # noqa: E402
from magwarp.envs.adapters import SkrlVecEnv  # noqa: E402
from magwarp.training import flatten_obs  # noqa: E402


def test_contract_matches_the_env_stepped_alone(rng):
    n, kw = 8, dict(device="cpu", seed=int(rng.integers(1 << 30)), timeout_steps=6, max_episode_steps=9)
    env = SkrlVecEnv(TrajectoryPlanningEnv, num_envs=n, **kw)
    twin = TrajectoryPlanningEnv(n, **kw)
    assert isinstance(env, Wrapper) and env.num_envs == n and env.num_agents == 1 and env.device == torch.device("cpu")
    assert env.action_space == twin.single_action_space and env.state_space is None and env.state() is None
    space = env.observation_space
    assert isinstance(space, gym.spaces.Box) and space.shape == (18,)
    assert space == gym.spaces.flatten_space(twin.single_observation_space)
    assert env.num_movers == 3  # attributes pass through to the magwarp env
    obs, info = env.reset()
    twin_obs, _ = twin.reset(seed=config.torch.key)  # the first reset is seeded with skrl's seed
    assert obs.shape == (n, 18) and obs.dtype == torch.float32 and info == {}
    torch.testing.assert_close(obs, flatten_obs(twin_obs), rtol=0, atol=0)
    seen = {"time_out": 0, "terminated": 0}
    # half the worlds collide (large actions: terminations), the other half creep until their timeout (time-outs);
    # all large actions gave a seed with no time-out at all in 30 steps
    scale = np.where(np.arange(n) < n // 2, 15.0, 0.3)[:, None]
    for _ in range(30):
        action = torch.as_tensor(rng.uniform(-1, 1, (n, 6)) * scale, dtype=torch.float32)
        obs, reward, terminated, truncated, info = env.step(action)
        t_obs, t_reward, term, trunc, t_info = twin.step(action)
        torch.testing.assert_close(obs, flatten_obs(t_obs), rtol=0, atol=0)
        # skrl's own unflattening of its observation space gives the goal dict back
        back = unflatten_tensorized_space(twin.single_observation_space, obs)
        assert all(torch.equal(back[k], t_obs[k]) for k in t_obs)
        assert reward.shape == terminated.shape == truncated.shape == (n, 1) and reward.dtype == torch.float32
        torch.testing.assert_close(reward[:, 0], t_reward, rtol=0, atol=0)
        assert terminated.dtype == truncated.dtype == torch.bool
        assert terminated[:, 0].tolist() == term.tolist() and truncated[:, 0].tolist() == (trunc & ~term).tolist()
        assert info["goals_reached"].tolist() == t_info["goals_reached"].tolist()
        # reset on done: a finished env starts its next episode in the same step, and reset() does not reset again
        assert env.env.num_steps[term | trunc].eq(0).all()
        again, _ = env.reset()
        assert again is obs
        seen["time_out"] += int((trunc & ~term).sum())
        seen["terminated"] += int(term.sum())
    assert seen["time_out"] > 0 and seen["terminated"] > 0, seen


def test_dict_space_and_errors():
    env = SkrlVecEnv("magwarp/TrajectoryPlanningB0-v0", num_envs=2, device="cpu", obs_mode="dict")
    assert env.observation_space == env.env.single_observation_space
    obs, _ = env.reset()
    assert sorted(unflatten_tensorized_space(env.observation_space, obs)) == ["achieved_goal", "desired_goal",
                                                                              "observation"]
    with pytest.raises(ValueError, match="obs_mode"):
        SkrlVecEnv(TrajectoryPlanningEnv, num_envs=1, device="cpu", obs_mode="tuple")
    with pytest.raises(ValueError, match="autoreset"):
        SkrlVecEnv(TrajectoryPlanningEnv(1, device="cpu", autoreset=False))
    with pytest.raises(TypeError, match="only accepted with an env id or class"):
        SkrlVecEnv(TrajectoryPlanningEnv(1, device="cpu"), num_envs=2)


def test_push_box_steps():
    env = SkrlVecEnv(PushBoxEnv, num_envs=2, device="cpu", seed=0, max_episode_steps=2, num_cycles=10)
    obs, _ = env.reset()
    assert obs.shape == (2, 8) and env.action_space.shape == (2,)
    for step in range(2):
        obs, reward, terminated, truncated, info = env.step(torch.zeros(2, 2))
        assert truncated[:, 0].tolist() == [step == 1] * 2 and not terminated.any()
        assert torch.isfinite(obs).all() and reward.shape == (2, 1)


def test_ppo_sequential_trainer_trains_b0(tmp_path):
    from skrl.agents.torch.ppo import PPO
    from skrl.memories.torch import RandomMemory
    from skrl.trainers.torch import SequentialTrainer
    from skrl.utils import set_seed
    from skrl.utils.model_instantiators.torch import deterministic_model, gaussian_model

    set_seed(0)
    env = SkrlVecEnv("magwarp/TrajectoryPlanningB0-v0", num_envs=16, device="cpu", max_episode_steps=20)
    net = [{"name": "net", "input": "OBSERVATIONS", "layers": [32, 32], "activations": "elu"}]
    spaces = dict(observation_space=env.observation_space, action_space=env.action_space, device=env.device)
    models = {"policy": gaussian_model(**spaces, clip_actions=True, network=net, output="ACTIONS"),
              "value": deterministic_model(**spaces, network=net, output="ONE")}
    memory = RandomMemory(memory_size=16, num_envs=env.num_envs, device=env.device)
    cfg = {"rollouts": 16, "learning_epochs": 2, "mini_batches": 2, "time_limit_bootstrap": True,
           "experiment": {"directory": str(tmp_path), "experiment_name": "b0", "write_interval": 50,
                          "checkpoint_interval": 200}}
    agent = PPO(models=models, memory=memory, cfg=cfg, **spaces)
    for role, model in models.items():  # the instantiators' lazy layers take their sizes from a first batch
        model.act({"observations": env.reset()[0]}, role=role)
    before = torch.cat([p.detach().reshape(-1).clone() for p in models["policy"].parameters()])
    calls = []
    step = env.env.step
    env.env.step = lambda action: calls.append(action) or step(action)
    SequentialTrainer(env=env, agents=agent, cfg={"timesteps": 200, "headless": True,
                                                  "disable_progressbar": True, "close_environment_at_exit": False}).train()
    after = torch.cat([p.detach().reshape(-1) for p in models["policy"].parameters()])
    assert len(calls) == 200 and not torch.equal(before, after)
    # the clipped Gaussian policy's actions reach the env inside the action space
    assert max(float(a.abs().max()) for a in calls) <= 10.0
    assert (tmp_path / "b0" / "checkpoints" / "agent_200.pt").exists()
