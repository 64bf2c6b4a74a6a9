"""magwarp/CoopPush-v0: the heavy object needs two movers, per-agent views, the multi-agent adapters, the scripted
baseline and the eval table."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

import magwarp  # noqa: F401 - registers the ids
from magwarp.envs.coop_push import GRAVITY, CoopPushEnv, heavy_object_mass

GAP = 0.1 + 0.155 / 2 + 0.003  # object half-size + mover half-size + 3 mm: a mover just behind the object's -x face


@pytest.fixture(scope="module")
def env():
    """Two worlds, two movers, no autoreset (a world is stepped past its episode's end where a test needs it)."""
    return CoopPushEnv(num_envs=2, device="cpu", seed=0, autoreset=False)


def _place(env, movers, obj=(0.72, 0.72), goal=(1.1, 0.72)):
    n = env.num_envs
    return env.reset(seed=0, options={
        "mover_xy": torch.as_tensor(movers, dtype=torch.float32),
        "object_xy": torch.tensor([obj] * n), "object_yaw": torch.zeros(n), "goal_xy": torch.tensor([goal] * n)})


def test_heavy_object_mass_is_the_documented_number():
    mass = heavy_object_mass(1.24, 10.0, 0.6, 1.5)
    assert mass == pytest.approx(1.5 * 12.4 / (0.6 * 9.81))
    assert mass == pytest.approx(3.16, abs=0.005)
    with pytest.raises(ValueError, match="force_ratio"):
        heavy_object_mass(1.24, 10.0, 0.6, -1.0)


def test_defaults_need_two_movers(env):
    assert env.object.mass == pytest.approx(3.16, abs=0.005)
    assert env.mover_force == pytest.approx(12.4)
    assert env.friction_force == pytest.approx(0.6 * env.object.mass * GRAVITY)
    assert env.mover_force < env.friction_force < 2 * env.mover_force
    assert env.movers_needed == 2


def test_one_mover_cannot_move_the_object_but_two_can(env):
    """World 0: one mover pushes +x at its acceleration limit for 1 s (the other is parked far away); world 1: two
    movers side by side do the same."""
    obs, _ = _place(env, [[[0.72 - GAP, 0.72], [0.3, 1.2]],
                          [[0.72 - GAP, 0.72 - 0.09], [0.72 - GAP, 0.72 + 0.09]]])
    start = obs["achieved_goal"].clone()
    action = torch.tensor([[10.0, 0.0, 0.0, 0.0], [10.0, 0.0, 10.0, 0.0]])
    for _ in range(25):
        obs, _, terminated, _, info = env.step(action)
        assert not terminated.any() and not info["mover_collision"].any()
    moved = (obs["achieved_goal"] - start).norm(dim=-1)
    assert moved[0] < 0.005, moved  # MuJoCo's soft friction creeps ~2.5 mm under a 12.4 N push on 18.6 N of friction
    assert moved[1] > 0.05, moved
    # the object's state is the tail of "observation"
    o = obs["observation"][:, -6:]
    assert torch.allclose(o[:, :2], obs["achieved_goal"])
    assert torch.allclose(o[:, 2] ** 2 + o[:, 3] ** 2, torch.ones(2))
    assert o[1, 4] > 0.1  # world 1's object moves along +x


def _agent_reference(obs: dict, m: int, dict_mode: bool):
    """Per-agent observations built element by element in numpy (the documented layout)."""
    o = obs["observation"].numpy()
    n = o.shape[0]
    pos, vel, objs = o[:, :2 * m].reshape(n, m, 2), o[:, 2 * m:4 * m].reshape(n, m, 2), o[:, 4 * m:]
    goal = obs["desired_goal"].numpy()
    rows = []
    for w in range(n):
        for i in range(m):
            others = [j for j in range(m) if j != i]
            row = [*pos[w, i], *vel[w, i], *(objs[w, :2] - pos[w, i]), *objs[w, 2:]]
            if not dict_mode:
                row += [*(goal[w, :2] - pos[w, i])]
            row += sum(([*(pos[w, j] - pos[w, i])] for j in others), [])
            row += sum(([*vel[w, j]] for j in others), [])
            rows.append(row)
    return np.asarray(rows, np.float32).reshape(n, m, -1)


@pytest.mark.parametrize("num_movers", [2, 3])
def test_agent_observations_match_the_documented_layout(rng, num_movers):
    from magwarp.envs.coop_push import CoopAgentObservations

    n, m = 3, num_movers
    fake = type("E", (), {"num_movers": m, "learn_jerk": False, "learn_pose": False, "device": torch.device("cpu")})
    obs = {"observation": torch.as_tensor(rng.normal(size=(n, 4 * m + 6)), dtype=torch.float32),
           "achieved_goal": torch.as_tensor(rng.normal(size=(n, 2)), dtype=torch.float32),
           "desired_goal": torch.as_tensor(rng.normal(size=(n, 2)), dtype=torch.float32)}
    flat = CoopAgentObservations(fake, "flat")
    got = flat(obs)
    assert got.shape == (n, m, flat.dim_flat) and flat.spaces().shape == (flat.dim_flat,)
    np.testing.assert_allclose(got.numpy(), _agent_reference(obs, m, False), rtol=1e-6, atol=1e-6)
    split = CoopAgentObservations(fake, "dict")(obs)
    np.testing.assert_allclose(split["observation"].numpy(), _agent_reference(obs, m, True), rtol=1e-6, atol=1e-6)
    assert torch.equal(split["desired_goal"][:, 1], obs["desired_goal"])
    assert torch.equal(split["achieved_goal"][:, -1], obs["achieved_goal"])
    with pytest.raises(ValueError, match="obs_mode"):
        CoopAgentObservations(fake, "bogus")


def test_bad_options_are_refused():
    with pytest.raises(ValueError, match="num_movers=1"):
        CoopPushEnv(num_envs=1, num_movers=1, device="cpu")
    with pytest.raises(ValueError, match="num_movers=5"):
        CoopPushEnv(num_envs=1, num_movers=5, device="cpu")
    with pytest.raises(ValueError, match="learn_mover_c_rotation"):
        CoopPushEnv(num_envs=1, learn_mover_c_rotation=True, device="cpu")
    with pytest.raises(ValueError, match="too small"):
        CoopPushEnv(num_envs=1, layout=np.ones((3, 3), np.int32), device="cpu")


def test_gymnasium_check_env():
    from gymnasium.utils.env_checker import check_env

    env = gym.make("magwarp/CoopPush-v0", device="cpu")
    check_env(env.unwrapped, skip_render_check=True)
    obs, _ = env.reset(seed=3)
    assert obs["observation"].shape == (14,)
    env.close()


def test_pettingzoo_parallel_api():
    from pettingzoo.test import parallel_api_test

    from magwarp.envs.adapters import MagwarpParallelEnv

    pz = MagwarpParallelEnv(CoopPushEnv, device="cpu", max_episode_steps=20)
    parallel_api_test(pz, num_cycles=30)
    assert pz.possible_agents == ["mover_0", "mover_1"]
    assert pz.metadata["name"] == "magwarp_coop_push_v0"
    obs, _ = pz.reset(seed=1)
    assert obs["mover_0"].shape == pz.observation_space("mover_0").shape == (16,)
    # the shared reward, per-agent infos, and a state for centralised critics
    obs, rewards, term, trunc, infos = pz.step({a: np.zeros(2, np.float32) for a in pz.agents})
    assert rewards["mover_0"] == rewards["mover_1"] and set(infos["mover_1"]) >= {"goal_reached", "mover_collision"}
    assert pz.state().shape == (18,)
    with pytest.raises(ValueError, match=r"shape \(2,\)"):
        pz.step({"mover_0": np.zeros(3, np.float32), "mover_1": np.zeros(2, np.float32)})
    pz.close()


def test_three_movers_get_a_wider_object_and_three_agents():
    from magwarp.envs.adapters import MagwarpParallelEnv

    pz = MagwarpParallelEnv(CoopPushEnv, obs_mode="dict", device="cpu", num_movers=3)
    assert pz.vec.object.width == pytest.approx(0.15) and pz.vec.movers_needed == 2
    obs, _ = pz.reset(seed=0)
    assert pz.possible_agents == ["mover_0", "mover_1", "mover_2"]
    assert obs["mover_2"]["observation"].shape == (4 + 6 + 8,)
    np.testing.assert_array_equal(obs["mover_0"]["desired_goal"], obs["mover_2"]["desired_goal"])
    pz.close()


def test_pettingzoo_still_refuses_single_agent_pushing():
    from magwarp.envs.adapters import MagwarpParallelEnv
    from magwarp.envs.push import PushBoxEnv

    with pytest.raises(TypeError, match="single-agent pushing"):
        MagwarpParallelEnv(PushBoxEnv, device="cpu")


def test_torchrl_multi_agent_group(env):
    from torchrl.envs.utils import check_env_specs

    from magwarp.envs.adapters import TorchRLEnv

    trl = TorchRLEnv(CoopPushEnv, num_envs=2, multi_agent=True, device="cpu", seed=0)
    check_env_specs(trl)
    td = trl.rollout(3)
    assert td["agents", "observation"].shape == (2, 3, 2, 16)
    assert td["next", "agents", "reward"].shape == (2, 3, 2, 1)
    r = td["next", "agents", "reward"]
    assert torch.equal(r[:, :, 0], r[:, :, 1])  # shared
    assert td["next", "state"].shape == (2, 3, 18)


@pytest.fixture(scope="module")
def solved():
    """The scripted baseline on 16 worlds for one episode (100 steps): success per world, collisions."""
    env = CoopPushEnv(num_envs=16, device="cpu", seed=1, autoreset=False)
    policy = env.scripted_policy()
    obs, _ = env.reset(seed=1)
    done = torch.zeros(16, dtype=torch.bool)
    success = torch.zeros(16, dtype=torch.bool)
    for _ in range(env.max_episode_steps):
        obs, _, terminated, truncated, info = env.step(policy(obs))
        success = torch.where(done, success, info["is_success"])
        done |= terminated | truncated
    assert done.all()
    return success


def test_scripted_baseline_solves_a_real_share(solved):
    # measured: 13 of 16 worlds (81%) with seed 1, no collision (three movers: 7 of 16, four: 3 of 16)
    assert solved.float().mean() >= 0.5, solved


def test_eval_prints_the_push_table(capsys):
    from magwarp import cli

    rc = cli.main(["eval", "magwarp/CoopPush-v0", "--policy", "scripted", "--episodes", "4", "--repeats", "1",
                   "--device", "cpu"])
    out, err = capsys.readouterr()
    assert rc == 0, err
    assert "magwarp/CoopPush-v0" in out and "1 repeats x 4 episodes" in out
    for label in ("Success Rate (%)", "Mover-Mover Collisions", "Overshoot Corrections", "Distance Corrections"):
        assert label in out, out
