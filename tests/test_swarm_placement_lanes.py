"""The placement rounds' lane shape (:attr:`magwarp.swarm.Placer.lanes`: a group of threads per listed mover in a
fixed grid walking the list, the world's movers split over the lanes, a vote per try) places the same spots and
leaves the same movers as the default shape (a thread per mover of every world), bit for bit, on random layouts with
holes, with and without ``hold``, dense and sparse requests, over back-to-back calls; several lanes run on a CPU as
blocks (``warp.config.enable_cpu_blocks``, ``wp.tile_sum`` votes), the logic the GPU's warp votes follow."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import warp as wp

from magwarp.kernels import placement as kpl
from magwarp.layout import MoverSpec
from magwarp.swarm import placement as spl
from magwarp.swarm.placement import Placer
from tests.magnetics_helpers import cpu_blocks  # noqa: F401 (a fixture)
from tests.test_swarm_placement import check_placement, random_layout


def _runs(layout, mover, movers, worlds, seed, lanes, density, tries, calls_seed):
    """Spots and movers left over a sample and four calls of two rounds (hold alternating)."""
    placer = Placer(layout, movers, worlds, mover=mover, device="cpu", seed=seed, search="world", lanes=lanes)
    xy = placer.sample()
    placer.tries = tries
    out = [xy.clone()]
    calls = np.random.default_rng(calls_seed)
    for hold in (True, False, True, True):
        mask = torch.from_numpy(calls.random((worlds, movers)) < density)
        mask[min(1, worlds - 1)] = False  # a world with nothing to place
        left = placer.place_async(xy, mask, rounds=2, hold=hold)
        out += [xy.clone(), left.clone()]
    return out


@pytest.mark.parametrize("shape", ["circle", "box"])
@pytest.mark.parametrize("density", [0.1, 0.6])
def test_lanes_place_as_the_default_shape(rng, cpu_blocks, shape, density):  # noqa: F811
    mover = MoverSpec(collision_shape=shape)
    for _ in range(8):  # a draw where some requests are placed and some are left (a sparse one may place them all)
        layout = random_layout(rng, 8, 8, holes=0.15)
        seed = int(rng.integers(1 << 20))
        movers = int(rng.choice([13, 16, 21]))
        args = (layout, mover, movers, 4, seed)
        want = _runs(*args, None, density, 2, seed)
        left = torch.stack(want[2::2])
        if left.any() and (~left).any():
            break
    else:
        pytest.fail(f"{rng}: 8 draws without both placed and left movers")
    check_placement(layout, mover, 0.0, want[1].numpy(), rng)  # after the first call (hold)
    for lanes in (1, 2, 4, 8, 32):
        got = _runs(*args, lanes, density, 2, seed)
        assert all(torch.equal(a, b) for a, b in zip(want, got)), f"{rng}: lanes={lanes} placed differently"


def test_lanes_with_a_small_grid_and_movers_from_memory(rng, cpu_blocks, monkeypatch):  # noqa: F811
    """Groups that walk the list several times (a grid of few threads) and lanes that read the world's movers from
    memory (more per lane than :data:`~magwarp.kernels.placement.MAX_PER_LANE`) place the same spots too."""
    # 10 x 10 tiles less about 10% holes: 40 movers stay well below random placement's density (about 0.58 movers per
    # tile) on any draw (9 x 9 tiles went past it when a draw left 67 tiles)
    layout = random_layout(rng, 10, 10, holes=0.1)
    seed = int(rng.integers(1 << 20))
    want = _runs(layout, MoverSpec(), 40, 3, seed, None, 0.5, 3, seed)
    monkeypatch.setattr(spl, "LANE_GRID_THREADS", 8)
    monkeypatch.setattr(kpl, "MAX_PER_LANE", 4)
    for lanes in (1, 4, 8):
        got = _runs(layout, MoverSpec(), 40, 3, seed, lanes, 0.5, 3, seed)
        assert all(torch.equal(a, b) for a, b in zip(want, got)), f"{rng}: lanes={lanes} placed differently"


def test_bad_lanes(cpu_blocks):  # noqa: F811
    layout = random_layout(np.random.default_rng(0), 4, 4, holes=0.0)
    with pytest.raises(ValueError, match="lanes"):
        Placer(layout, 3, device="cpu", lanes=3)
    wp.config.enable_cpu_blocks = False
    with pytest.raises(ValueError, match="enable_cpu_blocks"):
        Placer(layout, 3, device="cpu", lanes=4)
    Placer(layout, 3, device="cpu", lanes=1)
