"""TorchRL adapter: specs, check_env_specs, "_reset" masks, rollouts with partial resets, multi-agent group."""

from __future__ import annotations

import numpy as np
import pytest
import torch

pytest.importorskip("torchrl")
pytest.importorskip("tensordict")

from torchrl.envs.utils import check_env_specs  # noqa: E402

from magwarp.envs import TrajectoryPlanningEnv  # noqa: E402
from magwarp.envs.adapters import TorchRLEnv  # noqa: E402


@pytest.mark.parametrize("kwargs", [
    dict(),
    dict(learn_jerk=True, layout="B3"),
    dict(multi_agent=True),
    dict(multi_agent=True, obs_mode="dict", learn_jerk=True, layout="B8"),
])
def test_check_env_specs(kwargs):
    env = TorchRLEnv(TrajectoryPlanningEnv, num_envs=4, seed=0, **kwargs)
    assert env.batch_size == torch.Size([4])
    check_env_specs(env, seed=0)


def test_single_agent_specs_and_rollout(rng):
    n = 6
    env = TorchRLEnv(TrajectoryPlanningEnv, num_envs=n, seed=1)
    assert not env.env.autoreset
    assert env.action_spec.shape == (n, 6)
    assert torch.equal(env.action_spec.space.high, torch.full((n, 6), 10.0))
    assert set(env.observation_spec.keys()) == {"observation", "achieved_goal", "desired_goal"}
    assert env.reward_spec.shape == (n, 1)
    env.set_seed(int(rng.integers(1 << 30)))
    td = env.reset()
    dones = 0
    for _ in range(40):
        td["action"] = torch.from_numpy(rng.uniform(-10, 10, (n, 6)).astype(np.float32))
        goals = env.env.goals.reshape(n, -1).clone()
        td, td_next = env.step_and_maybe_reset(td)
        nxt = td["next"]
        # rewards follow the env's own reward of the observation it returned
        again = env.env.compute_reward(nxt["achieved_goal"], nxt["desired_goal"], None)
        col = nxt["terminated"].squeeze(-1)
        expect = torch.where(col, torch.full_like(again, -20.0), again)
        torch.testing.assert_close(nxt["reward"].squeeze(-1), expect)
        torch.testing.assert_close(nxt["desired_goal"], goals)
        done = nxt["done"].squeeze(-1)
        assert torch.equal(done, nxt["terminated"].squeeze(-1) | nxt["truncated"].squeeze(-1))
        # finished envs restart at rest, the others carry on from "next"
        assert (td_next["observation"][done] == 0).all()
        assert not td_next["done"].any()
        torch.testing.assert_close(td_next["achieved_goal"][~done], nxt["achieved_goal"][~done])
        dones += int(done.sum())
        td = td_next
    assert dones > 0


def test_reset_mask_resets_only_masked_envs(rng):
    n = 5
    env = TorchRLEnv(TrajectoryPlanningEnv, num_envs=n, seed=2)
    td = env.reset()
    for _ in range(3):
        td["action"] = torch.from_numpy(rng.uniform(-0.2, 0.2, (n, 6)).astype(np.float32))
        td = env.step(td)["next"].clone()
    assert not td["done"].any(), "pick gentler actions: an env finished"
    mask = torch.tensor([False, True, False, False, True])
    before = {k: td[k].clone() for k in ("observation", "achieved_goal", "desired_goal")}
    pos_before = env.env.sim.pos.clone()
    # as TorchRL's collectors do: the current data plus the "_reset" mask
    out = env.reset(td.exclude("action").set("_reset", mask[:, None]))
    for k, v in before.items():
        torch.testing.assert_close(out[k][~mask], v[~mask])
    assert (out["observation"][mask] == 0).all()
    torch.testing.assert_close(env.env.sim.pos[~mask], pos_before[~mask])
    assert not torch.equal(env.env.sim.pos[mask], pos_before[mask])
    assert (env.env.num_steps[mask] == 0).all() and (env.env.num_steps[~mask] == 3).all()


def test_multi_agent_group(rng):
    n = 3
    env = TorchRLEnv(TrajectoryPlanningEnv, num_envs=n, multi_agent=True, seed=3)
    m = env.num_movers
    assert env.action_key == ("agents", "action")
    assert env.reward_key == ("agents", "reward")
    assert env.full_action_spec["agents", "action"].shape == (n, m, 2)
    assert env.full_observation_spec["agents", "observation"].shape == (n, m, 6 + 4 * (m - 1))
    td = env.reset()
    # move only agent 1
    action = torch.zeros(n, m, 2)
    action[:, 1] = torch.tensor([2.0, -1.0])
    td["agents", "action"] = action
    nxt = env.step(td)["next"]
    vel = env.env.sim.vel[..., :2]
    assert (vel[:, [0, 2]] == 0).all() and (vel[:, 1] != 0).all()
    torch.testing.assert_close(nxt["agents", "observation"][:, 1, :2], vel[:, 1])
    r = nxt["agents", "reward"]
    assert r.shape == (n, m, 1) and (r == r[:, :1]).all()
    assert nxt["state"].shape == (n, 6 * m)
    rollout = env.rollout(30, break_when_any_done=False)
    assert rollout["next", "agents", "reward"].shape == (n, 30, m, 1)


def test_seeded_rollouts_repeat():
    env = TorchRLEnv(TrajectoryPlanningEnv, num_envs=4, seed=0)
    torch.manual_seed(0)
    policy_actions = torch.rand(25, 4, 6) * 20 - 10

    def run():
        env.set_seed(42)
        td = env.reset()
        out = []
        for a in policy_actions:
            td["action"] = a
            td, td_next = env.step_and_maybe_reset(td)
            out.append(td["next"].clone())
            td = td_next
        return torch.stack(out)

    a, b = run(), run()
    assert (a == b).all()


def test_wrong_arguments():
    with pytest.raises(TypeError, match="instance"):
        TorchRLEnv(TrajectoryPlanningEnv(num_envs=2), num_envs=2)
    with pytest.raises(TypeError, match="MagwarpVecEnv"):
        TorchRLEnv(object())
