"""PettingZoo adapter and the batched multi-agent torch view: API test, per-agent observation contents, shared
rewards and flags, action routing, errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch

pytest.importorskip("pettingzoo")

from pettingzoo.test import parallel_api_test  # noqa: E402

from magwarp.envs import TrajectoryPlanningEnv  # noqa: E402
from magwarp.envs.adapters import MagwarpParallelEnv, MultiAgentVecEnv  # noqa: E402


def _np(x):
    return x.detach().cpu().numpy()


def _expected_agent_obs(obs: dict[str, np.ndarray], m: int, jerk: bool) -> np.ndarray:
    """Per-agent flat observation of one world, written out mover by mover (the documented layout)."""
    vel = obs["observation"][: 2 * m].reshape(m, 2)
    acc = obs["observation"][2 * m:].reshape(m, 2) if jerk else None
    pos = obs["achieved_goal"].reshape(m, 2)
    goal = obs["desired_goal"].reshape(m, 2)
    rows = []
    for i in range(m):
        others = [j for j in range(m) if j != i]
        own = [vel[i], acc[i]] if jerk else [vel[i]]
        rows.append(np.concatenate([*own, pos[i], goal[i], *[pos[j] - pos[i] for j in others], *[vel[j] for j in others]]))
    return np.stack(rows)


def test_parallel_api_test_defaults():
    env = MagwarpParallelEnv()
    assert env.possible_agents == ["mover_0", "mover_1", "mover_2"]
    assert env.vec.layout_name == "B0" and env.vec.num_envs == 1 and not env.vec.autoreset
    parallel_api_test(env, num_cycles=120)


def test_parallel_api_test_dict_obs_jerk_other_layout():
    env = MagwarpParallelEnv(obs_mode="dict", layout="B3", learn_jerk=True)
    assert len(env.possible_agents) == 4
    parallel_api_test(env, num_cycles=80)


@pytest.mark.parametrize("learn_jerk", [False, True])
def test_agent_observations_rewards_and_flags(rng, learn_jerk):
    env = MagwarpParallelEnv(learn_jerk=learn_jerk, seed=3)
    m = len(env.possible_agents)
    obs, infos = env.reset(seed=int(rng.integers(1 << 30)))
    vec_obs = {k: _np(v[0]) for k, v in env.vec._get_obs().items()}
    expect = _expected_agent_obs(vec_obs, m, learn_jerk)
    for i, a in enumerate(env.possible_agents):
        np.testing.assert_allclose(obs[a], expect[i], rtol=0, atol=1e-6)
        assert obs[a].dtype == np.float32 and env.observation_space(a).contains(obs[a])
    np.testing.assert_array_equal(env.state(), np.concatenate([vec_obs[k] for k in ("observation", "achieved_goal", "desired_goal")]))
    limit = float(env.action_space("mover_0").high[0])
    assert limit == (100.0 if learn_jerk else 10.0)
    for _ in range(40):
        actions = {a: rng.uniform(-limit, limit, 2).astype(np.float32) for a in env.agents}
        before_goals = _np(env.vec.goals[0]).copy()
        obs, rew, term, trunc, infos = env.step(actions)
        assert len(set(rew.values())) == 1 and len(set(term.values())) == 1 and len(set(trunc.values())) == 1
        info0 = infos["mover_0"]
        r = next(iter(rew.values()))
        ach = np.stack([o[2 + 2 * learn_jerk: 4 + 2 * learn_jerk] for o in obs.values()]).reshape(-1)
        ref = float(_np(env.vec.compute_reward(torch.from_numpy(ach), torch.from_numpy(before_goals.reshape(-1)),
                                               {k: torch.tensor(info0[k]) for k in ("mover_collision", "wall_collision")})))
        assert r == ref, (r, ref, str(rng))
        assert next(iter(term.values())) == (info0["mover_collision"] or info0["wall_collision"])
        for i, a in enumerate(env.possible_agents):
            assert infos[a]["goal_reached"] == bool(np.linalg.norm(ach.reshape(m, 2)[i] - before_goals[i]) <= 0.1)
        if not env.agents:
            assert any(term.values()) or any(trunc.values())
            with pytest.raises(RuntimeError, match="reset"):
                env.step(actions)
            env.reset()
    env.close()


def test_actions_are_routed_to_their_mover():
    env = MagwarpParallelEnv(seed=0)
    env.reset(seed=1)
    obs, *_ = env.step({"mover_0": np.zeros(2), "mover_1": np.array([1.0, -2.0]), "mover_2": np.zeros(2)})
    vel = _np(env.vec.sim.vel[0, :, :2])
    assert np.abs(vel[[0, 2]]).max() == 0
    np.testing.assert_allclose(vel[1], np.array([1.0, -2.0]) * 0.04, rtol=1e-3)
    np.testing.assert_allclose(obs["mover_1"][:2], vel[1])


def test_bad_actions_and_arguments():
    env = MagwarpParallelEnv(seed=0)
    env.reset(seed=0)
    zero = {a: np.zeros(2, np.float32) for a in env.possible_agents}
    with pytest.raises(KeyError, match="mover_2"):
        env.step({a: v for a, v in zero.items() if a != "mover_2"})
    with pytest.raises(KeyError, match="mover_9"):
        env.step({**zero, "mover_9": np.zeros(2)})
    with pytest.raises(ValueError, match=r"mover_1.*\(3,\)"):
        env.step({**zero, "mover_1": np.zeros(3)})
    with pytest.raises(ValueError, match="nan"):
        env.step({**zero, "mover_0": np.array([np.nan, 0.0])})
    with pytest.raises(ValueError, match="obs_mode"):
        MagwarpParallelEnv(obs_mode="image")
    with pytest.raises(ValueError, match="autoreset"):
        MagwarpParallelEnv(TrajectoryPlanningEnv(num_envs=1))


def test_seeded_episodes_repeat(rng):
    env = MagwarpParallelEnv(seed=0)
    acts = [{a: rng.uniform(-10, 10, 2).astype(np.float32) for a in env.possible_agents} for _ in range(20)]

    def run():
        out = [env.reset(seed=7)[0]]
        for act in acts:
            if not env.agents:
                break
            out.append(env.step({a: act[a] for a in env.agents})[0])
        return out

    for x, y in zip(run(), run(), strict=True):
        for a in x:
            np.testing.assert_array_equal(x[a], y[a])


# ------------------------------------------------------------------------------------------ batched torch view
@pytest.mark.parametrize("obs_mode", ["flat", "dict"])
def test_batched_multi_agent_view(rng, obs_mode):
    n = 5
    env = TrajectoryPlanningEnv(num_envs=n, seed=2)
    ma = MultiAgentVecEnv(env, obs_mode=obs_mode)
    m = ma.num_movers
    assert ma.agents == [f"mover_{i}" for i in range(m)]
    obs, info = ma.reset(seed=int(rng.integers(1 << 30)))
    assert info["state"].shape == (n, ma.state_space.shape[0])
    for _ in range(25):
        actions = torch.from_numpy(rng.uniform(-10, 10, (n, m, 2)).astype(np.float32))
        obs, rew, term, trunc, info = ma.step(actions)
        assert rew.shape == term.shape == trunc.shape == (n, m)
        assert (rew == rew[:, :1]).all() and (term == term[:, :1]).all()
        final = info["final_obs"]
        done = _np(info["_final_obs"])
        flat = final if obs_mode == "flat" else None
        if flat is not None:
            got = _np(flat)
            assert got.shape == (n, m, ma.single_agent_observation_space.shape[0])
            state = _np(info["state"])
            for w in np.flatnonzero(~done):
                world = {"observation": state[w, : -4 * m], "achieved_goal": state[w, -4 * m: -2 * m],
                         "desired_goal": state[w, -2 * m:]}
                np.testing.assert_allclose(got[w], _expected_agent_obs(world, m, False), atol=1e-6)
        else:
            assert set(final) == {"observation", "achieved_goal", "desired_goal"}
            assert final["achieved_goal"].shape == (n, m, 2)
    with pytest.raises(ValueError, match=r"\(5, 3, 2\)"):
        ma.step(torch.zeros(n, 2 * m))
