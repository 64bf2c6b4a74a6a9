"""Simulator semantics: graph replay vs eager launches, stop-on-collision, masked reset, the per-step outputs
(flags_any, cycles, halted), cycle hooks, and CPU vs GPU agreement."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import warp as wp

from magwarp.layout import Layout, MoverSpec
from magwarp.sim import Simulator
from magwarp.types import COLLIDE_MOVER, COLLIDE_WALL

STATE_FIELDS = ("pos", "quat", "vel", "omega", "acc", "cmd", "flags", "flags_any", "partner", "world_pairs",
                "world_walls", "halted", "cycles")
PER_WORLD = ("world_pairs", "world_walls", "halted", "cycles")


def snapshot(sim) -> dict[str, np.ndarray]:
    out = {name: getattr(sim, name).cpu().numpy().copy() for name in STATE_FIELDS}
    out["target_pos"] = wp.to_torch(sim.state.target_pos).cpu().numpy().copy()
    out["target_quat"] = wp.to_torch(sim.state.target_quat).cpu().numpy().copy()
    out["wall"] = wp.to_torch(sim.state.wall).cpu().numpy().copy()
    return out


def assert_same(a: dict, b: dict, msg="", worlds=None):
    for name in a:
        x, y = a[name], b[name]
        if worlds is not None:
            x, y = x[worlds], y[worlds]
        np.testing.assert_array_equal(x, y, err_msg=f"{msg}: field {name}")


# Layouts and configurations for the three launch paths.
PATHS = {
    "fused": dict(m=4, fused_max_movers=16),
    "brute": dict(m=4, fused_max_movers=0),
    "grid": dict(m=40, fused_max_movers=0),
}


def make_sim(path, num_worlds=3, use_graph=True, device="cpu", stop_on_collision=True, shape="circle", **kw):
    cfg = PATHS[path]
    m = cfg["m"]
    if m <= 9:
        layout = Layout(np.array([[1, 1, 1], [1, 1, 0], [1, 1, 1]]))
        mover = MoverSpec(collision_shape=shape)
        starts = None
    else:  # 40 small movers on an 8x8 grid of points in a 4x4-tile layout with one hole
        tiles = np.ones((4, 4), dtype=int)
        tiles[2, 1] = 0
        layout = Layout(tiles)
        mover = MoverSpec(collision_shape=shape, collision_radius=0.03, collision_half_size=(0.025, 0.025))
        g = (np.arange(8) + 0.5) * 0.12  # 4 points per tile, 0.06 m from its edges: footprints stay on the tile
        pts = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
        starts = pts[layout.on_tiles(pts)][:m]
        assert len(starts) == m
    kw.setdefault("fused_max_movers", cfg["fused_max_movers"])
    return Simulator(layout, num_movers=m, num_worlds=num_worlds, mover=mover, start_xy=starts, device=device,
                     use_graph=use_graph, stop_on_collision=stop_on_collision, **kw)


def random_cmds(rng, sim, scale=15.0):
    return torch.as_tensor(rng.normal(size=(sim.num_worlds, sim.num_movers, 2)) * scale, dtype=torch.float32)


@pytest.mark.parametrize("shape", ["circle", "box"])
@pytest.mark.parametrize("path", list(PATHS))
def test_graph_replay_equals_eager(path, shape, rng):
    graph = make_sim(path, shape=shape)
    eager = make_sim(path, shape=shape, use_graph=False)
    assert graph._fused == eager._fused == (path == "fused")
    collided = 0
    for k, n in enumerate([7, 7, 40, 7, 40, 40, 40, 40, 1]):
        cmd = random_cmds(rng, graph, scale=[10.0, 30.0][k % 2])
        if k == 4:  # tilt one mover so that attitude dynamics run too
            for sim in (graph, eager):
                sim.quat[0, 0] = torch.tensor([0.02, 0.0, 0.0, 1.0]) / np.sqrt(1.0004)
        graph.step(n, cmd=cmd)
        eager.step(n, cmd=cmd)
        assert_same(snapshot(graph), snapshot(eager), f"{rng}, {path}/{shape}, step {k} ({n} cycles)")
        collided += int(graph.halted.sum())
        if k == 3:  # a masked reset between steps, identical on both
            mask = torch.as_tensor(rng.integers(0, 2, graph.num_worlds).astype(bool))
            graph.reset(mask)
            eager.reset(mask)
    assert len(graph._graphs) == 3 and not eager._graphs  # one graph per distinct cycle count
    assert collided > 0, f"{rng}: no world ever collided; the comparison missed the collision branch"


def pass_by_sim(path, stop, speed=1.5, num_worlds=3):
    """World 0: mover 0 slides along x past mover 1 (collides for a while, then clears). World 1: mover 1 out of
    reach (never collides). World 2: like world 0, faster. Movers 2 and 3 stand aside."""
    layout = Layout.grid(4, 3)
    xy = np.zeros((num_worlds, 4, 2))
    xy[:, 0] = (0.12, 0.12)
    xy[:, 1] = (0.48, 0.32)
    xy[1, 1] = (0.48, 0.60)
    xy[:, 2] = (0.84, 0.60)
    xy[:, 3] = (0.12, 0.60)
    fused = PATHS[path]["fused_max_movers"]
    sim = Simulator(layout, start_xy=xy, num_worlds=num_worlds, device="cpu", fused_max_movers=fused,
                    stop_on_collision=stop)
    v = torch.zeros(num_worlds)
    v[:] = speed
    v[2] = 1.7
    sim.vel[:, 0, 0] = v
    return sim


def first_collision_cycle(x0, x1, y_gap, speed, dt=0.001, reach=0.22):
    """1-based cycle at which mover 0 (moving at ``speed`` along x from x0) first comes within reach of mover 1."""
    c = np.arange(1, 2000)
    x = np.float32(x0) + np.cumsum(np.full(len(c), np.float32(speed) * np.float32(dt), dtype=np.float32))
    return int(c[np.hypot(x - x1, y_gap) <= reach][0])


@pytest.mark.parametrize("path", ["fused", "brute"])
def test_stop_on_collision_freezes_only_the_colliding_world(path, rng):
    n = 400
    free = pass_by_sim(path, stop=False)
    stop = pass_by_sim(path, stop=True)
    # Oracle for the first colliding cycle: the free-running simulator, one cycle at a time.
    first = {}
    history = []
    for c in range(1, n + 1):
        free.step(1)
        history.append(snapshot(free))
        for w in (0, 2):
            if w not in first and free.flags[w, 0] & COLLIDE_MOVER:
                first[w] = c
    assert set(first) == {0, 2}
    for w, speed in ((0, 1.5), (2, 1.7)):  # agrees with the kinematics (the x speed never changes)
        assert abs(first[w] - first_collision_cycle(0.12, 0.48, 0.20, speed)) <= 1
    stop.step(n)
    for w in (0, 2):
        c = first[w]
        assert int(stop.cycles[w]) == c, f"world {w}: cycles {int(stop.cycles[w])}, first collision at {c}"
        assert int(stop.halted[w]) == 1
        # Frozen exactly at the state of the colliding cycle.
        for name in ("pos", "quat", "vel", "flags", "partner", "world_pairs"):
            np.testing.assert_array_equal(getattr(stop, name)[w].numpy(), history[c - 1][name][w], err_msg=f"{w} {name}")
        np.testing.assert_array_equal(stop.flags[w].numpy(), [COLLIDE_MOVER, COLLIDE_MOVER, 0, 0])
        np.testing.assert_array_equal(stop.partner[w].numpy(), [1, 0, -1, -1])
        assert int(stop.world_pairs[w]) == 1
    # The world that never collides ran every cycle and matches the free-running simulator.
    assert int(stop.cycles[1]) == n and int(stop.halted[1]) == 0
    for name in ("pos", "quat", "vel", "flags", "flags_any"):
        np.testing.assert_array_equal(getattr(stop, name)[1].numpy(), history[-1][name][1], err_msg=name)
    # Next step: accumulators restart; the still-overlapping worlds advance one cycle, collide again and stop.
    x_before = stop.pos[:, 0, 0].clone()
    stop.step(10)
    np.testing.assert_array_equal(stop.cycles.numpy(), [1, 10, 1])
    np.testing.assert_array_equal(stop.halted.numpy(), [1, 0, 1])
    np.testing.assert_allclose((stop.pos[:, 0, 0] - x_before).numpy(), np.array([1.5, 1.5, 1.7]) * 1e-3 * [1, 10, 1],
                               rtol=1e-3)


@pytest.mark.parametrize("path", ["fused", "brute"])
def test_flags_any_accumulates_over_the_step(path, rng):
    """Without stop_on_collision, a transient collision inside a step shows in flags_any and halted, not in flags."""
    sim = pass_by_sim(path, stop=False)
    sim.step(400)  # the pass-by collision happens around cycles 180..300 and is over at the end
    np.testing.assert_array_equal(sim.cycles.numpy(), [400, 400, 400])
    np.testing.assert_array_equal(sim.flags.numpy(), 0)
    np.testing.assert_array_equal(sim.partner.numpy(), -1)
    np.testing.assert_array_equal(sim.world_pairs.numpy(), 0)
    np.testing.assert_array_equal(sim.flags_any.numpy(), [[1, 1, 0, 0], [0, 0, 0, 0], [1, 1, 0, 0]])
    np.testing.assert_array_equal(sim.halted.numpy(), [1, 0, 1])
    # The next step starts from clean accumulators.
    sim.step(5)
    np.testing.assert_array_equal(sim.flags_any.numpy(), 0)
    np.testing.assert_array_equal(sim.halted.numpy(), 0)
    np.testing.assert_array_equal(sim.cycles.numpy(), 5)
    # A mover driven off the tiles raises the wall bit (and only that) for its world.
    sim.vel[1, 2, 0] = 2.0  # mover 2 of world 1, from x = 0.84 toward the edge at 0.96 (radius 0.11)
    sim.step(20)
    assert int(sim.flags[1, 2]) == COLLIDE_WALL and int(sim.world_walls[1]) == 1
    assert int(sim.world_walls[0]) == 0 and int(sim.flags[0].sum()) == 0


@pytest.mark.parametrize("path", list(PATHS))
def test_reset_mask_resets_only_masked_worlds(path, rng):
    w = 4
    sim = make_sim(path, num_worlds=w)
    start = snapshot(sim)
    for _ in range(3):
        sim.step(20, cmd=random_cmds(rng, sim, 20.0))
    sim.set_targets(yaw=torch.as_tensor(rng.uniform(-1, 1, (w, sim.num_movers)), dtype=torch.float32))
    sim.quat[:, 0] = torch.tensor([0.0, 0.03, 0.0, 1.0]) / np.sqrt(1.0009)
    sim.step(3, cmd=random_cmds(rng, sim, 20.0))
    before = snapshot(sim)
    assert not np.array_equal(before["pos"], start["pos"])
    mask_np = rng.permutation([True, False, True, False])
    for mask in (torch.as_tensor(mask_np), mask_np, torch.as_tensor(mask_np.astype(np.int64)), list(mask_np)):
        sim2 = sim  # the reset is idempotent on the masked worlds, so each mask form can be applied in turn
        sim2.reset(mask)
        after = snapshot(sim2)
        keep = np.flatnonzero(~mask_np)
        reset = np.flatnonzero(mask_np)
        assert_same(before, after, f"{rng}: unmasked worlds changed", worlds=keep)
        msg = f"{rng}: masked worlds"
        np.testing.assert_array_equal(after["pos"][reset], sim.start_pos.numpy()[reset], err_msg=msg)
        np.testing.assert_array_equal(after["quat"][reset], sim.start_quat.numpy()[reset], err_msg=msg)
        np.testing.assert_array_equal(after["target_pos"][reset], sim.start_pos.numpy()[reset], err_msg=msg)
        np.testing.assert_array_equal(after["target_quat"][reset], sim.start_quat.numpy()[reset], err_msg=msg)
        for name in ("vel", "omega", "acc", "cmd", "flags", "flags_any", "wall", "world_pairs", "world_walls", "halted",
                     "cycles"):
            np.testing.assert_array_equal(after[name][reset], 0, err_msg=f"{msg}: {name}")
        np.testing.assert_array_equal(after["partner"][reset], -1, err_msg=msg)
    # Full reset equals a fresh simulator.
    sim.reset()
    assert_same(snapshot(sim), start, f"{rng}: full reset")


def test_cycle_hooks_run_every_cycle_inside_the_graph(rng):
    @wp.kernel
    def count(cycles: wp.array(dtype=wp.int32), counter: wp.array(dtype=wp.int32)):
        w = wp.tid()
        counter[w] = counter[w] + cycles[w]

    sim = make_sim("fused", num_worlds=2)
    counter = wp.zeros(2, dtype=wp.int32, device="cpu")
    sim.add_cycle_hook(lambda s: wp.launch(count, dim=s.num_worlds, inputs=[s.state.cycles, counter], device=s.device))
    assert not sim._fused
    sim.step(6)  # eager warm-up + capture
    sim.step(6)  # graph replay
    # after every cycle c the hook adds c: 2 * (1 + ... + 6)
    np.testing.assert_array_equal(counter.numpy(), [42, 42])


def test_cpu_and_gpu_agree(devices, rng):
    if len(devices) < 2:
        pytest.skip("no CUDA device: the CPU/GPU comparison needs one")
    for path in PATHS:
        results = {}
        m = PATHS[path]["m"]
        cmds = [torch.as_tensor(rng.normal(size=(3, m, 2)) * 15, dtype=torch.float32) for _ in range(4)]
        for dev in devices:
            sim = make_sim(path, device=dev)
            for cmd in cmds:
                sim.step(40, cmd=cmd.to(sim.torch_device))
            results[dev] = snapshot(sim)
        for name in ("pos", "vel", "quat"):
            np.testing.assert_allclose(results["cpu"][name], results["cuda:0"][name], atol=1e-5,
                                       err_msg=f"{rng}, {path}: {name}")
        for name in ("flags_any", "cycles", "halted"):
            np.testing.assert_array_equal(results["cpu"][name], results["cuda:0"][name], err_msg=f"{rng}, {path}: {name}")


@pytest.mark.parametrize("shape", ["circle", "box"])
@pytest.mark.parametrize("control", ["acceleration", "jerk"])
@pytest.mark.parametrize("m, per_cycle", [(4, "brute"), (40, "grid")])
def test_fused_and_per_cycle_paths_agree(m, per_cycle, control, shape, rng):
    """One thread per world for all cycles vs one launch per stage per cycle: the same numbers, bit for bit,
    through collisions, stops and resets."""
    path = "fused" if m <= 9 else "grid"
    fused = make_sim(path, num_worlds=4, shape=shape, control=control, fused_max_movers=1000)
    split = make_sim(path, num_worlds=4, shape=shape, control=control, fused_max_movers=0)
    assert fused._fused and not split._fused
    scale = 300.0 if control == "jerk" else 30.0
    collided = 0
    for k in range(6):
        cmd = random_cmds(rng, fused, scale)
        fused.step(40, cmd=cmd)
        split.step(40, cmd=cmd)
        assert_same(snapshot(fused), snapshot(split), f"{rng}, M={m} {control}/{shape}, step {k}")
        mask = fused.halted.bool()
        collided += int(mask.sum())
        fused.reset(mask)
        split.reset(mask)
    assert collided > 0, f"{rng}: no collision, the comparison missed the stop branch"


def test_state_is_zero_copy_and_starts_at_tile_centres():
    sim = Simulator(Layout(np.array([[1, 0], [1, 1]])), num_movers=3, num_worlds=2, device="cpu")
    assert sim.pos.data_ptr() == sim.state.pos.ptr and sim.vel.data_ptr() == sim.state.vel.ptr
    np.testing.assert_allclose(sim.pos[0, :, :2].numpy(), [[0.12, 0.12], [0.36, 0.12], [0.36, 0.36]], atol=1e-7)
    np.testing.assert_allclose(sim.pos[..., 2].numpy(), sim.mover.hover_z, atol=1e-7)
    np.testing.assert_array_equal(sim.quat[..., 3].numpy(), 1.0)
    sim.vel[1, 2, 0] = 0.5  # a write through the torch view is what the kernels see
    sim.step(10)
    assert float(sim.pos[1, 2, 0]) == pytest.approx(0.36 + 0.005, abs=1e-6)
    assert float(sim.pos[0, 2, 0]) == pytest.approx(0.36, abs=1e-7)
