"""The swarm planner's safety filter (:mod:`magwarp.swarm.safety`): segment closest points against a brute-force
search, and the guarantee itself: two movers that decide alone, from any state that keeps the invariant (committed
braking paths apart), never come closer than the collision distance over the held step and the braking that
follows (simulated cycle by cycle as the simulator integrates), keep the invariant, and stay off holes and edges."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from magwarp.swarm.safety import SafetyFilter, segment_closest_points, stop_length

T, DT, A_MAX, A_B, CONTACT, MARGIN, CRUISE = 0.04, 0.001, 10.0, 9.5, 0.22, 0.002, 1.0


def make_filter() -> SafetyFilter:
    return SafetyFilter(contact=CONTACT, wall_reach=0.11, a_max=A_MAX, step=T, dt=DT, a_brake=A_B, margin=MARGIN,
                        v_cap=CRUISE)


def segment_distance_bruteforce(p1, d1, p2, d2, n: int = 801) -> np.ndarray:
    s = np.linspace(0.0, 1.0, n)
    a = p1[:, None, :] + s[None, :, None] * d1[:, None, :]
    b = p2[:, None, :] + s[None, :, None] * d2[:, None, :]
    return np.linalg.norm(a[:, :, None] - b[:, None, :], axis=-1).min(axis=(1, 2))


def point_segment(q, p, d):
    t = np.clip(((q - p) * d).sum(-1) / np.maximum((d * d).sum(-1), 1e-300), 0.0, 1.0)
    return np.linalg.norm(q - p - t[..., None] * d, axis=-1)


def segment_distance(p1, d1, p2, d2) -> np.ndarray:
    """Exact distance of two 2-D segments: 0 where they cross, else the least endpoint-to-segment distance."""
    ends = np.minimum(np.minimum(point_segment(p1, p2, d2), point_segment(p1 + d1, p2, d2)),
                      np.minimum(point_segment(p2, p1, d1), point_segment(p2 + d2, p1, d1)))
    cross = lambda a, b: a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]  # noqa: E731
    den = cross(d1, d2)
    ok = np.abs(den) > 1e-15
    s = cross(p2 - p1, d2) / np.where(ok, den, 1.0)
    t = cross(p2 - p1, d1) / np.where(ok, den, 1.0)
    hit = ok & (s >= 0) & (s <= 1) & (t >= 0) & (t <= 1)
    return np.where(hit, 0.0, ends)


def committed_segment(v: np.ndarray) -> np.ndarray:
    speed = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.maximum(speed, 1e-12) * stop_length(speed, A_B, T)


def test_segment_closest_points_match_a_brute_force_search(rng):
    n = 300
    p1, p2 = rng.uniform(-1, 1, (n, 2)), rng.uniform(-1, 1, (n, 2))
    d1, d2 = rng.uniform(-1, 1, (n, 2)), rng.uniform(-1, 1, (n, 2))
    d1[:20] = 0.0  # points
    d2[10:30] = 0.0
    d2[40:60] = 2.0 * d1[40:60]  # parallel
    s, t = segment_closest_points(*(torch.tensor(x) for x in (p1, d1, p2, d2)))
    s, t = s.numpy(), t.numpy()
    assert ((0 <= s) & (s <= 1) & (0 <= t) & (t <= 1)).all(), str(rng)
    got = np.linalg.norm(p1 + s[:, None] * d1 - p2 - t[:, None] * d2, axis=-1)
    np.testing.assert_allclose(got, segment_distance(p1, d1, p2, d2), atol=1e-9, err_msg=str(rng))
    # and no sampled pair of points is closer
    np.testing.assert_array_less(got, segment_distance_bruteforce(p1, d1, p2, d2, 101) + 1e-9, err_msg=str(rng))


def simulate(p: np.ndarray, v: np.ndarray, v1: np.ndarray, steps: int = 12) -> np.ndarray:
    """Positions ``[B, cycles, 2]`` of movers that hold the acceleration reaching ``v1`` for one step, then brake
    step by step (``A_B`` against the velocity, or to rest), as the simulator's semi-implicit cycles do."""
    out = []
    a = (v1 - v) / T
    for step in range(steps):
        if step > 0:
            speed = np.linalg.norm(v, axis=-1, keepdims=True)
            a = -v / np.maximum(speed, 1e-12) * np.minimum(A_B, speed / T)
        for _ in range(round(T / DT)):
            v = v + a * DT
            p = p + v * DT
            out.append(p)
    return np.stack(out, 1)


def pair_states(rng, n: int):
    """Random pairs (mover i at the origin) whose committed paths keep the invariant."""
    ang, spd = rng.uniform(0, 2 * np.pi, (2, n)), CRUISE * np.sqrt(rng.uniform(0, 1, (2, n)))
    v_i = np.stack([np.cos(ang[0]), np.sin(ang[0])], -1) * spd[0, :, None]
    v_j = np.stack([np.cos(ang[1]), np.sin(ang[1])], -1) * spd[1, :, None]
    phi = rng.uniform(0, 2 * np.pi, n)
    p_j = np.stack([np.cos(phi), np.sin(phi)], -1) * rng.uniform(CONTACT, 0.7, (n, 1))
    gap = segment_distance(np.zeros_like(p_j), committed_segment(v_i), p_j, committed_segment(v_j))
    keep = gap >= CONTACT + MARGIN + 1e-3
    return v_i[keep], v_j[keep], p_j[keep]


def test_two_movers_deciding_alone_never_collide(rng):
    f = make_filter()
    v_i, v_j, p_j = pair_states(rng, 3000)
    assert len(v_i) > 500
    # wanted velocities: mostly straight at the other mover, at up to the cruise speed
    aim = p_j / np.linalg.norm(p_j, axis=-1, keepdims=True)
    want_i = aim * rng.uniform(0, CRUISE, (len(aim), 1)) + rng.normal(0, 0.3, aim.shape)
    want_j = -aim * rng.uniform(0, CRUISE, (len(aim), 1)) + rng.normal(0, 0.3, aim.shape)
    f32 = lambda x: torch.tensor(x, dtype=torch.float32)  # noqa: E731
    mask = torch.ones(len(v_i), 1, dtype=torch.bool)
    v1_i = f(f32(v_i), f32(want_i), f32(p_j)[:, None], f32(v_j - v_i)[:, None], mask).double().numpy()
    v1_j = f(f32(v_j), f32(want_j), f32(-p_j)[:, None], f32(v_i - v_j)[:, None], mask).double().numpy()
    # within one step of the acceleration limit, and not all braking (the filter lets safe wishes through)
    assert (np.linalg.norm(v1_i - v_i, axis=-1) <= A_MAX * T * (1 + 1e-5)).all()
    assert (np.linalg.norm(v1_i - want_i, axis=-1) < 1e-6).mean() > 0.05, str(rng)
    traj_i = simulate(np.zeros_like(p_j), v_i, v1_i)
    traj_j = simulate(p_j, v_j, v1_j)
    closest = np.linalg.norm(traj_i - traj_j, axis=-1).min(axis=1)
    assert closest.min() >= CONTACT + MARGIN - 1e-4, f"{rng}: contact at {closest.min()}"
    # the invariant holds again after the step (the committed paths from the new states are apart)
    end = round(T / DT) - 1
    gap = segment_distance(traj_i[:, end], committed_segment(v1_i), traj_j[:, end], committed_segment(v1_j))
    assert gap.min() >= CONTACT + MARGIN - 1e-4, f"{rng}: invariant broken ({gap.min()})"


def test_braking_always_satisfies_the_constraints(rng):
    """Recursive feasibility: from any state keeping the invariant, braking meets every pair constraint."""
    f = make_filter()
    v_i, v_j, p_j = pair_states(rng, 3000)
    f32 = lambda x: torch.tensor(x, dtype=torch.float32)  # noqa: E731
    normals, base, _ = f.constraints(f32(v_i), f32(p_j)[:, None], f32(v_j - v_i)[:, None],
                                     torch.ones(len(v_i), 1, dtype=torch.bool), None)
    brake = f.braking(f32(v_i))[:, None]
    assert float(f.violation(brake, normals, base).max()) <= 1e-6, str(rng)


def box_distance(x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Distance of points ``x [..., 2]`` to the boxes ``[lo, hi]`` ``[B, 2]`` -> ``[..., B]``."""
    c = np.maximum(np.minimum(x[..., None, :], hi), lo)
    return np.linalg.norm(x[..., None, :] - c, axis=-1)


@pytest.mark.parametrize("holes", [False, True])
def test_movers_stay_off_holes_and_edges(rng, holes):
    """Movers on a tile layout (with random holes) wanting anywhere: the cells off the tiles near each mover keep
    its held step and braking wall_reach + margin away from every hole and edge (obstacles: the non-tile cells of a
    one-cell frame around the layout)."""
    size, reach = 0.25, 0.11
    tiles = np.ones((8, 6), dtype=bool)
    if holes:
        tiles[rng.integers(0, 8, 4), rng.integers(0, 6, 4)] = False
    f = SafetyFilter(contact=CONTACT, wall_reach=reach, a_max=A_MAX, step=T, dt=DT, a_brake=A_B, margin=MARGIN,
                     v_cap=CRUISE, tiles=tiles, tile_size=size)
    framed = np.zeros((10, 8), dtype=bool)
    framed[1:-1, 1:-1] = tiles
    cells = np.argwhere(~framed) - 1
    lo, hi = cells * size, cells * size + size
    n = 600
    p = rng.uniform(0.0, [2.0, 1.5], (n, 2))
    v = rng.normal(0, 0.6, (n, 2))
    v *= np.minimum(1.0, CRUISE / np.linalg.norm(v, axis=-1, keepdims=True))
    # states that keep the invariant: the committed segment wall_reach + margin from every obstacle cell
    s = np.linspace(0, 1, 50)
    seg = p[:, None, :] + s[None, :, None] * committed_segment(v)[:, None, :]
    ok = box_distance(seg, lo, hi).min(axis=(1, 2)) >= reach + MARGIN
    p, v = p[ok], v[ok]
    assert len(p) > 100
    # wishes anywhere, and (every other mover) within one step's reach of the velocity: those pass unless unsafe
    want = rng.normal(0, 1.0, v.shape)
    want[::2] = v[::2] + rng.normal(0, 0.15, v[::2].shape)
    f32 = lambda x: torch.tensor(x, dtype=torch.float32)  # noqa: E731
    none = torch.zeros(len(p), 0, 2)
    v1 = f(f32(v), f32(want), none, none, torch.zeros(len(p), 0, dtype=torch.bool), f32(p)).double().numpy()
    passed = np.linalg.norm(v1 - want, axis=-1) < 1e-5
    assert 0.3 < passed[::2].mean() < 1.0, f"{rng}: {passed[::2].mean()}"  # safe wishes pass, unsafe ones do not
    traj = simulate(p, v, v1)
    clear = box_distance(traj, lo, hi).min(axis=(1, 2))
    assert clear.min() >= reach + MARGIN - 1e-4, f"{rng}: {clear.min()}"


def test_a_crowded_neighbour_list_keeps_the_path_in_a_ball():
    """k slots all filled within the reach radius: someone may be unseen (no nearer than the farthest seen, d_k),
    so the new path keeps within w_min (d_k - D(v0) - D(v_cap) - contact - margin) of the mover."""
    f = make_filter()
    k = 3
    rel = torch.tensor([[[0.0, 0.44], [0.0, -0.44], [-0.44, 0.0]]])
    vel = torch.tensor([[0.3, 0.0]])
    rel_vel = torch.zeros(1, k, 2) - vel[:, None]
    v1 = f(vel, torch.tensor([[1.0, 0.0]]), rel, rel_vel, torch.ones(1, k, dtype=bool))
    assert f.reach_radius > 0.44
    w_min = f.SHARE_FLOOR / (CRUISE + 2 * f.SHARE_FLOOR)
    ball = w_min * (0.44 - stop_length(0.3, A_B, T) - stop_length(CRUISE, A_B, T) - CONTACT - MARGIN)
    reach = float(f.path_reach_of(vel, v1[:, None])[0, 0])
    assert 0 < reach <= ball + 1e-7 and float(v1[0, 0]) > float(f.braking(vel)[0, 0])  # moves, within the ball
    traj = simulate(np.zeros((1, 2)), vel.double().numpy(), v1.double().numpy())
    assert np.linalg.norm(traj, axis=-1).max() <= ball + 1e-6
    # a free slot: every mover within reach is seen; sliding between the two neighbours is safe and fast
    v1_free = f(vel, torch.tensor([[1.0, 0.0]]), rel, rel_vel, torch.tensor([[True, True, False]]))
    assert float(v1_free[0, 0]) > 0.6


def test_bad_options_are_refused():
    for bad in (dict(a_brake=11.0), dict(contact=0.0), dict(margin=-1.0), dict(v_cap=float("nan")),
                dict(tile_size=0.0)):
        with pytest.raises(ValueError):
            SafetyFilter(**{**dict(contact=CONTACT, wall_reach=0.11, a_max=A_MAX, step=T, dt=DT, a_brake=A_B,
                                   margin=MARGIN, v_cap=CRUISE, tiles=np.ones((2, 2))), **bad})


def random_crowd(rng, w: int, m: int, k: int, device: str = "cpu", full: int = 0):
    """A filter on an 8 x 6 layout with 3 random holes and random states of ``[w, m]`` movers with ``k`` neighbour
    slots (70% live; the first ``full`` movers of world 0 with every slot live): ``(filter, (vel, wanted, rel_pos,
    rel_vel, mask, pos))`` on ``device``."""
    tiles = np.ones((8, 6), dtype=bool)
    tiles[rng.integers(0, 8, 3), rng.integers(0, 6, 3)] = False
    f = SafetyFilter(contact=CONTACT, wall_reach=0.11, a_max=A_MAX, step=T, dt=DT, a_brake=A_B, margin=MARGIN,
                     v_cap=CRUISE, tiles=tiles, tile_size=0.25, device=device)
    g = torch.Generator().manual_seed(int(rng.integers(1 << 30)))
    vel = torch.randn(w, m, 2, generator=g) * 0.5
    wanted = torch.randn(w, m, 2, generator=g)
    rel_pos = torch.randn(w, m, k, 2, generator=g) * 0.4
    rel_vel = torch.randn(w, m, k, 2, generator=g) * 0.5
    mask = torch.rand(w, m, k, generator=g) < 0.7
    mask[0, :full] = True
    pos = torch.rand(w, m, 2, generator=g) * torch.tensor([2.0, 1.5])
    return f, tuple(t.to(device) for t in (vel, wanted, rel_pos, rel_vel, mask, pos))


def test_blocks_of_movers_choose_as_all_at_once(rng):
    """For more movers than chunk_bytes holds, the torch form takes them a block at a time, and the kernel a block per
    launch: the same velocities and passes bit for bit (neighbours, walls and a leading [worlds, movers] shape)."""
    w, m, k = 5, 7, 4
    f, (vel, wanted, rel_pos, rel_vel, mask, pos) = random_crowd(rng, w, m, k)
    whole = f.choose_torch(vel, wanted, rel_pos, rel_vel, mask, pos)
    walls = f.cell_offsets.shape[0]
    f.chunk_bytes = 4 * f.num_candidates * (k + walls) * 3  # three movers per block: 12 blocks, the last one short
    blocks = f.choose_torch(vel, wanted, rel_pos, rel_vel, mask, pos)
    assert torch.equal(blocks[0], whole[0]) and torch.equal(blocks[1], whole[1]), str(rng)
    assert blocks[0].shape == (w, m, 2) and blocks[1].shape == (w, m)
    assert 0 < int(whole[1].sum()) < w * m, "the random states must mix passing and refused wishes"
    # the kernel's launches take a block of movers each within the same budget (its scratch): the same as one launch
    f.chunk_bytes = 1 << 31
    kernel_whole = f.choose(vel, wanted, rel_pos, rel_vel, mask, pos)
    f.chunk_bytes = (12 * (k + walls) + 8 * f.rot.shape[0]) * 4  # four movers per launch: 9 launches
    kernel_blocks = f.choose(vel, wanted, rel_pos, rel_vel, mask, pos)
    assert torch.equal(kernel_blocks[0], kernel_whole[0]) and torch.equal(kernel_blocks[1], kernel_whole[1]), str(rng)


def test_crossing_paths_take_the_centre_line_in_both_forms(rng):
    """A neighbour whose committed path crosses the mover's own (closest points a rounding apart, e.g. after a
    respawn): both forms take the centre line as the pair's normal (the points' difference is float32 noise: TOUCH_GAP),
    so the kernel's choice is safe by the torch form's constraints and the same as the torch form's. A float32 gap of
    1e-9 m once sent the two forms' normals different ways and the kernel's choice broke the torch form's constraint
    by 0.014 m/s."""
    n = 400
    f = make_filter()
    g = torch.Generator().manual_seed(int(rng.integers(1 << 30)))
    vel = torch.randn(n, 2, generator=g, dtype=torch.float64) * 0.5
    vel_j = torch.randn(n, 2, generator=g, dtype=torch.float64) * 0.5
    # paths that cross at a shallow angle have an ill-conditioned crossing (its float32 error is the rounding over the
    # angle): at least 0.01 rad here
    sine = (vel[:, 0] * vel_j[:, 1] - vel[:, 1] * vel_j[:, 0]) / (vel.norm(dim=-1) * vel_j.norm(dim=-1))
    vel_j = torch.where((sine.abs() < 0.01)[:, None], torch.stack([-vel[:, 1], vel[:, 0]], -1), vel_j)
    seg = lambda v: v / v.norm(dim=-1, keepdim=True) * stop_length(v.norm(dim=-1, keepdim=True), A_B, T)  # noqa
    s, t = torch.rand(n, 1, generator=g, dtype=torch.float64), torch.rand(n, 1, generator=g, dtype=torch.float64)
    rel_pos = s * seg(vel) - t * seg(vel_j)  # the two paths meet at s along the mover's, t along the neighbour's
    wanted = torch.randn(n, 2, generator=g)
    args = [x.float() for x in (vel, wanted, rel_pos[:, None], (vel_j - vel)[:, None])] + [torch.ones(n, 1, dtype=bool)]
    got, passes = f.choose(*args)
    want, passes_ref = f.choose_torch(*args)
    normals, base, _ = f.constraints(args[0], args[2], args[3], args[4])
    gap = (rel_pos - s * seg(vel) + t * seg(vel_j)).norm(dim=-1)
    assert float(gap.max()) < 1e-12  # the paths do cross (in float64)
    centre = args[2][:, 0] / args[2][:, 0].norm(dim=-1, keepdim=True)
    assert torch.allclose(normals[:, 0], centre, atol=1e-6), f"{rng}: not the centre line"
    violation = f.violation(got[:, None, :], normals, base)[..., 0]
    brake = (got - f.braking(args[0])).norm(dim=-1) <= 1e-6
    assert ((violation <= 1e-5) | brake).all(), f"{rng}: an unsafe velocity ({float(violation.max())})"
    assert ((got - want).norm(dim=-1) <= 1e-5).float().mean() >= 0.99 and torch.equal(passes, passes_ref), str(rng)


@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(
    not torch.cuda.is_available(), reason="needs a CUDA device"))])
def test_kernel_chooses_as_the_torch_form(rng, device):
    """The Warp kernel (a thread per mover) against the torch form on random crowds with holes: the same velocity
    but for float rounding for nearly every mover (a candidate at a constraint's boundary, or two at the same cost,
    may go either way) and the same passes; every velocity the kernel chooses is safe by the torch form's own
    constraints and within its ball, and it is one of the torch form's candidates."""
    w, m, k = 20, 50, 6
    f, (vel, wanted, rel_pos, rel_vel, mask, pos) = random_crowd(rng, w, m, k, device, full=5)
    got, passes = f.choose(vel, wanted, rel_pos, rel_vel, mask, pos)
    want, passes_ref = f.choose_torch(vel, wanted, rel_pos, rel_vel, mask, pos)
    close = (got - want).norm(dim=-1) <= 1e-5
    assert close.float().mean() >= 0.98 and (passes == passes_ref).float().mean() >= 0.99, \
        f"{rng}: {int((~close).sum())} velocities, {int((passes != passes_ref).sum())} passes differ"
    assert 0.05 < passes.float().mean() < 0.95, f"{rng}: the test needs passing and refused wishes"
    normals, base, ball = f.constraints(vel, rel_pos, rel_vel, mask, pos)
    cand = f.candidates(vel, wanted)
    assert ((cand - got[..., None, :]).norm(dim=-1).min(-1).values <= 1e-5).all(), f"{rng}: not a candidate"
    violation = f.violation(got[..., None, :], normals, base)[..., 0]
    brake = (got - f.braking(vel)).norm(dim=-1) <= 1e-6  # braking is safe by construction (no check)
    assert ((violation <= 1e-5) | brake).all(), f"{rng}: an unsafe velocity ({float(violation.max())})"
    assert ((f.path_reach_of(vel, got[..., None, :])[..., 0] <= ball + 1e-5) | brake).all(), f"{rng}: past the ball"
