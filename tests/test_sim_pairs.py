"""``Simulator.pair_list``: the colliding pairs of every world, on every launch path, against the numpy reference."""

from __future__ import annotations

import numpy as np
import pytest

from magwarp import Layout, MoverSpec, Simulator
from magwarp import reference as ref

# (movers, fused_max_movers): register-fused, global-fused, per-cycle brute force, per-cycle grid.
PATHS = {"register": (5, 16), "fused": (12, 16), "brute": (12, 0), "grid": (48, 16)}


@pytest.mark.parametrize("shape", ["circle", "box"])
@pytest.mark.parametrize("path", sorted(PATHS))
def test_pair_list_matches_reference(path, shape, rng):
    m, fused_max = PATHS[path]
    layout = Layout.grid(4, 4)
    xy = rng.uniform(0.12, 0.84, (3, m, 2))
    # movers 0 and 1 overlap in every world (the rest are random), so the sample always holds collisions
    xy[:, 1] = np.clip(xy[:, 0] + rng.uniform(-0.04, 0.04, (3, 2)), 0.12, 0.84)
    yaw = rng.uniform(-np.pi, np.pi, (3, m))
    mover = MoverSpec(collision_shape=shape, collision_radius=0.08, collision_half_size=(0.05, 0.07))
    sim = Simulator(layout, num_worlds=3, mover=mover, start_xy=xy, start_yaw=yaw, device="cpu",
                    fused_max_movers=fused_max, validate_starts=False, stop_on_collision=False)
    sim.step(1)
    pos = sim.pos.numpy()[..., :2].astype(np.float64)
    q = sim.quat.numpy()
    got_yaw = np.arctan2(2 * (q[..., 3] * q[..., 2] + q[..., 0] * q[..., 1]), 1 - 2 * (q[..., 1] ** 2 + q[..., 2] ** 2))
    total = 0
    for w in range(3):
        want = sorted(ref.mover_collision_pairs(mover, pos[w], got_yaw[w]))
        n = int(sim.world_pairs[w])
        got = sorted(tuple(p) for p in sim.pair_list[w, : min(n, sim.max_pairs)].tolist())
        assert n == len(want), f"{rng}, {path}/{shape}, world {w}"
        assert got == want, f"{rng}, {path}/{shape}, world {w}"
        total += n
    assert total > 0, f"{rng}: the sample must contain collisions"


def test_pair_list_keeps_the_first_pairs_and_counts_all(rng):
    xy = rng.uniform(0.3, 0.4, (1, 8, 2))  # all eight movers on top of each other: 28 pairs
    sim = Simulator(Layout.grid(3, 3), num_worlds=1, start_xy=xy, device="cpu", max_pairs=5, validate_starts=False,
                    stop_on_collision=False)
    sim.step(1)
    assert int(sim.world_pairs[0]) == 28
    assert sim.pair_list.shape == (1, 5, 2)
    pairs = sim.pair_list[0].tolist()
    assert len({tuple(p) for p in pairs}) == 5 and all(0 <= i < j < 8 for i, j in pairs)


def test_max_pairs_must_be_positive():
    with pytest.raises(ValueError, match="max_pairs"):
        Simulator(Layout.grid(2, 2), 2, device="cpu", max_pairs=0)
