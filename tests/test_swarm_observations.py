"""Local swarm observations (:mod:`magwarp.kernels.neighbors`, :class:`magwarp.swarm.LocalObservations`) against
brute-force numpy references on random configurations: the k nearest movers within the radius (all pairs sorted by
distance) and the distance along each ray to the first missing tile or the layout's edge (ray-box intersections
with every hole and the layout's rectangle)."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from magwarp.layout import Layout
from magwarp.swarm.observations import LocalObservations, ray_directions


def knn_reference(xy: np.ndarray, k: int, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Indices ``(W, M, k)`` (-1 padded) and distances of the k nearest others within ``radius``."""
    w, m = xy.shape[:2]
    idx = np.full((w, m, k), -1)
    dist = np.full((w, m, k), np.inf)
    for a in range(w):
        d = np.linalg.norm(xy[a, :, None] - xy[a, None], axis=-1)
        np.fill_diagonal(d, np.inf)
        for i in range(m):
            order = np.lexsort((np.arange(m), d[i]))
            keep = [j for j in order[:k] if d[i, j] <= radius]
            idx[a, i, : len(keep)] = keep
            dist[a, i, : len(keep)] = d[i, keep]
    return idx, dist


def clear_of_ties(dist: np.ndarray, radius: float) -> np.ndarray:
    """``(W, M)``: the mover's reference neighbours have no near-tie and none is near the radius (float32 may order
    or keep those otherwise)."""
    kept = np.where(np.isinf(dist), np.nan, dist)  # padded slots tie with nothing
    with np.errstate(invalid="ignore"):
        near_tie = np.abs(np.diff(kept, axis=-1)) < 1e-5
        border = np.abs(kept - radius) < 1e-5
    return ~(near_tie.any(-1) | border.any(-1))


def ray_reference(layout: Layout, p: np.ndarray, d: np.ndarray, max_range: float) -> float:
    """Entry distance of the ray into the first missing tile, or its exit from the layout's rectangle."""
    size = layout.tile.size
    ext = np.asarray(layout.extent)

    def slab(lo, hi):
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (lo - p) / d, (hi - p) / d
        t_in, t_out = np.minimum(t1, t2), np.maximum(t1, t2)
        inside = (p >= lo) & (p <= hi)
        t_in = np.where(d == 0, np.where(inside, -np.inf, np.inf), t_in)  # parallel to the slab: all or nothing
        t_out = np.where(d == 0, np.where(inside, np.inf, -np.inf), t_out)
        return t_in.max(), t_out.min()

    best = slab(np.zeros(2), ext)[1]  # leaving the rectangle
    for i, j in zip(*np.nonzero(layout.tiles == 0)):
        t_in, t_out = slab(np.array([i, j]) * size, np.array([i + 1, j + 1]) * size)
        if t_in <= t_out and t_out >= 0:
            best = min(best, max(t_in, 0.0))
    return float(min(best, max_range))


def _sim_arrays(xy: np.ndarray, vel: np.ndarray, device: str = "cpu"):
    w, m = xy.shape[:2]
    pos3 = np.concatenate([xy, np.full((w, m, 1), 0.01)], axis=-1).astype(np.float32)
    vel3 = np.concatenate([vel, np.zeros((w, m, 1))], axis=-1).astype(np.float32)
    return wp.array(pos3, dtype=wp.vec3, device=device), wp.array(vel3, dtype=wp.vec3, device=device)


@pytest.mark.parametrize("k,radius", [(4, 0.5), (8, 1.3), (3, 0.05)])
def test_knn_matches_brute_force(rng, k, radius):
    layout = Layout(np.ones((8, 6), dtype=np.int32))
    w, m = 3, int(rng.integers(40, 120))
    ext = np.asarray(layout.extent)
    xy = rng.random((w, m, 2)) * ext
    xy[0, :5] = rng.random((5, 2)) * 0.2  # a tight cluster: more than k candidates close together
    xy = xy.astype(np.float32).astype(np.float64)
    vel = rng.normal(size=(w, m, 2)).astype(np.float32).astype(np.float64)
    obs = LocalObservations(layout, w, m, k=k, radius=radius, num_rays=0, device="cpu")
    obs.compute(*_sim_arrays(xy, vel))
    ref_idx, ref_dist = knn_reference(xy, k, radius)
    idx = obs.index.numpy()
    rel = obs.rel_pos.numpy().astype(np.float64)
    got_dist = np.where(idx >= 0, np.linalg.norm(rel, axis=-1), np.inf)
    # distances agree slot by slot (float32 may swap near-ties, never change the sorted distances)
    np.testing.assert_allclose(np.where(np.isinf(ref_dist), 0, ref_dist), np.where(np.isinf(got_dist), 0, got_dist),
                               atol=1e-5, err_msg=str(rng))
    clear = clear_of_ties(ref_dist, radius)
    assert np.array_equal(idx[clear], ref_idx[clear]), f"{rng}: neighbour indices differ"
    # relative positions and velocities of the returned neighbours, zeros in padded slots
    a, i, s = np.nonzero(idx >= 0)
    j = idx[a, i, s]
    np.testing.assert_allclose(rel[a, i, s], xy[a, j] - xy[a, i], atol=1e-5, err_msg=str(rng))
    np.testing.assert_allclose(obs.rel_vel.numpy()[a, i, s], vel[a, j] - vel[a, i], atol=1e-5, err_msg=str(rng))
    assert not obs.rel_pos.numpy()[idx < 0].any() and not obs.rel_vel.numpy()[idx < 0].any()
    assert obs.mask.numpy().sum() == (ref_idx >= 0).sum()


def test_wall_distances_match_ray_box_reference(rng):
    tiles = (rng.random((9, 7)) >= 0.25).astype(np.int32)
    tiles[4, 3] = 1
    layout = Layout(tiles)
    w, m, rays, max_range = 2, 60, 8, float(rng.uniform(0.5, 2.0))
    # movers on present tiles (and a few over holes: distance 0)
    i, j = np.nonzero(tiles)
    pick = rng.integers(len(i), size=(w, m))
    xy = (np.stack([i[pick], j[pick]], -1) + rng.uniform(0.02, 0.98, (w, m, 2))) * layout.tile.size
    hi, hj = np.nonzero(tiles == 0)
    if len(hi):
        xy[0, :3] = (np.stack([hi[:1], hj[:1]], -1) + 0.5) * layout.tile.size
    xy = xy.astype(np.float32).astype(np.float64)
    obs = LocalObservations(layout, w, m, k=0, num_rays=rays, max_range=max_range, device="cpu")
    obs.compute(*_sim_arrays(xy, np.zeros((w, m, 2))))
    got = obs.walls.numpy()
    dirs = ray_directions(rays)
    for a in range(w):
        for b in range(m):
            for r in range(rays):
                want = ray_reference(layout, xy[a, b], dirs[r], max_range)
                assert abs(got[a, b, r] - want) < 2e-4, f"{rng}: world {a} mover {b} ray {r}: {got[a, b, r]} vs {want}"
    assert obs.features().shape == (w, m, rays)


def test_features_layout_and_bad_options():
    obs = LocalObservations(np.ones((3, 3)), 1, 4, k=2, num_rays=4, device="cpu")
    xy = np.array([[[0.1, 0.1], [0.3, 0.1], [0.1, 0.5], [0.7, 0.7]]])
    obs.compute(*_sim_arrays(xy, np.zeros((1, 4, 2))))
    f = obs.features().numpy()
    assert f.shape == (1, 4, 14) and obs.dim == 14
    np.testing.assert_allclose(f[0, 0, :5], [0.2, 0.0, 0.0, 0.0, 1.0], atol=1e-6)  # mover 1 is the nearest of 0
    np.testing.assert_allclose(f[0, 0, 10:], [0.62, 0.62, 0.1, 0.1], atol=1e-5)  # +x, +y, -x, -y to the edges
    with pytest.raises(ValueError, match="radius"):
        LocalObservations(np.ones((3, 3)), 1, 4, radius=0.0, device="cpu")
    with pytest.raises(ValueError, match="k must"):
        LocalObservations(np.ones((3, 3)), 1, 4, k=-1, device="cpu")


@pytest.mark.parametrize("jerk,carry", [(False, False), (True, True)])
def test_observe_writes_own_state_then_features(rng, jerk, carry):
    """observe(): the own state columns, then exactly compute()'s features, in the caller's rows; the local views
    point at those rows; the non-finite flag marks the worlds with a NaN or an infinity in a row."""
    import torch

    layout = Layout(np.ones((7, 5), dtype=np.int32))
    w, m, k, rays = 3, int(rng.integers(20, 50)), 4, 6
    xy = rng.random((w, m, 2)) * np.asarray(layout.extent)
    vel = rng.normal(size=(w, m, 2))
    goals = torch.tensor(rng.random((w, m, 2)) * 3, dtype=torch.float32)
    acc = torch.tensor(rng.normal(size=(w, m, 2)), dtype=torch.float32) if jerk else None
    carrying = torch.tensor(rng.random((w, m)) < 0.5) if carry else None
    own = 4 + 2 * jerk + carry
    local = LocalObservations(layout, w, m, k=k, radius=0.9, num_rays=rays, device="cpu")
    pos3, vel3 = _sim_arrays(xy, vel)
    out = torch.full((w, m, own + local.dim), 7.0)
    local.observe(pos3, vel3, out, goals=goals, acc=acc, carrying=carrying)
    p, v = pos3.numpy()[..., :2], vel3.numpy()[..., :2]
    got = out.numpy()
    np.testing.assert_array_equal(got[..., 0:2], v, err_msg=str(rng))
    np.testing.assert_array_equal(got[..., 2:4], goals.numpy() - p, err_msg=str(rng))
    if jerk:
        np.testing.assert_array_equal(got[..., 4:6], acc.numpy())
    if carry:
        np.testing.assert_array_equal(got[..., own - 1], carrying.numpy().astype(np.float32))
    assert not local.nonfinite.any()
    assert local.rel_pos.data_ptr() == out[..., own:].data_ptr()  # the views are the rows written
    ref = LocalObservations(layout, w, m, k=k, radius=0.9, num_rays=rays, device="cpu")
    ref.compute(pos3, vel3)
    np.testing.assert_array_equal(got[..., own:], ref.features().numpy(), err_msg=str(rng))
    np.testing.assert_array_equal(local.index.numpy(), ref.index.numpy())
    bad = vel.copy()
    bad[1, int(rng.integers(m)), 0] = np.inf
    local.observe(pos3, _sim_arrays(xy, bad)[1], out, goals=goals, acc=acc, carrying=carrying)
    assert local.nonfinite.tolist() == [0, 1, 0], f"{rng}"
    with pytest.raises(ValueError, match="observation rows"):
        local.observe(pos3, vel3, out[..., 1:], goals=goals, acc=acc, carrying=carrying)
    with pytest.raises(ValueError, match=r"goals must have shape \(3, "):
        local.observe(pos3, vel3, out, goals=goals[:, :-1], acc=acc, carrying=carrying)


def _search_obs(layout, w, m, search, tiled, monkeypatch, device="cpu", unrolled=None, staged=False,
                **kw) -> LocalObservations:
    obs = LocalObservations(layout, w, m, search=search, device=device, **kw)
    obs.staged = staged
    if tiled and device == "cpu":  # the CUDA shape (a block per world, shared memory) on Warp's cooperative CPU blocks
        monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
        obs.tiled = True
    if unrolled is not None:
        obs.unrolled = unrolled
    return obs


@pytest.mark.parametrize("search,tiled,unrolled,staged,device,merge,sift", [
    ("world", False, False, False, "cpu", False, False), ("world", True, True, False, "cpu", False, False),
    ("world", True, False, True, "cpu", False, False), ("world", False, None, False, "cpu", None, None),
    ("world", True, None, True, "cpu", None, None), ("grid", False, True, False, "cpu", None, None),
    ("world", True, None, False, "cuda:0", None, None), ("world", True, None, True, "cuda:0", True, False),
    ("world", True, None, True, "cuda:0", True, True), ("world", True, None, True, "cuda:0", False, False),
    ("grid", True, False, False, "cuda:0", None, None)])  # tiled: the attribute (the grid ignores it); None: default
def test_searches_match_reference_and_each_other(rng, monkeypatch, search, tiled, unrolled, staged, device, merge,
                                                 sift):
    """Every search (the grid's cells; every mover of the world, per thread or a block per world with the positions in
    shared memory, its rows written directly or staged in shared memory) and either insertion into the sorted slots
    (the unrolled chain, the shift, the merge with or without the sift) write the same rows bit for bit, which match
    the brute-force reference:
    clusters with more than k candidates, isolated movers with fewer than k (padded, masked), movers over holes and
    off the layout, a NaN mover (never a neighbour, its own row flagged), a world size that leaves idle lanes in the
    last warp. On CUDA (where present) against the grid kernel of the same build."""
    import torch

    if device != "cpu" and not wp.is_cuda_available():
        pytest.skip("no CUDA device")

    tiles = (rng.random((9, 7)) >= 0.2).astype(np.int32)
    layout = Layout(tiles)
    w, m, k, rays = 3, 45, 6, 5
    ext = np.asarray(layout.extent)
    xy = rng.random((w, m, 2)) * ext
    xy[0, :9] = 0.3 + rng.random((9, 2)) * 0.15  # a cluster: more candidates than slots
    xy[1, 5] = [0.5 * ext[0], -0.2]  # off the layout
    hi, hj = np.nonzero(tiles == 0)
    if len(hi):
        xy[1, 6] = (np.array([hi[0], hj[0]]) + 0.5) * layout.tile.size  # over a hole
    xy[2] *= 3.0  # sparse (mostly off the layout): fewer than k neighbours
    xy = xy.astype(np.float32).astype(np.float64)
    vel = rng.normal(size=(w, m, 2)).astype(np.float32).astype(np.float64)
    xy_nan = xy.copy()
    xy_nan[1, 7] = np.nan
    goals = torch.tensor(rng.random((w, m, 2)) * 2, dtype=torch.float32, device=device)
    kw = dict(k=k, radius=0.6, num_rays=rays, max_range=0.8, device=device)
    ref = _search_obs(layout, w, m, "grid", False, monkeypatch, **kw)
    obs = _search_obs(layout, w, m, search, tiled, monkeypatch, unrolled=unrolled, staged=staged, **kw)
    assert obs.search == search and obs.tiled == tiled
    if merge is not None:
        obs.merge, obs.sift = merge, sift
    assert (ref.unrolled, obs.unrolled) == (device != "cpu", device != "cpu" if unrolled is None else unrolled)
    pos3, vel3 = _sim_arrays(xy_nan, vel, device)
    rows = [torch.full((w, m, 4 + ref.dim), 7.0, device=device) for _ in range(2)]
    for o, out in zip((ref, obs), rows):
        o.observe(pos3, vel3, out, goals=goals)
    rows = [r.cpu().numpy() for r in rows]
    np.testing.assert_array_equal(rows[1], rows[0], err_msg=str(rng))
    np.testing.assert_array_equal(obs.index.cpu().numpy(), ref.index.cpu().numpy(), err_msg=str(rng))
    assert obs.nonfinite.tolist() == ref.nonfinite.tolist() == [0, 1, 0], f"{rng}"
    # against the brute-force reference (the NaN mover left out of it: it is nobody's neighbour)
    idx = obs.index.cpu().numpy()
    assert not (idx[1] == 7).any()
    keep = np.arange(m) != 7
    want_idx, want_dist = knn_reference(xy, k, 0.6)
    clear = clear_of_ties(want_dist, 0.6)
    for a in (0, 2):
        np.testing.assert_array_equal(idx[a][clear[a]], want_idx[a][clear[a]], err_msg=str(rng))
    sub_idx, sub_dist = knn_reference(xy[1:2, keep], k, 0.6)
    remap = np.flatnonzero(keep)
    clear1 = clear_of_ties(sub_dist, 0.6)[0]
    np.testing.assert_array_equal(idx[1, keep][clear1], np.where(sub_idx[0] >= 0, remap[sub_idx[0]], -1)[clear1],
                                  err_msg=str(rng))
    assert clear[[0, 2]].mean() > 0.8 and clear1.mean() > 0.8, f"{rng}: too many near-ties to check"
    padded = (idx[2] >= 0).sum(-1)
    assert (padded < k).mean() > 0.5 and padded.max() >= 1, f"{rng}"  # fewer than k neighbours: padded, masked
    mask = obs.mask.cpu().numpy()
    assert not rows[1][..., 4:4 + 5 * k].reshape(w, m, k, 5)[~mask].any()  # padded slots are zeros


def test_world_search_inside_the_env_with_respawns(rng, monkeypatch):
    """In the swarm env (worlds whose movers collide, stop and respawn), the grid search writes the env's rows (the
    CPU's default for small worlds: each mover scanning its world) bit for bit, after every step."""
    import torch

    from magwarp.swarm import SwarmEnv

    env = SwarmEnv(3, num_movers=40, occupancy=0.6, device="cpu", seed=int(rng.integers(1 << 30)), obs_radius=0.7)
    assert env.local.search == "world" and not env.local.unrolled  # the CPU's default at 40 movers
    ref = _search_obs(env.layout, 3, 40, "grid", False, monkeypatch, unrolled=True, k=env.config.k, radius=0.7,
                      num_rays=env.config.num_rays, max_range=env.config.ray_range)
    respawned = 0
    for _ in range(6):
        action = torch.as_tensor(rng.normal(size=(3, 40, 2)) * 12.0, dtype=torch.float32)
        obs, _, _, _, info = env.step(action)
        respawned += int(info["agent_terminated"].sum())
        want = torch.empty_like(obs)
        ref.observe(env.sim.state.pos, env.sim.state.vel, want, goals=env.goals)
        np.testing.assert_array_equal(obs.numpy(), want.numpy(), err_msg=str(rng))
    assert respawned > 0, f"{rng}: no mover collided (the respawn path was not exercised)"


def test_search_option_errors():
    with pytest.raises(ValueError, match="search must be None or one of"):
        LocalObservations(np.ones((3, 3)), 1, 4, search="tree", device="cpu")
    with pytest.raises(ValueError, match="at most 256 movers"):
        LocalObservations(np.ones((30, 30)), 1, 300, search="world", device="cpu")
    assert LocalObservations(np.ones((30, 30)), 1, 129, device="cpu").search == "grid"
    big = LocalObservations(np.ones((30, 30)), 1, 300, device="cpu")
    assert big.search == "grid"
    with pytest.raises(ValueError, match="at most 256 movers"):
        big.search = "world"
    assert big.search == "grid"
    assert LocalObservations(np.ones((3, 3)), 1, 4, search="world", device="cpu").search == "world"
    obs = LocalObservations(np.ones((3, 3)), 1, 4, search="world", device="cpu")
    obs.tiled = True
    with pytest.raises(ValueError, match="enable_cpu_blocks"):
        obs.compute(*_sim_arrays(np.zeros((1, 4, 2)), np.zeros((1, 4, 2))))


@pytest.mark.parametrize("tiled,staged,sift", [(False, False, False), (True, False, False), (True, True, False),
                                               (False, False, True), (True, True, True)])
def test_merge_and_rect_rays_match_the_chain_and_the_walk(rng, monkeypatch, tiled, staged, sift):
    """The world search's branch-free merge into the slots (all candidates, or ``sift``: only those within the
    radius, a word of 32 at a time) and the closed-form rays of a full rectangle
    (:func:`~magwarp.kernels.neighbors.ray_to_rect`) write the same rows bit for bit as the chain and the tile walk:
    movers on tile boundaries and the layout's edges, off the layout, a cluster, a NaN mover; rays shorter and
    longer than the layout; a hole turns the closed form off (and asking for it is an error)."""
    import torch

    nx, ny = int(rng.integers(1, 12)), int(rng.integers(1, 12))
    layout = Layout(np.ones((nx, ny), dtype=np.int32))
    size, ext = layout.tile.size, np.asarray(layout.extent)
    w, m = 3, 45
    xy = rng.random((w, m, 2)) * ext * 1.2 - 0.1 * ext
    xy[0, :8, 0] = rng.integers(0, nx + 1, 8) * size  # on tile boundaries (and the edges)
    xy[0, 8:16, 1] = rng.integers(0, ny + 1, 8) * size
    xy[1, :3] = 0.0
    xy[1, 3:6] = ext * (1 - 1e-7)
    xy[2, :12] = 0.2 + rng.random((12, 2)) * 0.1  # a cluster: more candidates than slots, near-ties
    xy[2, 12] = np.nan
    xy = xy.astype(np.float32).astype(np.float64)
    vel = rng.normal(size=(w, m, 2))
    goals = torch.tensor(rng.random((w, m, 2)), dtype=torch.float32)
    pos3, vel3 = _sim_arrays(xy, vel)
    for max_range in (0.3, float(ext.max()) * 1.5):
        kw = dict(k=6, radius=0.5, num_rays=7, max_range=max_range)
        ref = _search_obs(layout, w, m, "grid", False, monkeypatch, unrolled=True, **kw)
        ref.rect = False
        obs = _search_obs(layout, w, m, "world", tiled, monkeypatch, unrolled=True, staged=staged, **kw)
        assert obs.rect and obs.merge and obs.sift  # the defaults: closed-form rays, the merge with the sift
        obs.merge, obs.sift = True, sift
        rows = [torch.full((w, m, 4 + ref.dim), 7.0) for _ in range(2)]
        for o, out in zip((ref, obs), rows):
            o.observe(pos3, vel3, out, goals=goals)
        np.testing.assert_array_equal(rows[1].numpy(), rows[0].numpy(), err_msg=str(rng))
        np.testing.assert_array_equal(obs.index.numpy(), ref.index.numpy(), err_msg=str(rng))
        assert obs.nonfinite.tolist() == ref.nonfinite.tolist() == [0, 0, 1]
        walls = rows[1][..., 4 + 5 * 6:].numpy()
        assert (walls[:2] < max_range).any()  # edges within reach (longer range: every ray ends at an edge)
        assert (walls[:2] == max_range).any() or max_range > 1.0 or max(nx, ny) < 3
    holed = np.ones((4, 4), dtype=np.int32)
    holed[1, 2] = 0
    obs = LocalObservations(Layout(holed), 1, 4, device="cpu")
    assert not obs.rect
    obs.rect = True
    with pytest.raises(ValueError, match="every tile of its rectangle"):
        obs.compute(*_sim_arrays(np.full((1, 4, 2), 0.1), np.zeros((1, 4, 2))))
    with pytest.raises(ValueError, match="radius squared"):
        LocalObservations(np.ones((3, 3)), 1, 4, radius=1e20, device="cpu")


def test_sift_default_follows_the_environment(monkeypatch):
    """``MAGWARP_OBS_SIFT`` picks the default of the sift (0 or 1); another value is an error naming it. On the CPU
    the merge is on only with the sift (without it the merge is slower there than the shift)."""
    from magwarp.kernels import neighbors as knb

    for text, want in (("0", False), ("1", True), ("", knb.SIFT)):
        monkeypatch.setenv("MAGWARP_OBS_SIFT", text)
        assert knb.sift_default() is want
        obs = LocalObservations(np.ones((3, 3)), 1, 4, device="cpu")
        assert obs.sift is want and obs.merge is want
    monkeypatch.setenv("MAGWARP_OBS_SIFT", "yes")
    with pytest.raises(ValueError, match="MAGWARP_OBS_SIFT must be 0 or 1, got 'yes'"):
        knb.sift_default()


@pytest.mark.parametrize("name", ["tiled", "unrolled", "staged", "merge", "sift", "rect"])
def test_launch_switches_take_bools_only(name):
    """Every launch choice is a bool: another value (a string, an int) is an error naming the attribute and the
    value, and the setting is left as it was."""
    obs = LocalObservations(np.ones((3, 3)), 1, 4, device="cpu")
    before = getattr(obs, name)
    for bad in ("yes", 1, None):
        with pytest.raises(ValueError, match=rf"LocalObservations.{name} must be a bool, got {bad!r}"):
            setattr(obs, name, bad)
        assert getattr(obs, name) is before
    setattr(obs, name, np.bool_(not before))
    assert getattr(obs, name) is (not before)
