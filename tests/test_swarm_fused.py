"""The swarm env's fused step (magwarp.swarm.fused, magwarp.kernels.swarm_step) against the per-cycle path (the step
kernels with the grid or brute-force narrow phase, then the stop hook after every cycle) on random worlds: the same
movers flagged in the same cycle, the same stops, the same state, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import warp as wp

import magwarp.swarm.fused as fused_mod
from magwarp.swarm import SwarmConfig, SwarmEnv

FIELDS = ("pos", "quat", "vel", "omega", "acc", "cmd", "flags", "flags_any", "partner", "world_pairs", "world_walls",
          "halted", "cycles", "nonfinite_step")


def _env(fused: bool, worlds: int, movers: int, seed: int, device: str = "cpu", **options) -> SwarmEnv:
    return SwarmEnv(worlds, num_movers=movers, device=device, seed=seed, fused=fused, check_inputs=False, **options)


def _pairs(sim) -> set:
    """The last cycle's colliding pairs as a set (the per-cycle path lists them in atomic order)."""
    out = set()
    for w in range(sim.num_worlds):
        n = min(int(sim.world_pairs[w]), sim.max_pairs)
        out |= {(w, int(i), int(j)) for i, j in sim.pair_list[w, :n].tolist()}
    return out


def _run_both(rng, worlds: int, movers: int, steps: int, scale: float = 12.0, setup=None, device: str = "cpu",
              **options):
    """Step a per-cycle env and a fused env with the same random actions; assert every output and state field equal
    after every step. Returns the total count of collision flags seen (so a test can insist on collisions)."""
    seed = int(rng.integers(1 << 30))
    envs = [_env(False, worlds, movers, seed, device, **options), _env(True, worlds, movers, seed, device, **options)]
    assert envs[0].fused_step is None and envs[1].fused_step is not None
    if setup is not None:
        for env in envs:
            setup(env)
    flagged = 0
    for k in range(steps):
        action = torch.as_tensor(rng.uniform(-scale, scale, (worlds, movers, 2)), dtype=torch.float32, device=device)
        outs = [env.step(action.clone()) for env in envs]
        (obs0, r0, te0, tr0, info0), (obs1, r1, te1, tr1, info1) = outs
        for name in FIELDS:
            a, b = getattr(envs[0].sim, name), getattr(envs[1].sim, name)
            assert torch.equal(a, b), f"step {k}: sim.{name} differs at {torch.nonzero(a != b)[:4].tolist()}"
        assert torch.equal(envs[0].stopped, envs[1].stopped), f"step {k}: stopped differs"
        for name in ("wall", "planar"):
            a, b = (getattr(env.sim.state, name).numpy() for env in envs)
            assert np.array_equal(a, b), f"step {k}: state.{name} differs"
        assert _pairs(envs[0].sim) == _pairs(envs[1].sim), f"step {k}: pair lists differ"
        assert torch.equal(obs0, obs1) and torch.equal(r0, r1), f"step {k}: observation or reward differs"
        for key in ("agent_reward", "mover_collision", "wall_collision", "agent_terminated", "goal_reached"):
            assert torch.equal(info0[key], info1[key]), f"step {k}: info[{key!r}] differs"
        flagged += int((envs[0].sim.flags_any != 0).sum())
    return flagged


@pytest.mark.parametrize("movers, shape", [(20, "circle"), (48, "circle"), (40, "box")])
def test_fused_matches_per_cycle(rng, movers, shape):
    """Small worlds (brute-force narrow phase) and grid worlds, circles and boxes, at a density where movers collide,
    stop and respawn during the run."""
    flagged = _run_both(rng, 3, movers, 6, occupancy=0.45, collision_shape=shape,
                        safety_margin=float(rng.uniform(0.0, 0.01)))
    assert flagged > 0  # the comparison covered collisions


def test_fused_matches_with_jerk_control_and_latency(rng):
    """Jerk commands and per-world action latency (the previous command during a world's first cycles; stopped
    movers zero the command that becomes the next previous one)."""
    delays = torch.as_tensor(rng.integers(0, 12, 3), dtype=torch.int32)

    def setup(env):
        env.sim.set_latency(delays, bound=12)

    assert _run_both(rng, 3, 36, 5, scale=300.0, setup=setup, occupancy=0.45, learn_jerk=True) > 0


def test_fused_candidate_overflow_and_travel_guard(rng, monkeypatch):
    """Both fallbacks of the candidate lists stay exact: movers with more candidates than the list holds (a high speed
    cap widens every list), and a travel budget of zero (every mover that moves leaves it: each cycle its world
    checks every pair)."""
    assert _run_both(rng, 2, 40, 4, occupancy=0.45, v_max=10.0, a_max=200.0) > 0
    monkeypatch.setattr(fused_mod, "TRAVEL_SLACK", 0.0)
    assert _run_both(rng, 2, 40, 4, occupancy=0.45) > 0


@pytest.mark.skipif(not wp.is_cuda_available(), reason="needs a CUDA device")
@pytest.mark.parametrize("exchange", ["native", "tile"])
def test_fused_matches_per_cycle_on_cuda(rng, monkeypatch, exchange):
    """The tiled CUDA kernel with either pose exchange (one ``__syncthreads_or`` a cycle over two shared buffers, or a
    Warp tile and a tile reduction) against the per-cycle path, bit for bit: worlds of several warps (100 and 256
    movers), the candidate lists' overflow, and a travel budget of zero (every world checks every pair each cycle)."""
    monkeypatch.setenv("MAGWARP_SWARM_EXCHANGE", exchange)
    assert _run_both(rng, 4, 100, 3, device="cuda:0") > 0
    assert _run_both(rng, 2, 256, 2, device="cuda:0", occupancy=0.45, v_max=10.0, a_max=200.0) > 0
    monkeypatch.setattr(fused_mod, "TRAVEL_SLACK", 0.0)
    assert _run_both(rng, 2, 100, 3, device="cuda:0", occupancy=0.45) > 0


@pytest.mark.skipif(not wp.is_cuda_available(), reason="needs a CUDA device")
@pytest.mark.parametrize("exchange", ["native", "tile"])
def test_several_worlds_per_block_on_cuda(rng, monkeypatch, exchange):
    """Worlds packed into blocks on CUDA (2 worlds of 100 movers in 7 warps; 2 of 16 in one warp; 3 of 36 with a
    mirrored world in the last block), either exchange, against the per-cycle path bit for bit, a zero travel budget
    included."""
    monkeypatch.setenv("MAGWARP_SWARM_EXCHANGE", exchange)
    monkeypatch.setenv("MAGWARP_SWARM_WORLDS", "auto")
    assert _run_both(rng, 5, 100, 3, device="cuda:0") > 0
    assert _run_both(rng, 7, 16, 3, device="cuda:0", occupancy=0.45) > 0
    monkeypatch.setenv("MAGWARP_SWARM_WORLDS", "3")
    monkeypatch.setattr(fused_mod, "TRAVEL_SLACK", 0.0)
    assert _run_both(rng, 4, 36, 3, device="cuda:0", occupancy=0.45) > 0


def test_swarm_exchange_option(monkeypatch):
    """MAGWARP_SWARM_EXCHANGE picks the CUDA kernel's pose exchange; an unknown value is an error that names it."""
    monkeypatch.delenv("MAGWARP_SWARM_EXCHANGE", raising=False)
    assert fused_mod.exchange() == fused_mod.EXCHANGE
    for value in ("tile", "native"):
        monkeypatch.setenv("MAGWARP_SWARM_EXCHANGE", value)
        assert fused_mod.exchange() == value
    monkeypatch.setenv("MAGWARP_SWARM_EXCHANGE", "shared")
    with pytest.raises(ValueError, match="'shared'"):
        fused_mod.exchange()


def test_fused_steps_aside_for_other_cycle_hooks(rng):
    """A further cycle hook must run between cycles: the fused motion declines and the per-cycle path runs (with the
    stop hook), still matching a per-cycle env."""
    calls = []

    def setup(env):
        env.sim.add_cycle_hook(lambda sim: calls.append(1))

    _run_both(rng, 2, 36, 2, setup=setup, occupancy=0.5)
    assert calls  # the hook ran: the per-cycle path was taken by both envs


def test_fused_steps_aside_for_an_in_step_actuator():
    """The in-step magnetic drive (Simulator.set_actuator) runs inside the simulator's step kernels, which the fused
    swarm kernel does not call: while one is set, the per-cycle path must run."""
    env = _env(True, 2, 8, 0)
    assert env.fused_step.applies(env.sim)
    env.sim._actuator = object()  # what set_actuator leaves (the drive itself needs force_aux columns the env lacks)
    assert not env.fused_step.applies(env.sim)


@pytest.mark.parametrize("movers, shape, jerk", [(40, "circle", False), (36, "box", True)])
def test_tiled_kernel_with_cooperative_cpu_blocks(rng, monkeypatch, movers, shape, jerk):
    """The CUDA shape itself (a block per world, one lane per mover, lanes past the last mover mirroring it, positions
    exchanged through shared tiles each cycle, the travel reduction) on Warp's cooperative CPU blocks: the same results
    as the per-cycle path, collisions, jerk control and action latency included."""
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    delays = torch.as_tensor(rng.integers(0, 12, 2), dtype=torch.int32)

    def setup(env):
        env.sim.set_latency(delays, bound=12)
        if env.fused_step is not None:
            env.fused_step.tiled = True
            env.sim._graphs.clear()

    assert _run_both(rng, 2, movers, 5, scale=300.0 if jerk else 12.0, setup=setup, occupancy=0.45,
                     collision_shape=shape, learn_jerk=jerk) > 0


@pytest.mark.parametrize("movers, worlds, per_block, shape", [(20, 5, "2", "circle"), (20, 5, "auto", "box"),
                                                              (36, 3, "3", "circle")])
def test_tiled_kernel_with_several_worlds_per_block(rng, monkeypatch, movers, worlds, per_block, shape):
    """Several worlds in one block (lane l is mover l % M of the block's world l // M; the last block's missing
    worlds and the lanes past them mirror a mover; the travel guard is the block's): the same results as the
    per-cycle path, on Warp's cooperative CPU blocks."""
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    monkeypatch.setenv("MAGWARP_SWARM_WORLDS", per_block)
    assert fused_mod.worlds_per_block(movers) == (fused_mod.pack_worlds(movers) if per_block == "auto"
                                                  else int(per_block)) > 1

    def setup(env):
        if env.fused_step is not None:
            env.fused_step.tiled = True
            env.sim._graphs.clear()

    assert _run_both(rng, worlds, movers, 4, setup=setup, occupancy=0.45, collision_shape=shape) > 0


@pytest.mark.parametrize("tiled, guard, device", [(False, "fused", "cpu"), (True, "fused", "cpu"),
                                                  (True, "separate", "cpu"),
                                                  pytest.param(True, "fused", "cuda:0", marks=pytest.mark.skipif(
                                                      not wp.is_cuda_available(), reason="needs a CUDA device"))])
def test_fused_step_writes_the_nan_guard_record(rng, monkeypatch, tiled, guard, device):
    """The fused step writes the NaN guard's record itself (no separate check over every mover): a mover made
    non-finite in a random world flags that world at the step's number, as the per-cycle path's check does, keeps the
    first step, and leaves the other worlds at -1; per world and in the tiled shape (cooperative CPU blocks). With
    MAGWARP_SWARM_GUARD=separate the simulator's own check writes the same record."""
    import magwarp.kernels.guard as kguard

    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    monkeypatch.setenv("MAGWARP_SWARM_GUARD", guard)
    worlds, movers = 4, 24
    seed = int(rng.integers(1 << 30))
    envs = [_env(False, worlds, movers, seed, device), _env(True, worlds, movers, seed, device)]
    if tiled:
        envs[1].fused_step.tiled = True
    launched = []
    real_launch = wp.launch

    def spy(kernel, *args, **kwargs):
        launched.append(kernel)
        return real_launch(kernel, *args, **kwargs)

    monkeypatch.setattr(wp, "launch", spy)
    bad_world, bad_mover = int(rng.integers(worlds)), int(rng.integers(movers))
    field = ("vel", "omega", "pos")[int(rng.integers(3))]
    for k in range(4):
        if k == 1:  # before the second step: one mover's state turns non-finite in both envs
            for env in envs:
                getattr(env.sim, field)[bad_world, bad_mover, 0] = float("nan")
        action = torch.as_tensor(rng.uniform(-5.0, 5.0, (worlds, movers, 2)), dtype=torch.float32, device=device)
        for env in envs:
            launched.clear()
            env.step(action.clone())
            # the per-cycle env checks every mover (launched, or replayed by the simulator's graph after its first
            # step); the fused env never launches that check
            if env.fused_step is not None and guard == "fused":
                assert kguard.flag_nonfinite not in launched, (rng, k)
            elif k == 0:
                assert kguard.flag_nonfinite in launched, (rng, k)
        want = [-1] * worlds
        if k >= 1:
            want[bad_world] = 2  # the sim's second step, kept after it
        for env in envs:
            assert env.sim.nonfinite_step.tolist() == want, (rng, k, field, env.fused_step is not None)
            assert env.sim.steps_taken == k + 1


def test_guard_option(monkeypatch):
    """MAGWARP_SWARM_GUARD: 'fused' (default) or 'separate'; anything else is an error naming the value."""
    assert fused_mod.guard_in_step()
    monkeypatch.setenv("MAGWARP_SWARM_GUARD", "separate")
    assert not fused_mod.guard_in_step()
    monkeypatch.setenv("MAGWARP_SWARM_GUARD", "both")
    with pytest.raises(ValueError, match="'both'"):
        fused_mod.guard_in_step()


def test_worlds_per_block_option(monkeypatch):
    """MAGWARP_SWARM_WORLDS: 'auto' packs the worlds that waste the fewest lanes; a bad value or too many movers for
    a block is an error that names it."""
    monkeypatch.delenv("MAGWARP_SWARM_WORLDS", raising=False)
    assert fused_mod.worlds_per_block(100) == fused_mod.WORLDS_PER_BLOCK == 1
    assert [fused_mod.pack_worlds(m) for m in (16, 48, 64, 100, 256)] == [2, 2, 1, 2, 1]
    for value, match in (("0", "'auto' or an integer >= 1, got '0'"), ("two", "got 'two'"),
                         ("3", "MAGWARP_SWARM_WORLDS=3 worlds of 100 movers exceed the 256 threads")):
        monkeypatch.setenv("MAGWARP_SWARM_WORLDS", value)
        with pytest.raises(ValueError, match=match):
            fused_mod.worlds_per_block(100)


def test_register_cap_by_block_size(monkeypatch):
    """The tiled kernel's register cap is 96 where that fits more blocks of the launch's size on a multiprocessor
    (65,536 registers) than 128, else 128; MAGWARP_SWARM_MAX_REGISTERS overrides it, and a bad value is an error that
    names it."""
    monkeypatch.delenv("MAGWARP_SWARM_MAX_REGISTERS", raising=False)
    monkeypatch.delenv("MAGWARP_SWARM_WORLDS", raising=False)
    blocks = (32, 64, 96, 128, 160, 192, 224, 256)
    want = [96 if 65536 // (96 * b) > 65536 // (128 * b) else 128 for b in blocks]
    assert [fused_mod.max_registers(b) for b in blocks] == want == [96] * 7 + [128]
    assert [fused_mod.max_registers(b, worlds=2) for b in blocks] == [128] * 8  # packed blocks spill more
    assert [fused_mod.launch_block(m) for m in (6, 64, 100, 160, 256)] == [
        (1, 32, 96), (1, 64, 96), (1, 128, 96), (1, 160, 96), (1, 256, 128)]
    monkeypatch.setenv("MAGWARP_SWARM_WORLDS", "auto")
    assert fused_mod.launch_block(100) == (2, 224, 128)
    monkeypatch.setenv("MAGWARP_SWARM_MAX_REGISTERS", "0")
    assert fused_mod.max_registers(128) == 0
    for bad in ("ninety", "8", "256", "-96"):
        monkeypatch.setenv("MAGWARP_SWARM_MAX_REGISTERS", bad)
        with pytest.raises(ValueError, match=f"got '{bad}'"):
            fused_mod.max_registers(128)


def test_fused_default_and_options():
    env = SwarmEnv(2, num_movers=8, device="cpu", seed=0)
    assert env.fused_step is not None and env.sim._motion is env.fused_step  # on by default for the respawn rule
    assert SwarmEnv(2, num_movers=8, device="cpu", seed=0, on_collision="end").fused_step is None
    with pytest.raises(ValueError, match="on_collision='end'"):
        SwarmConfig(num_movers=8, on_collision="end", fused=True)
    with pytest.raises(ValueError, match="256 movers"):
        SwarmConfig(num_movers=257, fused=True)
    with pytest.raises(ValueError, match="fused must be None, True or False"):
        SwarmConfig(num_movers=8, fused="yes")
    assert np.isclose(env.fused_step.travel(env.sim, 40), 40 * 1e-3 * 2.0 * fused_mod.TRAVEL_SLACK)


def test_set_motion_refuses_a_non_callable():
    env = _env(True, 2, 8, 0)
    with pytest.raises(TypeError, match="set_motion needs a callable.*got 3"):
        env.sim.set_motion(3)
    assert env.sim._motion is env.fused_step  # unchanged
