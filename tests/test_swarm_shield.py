"""The swarm env's shield (``shield=True``): every action through the planner's safety filter inside the step.
Random and adversarial actions (each mover accelerating at its nearest neighbour, or at its nearest wall) collide
often without it and never with it; an action the filter keeps (nothing near) passes bit for bit; the option off
changes nothing; bad combinations are refused; the filter is the planner's."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from magwarp.swarm import SwarmEnv, SwarmPlanner
from magwarp.swarm.safety import SAFE_K, SAFE_SPEED

SMALL = dict(num_movers=20, layout=np.ones((7, 7)), device="cpu")
HOLES = np.ones((8, 8))
HOLES[3:5, 3:5] = 0  # a hole in the middle: walls inside the layout too
HOLES[0, :3] = 0


def at_nearest_neighbour(env: SwarmEnv) -> torch.Tensor:
    pos = env.sim.pos[..., :2]
    d = (pos[:, :, None] - pos[:, None]).norm(dim=-1)
    d = d + torch.eye(env.num_movers) * 1e9
    j = d.argmin(-1)
    to = torch.gather(pos, 1, j[..., None].expand(-1, -1, 2)) - pos
    return env.config.a_max * to / to.norm(dim=-1, keepdim=True).clamp_min(1e-6)


def at_nearest_wall(env: SwarmEnv) -> torch.Tensor:
    """Full acceleration towards the nearest cell off the tiles (a hole or beyond the edge)."""
    pos = env.sim.pos[..., :2]
    tiles = np.pad(np.asarray(env.layout.tiles, bool), 1)  # the ring beyond the edge is off the tiles
    size = float(env.layout.tile.size)
    cells = torch.tensor(np.argwhere(~tiles) - 1, dtype=torch.float32)  # [C, 2] cell indices
    lo, hi = cells * size, (cells + 1) * size
    closest = torch.maximum(torch.minimum(pos[..., None, :], hi), lo)  # [N, M, C, 2]
    dist = (closest - pos[..., None, :]).norm(dim=-1)
    best = dist.argmin(-1)
    to = torch.gather(closest, 2, best[..., None, None].expand(-1, -1, 1, 2))[..., 0, :] - pos
    return env.config.a_max * to / to.norm(dim=-1, keepdim=True).clamp_min(1e-6)


def random_actions(env: SwarmEnv, gen: torch.Generator) -> torch.Tensor:
    return torch.randn(env.num_envs, env.num_movers, 2, generator=gen) * env.config.a_max


def collisions(shield: bool, policy, steps: int, seed: int, **options) -> tuple[int, int, int]:
    env = SwarmEnv(2, seed=seed, shield=shield, **{**SMALL, **options})
    gen = torch.Generator().manual_seed(seed)
    movers = walls = active = 0
    for _ in range(steps):
        _, _, _, _, info = env.step(policy(env) if policy is not random_actions else policy(env, gen))
        movers += int(info["mover_collision"].sum())
        walls += int(info["wall_collision"].sum())
        if shield:
            assert info["shield_active"].shape == (2, env.num_movers) and info["shield_active"].dtype == torch.bool
            assert (info["shield_delta"][~info["shield_active"]] == 0).all()
            assert (info["shield_delta"] <= 2 * env.config.a_max + 1e-3).all()
            active += int(info["shield_active"].sum())
    return movers, walls, active


@pytest.mark.parametrize("policy, options", [(at_nearest_neighbour, {}), (at_nearest_wall, {}),
                                             (at_nearest_wall, dict(layout=HOLES, num_movers=16)),
                                             (random_actions, dict(layout=HOLES, num_movers=16))],
                         ids=["neighbour", "wall", "wall-holes", "random-holes"])
def test_the_shield_stops_every_collision(rng, policy, options):
    seed = int(rng.integers(1 << 30))
    movers, walls, _ = collisions(False, policy, 40, seed, **options)
    assert movers + walls >= 10, f"seed {seed}: the unshielded run should collide often ({movers}, {walls})"
    if policy is at_nearest_wall:
        assert walls >= 10, f"seed {seed}: {walls} wall collisions without the shield"
    movers, walls, active = collisions(True, policy, 40, seed, **options)
    assert (movers, walls) == (0, 0), f"seed {seed}: the shielded run collided ({movers} mover, {walls} wall)"
    assert active > 0


def test_the_shield_passes_actions_it_keeps_bit_for_bit(rng):
    """Two movers far apart and far from the edges, gentle actions: the shield never acts, and the run is the
    unshielded one bit for bit."""
    envs = [SwarmEnv(1, num_movers=2, layout=np.ones((24, 24)), device="cpu", seed=0, shield=s) for s in (False, True)]
    start = torch.tensor([[2.0, 2.0], [4.0, 4.0]])
    for env in envs:
        env.sim.pos[0, :, :2] = start
        env.goals[0] = torch.tensor([[5.0, 5.0], [1.0, 1.0]])
    for _ in range(20):
        action = torch.from_numpy(rng.uniform(-0.7, 0.7, (1, 2, 2)).astype(np.float32))
        outs = [env.step(action) for env in envs]
        (obs0, r0, _, _, info0), (obs1, r1, _, _, info1) = outs
        assert not info1["shield_active"].any() and (info1["shield_delta"] == 0).all(), f"{rng}"
        assert torch.equal(obs0, obs1) and torch.equal(r0, r1)
        assert np.array_equal(envs[0].sim.state.cmd.numpy(), envs[1].sim.state.cmd.numpy())
    assert torch.equal(envs[0].sim.pos, envs[1].sim.pos)
    # the same movers heading for each other fast: now the shield acts
    env = envs[1]
    env.sim.pos[0, :, :2] = torch.tensor([[3.0, 3.0], [3.5, 3.0]])
    env.sim.vel[0, :, :2] = torch.tensor([[1.4, 0.0], [-1.4, 0.0]])
    _, _, _, _, info = env.step(torch.tensor([[[10.0, 0.0], [-10.0, 0.0]]]))
    assert info["shield_active"].all() and (info["shield_delta"] > 1).all()
    assert not info["collided"].any()


def test_the_option_off_changes_nothing(rng):
    seed = int(rng.integers(1 << 30))
    a, b = SwarmEnv(2, seed=seed, **SMALL), SwarmEnv(2, seed=seed, shield=False, **SMALL)
    assert a.shield_filter is None and b.shield_filter is None
    for _ in range(10):
        action = torch.from_numpy(rng.normal(0, 6, (2, 20, 2)).astype(np.float32))
        (oa, ra, ta, ua, ia), (ob, rb, tb, ub, ib) = a.step(action), b.step(action)
        assert torch.equal(oa, ob) and torch.equal(ra, rb) and torch.equal(ta, tb) and torch.equal(ua, ub)
        assert set(ia) == set(ib) and "shield_active" not in ia
        for key in ia:
            assert torch.equal(ia[key], ib[key]), key


def test_the_shield_is_the_planners_filter():
    env = SwarmEnv(1, shield=True, **SMALL)
    planner = SwarmPlanner(env)
    f, p = env.shield_filter, planner.safety
    for name in ("contact", "wall_reach", "a_max", "step", "dt", "a_brake", "margin", "v_cap", "reach_radius"):
        assert getattr(f, name) == getattr(p, name), name
    assert f.v_cap == SAFE_SPEED == planner.cruise and env.shield_near.k == planner.near.k == SAFE_K
    assert env.shield_near.radius == planner.near.radius and env.shield_near.num_rays == 0
    assert torch.equal(f.tiles, p.tiles)
    slow = SwarmEnv(1, shield=True, shield_speed=0.8, **SMALL)
    assert slow.shield_filter.v_cap == 0.8


def test_bad_combinations_are_refused():
    with pytest.raises(ValueError, match="learn_jerk"):
        SwarmEnv(1, shield=True, learn_jerk=True, **SMALL)
    with pytest.raises(ValueError, match=r"shield_speed=3\.0"):
        SwarmEnv(1, shield=True, shield_speed=3.0, **SMALL)  # above v_max (2.0)
    with pytest.raises(ValueError, match=r"shield_speed=1\.5"):
        SwarmEnv(1, shield=True, v_max=1.0, **SMALL)
    for bad in (0.0, -1.0, float("nan"), True):
        with pytest.raises(ValueError, match="shield_speed"):
            SwarmEnv(1, shield=True, shield_speed=bad, **SMALL)
    with pytest.raises(ValueError, match="shield must be True or False"):
        SwarmEnv(1, shield="yes", **SMALL)
    SwarmEnv(1, learn_jerk=True, shield=False, **SMALL)  # the option off: jerk control as before


def test_the_flat_view_carries_the_shield_info():
    from magwarp.swarm import FlatSwarmEnv

    flat = FlatSwarmEnv(num_envs=2, shield=True, seed=0, **SMALL)
    flat.reset(seed=0)
    _, _, _, _, info = flat.step(torch.zeros(40, 2))
    assert info["shield_active"].shape == (40,) and info["shield_delta"].shape == (40,)
