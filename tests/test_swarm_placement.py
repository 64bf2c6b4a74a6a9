"""Parallel placement (:mod:`magwarp.kernels.placement`, :class:`magwarp.swarm.Placer`) against brute-force numpy
checks on random layouts with holes: every placed footprint (grown by the sampling offset and the wall margin) lies
on the tiles, no two movers are within the exclusion distance (collision size + safety margin + offset, each), fixed
movers stay where they are, and infeasible requests fail with the density asked and the density possible."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import warp as wp

from magwarp import reference as ref
from magwarp.layout import Layout, MoverSpec
from magwarp.sim import Simulator
from magwarp.swarm import placement
from magwarp.swarm.placement import SCAN_SHAPES, Placer, PlacementError


def random_layout(rng, nx: int, ny: int, holes: float) -> Layout:
    tiles = (rng.random((nx, ny)) >= holes).astype(np.int32)
    tiles[0, 0] = 1
    return Layout(tiles)


def check_placement(layout: Layout, mover: MoverSpec, offset: float, xy: np.ndarray, rng) -> None:
    """Brute force: footprints on the tiles (the reference wall rule) and pairwise exclusion, per world."""
    xy = np.asarray(xy, dtype=np.float64)
    w, m = xy.shape[:2]
    r = np.full(m, mover.collision_radius + offset)
    h = np.tile(np.asarray(mover.collision_half_size) + offset, (m, 1))
    wall = ref.wall_collisions(layout, mover, xy, np.zeros((w, m)), r, h)
    assert not wall.any(), f"{rng}: movers {np.argwhere(wall)[:5].tolist()} are off the tiles"
    grow = mover.margin + offset
    for k in range(w):
        d = xy[k, :, None] - xy[k, None]
        if mover.collision_shape == "circle":
            hit = np.linalg.norm(d, axis=-1) <= 2 * (mover.collision_radius + grow)
        else:
            hit = (np.abs(d) <= 2 * (np.asarray(mover.collision_half_size) + grow)).all(axis=-1)
        np.fill_diagonal(hit, False)
        assert not hit.any(), f"{rng}: world {k} pairs {np.argwhere(hit)[:3].tolist()} are too close"


@pytest.mark.parametrize("shape", ["circle", "box"])
def test_random_layouts_with_holes(rng, shape):
    for _ in range(3):
        layout = random_layout(rng, int(rng.integers(6, 12)), int(rng.integers(6, 12)), holes=0.2)
        mover = MoverSpec(collision_shape=shape, collision_radius=float(rng.uniform(0.06, 0.12)),
                          collision_half_size=tuple(rng.uniform(0.05, 0.1, 2)), margin=float(rng.uniform(0, 0.01)),
                          wall_margin=float(rng.uniform(0, 0.02)))
        offset = float(rng.uniform(0, 0.01))
        probe = Placer(layout, 1, 1, mover=mover, offset=offset, device="cpu")
        m = max(1, int(0.3 * probe.max_movers))  # well below random jamming
        placer = Placer(layout, m, 3, mover=mover, offset=offset, device="cpu", seed=int(rng.integers(1 << 20)))
        xy = placer.sample().numpy()
        check_placement(layout, mover, offset, xy, rng)
        assert not np.allclose(xy[0], xy[1]), f"{rng}: worlds got the same placement"


def test_half_the_tiles_in_one_call_and_the_simulator_accepts_it(rng):
    """MagBotSim's default mover (circle 0.11 m) on half of a 30 x 30 grid, with margins: one call, then the
    simulator's own start check (walls and pairs with the safety margin) passes."""
    layout = Layout(np.ones((30, 30), dtype=np.int32))
    mover = MoverSpec(margin=0.002, wall_margin=0.002)
    placer = Placer(layout, 450, 2, mover=mover, offset=0.001, device="cpu", seed=int(rng.integers(1 << 20)))
    xy = placer.sample().numpy()
    check_placement(layout, mover, 0.001, xy, rng)
    Simulator(layout, 450, 2, mover=mover, start_xy=xy, device="cpu")  # raises if any start collides


def test_masked_movers_avoid_the_fixed_ones(rng):
    layout = random_layout(rng, 10, 10, holes=0.15)
    mover = MoverSpec(collision_shape="box")
    placer = Placer(layout, 40, 2, mover=mover, device="cpu", seed=int(rng.integers(1 << 20)))
    xy = placer.sample()
    before = xy.clone()
    mask = torch.from_numpy(rng.random((2, 40)) < 0.3)
    left = placer.place_async(xy, mask, rounds=8)
    moved = (xy != before).any(dim=-1)
    assert not (moved & ~mask).any(), f"{rng}: a fixed mover moved"
    assert torch.equal(moved | left, mask), f"{rng}: a masked mover was neither placed nor reported left"
    assert not (moved & left).any(), f"{rng}: a mover both placed and reported left"
    assert moved.sum() > 0, f"{rng}: nothing was re-placed"
    check_placement(layout, mover, 0.0, xy.numpy(), rng)


def test_infeasible_requests_name_the_densities():
    layout = Layout(np.ones((6, 6), dtype=np.int32))
    with pytest.raises(PlacementError, match=r"asked 1\.667 movers per tile .*possible at most"):
        Placer(layout, 60, 1, device="cpu").sample()
    # below the packing bound, above what random placement reaches: reported after the rounds
    placer = Placer(layout, 36, 1, device="cpu")
    assert placer.max_movers >= 36
    with pytest.raises(PlacementError, match=r"asked 1\.000 movers per tile .*possible by random placement about"):
        placer.sample(max_rounds=32)
    with pytest.raises(PlacementError, match="no valid position"):
        Placer(Layout(np.ones((1, 1), dtype=np.int32)), 1, mover=MoverSpec(collision_radius=0.2), device="cpu")


def test_bad_inputs():
    placer = Placer(Layout(np.ones((4, 4), dtype=np.int32)), 3, 2, device="cpu")
    with pytest.raises(ValueError, match="float32 tensor of shape"):
        placer.place(torch.zeros(2, 3, 2, dtype=torch.float64))
    with pytest.raises(ValueError, match="mask must have shape"):
        placer.place(torch.zeros(2, 3, 2), torch.ones(3, dtype=torch.bool))
    with pytest.raises(ValueError, match="offset"):
        Placer(Layout(np.ones((4, 4), dtype=np.int32)), 3, offset=-1.0, device="cpu")


def test_hold_keeps_the_spots_of_movers_still_to_place(rng):
    """With ``hold``, a mover that finds no room stays where it is, and nothing is placed onto it."""
    layout = Layout(np.ones((6, 6), dtype=np.int32))
    placer = Placer(layout, 16, 4, device="cpu", seed=int(rng.integers(1 << 20)))
    xy = placer.sample()
    placer.tries = 1  # one candidate each: some movers find no room
    mask = torch.from_numpy(rng.random((4, 16)) < 0.5)
    left = placer.place_async(xy, mask, rounds=1, hold=True).clone()
    assert left.any(), f"{rng}: every mover found room in one try: the test checks nothing"
    check_placement(layout, MoverSpec(), 0.0, xy.numpy(), rng)  # the unplaced ones kept their (valid) spots


@pytest.mark.parametrize("hold,search", [(False, "grid"), (True, "grid"), (True, "world")])
def test_rounds_do_not_depend_on_the_order_of_the_listed_movers(rng, hold, search):
    """The rounds run a thread per mover to place, listed at the call's start in whatever order the device's atomics
    give (on CUDA: any): placing from the list reversed gives the same spots and the same movers left, bit for bit
    (each mover draws from its own random stream; claims and acceptance go by index)."""
    layout = random_layout(rng, 8, 8, holes=0.0)
    for _attempt in range(8):  # a case with movers placed and movers left (all 27 were left once in 19 runs)
        seed = int(rng.integers(1 << 20))
        mask = torch.from_numpy(rng.random((3, 30)) < 0.5)
        mask[1] = False  # a world with nothing to place
        results = []
        for reverse in (False, True):
            placer = Placer(layout, 30, 3, device="cpu", seed=seed, search=search)
            xy = placer.sample()
            placer.tries = 1  # one candidate per round: some movers are left
            pos = placer._begin(xy, mask, hold)
            count = int(placer._count.numpy()[0])
            assert count == int(mask.sum())
            listed = placer._listed.numpy()
            assert sorted(listed[:count].tolist()) == np.flatnonzero(mask.numpy().ravel()).tolist()
            if reverse:
                placer._listed.assign(np.concatenate([listed[:count][::-1], listed[count:]]))
            placer._rounds(pos, 3)
            placer._end(pos)
            results.append((xy.clone(), placer._todo.numpy().copy()))
        assert torch.equal(results[0][0], results[1][0]), f"{rng}"
        assert np.array_equal(results[0][1], results[1][1]), f"{rng}"
        left = results[0][1][mask.numpy()]
        if (left == 0).any() and (left == 1).any():
            break
    assert (left == 0).any() and (left == 1).any(), f"{rng}: {left.sum()} of {left.size} left (the test needs both)"
    if hold:  # the unplaced movers kept their spots, which nothing was placed onto
        check_placement(layout, MoverSpec(), 0.0, results[0][0].numpy(), rng)


@pytest.mark.parametrize("shape,tries", [("circle", 2), ("box", 2), ("circle", 7)])
def test_world_scan_places_as_the_grid_does(rng, devices, shape, tries):
    """``search="world"`` (each candidate checked against every mover of its world, no cell lists), in every
    ``scan`` shape (one try and one mover after another, or the movers read a chunk at a time),
    places the same spots and leaves the same movers as the
    grid's lists, bit for bit, with and without ``hold``, over back-to-back calls; so does a checked ``place``. A few
    tries per round on a crowded layout with holes: rounds reject candidates for walls, placed movers, held spots and
    lower-indexed winners alike."""
    layout = random_layout(rng, 8, 8, holes=0.15)
    mover = MoverSpec(collision_shape=shape)
    seed = int(rng.integers(1 << 20))
    runs = []
    shapes = [("cpu", "grid", "serial")] + [(d, "world", scan) for d in devices for scan in SCAN_SHAPES]
    for device, search, scan in shapes:
        placer = Placer(layout, 16, 5, mover=mover, device=device, seed=seed, search=search, scan=scan)
        xy = placer.sample()
        placer.tries = tries
        out = [xy.to("cpu", copy=True)]
        calls = np.random.default_rng(seed)
        for hold in (True, False, True, True):
            mask = torch.from_numpy(calls.random((5, 16)) < 0.4)
            mask[3] = False
            left = placer.place_async(xy, mask.to(xy.device), rounds=2, hold=hold)
            out += [xy.to("cpu", copy=True), left.to("cpu", copy=True)]
        runs.append(out)
    grid = runs[0]
    for run, (device, _, scan) in zip(runs[1:], shapes[1:]):
        assert all(torch.equal(a, b) for a, b in zip(grid, run)), \
            f"{rng}: the world scan ({scan}, {device}) placed differently from the grid"
    left = torch.stack(grid[2::2])
    assert left.any() and (~left).any(), f"{rng}: the test needs movers placed and movers left"
    check_placement(layout, mover, 0.0, grid[1].numpy(), rng)
    with pytest.raises(ValueError, match="'ring'"):
        Placer(layout, 3, device="cpu", search="ring")
    with pytest.raises(ValueError, match="scan.*'yes'"):
        Placer(layout, 3, device="cpu", scan="yes")


def test_blocks_option(monkeypatch):
    """``blocks`` (CUDA blocks per SM of the launches that walk every mover index): 0 (no cap) by default,
    ``MAGWARP_PLACE_BLOCKS`` sets the default; bad values are errors naming them; part of the placer's shape (a
    recorded step graph is recorded anew when it changes); no effect on the CPU."""
    layout = Layout(np.ones((4, 4), dtype=np.int32))
    placer = Placer(layout, 3, 2, device="cpu")
    assert placer.blocks == placement.ROUND_BLOCKS_PER_SM == 0 and placer.shape[-1] == 0
    placer.blocks = 8
    assert placer.shape[-1] == 8
    assert placer._max_blocks() == 0  # the CPU: Warp's own launch
    for bad in (-1, 2.5, True, "8", 5000):
        with pytest.raises((TypeError, ValueError), match="blocks"):
            placer.blocks = bad
    monkeypatch.setenv("MAGWARP_PLACE_BLOCKS", "2")
    assert Placer(layout, 3, 2, device="cpu").blocks == 2
    monkeypatch.setenv("MAGWARP_PLACE_BLOCKS", "many")
    with pytest.raises(ValueError, match="'many'"):
        Placer(layout, 3, 2, device="cpu")


@pytest.mark.parametrize("search", ["grid", "world"])
def test_capped_launches_use_grid_stride_kernels(rng, monkeypatch, search):
    """Every kernel the placer launches with ``max_blocks`` compiles with a grid-stride loop (the lean kernels'
    ``strided`` twins): Warp refuses a capped launch of a lean kernel on CUDA only (the magwarp modules default to
    lean kernels; a placer on the GPU once failed at its first call), so the CPU launches are checked here with a cap
    forced on, and place the same spots as the lean kernels."""
    layout = random_layout(rng, 8, 8, holes=0.1)  # 12 movers on at least ~45 tiles: always placeable
    seed = int(rng.integers(1 << 20))
    capped, launch = [], wp.launch

    def recording_launch(kernel, *args, max_blocks=0, **kwargs):
        out = launch(kernel, *args, max_blocks=max_blocks, **kwargs)
        if max_blocks:
            capped.append((kernel.key, kernel.grid_stride))
        return out

    runs = []
    for cap in (0, 1):
        placer = Placer(layout, 12, 3, device="cpu", seed=seed, search=search, tries=2)
        monkeypatch.setattr(placer, "_max_blocks", lambda cap=cap: cap)
        monkeypatch.setattr(wp, "launch", recording_launch)
        xy = placer.sample()
        mask = torch.from_numpy(np.random.default_rng(seed).random((3, 12)) < 0.5)
        left = placer.place_async(xy, mask, rounds=2, hold=True)
        monkeypatch.setattr(wp, "launch", launch)
        runs.append((xy.clone(), left.clone()))
    assert {k.removesuffix("_strided") for k, _ in capped} >= {"begin_todo", "resolve"}, capped
    lean = sorted({k for k, stride in capped if not stride})
    assert not lean, f"capped launches of kernels without a grid-stride loop: {lean}"
    assert torch.equal(runs[0][0], runs[1][0]) and torch.equal(runs[0][1], runs[1][1])


@pytest.mark.skipif(not torch.cuda.is_available() or not wp.is_cuda_available(), reason="needs a CUDA device")
@pytest.mark.parametrize("search", ["grid", "world"])
def test_capped_blocks_place_the_same_spots_on_cuda(rng, monkeypatch, search):
    """On CUDA the launches that walk every mover index in a few blocks (Warp's grid-stride loop: here one block of
    256 threads for 20 x 20 indices, each thread taking one or two) place the same spots and leave the same movers
    as one thread per index, bit for bit, over back-to-back calls with and without ``hold``. (30 movers on an 8 x 8
    layout with holes asked more than random placement allows on two seeds: 20 here.)"""
    layout = random_layout(rng, 8, 8, holes=0.1)
    seed = int(rng.integers(1 << 20))
    runs = []
    for blocks in (0, 8, "one"):
        placer = Placer(layout, 20, 20, device="cuda:0", seed=seed, search=search, tries=2)
        if blocks == "one":
            monkeypatch.setattr(placer, "_max_blocks", lambda: 1)
        else:
            placer.blocks = blocks
        xy = placer.sample()
        out = [xy.cpu()]
        calls = np.random.default_rng(seed)
        for hold in (True, False, True):
            mask = torch.from_numpy(calls.random((20, 20)) < 0.4).to("cuda:0")
            left = placer.place_async(xy, mask, rounds=2, hold=hold)
            out += [xy.cpu(), left.cpu()]
        runs.append(out)
    for run in runs[1:]:
        assert all(torch.equal(a, b) for a, b in zip(runs[0], run)), f"{rng}: the capped launches placed differently"
    left = torch.stack(runs[0][2::2])
    assert left.any() and (~left).any(), f"{rng}: the test needs movers placed and movers left"


def test_on_torch_stream_uses_the_shared_stream_wrapper(monkeypatch):
    """On a CUDA device the placers' stream context wraps torch's current stream through
    :func:`magwarp._streams.torch_stream` (it once called itself with a torch device, which Warp refused: every swarm
    placement on CUDA failed; a CPU run never reaches that branch, so the CUDA device is faked here)."""
    import types

    from magwarp.swarm import placement

    seen = []
    fake = types.SimpleNamespace(is_cuda=True, ordinal=3)
    monkeypatch.setattr(placement.wp, "get_device", lambda d: fake)
    monkeypatch.setattr(placement, "_torch_stream", lambda d: seen.append(d) or "the wrapper")
    monkeypatch.setattr(placement.wp, "ScopedStream", lambda s: ("scoped", s))
    assert placement.on_torch_stream("cuda:3") == ("scoped", "the wrapper")
    assert seen == [torch.device("cuda", 3)]
