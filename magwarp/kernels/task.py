"""Task kernels of the trajectory-planning env's fused step: evaluation, goal resampling and autoreset in two launches
(one thread per world), around the simulator's step and reset kernels.

* :func:`trajectory_step` — after the physics: the observation the reward is computed for (kept as the final
  observation), reward, collision termination, timeout/truncation, reached goals resampled, the goal counters, the
  NaN guard, and for the worlds that finished: new start poses and goals written, counters cleared and the
  simulator's reset mask set;
* (the simulator's reset kernels then put the finished worlds back at their new starts);
* :func:`trajectory_obs` — the returned observation: the next episode's first one where a world finished, else the
  final one; it also advances the device clock (env steps, draw clock).

Sensor models (:class:`SensorParams`): both kernels read the mover positions and velocities as
:class:`magwarp.envs.sim2real.SensorModel` does (bias, then white noise), and :func:`trajectory_step` repeats the held
reading of a world whose reading is dropped; goal checks and the NaN guard see the reading.

The goals' and starts' random numbers are drawn before the kernels, with the env's torch generator, in the same calls
and order as the eager step (:mod:`magwarp.envs.trajectory_fused`): the kernels only select among them. The sim2real
models' draws (white noise, new biases, dropped readings, action delays) are counter-based
(:mod:`magwarp.kernels.sensor_draws`): the kernels compute them from the key and the draw clock, as the torch step's
fill kernels do. Both paths give the same numbers for the same seed. Floating-point contraction is off in this module
(``fuse_fp``): ``lo + u * span`` must round as torch's separate multiply and add do.
"""

from __future__ import annotations

import warp as wp

from magwarp.kernels import sensor_draws as kdraw
from magwarp.kernels.collision import hits_wall_cs
from magwarp.types import COLLIDE_MOVER, COLLIDE_WALL, Collision

wp.set_module_options({"enable_backward": False, "fuse_fp": False})


@wp.struct
class TrajectoryTask:
    """The task's constants (see :class:`magwarp.envs.trajectory.TrajectoryPlanningEnv`)."""

    learn_jerk: int  # 1: the observation carries the x/y accelerations after the velocities
    threshold: float  # goal reached within this distance (m)
    reward_success: float
    reward_collision: float
    reward_per_step: float
    timeout_steps: int  # truncate when more steps than this passed since the last goal; -1: never
    max_episode_steps: int  # truncate after this many steps; -1: never
    draw_latency: int  # 1: resets draw the world's action delay in [delay_low, delay_low + delay_span)
    delay_low: int
    delay_span: int


@wp.struct
class SensorParams:
    """:class:`magwarp.envs.sim2real.SensorModel` on the device: a reading is ``x + bias`` (where set), then ``+ std *
    noise`` (where the std is not 0); a world whose uniform is below ``drop_prob`` repeats its held reading; a
    finished world draws new biases ``mean + bias_std * draw`` (draws: :mod:`magwarp.kernels.sensor_draws`)."""

    pos_bias_on: int  # 1: add the per-world position bias
    vel_bias_on: int  # 1: add the per-world velocity bias
    pos_std: float  # white noise std on positions (0: none drawn)
    vel_std: float  # white noise std on velocities (0: none drawn)
    pos_bias_std: float  # 0: a set bias (none drawn at resets)
    vel_bias_std: float
    dropout: int  # 1: dropped readings (the world's uniform < ``drop_prob``) repeat the held observation and goal
    drop_prob: float
    # State in/out (the model's own tensors, [W, M] x/y; the held readings [W, D] and [W, 2 M]):
    pos_bias: wp.array2d(dtype=wp.vec2)
    vel_bias: wp.array2d(dtype=wp.vec2)
    pos_mean: wp.array2d(dtype=wp.vec2)
    vel_mean: wp.array2d(dtype=wp.vec2)
    drop: wp.array(dtype=wp.bool)
    held_obs: wp.array2d(dtype=float)
    held_achieved: wp.array2d(dtype=float)


@wp.struct
class GoalSampler:
    """:class:`magwarp.envs.sampling.PoseSampler`'s goal rule: candidates ``lo + u * span`` in the sampling box, the
    first one whose footprint is on the tiles, else a point of the pool of valid goals."""

    lo: wp.vec2
    span: wp.vec2
    hi: wp.vec2  # lo + span, rounded as torch rounds it
    candidates: int
    full_rect: int  # 1: every point of the box is valid (no tile lookup)
    radius: float
    half: wp.vec2
    offset: float


@wp.func
def goal_on_tiles(s: GoalSampler, tiles: wp.array2d(dtype=wp.int32), col: Collision, p: wp.vec2):
    """The sampler's ``on_tiles``: inside the box on a full rectangle, else the footprint (yaw 0, grown by the
    offset) fully on the tiles (the ``footprints_on_tiles`` kernel's rule)."""
    if s.full_rect == 1:
        return p[0] >= s.lo[0] and p[1] >= s.lo[1] and p[0] <= s.hi[0] and p[1] <= s.hi[1]
    grow = wp.vec2(s.offset, s.offset)
    return not hits_wall_cs(tiles, col, p, wp.vec2(1.0, 0.0), s.radius + s.offset, s.half + grow)


@wp.func
def sample_goal(
    s: GoalSampler, tiles: wp.array2d(dtype=wp.int32), col: Collision, pool: wp.array(dtype=wp.vec2),
    u: wp.array3d(dtype=wp.vec2), fallback: wp.array2d(dtype=wp.int64), w: int, m: int,
):
    """One goal from the pre-drawn uniforms ``u[w, m, :]`` and pool index ``fallback[w, m]``
    (``PoseSampler.sample_goals``)."""
    for k in range(s.candidates):
        c = u[w, m, k]
        p = s.lo + wp.cw_mul(c, s.span)
        if goal_on_tiles(s, tiles, col, p):
            return p
    return pool[int(fallback[w, m])]


@wp.func
def write_obs(
    w: int, m: int, num_movers: int, learn_jerk: int, v: wp.vec2, a: wp.vec2, p: wp.vec2, g: wp.vec2,
    obs: wp.array2d(dtype=float), achieved: wp.array2d(dtype=float), desired: wp.array2d(dtype=float),
):
    """Mover ``m``'s entries of world ``w``'s observation: velocity (then acceleration when learning jerk, after all
    velocities), position (achieved goal) and goal (desired goal)."""
    obs[w, 2 * m] = v[0]
    obs[w, 2 * m + 1] = v[1]
    if learn_jerk == 1:
        obs[w, 2 * num_movers + 2 * m] = a[0]
        obs[w, 2 * num_movers + 2 * m + 1] = a[1]
    achieved[w, 2 * m] = p[0]
    achieved[w, 2 * m + 1] = p[1]
    desired[w, 2 * m] = g[0]
    desired[w, 2 * m + 1] = g[1]


@wp.func
def sense(s: SensorParams, vel: wp.vec2, pos: wp.vec2, ws: wp.uint32, reading: int, w: int, m: int):
    """Mover ``m``'s sensed (velocity, position) as ``(vx, vy, px, py)`` (``SensorModel._sense``: the bias added
    first, then the scaled noise, in float32); the noise is the world's (``ws``) draws of reading ``reading``."""
    v = wp.vec2(vel[0], vel[1])
    p = wp.vec2(pos[0], pos[1])
    if s.vel_bias_on == 1:
        v = v + s.vel_bias[w, m]
    if s.vel_std != 0.0:
        v = v + s.vel_std * kdraw.normal2(kdraw.value_state(ws, kdraw.READ + 2 * reading, m))
    if s.pos_bias_on == 1:
        p = p + s.pos_bias[w, m]
    if s.pos_std != 0.0:
        p = p + s.pos_std * kdraw.normal2(kdraw.value_state(ws, kdraw.READ + 2 * reading + 1, m))
    return wp.vec4(v[0], v[1], p[0], p[1])


@wp.func
def redraw_biases(s: SensorParams, ws: wp.uint32, w: int, num_movers: int):
    """A reset world's new biases (``SensorModel.reset``: ``mean + std * draw``) and a fresh next reading."""
    for m in range(num_movers):
        if s.vel_bias_std != 0.0:
            s.vel_bias[w, m] = s.vel_mean[w, m] + s.vel_bias_std * kdraw.normal2(
                kdraw.value_state(ws, kdraw.BIAS_VEL, m))
        if s.pos_bias_std != 0.0:
            s.pos_bias[w, m] = s.pos_mean[w, m] + s.pos_bias_std * kdraw.normal2(
                kdraw.value_state(ws, kdraw.BIAS_POS, m))
    if s.dropout == 1:
        s.drop[w] = False


@wp.func
def finite2(v: wp.vec2):
    return wp.isfinite(v[0]) and wp.isfinite(v[1])


@wp.kernel
def trajectory_step(
    # Model:
    task: TrajectoryTask,
    sampler: GoalSampler,
    tiles: wp.array2d(dtype=wp.int32),
    col: Collision,
    goal_pool: wp.array(dtype=wp.vec2),
    start_pool: wp.array2d(dtype=wp.vec2),
    # State in:
    pos: wp.array2d(dtype=wp.vec3),
    vel: wp.array2d(dtype=wp.vec3),
    acc: wp.array2d(dtype=wp.vec2),
    flags_any: wp.array2d(dtype=wp.int32),
    sim_nonfinite: wp.array(dtype=wp.int32),
    clock: wp.array(dtype=wp.int64),  # [env steps before this one, the sim2real models' draw clock]
    key: wp.array(dtype=wp.int32),  # [1]: the sim2real models' draw key
    step_u: wp.array3d(dtype=wp.vec2),  # draws for the goals reached this step
    step_fallback: wp.array2d(dtype=wp.int64),
    start_index: wp.array(dtype=wp.int64),  # draws for the autoreset: start configuration, goals
    reset_u: wp.array3d(dtype=wp.vec2),
    reset_fallback: wp.array2d(dtype=wp.int64),
    # Sensors (the model, its biases, dropped readings and held readings):
    sensor: SensorParams,
    # State in/out:
    goals: wp.array2d(dtype=wp.vec2),
    num_steps: wp.array(dtype=wp.int64),
    last_goal_step: wp.array(dtype=wp.int64),
    collected: wp.array2d(dtype=wp.int64),
    init_pos: wp.array2d(dtype=wp.vec3),
    init_quat: wp.array2d(dtype=wp.quat),
    reset_mask: wp.array(dtype=wp.int32),
    delay: wp.array(dtype=wp.int32),
    # State out (the step's returns):
    final_obs: wp.array2d(dtype=float),
    final_achieved: wp.array2d(dtype=float),
    final_desired: wp.array2d(dtype=float),
    reward: wp.array(dtype=float),
    terminated: wp.array(dtype=wp.bool),
    truncated: wp.array(dtype=wp.bool),
    mover_collision: wp.array(dtype=wp.bool),
    wall_collision: wp.array(dtype=wp.bool),
    steps_since_goal: wp.array(dtype=wp.int64),
    collected_out: wp.array2d(dtype=wp.int64),
    goals_reached: wp.array2d(dtype=wp.bool),
    time_limit: wp.array(dtype=wp.bool),
    nonfinite: wp.array(dtype=wp.bool),
    nonfinite_step: wp.array(dtype=wp.int64),
    done: wp.array(dtype=wp.bool),
):
    w = wp.tid()
    num_movers = pos.shape[1]
    ws = kdraw.world_state(key[0], clock[1], w)  # the world's sim2real draws of this step
    # The observation the reward is computed for (sensed: reading 0; a dropped reading repeats the held one).
    for m in range(num_movers):
        sv = sense(sensor, wp.vec2(vel[w, m][0], vel[w, m][1]), wp.vec2(pos[w, m][0], pos[w, m][1]), ws, 0, w, m)
        write_obs(w, m, num_movers, task.learn_jerk, wp.vec2(sv[0], sv[1]), acc[w, m], wp.vec2(sv[2], sv[3]),
                  goals[w, m], final_obs, final_achieved, final_desired)
    if sensor.dropout == 1:
        dropped = kdraw.uniform(kdraw.value_state(ws, kdraw.DROP, 0)) < sensor.drop_prob
        sensor.drop[w] = dropped
        if dropped:
            for k in range(final_obs.shape[1]):
                final_obs[w, k] = sensor.held_obs[w, k]
            for k in range(final_achieved.shape[1]):
                final_achieved[w, k] = sensor.held_achieved[w, k]
    # Collisions over the step, goals reached, the NaN guard's check (all on what the observation shows).
    ok = bool(sim_nonfinite[w] < 0)
    hit_mover = bool(False)
    hit_wall = bool(False)
    reached = int(0)
    for m in range(num_movers):
        v = wp.vec2(final_obs[w, 2 * m], final_obs[w, 2 * m + 1])
        p = wp.vec2(final_achieved[w, 2 * m], final_achieved[w, 2 * m + 1])
        g = goals[w, m]
        ok = ok and finite2(v) and finite2(p) and finite2(g)
        if task.learn_jerk == 1:
            j = 2 * (num_movers + m)
            ok = ok and finite2(wp.vec2(final_obs[w, j], final_obs[w, j + 1]))
        f = flags_any[w, m]
        hit_mover = hit_mover or (f & COLLIDE_MOVER) != 0
        hit_wall = hit_wall or (f & COLLIDE_WALL) != 0
        d = p - g
        at_goal = wp.sqrt(d[0] * d[0] + d[1] * d[1]) <= task.threshold
        goals_reached[w, m] = at_goal
        if at_goal:
            reached += 1
    collision = hit_mover or hit_wall
    mover_collision[w] = hit_mover
    wall_collision[w] = hit_wall
    since = num_steps[w] - last_goal_step[w]
    steps_since_goal[w] = since
    r = task.reward_per_step
    if reached > 0:
        r = task.reward_success * float(reached)
    if collision:
        r = task.reward_collision
    timed_out = task.timeout_steps >= 0 and since > wp.int64(task.timeout_steps)
    trunc = timed_out
    if task.max_episode_steps >= 0:
        cut = num_steps[w] + wp.int64(1) >= wp.int64(task.max_episode_steps)
        trunc = timed_out or cut
        time_limit[w] = cut and not timed_out and not collision
    # Bookkeeping: counters, and reached goals resampled (the observation above keeps the goal of the reward).
    steps = num_steps[w] + wp.int64(1)
    num_steps[w] = steps
    if reached > 0:
        last_goal_step[w] = steps
    for m in range(num_movers):
        if goals_reached[w, m]:
            collected[w, m] = collected[w, m] + wp.int64(1)
            goals[w, m] = sample_goal(sampler, tiles, col, goal_pool, step_u, step_fallback, w, m)
        collected_out[w, m] = collected[w, m]
    # NaN guard: a non-finite world ends with reward 0.
    nonfinite[w] = not ok
    term = collision
    nonfinite_step[w] = wp.int64(-1)
    if not ok:
        r = 0.0
        term = True
        nonfinite_step[w] = clock[0] + wp.int64(1)
    reward[w] = r
    terminated[w] = term
    truncated[w] = trunc
    finished = term or trunc
    done[w] = finished
    # Autoreset: the finished worlds' next episode (the simulator's reset kernels move them there).
    reset_mask[w] = 0
    if finished:
        reset_mask[w] = 1
        start = int(start_index[w])
        for m in range(num_movers):
            s = start_pool[start, m]
            init_pos[w, m] = wp.vec3(s[0], s[1], init_pos[w, m][2])
            init_quat[w, m] = wp.quat(0.0, 0.0, 0.0, 1.0)
            goals[w, m] = sample_goal(sampler, tiles, col, goal_pool, reset_u, reset_fallback, w, m)
            collected[w, m] = wp.int64(0)
        num_steps[w] = wp.int64(0)
        last_goal_step[w] = wp.int64(0)
        if task.draw_latency == 1:
            delay[w] = kdraw.uniform_int(kdraw.value_state(ws, kdraw.DELAY, 0), task.delay_low, task.delay_span)
        redraw_biases(sensor, ws, w, num_movers)


@wp.kernel
def trajectory_obs(
    # Model:
    learn_jerk: int,
    # State in:
    pos: wp.array2d(dtype=wp.vec3),
    vel: wp.array2d(dtype=wp.vec3),
    acc: wp.array2d(dtype=wp.vec2),
    goals: wp.array2d(dtype=wp.vec2),
    sensor: SensorParams,  # the next episode's first reading: the new biases, reading 1's noise
    clock: wp.array(dtype=wp.int64),  # [env steps before this one, draw clock] (as trajectory_step's)
    key: wp.array(dtype=wp.int32),
    done: wp.array(dtype=wp.bool),
    final_obs: wp.array2d(dtype=float),
    final_achieved: wp.array2d(dtype=float),
    final_desired: wp.array2d(dtype=float),
    # State out:
    clock_next: wp.array(dtype=wp.int64),  # the next step's clock: another array than ``clock`` (no race)
    obs: wp.array2d(dtype=float),
    achieved: wp.array2d(dtype=float),
    desired: wp.array2d(dtype=float),
):
    """The returned observation: the first of the next episode where the world finished (after the reset), else the
    final one. Thread 0 writes the next step's clock (``clock + 1``) into ``clock_next``: every thread reads ``clock``,
    so it cannot be advanced in place (the fused step alternates two clock arrays)."""
    w = wp.tid()
    if w == 0:
        clock_next[0] = clock[0] + wp.int64(1)
        clock_next[1] = clock[1] + wp.int64(1)
    num_movers = pos.shape[1]
    if done[w]:
        ws = kdraw.world_state(key[0], clock[1], w)
        for m in range(num_movers):
            sv = sense(sensor, wp.vec2(vel[w, m][0], vel[w, m][1]), wp.vec2(pos[w, m][0], pos[w, m][1]), ws, 1, w, m)
            write_obs(w, m, num_movers, learn_jerk, wp.vec2(sv[0], sv[1]), acc[w, m], wp.vec2(sv[2], sv[3]),
                      goals[w, m], obs, achieved, desired)
    else:
        for k in range(obs.shape[1]):
            obs[w, k] = final_obs[w, k]
        for k in range(achieved.shape[1]):
            achieved[w, k] = final_achieved[w, k]
            desired[w, k] = final_desired[w, k]
    if sensor.dropout == 1:  # SensorModel.commit: what a dropped reading repeats; the next reading is fresh
        for k in range(obs.shape[1]):
            sensor.held_obs[w, k] = obs[w, k]
        for k in range(achieved.shape[1]):
            sensor.held_achieved[w, k] = achieved[w, k]
        sensor.drop[w] = False
