"""Parameter-shared (IPPO) training on the swarm: ``magwarp train magwarp/Swarm-v0`` runs the package's PPO on the
flat agent view (every mover of every world one sub-env, one network), and the saved policy acts zero-shot on a
larger swarm (its observation is local: the same width for any number of movers), through ``magwarp eval`` too."""

from __future__ import annotations

import json
import os

import numpy as np
import torch

from magwarp import cli
from magwarp.swarm import FlatSwarmEnv, SwarmEnv
from magwarp.training.common import make_env
from magwarp.training.policy import load_policy

SMALL = {"num_movers": 8, "layout": np.ones((6, 6), dtype=int).tolist()}


def test_training_envs_come_as_the_flat_agent_view():
    env, base = make_env("magwarp/Swarm-v0", 3, "cpu", 0, {"num_movers": 5, "layout": np.ones((5, 5))})
    assert isinstance(env, FlatSwarmEnv) and base is env and env.num_envs == 15
    obs, _ = env.reset(seed=1)
    assert obs.shape == (15, env.single_observation_space.shape[0])
    obs, reward, terminated, truncated, info = env.step(torch.zeros(15, 2))
    # PPO reads final_obs every step; worlds that never end report none finished
    assert info["final_obs"].shape == obs.shape and not info["_final_obs"].any()
    assert info["goals_reached"].shape == (15, 1) and info["time_limit"].shape == (15,)
    assert reward.shape == terminated.shape == truncated.shape == (15,)
    assert env.num_cycles == base.env.num_cycles


def test_train_small_swarm_then_act_zero_shot_on_a_larger_one(tmp_path, capsys):
    out = str(tmp_path / "run")
    rc = cli.main(["train", "magwarp/Swarm-v0", "--num-envs", "2", "--total-steps", "512", "--device", "cpu",
                   "--seed", "0", "--out", out, "--env-kwargs", json.dumps(SMALL),
                   "--args", "--num-steps 8 --eval-steps 5 --no-progress --hidden 32,32"])
    assert rc == 0, capsys.readouterr().err
    assert os.path.exists(os.path.join(out, "policy.pt"))
    summary = json.load(open(os.path.join(out, "run.json")))
    assert summary["summary"]["global_step"] >= 512
    policy = load_policy(os.path.join(out, "policy.pt"))  # TorchScript: no trust needed
    big = SwarmEnv(1, num_movers=100, device="cpu", seed=3)
    obs, _ = big.reset(seed=3)
    with torch.no_grad():
        for _ in range(3):
            action = policy(obs)
            assert action.shape == (1, 100, 2) and torch.isfinite(action).all()
            assert float(action.abs().max()) <= big.config.a_max + 1e-5
            obs, *_ = big.step(action)
    # and through magwarp eval, on 64 movers (default layout for them)
    rc = cli.main(["eval", "magwarp/Swarm-v0", "--policy", os.path.join(out, "policy.pt"), "--episodes", "1",
                   "--repeats", "1", "--steps", "3", "--device", "cpu", "--env-kwargs", '{"num_movers": 64}'])
    text = capsys.readouterr().out
    assert rc == 0 and "Throughput" in text
