"""Multi-agent views of the swarm env: the flat parameter-shared VectorEnv, TorchRL's ``check_env_specs`` and
PettingZoo's ``parallel_api_test`` on small instances (with and without the shield)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from magwarp.swarm import FlatSwarmEnv, SwarmEnv

SMALL = dict(num_movers=5, layout=np.ones((4, 4)), k=2, num_rays=4, num_cycles=10, device="cpu")


def test_flat_view_matches_the_world_env(rng):
    seed = int(rng.integers(1 << 30))
    flat = FlatSwarmEnv(num_envs=3, max_episode_steps=4, seed=seed, **SMALL)
    ref = SwarmEnv(3, max_episode_steps=4, seed=seed, **SMALL)
    obs, _ = flat.reset(seed=seed)
    ref_obs, _ = ref.reset(seed=seed)
    assert obs.shape == (15, 4 + 10 + 4) and flat.single_action_space.shape == (2,)
    assert torch.equal(obs, ref_obs.reshape(15, -1))
    for t in range(4):
        action = torch.from_numpy(rng.normal(0, 8, (15, 2)).astype(np.float32))
        obs, reward, terminated, truncated, info = flat.step(action)
        r_obs, _, _, r_trunc, r_info = ref.step(action.reshape(3, 5, 2))
        assert torch.equal(obs, r_obs.reshape(15, -1)) and torch.equal(reward, r_info["agent_reward"].reshape(-1))
        assert torch.equal(terminated, r_info["agent_terminated"].reshape(-1)), f"{rng}"
        last = t == 3
        assert torch.equal(truncated, (torch.full((15,), last) & ~terminated))
        assert bool(info["_final_obs"].all()) == last
    with pytest.raises(ValueError, match=r"shape \(15, 2\)"):
        flat.step(torch.zeros(3, 5, 2))


@pytest.mark.parametrize("shield", [False, True])
def test_torchrl_check_env_specs_and_rollout(shield):
    pytest.importorskip("torchrl")
    from torchrl.envs.utils import check_env_specs

    from magwarp.swarm import SwarmTorchRLEnv

    env = SwarmTorchRLEnv(num_envs=2, max_episode_steps=3, shield=shield, **SMALL)
    check_env_specs(env, seed=0)
    td = env.rollout(5, break_when_any_done=False)
    assert td["next", "agents", "reward"].shape == (2, 5, 5, 1)
    assert td["agents", "observation"].shape == (2, 5, 5, 18)
    assert td["next", "truncated"][:, 2].all()  # third step: the step limit ends every world


@pytest.mark.parametrize("shield", [False, True])
def test_pettingzoo_parallel_api_test(shield):
    pytest.importorskip("pettingzoo")
    from pettingzoo.test import parallel_api_test

    from magwarp.swarm import SwarmParallelEnv

    env = SwarmParallelEnv(max_episode_steps=6, shield=shield, **SMALL)
    parallel_api_test(env, num_cycles=20)
    obs, _ = env.reset(seed=1)
    assert set(obs) == {f"mover_{i}" for i in range(5)} and obs["mover_0"].shape == (18,)
