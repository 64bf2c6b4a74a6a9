"""Regression tests: start sampling keeps the per-cycle safety margin, trajectory envs do not depend on placeholder
tile-centre starts, and CPU evaluation runs with one torch intra-op thread."""

from __future__ import annotations

import sys
import types

import gymnasium as gym
import numpy as np
import pytest
import torch

import magwarp  # noqa: F401 - registers the envs
from magwarp.envs import TrajectoryPlanningEnv


def _min_pair_gap(env) -> float:
    """Smallest centre distance minus the sum of the two radii, over all mover pairs of all worlds (start poses)."""
    xy = env.sim.start_pos[..., :2].cpu().double()
    d = (xy.unsqueeze(-2) - xy.unsqueeze(-3)).norm(dim=-1)
    r = torch.as_tensor(env.sim._radii_np, dtype=torch.float64)
    gap = d - (r[:, None] + r[None, :])
    m = xy.shape[1]
    gap = gap + torch.eye(m, dtype=torch.float64) * 1e9
    return float(gap.min())


@pytest.mark.parametrize("margin", [0.01, 0.05])
def test_starts_respect_safety_margin(margin):
    env = gym.make_vec("magwarp/TrajectoryPlanningB0-v0", num_envs=64, safety_margin=margin, device="cpu", seed=3)
    env = env.unwrapped if hasattr(env, "unwrapped") else env
    # reset a few times: every world's start must already be clear of the grown collision shapes
    for seed in range(4):
        env.reset(seed=seed)
        assert _min_pair_gap(env) > 2 * margin, f"starts closer than the safety margin (seed {seed})"
        env.sim.check_collisions()
        assert not env.sim.flags.any(), "a world starts in collision"
    # and a zero action cannot produce a collision on the first step
    obs, _ = env.reset(seed=11)
    _, _, terminated, _, info = env.step(torch.zeros(env.num_envs, env.num_movers * 2))
    assert not bool(info["mover_collision"].any()) and not bool(info["wall_collision"].any())
    assert not bool(terminated.any())


def test_box_starts_respect_safety_margin():
    margin = 0.04
    env = TrajectoryPlanningEnv(num_envs=64, layout="B0", collision_shape="box", collision_size=(0.07, 0.07),
                                safety_margin=margin, seed=1, device="cpu")
    xy = env.sim.start_pos[..., :2].cpu().double()
    d = (xy.unsqueeze(-2) - xy.unsqueeze(-3)).abs()
    m = xy.shape[1]
    sep = (d > 2 * (0.07 + margin)).any(dim=-1) | torch.eye(m, dtype=torch.bool)
    assert sep.all()
    env.sim.check_collisions()
    assert not env.sim.flags.any()


def test_large_collision_size_on_b3_builds_and_starts_clear():
    env = TrajectoryPlanningEnv(num_envs=8, layout="B3", collision_size=0.12, seed=0, device="cpu")
    assert env.sim.mover.collision_radius == 0.12
    assert _min_pair_gap(env) > 0
    env.sim.check_collisions()
    assert not env.sim.flags.any()
    _, _, terminated, _, _ = env.step(torch.zeros(env.num_envs, env.num_movers * 2))
    assert not bool(terminated.any())


def test_more_movers_than_tiles_is_not_a_default_start_problem():
    # 3 small movers on a single tile: the tile-centre defaults cannot hold them, sampled starts can
    env = TrajectoryPlanningEnv(num_envs=4, layout=np.ones((1, 1)), num_movers=3, collision_size=0.03, seed=0,
                                device="cpu")
    assert _min_pair_gap(env) > 0


def test_impossible_collision_size_names_the_value():
    with pytest.raises(ValueError, match="collision_size"):
        TrajectoryPlanningEnv(num_envs=2, layout="B3", collision_size=0.6, device="cpu")


def test_impossible_packing_names_the_values():
    # each mover fits on the 2x2 tiles, but four cannot be placed together with this margin
    with pytest.raises(ValueError, match="safety_margin"):
        TrajectoryPlanningEnv(num_envs=2, layout=np.ones((2, 2)), num_movers=4, collision_size=0.11,
                              safety_margin=0.06, device="cpu")


# ------------------------------------------------------------------------------------------- eval: torch threads
def test_cpu_evaluate_uses_one_thread_and_restores(monkeypatch):
    from magwarp.evaluate import evaluate

    seen: list[int] = []

    def probe(obs):
        seen.append(torch.get_num_threads())
        return torch.zeros_like(obs["achieved_goal"])

    mod = types.ModuleType("_magwarp_thread_probe")
    mod.probe = probe
    monkeypatch.setitem(sys.modules, "_magwarp_thread_probe", mod)
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        evaluate("TrajectoryPlanningB0", "_magwarp_thread_probe:probe", 2, 1, device="cpu", steps=2, progress=False)
        assert seen and set(seen) == {1}
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)
