"""The swarm env's step as one CUDA graph (magwarp.swarm.env): the graph replay against the same launches run eagerly
(CUDA, bit for bit, skipped without it); on the CPU the per-world finishing kernel against numpy, the placers' device
counters (the random streams a graph replays) and the eager path's options."""

from __future__ import annotations

import operator

import numpy as np
import pytest
import torch
import warp as wp

from magwarp.kernels.swarm import finish_worlds
from magwarp.layout import Layout
from magwarp.swarm import SwarmEnv
from magwarp.swarm.fused import exchange, launch_block
from magwarp.swarm.placement import Placer

CUDA = torch.cuda.is_available() and wp.is_cuda_available()


@pytest.mark.parametrize("end", [False, True])
def test_finish_worlds_matches_numpy(rng, end):
    w, m, limit = 6, 23, 5
    reward = rng.integers(-3, 4, (w, m)).astype(np.float32) * 0.5  # exact sums in any order
    collided = rng.random((w, m)) < 0.05
    sim_bad = np.where(rng.random(w) < 0.3, rng.integers(1, 9, w), -1).astype(np.int32)
    obs_bad = (rng.random(w) < 0.3).astype(np.int32)
    steps0 = rng.integers(0, 7, w)
    arr = lambda a, dt: wp.array(a, dtype=dt, device="cpu")  # noqa: E731
    num_steps = arr(steps0, wp.int64)
    outs = [arr(np.zeros(w), dt) for dt in (wp.float32, wp.bool, wp.bool, wp.bool, wp.int64, wp.bool)]
    wp.launch(finish_worlds, dim=w, device="cpu",
              inputs=[int(end), limit, arr(reward, wp.float32), arr(collided, wp.bool), arr(sim_bad, wp.int32),
                      arr(obs_bad, wp.int32), arr([17], wp.int64)],
              outputs=[num_steps, *outs])
    got_reward, terminated, truncated, nonfinite, nonfinite_step, done = (o.numpy() for o in outs)
    bad = (sim_bad >= 0) | (obs_bad != 0)
    ended = collided.any(axis=1) & end
    np.testing.assert_array_equal(num_steps.numpy(), steps0 + 1, err_msg=str(rng))
    np.testing.assert_array_equal(got_reward, np.where(bad, 0.0, reward.sum(axis=1)), err_msg=str(rng))
    np.testing.assert_array_equal(terminated, ended | bad, err_msg=str(rng))
    np.testing.assert_array_equal(truncated, (steps0 + 1 >= limit) & ~ended, err_msg=str(rng))
    np.testing.assert_array_equal(nonfinite, bad, err_msg=str(rng))
    np.testing.assert_array_equal(nonfinite_step, np.where(bad, 17, -1), err_msg=str(rng))
    np.testing.assert_array_equal(done, ended | bad | ((steps0 + 1 >= limit) & ~ended), err_msg=str(rng))


def test_placer_counter_advances_per_round_and_batches_match_whole_calls(rng):
    """The device counter advances by the rounds of a call (place_async: the call's first kernel; place: a launch per
    batch); both draw the same streams: a whole placement in one batch and in one async call give the same spots."""
    layout = Layout(np.ones((5, 5), dtype=np.int32))
    seed = int(rng.integers(1 << 20))
    a, b = (Placer(layout, 9, 3, device="cpu", seed=seed) for _ in range(2))
    xa = torch.zeros(3, 9, 2)
    left = a.place_async(xa, rounds=16)
    assert not left.any(), f"{rng}: 9 movers on 25 tiles not placed in 16 rounds"
    xb = b.place(torch.zeros(3, 9, 2), rounds_per_check=16)
    assert torch.equal(xa, xb), f"{rng}: the batch and the async call drew different streams"
    assert a._calls == 16 and b._calls == 16 and a._seed == b._seed == seed
    a.place_async(xa, torch.zeros(3, 9, dtype=torch.bool), rounds=3)
    assert a._calls == 19
    a.reseed(seed)
    assert a._calls == 0 and a._seed == seed
    again = torch.zeros(3, 9, 2)
    a.place_async(again, rounds=16)
    assert torch.equal(again, xa), f"{rng}: a reseed did not restart the streams"


def test_step_path_and_graph_option():
    env = SwarmEnv(2, num_movers=6, layout=np.ones((4, 4)), k=2, num_rays=2, device="cpu", seed=0)
    assert env.step_path == "eager (the CPU)"
    env.graph = False
    assert env.step_path == "eager (graph=False)"
    with pytest.raises(ValueError, match="graph must be True or False, got 'yes'"):
        SwarmEnv(1, num_movers=3, layout=np.ones((3, 3)), device="cpu", graph="yes")


def test_graph_key_follows_every_launch_shape(monkeypatch):
    """A recorded step is recorded anew when any launch shape it holds changes: each placer's search, lanes and scan,
    and each of the local observation's switches (the same results, other kernels)."""
    env = SwarmEnv(2, num_movers=6, layout=np.ones((4, 4)), k=2, num_rays=2, device="cpu", seed=0)
    changes = [(env.placer, "scan", "serial" if env.placer.scan == "chunked" else "chunked"),
               (env.respawn_placer, "scan", "serial" if env.respawn_placer.scan == "chunked" else "chunked"),
               (env.placer, "search", "grid" if env.placer.search == "world" else "world"),
               (env.respawn_placer, "search", "grid" if env.respawn_placer.search == "world" else "world"),
               (env.local, "merge", not env.local.merge), (env.local, "staged", not env.local.staged),
               (env.local, "unrolled", not env.local.unrolled), (env.local, "sift", not env.local.sift)]
    for obj, name, value in changes:
        before, saved = env._graph_key(), getattr(obj, name)
        setattr(obj, name, value)
        assert env._graph_key() != before, f"{type(obj).__name__}.{name} = {value!r} left the graph key unchanged"
        setattr(obj, name, saved)
        assert env._graph_key() == before
    env.placer._lanes = 4  # the lane setter needs CPU blocks on the CPU; the key reads the shape alone
    assert env._graph_key() != before, "Placer.lanes left the graph key unchanged"
    env.placer._lanes = 1
    # the fused step kernel's tuning knobs (read at every kernel build)
    for var, value in (("MAGWARP_SWARM_EXCHANGE", "tile" if exchange() == "native" else "native"),
                       ("MAGWARP_SWARM_MAX_REGISTERS", "80" if launch_block(6)[2] != 80 else "0")):
        before = env._graph_key()
        monkeypatch.setenv(var, value)
        assert env._graph_key() != before, f"{var}={value} left the graph key unchanged"


def test_eager_step_counts_steps_on_the_device():
    """The NaN guard's step number comes from the env's device count (what a graph replay advances)."""
    env = SwarmEnv(2, num_movers=6, layout=np.ones((4, 4)), k=2, num_rays=2, device="cpu", seed=0)
    for _ in range(3):
        _, _, _, _, info = env.step(torch.zeros(2, 6, 2))
    assert int(env._env_steps) == env._step_count == 3
    assert info["nonfinite_step"].tolist() == [-1, -1] and not info["nonfinite"].any()
    assert env.num_steps.tolist() == [3, 3]


# ---------------------------------------------------------------------------------------------------------------- CUDA
def _flat(out, prefix=""):
    if isinstance(out, torch.Tensor):
        return {prefix: out}
    items = out.items() if isinstance(out, dict) else enumerate(out)
    flat = {}
    for k, v in items:
        if isinstance(v, (torch.Tensor, dict, tuple, list)):
            flat.update(_flat(v, f"{prefix}/{k}"))
    return flat


STATE = ("pos", "quat", "vel", "omega", "acc", "cmd", "flags_any")


def _run_twins(rng, steps: int, worlds: int, reseed_at: int | None = None, cls=SwarmEnv, extra: tuple[str, ...] = (),
               **options) -> dict:
    """A graph env and an eager env (graph=False) on CUDA with the same seed and actions: every returned tensor and
    state field equal after every step (kept returns checked after the next step: they stay valid through it).
    ``cls``: the env class (a SwarmEnv subclass); ``extra``: more of its state to compare (dotted attribute names)."""
    seed = int(rng.integers(1 << 20))
    envs = [cls(worlds, device="cuda:0", seed=seed, check_inputs=False, graph=g, **options) for g in (False, True)]
    assert envs[1].step_path == "graph" and envs[0].step_path == "eager (graph=False)"
    counts = {"respawns": 0, "goals": 0, "done": 0}
    kept = None
    for t in range(steps):
        if t == reseed_at:
            obs = [env.reset(seed=seed + 1)[0] for env in envs]
            assert torch.equal(obs[0], obs[1]), f"{rng}: reseed observations differ"
        m = envs[0].num_movers
        action = torch.as_tensor(rng.uniform(-12, 12, (worlds, m, 2)), dtype=torch.float32, device="cuda:0")
        outs = [_flat(env.step(action.clone())) for env in envs]
        if kept is not None:  # the previous step's returns are still the values they were
            for key, (value, copy) in kept.items():
                assert torch.equal(value, copy), f"{rng}: step {t}: the previous step's {key} was overwritten"
        assert outs[0].keys() == outs[1].keys()
        for key in outs[0]:
            assert torch.equal(outs[0][key], outs[1][key]), f"{rng}: step {t}: {key} differs"
        for name in STATE:
            a, b = (getattr(env.sim, name) for env in envs)
            assert torch.equal(a, b), f"{rng}: step {t}: sim.{name} differs"
        for name in ("goals", "stopped", "respawn_pending", "goal_pending", "collected_goals", "num_steps",
                     "goal_dist", *extra):
            a, b = (operator.attrgetter(name)(env) for env in envs)
            assert torch.equal(a, b), f"{rng}: step {t}: env.{name} differs"
        # the local observation's views follow the replayed graph's observation
        local, width = envs[1].local, envs[1].own_dim + envs[1].local.dim  # (a subclass may add columns after)
        assert torch.equal(local.walls, outs[1]["/0"][..., width - local.num_rays:width]) or local.num_rays == 0
        kept = {key: (value, value.clone()) for key, value in outs[1].items()}
        counts["respawns"] += int(outs[0]["/4/agent_terminated"].sum())
        counts["goals"] += int(outs[0]["/4/goal_reached"].sum())
        if "/4/_final_obs" in outs[0]:
            counts["done"] += int(outs[0]["/4/_final_obs"].sum())
    assert envs[1].step_path == "graph" and envs[1]._graphs[0] is not None and envs[1]._graphs[1] is not None
    return counts


@pytest.mark.skipif(not CUDA, reason="needs CUDA")
def test_graph_step_matches_eager_with_respawns_and_goal_streams(rng):
    counts = _run_twins(rng, 12, 16, reseed_at=8, num_movers=48, occupancy=0.5, reward_progress=3.0)
    assert counts["respawns"] > 0, f"{rng}: no respawn: the comparison covered none"


@pytest.mark.skipif(not CUDA, reason="needs CUDA")
def test_graph_step_matches_eager_with_stations_and_grid_search(rng):
    """Stations draw from the env's torch generator (registered with the graph); 80 movers per world place and
    observe with the grid on the CUDA defaults above 64 movers (observations) and the world scan (placers)."""
    counts = _run_twins(rng, 10, 8, reseed_at=6, num_movers=80, occupancy=0.45, stations="auto")
    assert counts["respawns"] > 0


@pytest.mark.skipif(not CUDA, reason="needs CUDA")
@pytest.mark.parametrize("mode", ["end", "respawn"])
def test_graph_step_matches_eager_with_autoresets(rng, mode):
    """Episodes that end inside the graph (a collision in "end" mode, the step limit): the autoreset's placement,
    the simulator's reset kernels and the new episodes' observations, all replayed."""
    counts = _run_twins(rng, 12, 8, num_movers=24, occupancy=0.5, on_collision=mode, max_episode_steps=4,
                        reward_progress=2.5)  # the progress reward's goal distances refreshed in the graph's resets
    assert counts["done"] > 0


@pytest.mark.skipif(not CUDA, reason="needs CUDA")
@pytest.mark.parametrize("num_movers", [48, 300])
def test_graph_step_matches_eager_with_the_shield(rng, num_movers):
    """The shield (its neighbour search, world scan at 48 movers and grid at 300, and the safety filter's torch
    operations) inside the captured step: replayed bit for bit, and (run_twins' last check) captured at all; no
    collision under random actions."""
    counts = _run_twins(rng, 10, 4, num_movers=num_movers, occupancy=0.5, shield=True)
    assert counts["respawns"] == 0, f"{rng}: a shielded mover collided"
