"""The swarm env's per-step kernels (:mod:`magwarp.kernels.swarm`: the movers' outcome, respawns) and the placer's
reuse of its grid between calls (:mod:`magwarp.kernels.placement`), against plain numpy on random inputs."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import warp as wp

from magwarp.kernels.swarm import SwarmRewards, apply_respawns, command_unless_stopped, evaluate_movers
from magwarp.layout import Layout
from magwarp.swarm.placement import Placer


@pytest.mark.parametrize("progress", [False, True])
@pytest.mark.parametrize("stations", [False, True])
def test_evaluate_movers_matches_numpy(rng, stations, progress):
    w, m, thr = 4, 37, 0.1
    flags = rng.integers(0, 4, (w, m)) * (rng.random((w, m)) < 0.4)
    xy = rng.random((w, m, 2)) * 2
    goals = xy + rng.normal(0, 0.1, (w, m, 2))  # about half within the threshold
    pending, goal_pending, carrying = (rng.random((w, m)) < q for q in (0.2, 0.2, 0.5))
    collected0 = rng.integers(0, 9, (w, m))
    jobs0 = rng.integers(0, 9, (w, m))
    rule = SwarmRewards()
    rule.threshold, rule.reward_goal, rule.reward_collision, rule.reward_per_step = thr, 20.0, -20.0, -1.0
    prog = float(rng.uniform(0.5, 10.0)) if progress else 0.0
    rule.reward_progress = prog
    d_before = (rng.random((w, m)) * 2).astype(np.float32)
    t = lambda a, dt=torch.float32: torch.tensor(np.asarray(a), dtype=dt)  # noqa: E731
    pos = wp.array(np.concatenate([xy, np.zeros((w, m, 1))], -1).astype(np.float32), dtype=wp.vec3, device="cpu")
    goals_t = t(goals)
    outs = [torch.zeros(w, m)] + [torch.zeros(w, m, dtype=torch.bool) for _ in range(7)]
    if not stations:
        outs[5] = torch.zeros(0, 0, dtype=torch.bool)
    collected, jobs = t(collected0, torch.int64), t(jobs0, torch.int64)
    collected_out, xy_out = torch.full((w, m), -7, dtype=torch.int64), torch.zeros(w, m, 2)
    f = wp.from_torch
    wp.launch(evaluate_movers, dim=(w, m), device="cpu",
              inputs=[rule, wp.array(flags.astype(np.int32), dtype=wp.int32, device="cpu"), pos,
                      f(goals_t, dtype=wp.vec2), f(t(pending, torch.bool)), f(t(goal_pending, torch.bool)),
                      f(t(carrying, torch.bool)), f(t(d_before))],
              outputs=[f(o) for o in outs] + [f(collected), f(jobs), f(collected_out), f(xy_out, dtype=wp.vec2)])
    assert torch.equal(collected_out, collected), f"{rng}: info's copy of the goal counts"
    np.testing.assert_array_equal(xy_out.numpy(), xy.astype(np.float32), err_msg=f"{rng}: the respawn positions")
    p32, g32 = xy.astype(np.float32), goals_t.numpy()
    dist = np.linalg.norm(p32.astype(np.float64) - g32, axis=-1)
    clear = np.abs(dist - thr) > 1e-5
    active = ~pending
    hit = (flags != 0) & active
    reached = (dist <= thr) & active & ~hit & ~goal_pending
    step = -1.0 + prog * (d_before - dist) if progress else -1.0  # the progress term: distance closed
    reward = np.where(active, np.where(hit, -20.0, np.where(reached, 20.0, step)), 0.0)
    got = [o.numpy() for o in outs]
    if progress:
        np.testing.assert_allclose(got[0][clear], reward[clear], rtol=1e-5, atol=1e-5, err_msg=str(rng))
    else:
        np.testing.assert_array_equal(got[0][clear], reward[clear], err_msg=str(rng))
    assert np.array_equal(got[1], (flags & 1) != 0) and np.array_equal(got[2], (flags & 2) != 0), f"{rng}"
    assert np.array_equal(got[3], hit), f"{rng}: collided"
    assert np.array_equal(got[4][clear], reached[clear]), f"{rng}: reached"
    assert np.array_equal(got[6][clear], (reached | goal_pending)[clear]), f"{rng}: goal requests"
    assert np.array_equal(got[7], hit | pending), f"{rng}: respawn requests"
    assert np.array_equal(collected.numpy()[clear], (collected0 + reached)[clear]), f"{rng}: goal counts"
    if stations:
        assert np.array_equal(got[5][clear], (reached & carrying)[clear]), f"{rng}: jobs done"
        assert np.array_equal(jobs.numpy()[clear], (jobs0 + (reached & carrying))[clear]), f"{rng}: job counts"
    else:
        assert np.array_equal(jobs.numpy(), jobs0), "jobs counted without stations"


def test_apply_respawns_matches_numpy(rng):
    w, m = 3, 29
    want, left = rng.random((w, m)) < 0.4, rng.random((w, m)) < 0.3
    xy = rng.random((w, m, 2)).astype(np.float32)
    pos0, vel0 = rng.normal(size=(w, m, 3)).astype(np.float32), rng.normal(size=(w, m, 3)).astype(np.float32)
    acc0, cmd0 = rng.normal(size=(w, m, 2)).astype(np.float32), rng.normal(size=(w, m, 2)).astype(np.float32)
    stopped0 = rng.integers(0, 2, (w, m)).astype(np.int32)
    arr = lambda a, dt: wp.array(a, dtype=dt, device="cpu")  # noqa: E731
    pos, vel, acc, cmd = arr(pos0, wp.vec3), arr(vel0, wp.vec3), arr(acc0, wp.vec2), arr(cmd0, wp.vec2)
    stopped, pending = arr(stopped0, wp.int32), arr(rng.random((w, m)) < 0.5, wp.bool)
    pending_out = arr(np.zeros((w, m), dtype=bool), wp.bool)
    todo = left.astype(np.int32) * rng.integers(1, 3, (w, m))  # the placer's marks: any nonzero is unplaced
    wp.launch(apply_respawns, dim=(w, m), device="cpu",
              inputs=[arr(want, wp.bool), arr(todo.astype(np.int32), wp.int32), arr(xy, wp.vec2)],
              outputs=[pos, vel, acc, cmd, stopped, pending, pending_out])
    moved = want & ~left
    want_pos = pos0.copy()
    want_pos[moved, :2] = xy[moved]
    np.testing.assert_array_equal(pos.numpy(), want_pos, err_msg=str(rng))
    np.testing.assert_array_equal(vel.numpy(), np.where(moved[..., None], 0.0, vel0))
    np.testing.assert_array_equal(acc.numpy(), np.where(moved[..., None], 0.0, acc0))
    np.testing.assert_array_equal(cmd.numpy(), np.where(moved[..., None], 0.0, cmd0))
    np.testing.assert_array_equal(stopped.numpy(), np.where(moved, 0, stopped0))
    np.testing.assert_array_equal(pending.numpy(), want & left)
    np.testing.assert_array_equal(pending_out.numpy(), want & left)


def test_command_unless_stopped_matches_numpy(rng):
    w, m = 3, 21
    stopped = rng.integers(0, 2, (w, m)).astype(np.int32)
    action = rng.normal(0, 5, (w, m, 2)).astype(np.float32)
    cmd = wp.array(rng.normal(size=(w, m, 2)).astype(np.float32), dtype=wp.vec2, device="cpu")
    steps = wp.array([41], dtype=wp.int64, device="cpu")
    wp.launch(command_unless_stopped, dim=(w, m), device="cpu",
              inputs=[wp.array(stopped, dtype=wp.int32, device="cpu"), wp.array(action, dtype=wp.vec2, device="cpu")],
              outputs=[cmd, steps])
    np.testing.assert_array_equal(cmd.numpy(), np.where(stopped[..., None] != 0, 0.0, action), err_msg=str(rng))
    assert steps.numpy().tolist() == [42], "the env's device step count advances once per launch"


@pytest.mark.parametrize("search", ["grid", "world"])
def test_placer_leaves_its_grid_clean_and_places_only_where_asked(rng, search):
    """A call empties the cells it filled (no per-cell clearing) and leaves its claims to be beaten by later rounds'
    so back-to-back calls place as a placer with a cleared grid does; worlds with nothing to place are left alone."""
    layout = Layout(np.ones((6, 6), dtype=np.int32))
    w, m = 4, 12
    placers = [Placer(layout, m, w, device="cpu", seed=int(rng.integers(1 << 20)), search=search) for _ in range(2)]
    xy = placers[0].sample()
    for hold in (False, True, True):
        mask = torch.tensor(rng.random((w, m)) < 0.3)
        mask[2] = False  # world 2: nothing to place
        before = xy.clone()
        left = placers[0].place_async(xy, mask, rounds=3, hold=hold)
        p = placers[0]
        assert (p._head.numpy() == -1).all() and (p._head_old.numpy() == -1).all(), f"{rng}: cells left filled"
        assert p._active.numpy().tolist() == mask.any(dim=1).int().tolist()
        assert torch.equal(xy[~mask], before[~mask]) and torch.equal(xy[2], before[2])
        placed = mask & ~left
        assert placed.any(), f"{rng}: nothing placed"
        for a in range(w):
            if not placed[a].any():
                continue
            d = torch.cdist(xy[a].double(), xy[a].double()) + torch.eye(m, dtype=torch.float64) * 9
            # without hold, a masked mover left unplaced keeps a row that is no spot (place_async's contract)
            spots = ~mask[a] | placed[a] | hold
            assert float(d[placed[a]][:, spots].min()) > p.excl * 0.99999, f"{rng}: placed movers overlap"
        # the same request on a placer whose grid was just cleared places the same spots (same seeds)
        q = placers[1]
        q._seed, q._calls, q._grid_clean = p._seed, p._calls - 3, False
        again = before.clone()
        q.place_async(again, mask, rounds=3, hold=hold)
        assert torch.equal(again, xy), f"{rng}: a reused grid placed differently"


def test_place_async_refuses_a_bad_out_tensor():
    placer = Placer(Layout(np.ones((4, 4), dtype=np.int32)), 3, 2, device="cpu", seed=1)
    xy = placer.sample()
    mask = torch.zeros(2, 3, dtype=torch.bool)
    for out, what in ((torch.zeros(2, 3, dtype=torch.int32), "torch.int32"), (torch.zeros(2, 4, dtype=torch.bool),
                                                                             r"\(2, 4\)")):
        with pytest.raises(ValueError, match=f"out must be a bool tensor of shape \\(2, 3\\).*{what}"):
            placer.place_async(xy, mask, out=out)
