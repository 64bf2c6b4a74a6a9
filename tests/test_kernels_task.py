"""The fused trajectory step's task kernels (magwarp.kernels.task) and the simulator's reset-guard kernel against
plain numpy references on random inputs."""

from __future__ import annotations

import numpy as np
import warp as wp

from magwarp.kernels import guard as kguard
from magwarp.kernels import sensor_draws as kdraw
from magwarp.kernels import task as ktask
from magwarp.layout import Layout
from magwarp.sim import Simulator


def _task(rng, learn_jerk: int) -> ktask.TrajectoryTask:
    t = ktask.TrajectoryTask()
    t.learn_jerk = learn_jerk
    t.threshold = 0.1
    t.reward_success, t.reward_collision, t.reward_per_step = 20.0, -20.0, -1.0
    t.timeout_steps = int(rng.choice([-1, 2, 4]))
    t.max_episode_steps = int(rng.choice([-1, 5, 8]))
    t.draw_latency = 1
    t.delay_low, t.delay_span = 2, 7
    return t


def _draws(kernel, shape, dtype, key, clock: int, slot: int, *extra) -> np.ndarray:
    """The counter-based draws of ``slot`` (the fill kernels: tested against numpy in test_sensor_draws.py)."""
    out = wp.zeros(shape, dtype=dtype, device="cpu")
    wp.launch(kernel, dim=shape, inputs=[key, wp.int64(clock), slot, *extra], outputs=[out], device="cpu")
    return out.numpy()


def test_trajectory_step_and_obs_match_numpy(rng):
    W, M, C, P = 200, 3, 2, 50
    sim = Simulator(Layout.grid(4, 3), M, 1, device="cpu", validate_starts=False)  # for a Collision and tiles
    learn_jerk = int(rng.integers(0, 2))
    task = _task(rng, learn_jerk)
    s = ktask.GoalSampler()
    s.lo, s.span, s.hi = wp.vec2(0.1, 0.1), wp.vec2(0.76, 0.52), wp.vec2(0.86, 0.62)
    s.candidates, s.full_rect, s.radius, s.half, s.offset = C, 1, 0.1, wp.vec2(0.1, 0.1), 0.0
    f32 = np.float32
    pos = rng.uniform(0, 1, (W, M, 3)).astype(f32)
    goals = (pos[..., :2] + rng.normal(0, 0.08, (W, M, 2))).astype(f32)
    vel = rng.normal(0, 1, (W, M, 3)).astype(f32)
    acc = rng.normal(0, 5, (W, M, 2)).astype(f32)
    vel[3, 1, 0] = np.nan  # one non-finite world
    flags = rng.choice([0] * 16 + [1, 2, 3], (W, M)).astype(np.int32)
    sim_bad = np.where(rng.uniform(size=W) < 0.05, 4, -1).astype(np.int32)
    u1 = rng.uniform(-0.3, 1, (W, M, C, 2)).astype(f32)  # some candidates outside the box: the fallback is taken
    u2 = rng.uniform(-0.3, 1, (W, M, C, 2)).astype(f32)
    i1, i2 = rng.integers(0, P, (W, M)), rng.integers(0, P, (W, M))
    si = rng.integers(0, P, W)
    goal_pool = rng.uniform(0, 1, (P, 2)).astype(f32)
    start_pool = rng.uniform(0, 1, (P, M, 2)).astype(f32)
    num_steps = rng.integers(0, 8, W)
    last = np.minimum(num_steps, rng.integers(0, 8, W))
    collected = rng.integers(0, 5, (W, M))
    init_pos = rng.uniform(0, 1, (W, M, 3)).astype(f32)
    clock = np.array([17, int(rng.integers(-3, 40))])  # [env steps, draw clock]
    key = wp.array([int(rng.integers(-(1 << 31), 1 << 31))], dtype=wp.int32, device="cpu")
    D = 2 * M * (1 + learn_jerk)
    # sensor models: each part on or off at random
    sp = ktask.SensorParams()
    sp.pos_bias_on, sp.vel_bias_on, sp.dropout = (int(v) for v in rng.integers(0, 2, 3))
    sp.pos_std, sp.vel_std, sp.pos_bias_std, sp.vel_bias_std = (float(v) for v in rng.choice([0.0, 0.01], 4))
    sp.drop_prob = 0.3
    pos_bias, vel_bias, pos_mean, vel_mean = rng.normal(0, 0.01, (4, W, M, 2)).astype(f32)
    # the counter-based draws the kernels compute: [pos, vel] biases, [reading][pos, vel] noise, dropout, delays
    bias_draw = np.stack([_draws(kdraw.fill_normals, (W, M), wp.vec2, key, clock[1], slot)
                          for slot in (kdraw.BIAS_POS, kdraw.BIAS_VEL)])
    noise = np.stack([np.stack([_draws(kdraw.fill_normals, (W, M), wp.vec2, key, clock[1], kdraw.READ + 2 * r + k)
                                for k in (1, 0)]) for r in (0, 1)])
    drop_u = _draws(kdraw.fill_uniforms, W, float, key, clock[1], kdraw.DROP)
    lat = _draws(kdraw.fill_ints, W, wp.int32, key, clock[1], kdraw.DELAY, 2, 7)
    held_obs, held_ach = rng.normal(0, 1, (W, D)).astype(f32), rng.uniform(0, 1, (W, 2 * M)).astype(f32)
    w5 = int(np.flatnonzero(drop_u < f32(0.3))[0])
    held_ach[w5] = goals[w5].reshape(-1)  # a dropped reading at its goals: reached on the held reading
    drop_before = rng.uniform(size=W) < 0.5
    sensor_arrays = {k: wp.array(v, dtype=wp.vec2, device="cpu") for k, v in [
        ("pos_bias", pos_bias), ("vel_bias", vel_bias), ("pos_mean", pos_mean), ("vel_mean", vel_mean)]}
    sensor_arrays.update(drop=wp.array(drop_before, device="cpu"), held_obs=wp.array(held_obs, device="cpu"),
                         held_achieved=wp.array(held_ach, device="cpu"))
    for k, v in sensor_arrays.items():
        setattr(sp, k, v)

    a = {k: wp.array(v, device="cpu", dtype=dt) for k, v, dt in [
        ("goals", goals, wp.vec2), ("num_steps", num_steps, wp.int64), ("last", last, wp.int64),
        ("collected", collected, wp.int64), ("init_pos", init_pos, wp.vec3), ("pos", pos, wp.vec3),
        ("vel", vel, wp.vec3), ("acc", acc, wp.vec2), ("clock", clock, wp.int64)]}
    init_quat = wp.zeros((W, M), dtype=wp.quat, device="cpu")
    mask, delay = wp.zeros(W, dtype=wp.int32, device="cpu"), wp.zeros(W, dtype=wp.int32, device="cpu")
    outs = [wp.zeros((W, D), dtype=float, device="cpu"), wp.zeros((W, 2 * M), dtype=float, device="cpu"),
            wp.zeros((W, 2 * M), dtype=float, device="cpu"), wp.zeros(W, dtype=float, device="cpu"),
            *[wp.zeros(W, dtype=wp.bool, device="cpu") for _ in range(4)], wp.zeros(W, dtype=wp.int64, device="cpu"),
            wp.zeros((W, M), dtype=wp.int64, device="cpu"), wp.zeros((W, M), dtype=wp.bool, device="cpu"),
            wp.zeros(W, dtype=wp.bool, device="cpu"), wp.zeros(W, dtype=wp.bool, device="cpu"),
            wp.zeros(W, dtype=wp.int64, device="cpu"), wp.zeros(W, dtype=wp.bool, device="cpu")]
    m = sim.model

    def arr(x, dt=None):
        return wp.array(x, device="cpu") if dt is None else wp.array(x, dtype=dt, device="cpu")

    def sensed(x, bias, use_bias, std, nz):  # SensorModel._sense, in float32
        x = x + bias if use_bias else x
        return (x + f32(std) * nz if std else x).reshape(W, -1)

    def reading(k, pb, vb):
        v = sensed(vel[..., :2], vb, sp.vel_bias_on, sp.vel_std, noise[k, 1])
        p = sensed(pos[..., :2], pb, sp.pos_bias_on, sp.pos_std, noise[k, 0])
        return np.concatenate([v] + ([acc.reshape(W, -1)] if learn_jerk else []), 1), p

    wp.launch(ktask.trajectory_step, dim=W, device="cpu",
              inputs=[task, s, m.tiles, m.collision, arr(goal_pool, wp.vec2), arr(start_pool, wp.vec2), a["pos"],
                      a["vel"], a["acc"], arr(flags), arr(sim_bad), a["clock"], key, arr(u1, wp.vec2), arr(i1),
                      arr(si), arr(u2, wp.vec2), arr(i2), sp, a["goals"], a["num_steps"], a["last"], a["collected"],
                      a["init_pos"], init_quat, mask, delay], outputs=outs)
    obs = [wp.zeros((W, D), dtype=float, device="cpu"), wp.zeros((W, 2 * M), dtype=float, device="cpu"),
           wp.zeros((W, 2 * M), dtype=float, device="cpu")]
    clock_next = wp.zeros(2, dtype=wp.int64, device="cpu")
    wp.launch(ktask.trajectory_obs, dim=W, device="cpu",
              inputs=[learn_jerk, a["pos"], a["vel"], a["acc"], a["goals"], sp, a["clock"], key, outs[-1],
                      *outs[:3], clock_next],
              outputs=obs)
    (f_obs, f_ach, f_des, reward, term, trunc, mc, wc, since, coll_out, reached, tl, bad, bad_step,
     done) = (o.numpy() for o in outs)

    # numpy reference
    def pick(u, idx):
        cand = np.float32(0.1) + u * np.array([0.76, 0.52], f32)  # lo + u * span, in float32
        ok = (cand >= f32(0.1)).all(-1) & (cand[..., 0] <= f32(0.86)) & (cand[..., 1] <= f32(0.62))
        first = ok.argmax(-1)
        chosen = np.take_along_axis(cand, first[..., None, None].repeat(2, -1), 2)[:, :, 0]
        return np.where(ok.any(-1)[..., None], chosen, goal_pool[idx])

    ref_obs, ref_ach = reading(0, pos_bias, vel_bias)
    drop = drop_u < f32(0.3)
    if sp.dropout:
        ref_obs = np.where(drop[:, None], held_obs, ref_obs)
        ref_ach = np.where(drop[:, None], held_ach, ref_ach)
    np.testing.assert_array_equal(f_obs, ref_obs)
    np.testing.assert_array_equal(f_ach, ref_ach)
    np.testing.assert_array_equal(f_des, goals.reshape(W, -1))
    d = ref_ach.reshape(W, M, 2) - goals
    at = np.sqrt(d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1]) <= f32(0.1)
    np.testing.assert_array_equal(reached, at)
    np.testing.assert_array_equal(mc, (flags & 1).any(1))
    np.testing.assert_array_equal(wc, (flags & 2).any(1))
    col = mc | wc
    n_at = at.sum(1)
    ref_r = np.where(col, -20.0, np.where(n_at > 0, 20.0 * n_at, -1.0)).astype(f32)
    finite = np.isfinite(ref_obs).all(1) & np.isfinite(ref_ach).all(1) & (sim_bad < 0)
    np.testing.assert_array_equal(bad, ~finite)
    np.testing.assert_array_equal(reward, np.where(finite, ref_r, 0.0))
    np.testing.assert_array_equal(since, num_steps - last)
    timed_out = (task.timeout_steps >= 0) & (num_steps - last > task.timeout_steps)
    cut = (task.max_episode_steps >= 0) & (num_steps + 1 >= task.max_episode_steps)
    np.testing.assert_array_equal(term, col | ~finite)
    np.testing.assert_array_equal(trunc, timed_out | cut)
    if task.max_episode_steps >= 0:
        np.testing.assert_array_equal(tl, cut & ~timed_out & ~col)
    np.testing.assert_array_equal(done, term | trunc)
    np.testing.assert_array_equal(bad_step, np.where(finite, -1, 18))
    np.testing.assert_array_equal(coll_out, collected + at)
    # state after the step: counters, goals (reached: resampled; finished: the reset draws), starts, mask, delays
    new_goals = np.where(at[..., None], pick(u1, i1), goals)
    new_goals = np.where(done[:, None, None], pick(u2, i2), new_goals)
    np.testing.assert_array_equal(a["goals"].numpy(), new_goals)
    steps = num_steps + 1
    np.testing.assert_array_equal(a["num_steps"].numpy(), np.where(done, 0, steps))
    np.testing.assert_array_equal(a["last"].numpy(), np.where(done, 0, np.where(at.any(1), steps, last)))
    np.testing.assert_array_equal(a["collected"].numpy(), np.where(done[:, None], 0, collected + at))
    ref_init = init_pos.copy()
    ref_init[done, :, :2] = start_pool[si[done]]
    np.testing.assert_array_equal(a["init_pos"].numpy(), ref_init)
    np.testing.assert_array_equal(init_quat.numpy()[done], np.tile([0, 0, 0, 1], (done.sum(), M, 1)))
    np.testing.assert_array_equal(mask.numpy(), done.astype(np.int32))
    np.testing.assert_array_equal(delay.numpy(), np.where(done, lat, 0))
    # the returned observation: the next episode's first where finished, the final one elsewhere
    # new biases where finished (mean + std * draw); the next reading uses them
    new_pb = np.where(done[:, None, None] & bool(sp.pos_bias_std), pos_mean + f32(sp.pos_bias_std) * bias_draw[0],
                      pos_bias)
    new_vb = np.where(done[:, None, None] & bool(sp.vel_bias_std), vel_mean + f32(sp.vel_bias_std) * bias_draw[1],
                      vel_bias)
    np.testing.assert_array_equal(sensor_arrays["pos_bias"].numpy(), new_pb)
    np.testing.assert_array_equal(sensor_arrays["vel_bias"].numpy(), new_vb)
    ref_next, ref_next_ach = reading(1, new_pb, new_vb)
    np.testing.assert_array_equal(obs[0].numpy(), np.where(done[:, None], ref_next, f_obs))
    np.testing.assert_array_equal(obs[1].numpy(), np.where(done[:, None], ref_next_ach, f_ach))
    if sp.dropout:  # the returned reading is held, the next one fresh
        np.testing.assert_array_equal(sensor_arrays["held_obs"].numpy(), obs[0].numpy())
        np.testing.assert_array_equal(sensor_arrays["held_achieved"].numpy(), obs[1].numpy())
        assert not sensor_arrays["drop"].numpy().any()
    else:  # untouched
        np.testing.assert_array_equal(sensor_arrays["held_obs"].numpy(), held_obs)
        np.testing.assert_array_equal(sensor_arrays["drop"].numpy(), drop_before)
    np.testing.assert_array_equal(obs[2].numpy(), np.where(done[:, None], new_goals.reshape(W, -1), f_des))
    np.testing.assert_array_equal(a["clock"].numpy(), clock)  # read only; the next step's clock goes to clock_next
    np.testing.assert_array_equal(clock_next.numpy(), clock + 1)
    assert done.any() and (~done).any() and at.any()


def test_clear_reset_worlds_matches_numpy(rng):
    W, M = 64, 4
    mask = rng.integers(0, 2, W).astype(np.int32)
    nonfinite = rng.integers(-1, 9, W).astype(np.int32)
    prev = rng.normal(size=(W, M, 2)).astype(np.float32)
    for latency in (0, 1):
        nf, pc = wp.array(nonfinite, device="cpu"), wp.array(prev, dtype=wp.vec2, device="cpu")
        wp.launch(kguard.clear_reset_worlds, dim=(W, M), inputs=[wp.array(mask, device="cpu"), latency],
                  outputs=[nf, pc], device="cpu")
        np.testing.assert_array_equal(nf.numpy(), np.where(mask == 1, -1, nonfinite))
        ref = np.where((mask == 1)[:, None, None] & bool(latency), 0.0, prev)
        np.testing.assert_array_equal(pc.numpy(), ref)
