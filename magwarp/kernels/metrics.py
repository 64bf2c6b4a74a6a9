"""Per-cycle benchmark metric kernels (the paper's Tables 1-2), run as cycle hooks inside the step graph.

Definitions (``DESIGN.md``, "Benchmark metrics"), per world and 1 ms control cycle:

* overshoot correction: the object was within the threshold last cycle (``d < e``) and is outside now, by more than
  2e-5 m (MagBotSim's ``CorrectiveMovementMeasurement``);
* distance correction: the distance rose by more than 2e-5 m, and later falls by more than 2e-5 m (counted at the
  fall);
* smoothness: ``sum over movers of 15 |jerk|_1 + 5 |acc|_1 + |vel|_1`` (x/y components, as MagBotSim sums them),
  with ``jerk = (acc - acc_prev) / dt`` over the real cycle time (MagBotSim divides a 40 ms difference by 1 ms);
* collision *events*: the count of colliding mover pairs, of movers over a wall, of mover-obstacle and of
  object-obstacle contacts rising from one cycle to the next (a collision that lasts several cycles is one event).

Event columns of the ``events`` arrays: see ``EV_*``. Worlds whose ``active`` flag is 0 are frozen (an evaluation
stops counting a world once its episode is over).
"""

import warp as wp

from magwarp.kernels.collision import free_joint_xy_yaw, hits_wall, model_row, movers_collide, world_collision
from magwarp.types import Collision

wp.set_module_options({"enable_backward": False})

EV_MOVER_MOVER = 0
EV_MOVER_WALL = 1
EV_MOVER_OBSTACLE = 2
EV_OBJECT_OBSTACLE = 3
NUM_EVENTS = 4

CHANGE_EPS = wp.constant(2.0e-5)  # MagBotSim's tolerance for "the distance changed"
W_JERK = wp.constant(15.0)
W_ACC = wp.constant(5.0)
W_VEL = wp.constant(1.0)


@wp.func
def corrective_update(dist: float, threshold: float, success_last: int, last_dist: float, increased: int):
    """One cycle of the corrective-movement rules. Returns (overshoot 0/1, correction 0/1, success_last, increased)."""
    at_goal = dist < threshold
    overshoot = 0
    if success_last != 0 and not at_goal and wp.abs(dist - threshold) > CHANGE_EPS:
        overshoot = 1
    correction = 0
    inc = increased
    if last_dist < dist and wp.abs(last_dist - dist) > CHANGE_EPS:
        inc = 1
    elif increased != 0 and dist < last_dist and wp.abs(last_dist - dist) > CHANGE_EPS:
        inc = 0
        correction = 1
    return overshoot, correction, wp.where(at_goal, 1, 0), inc


@wp.func
def smooth_term(vel: wp.vec2, acc: wp.vec2, prev_acc: wp.vec2, dt: float) -> float:
    jerk = (acc - prev_acc) / dt
    return (W_JERK * (wp.abs(jerk[0]) + wp.abs(jerk[1])) + W_ACC * (wp.abs(acc[0]) + wp.abs(acc[1]))
            + W_VEL * (wp.abs(vel[0]) + wp.abs(vel[1])))


@wp.func
def count_rise(now: int, w: int, k: int, prev: wp.array2d[int], events: wp.array2d[int]):
    """Add the rise of ``now`` over last cycle's value to event column ``k`` (a new collision is one event)."""
    if now > prev[w, k]:
        events[w, k] += now - prev[w, k]
    prev[w, k] = now


@wp.kernel
def trajectory_movers_kernel(
    # Model:
    dt: float,
    threshold: float,
    # State in:
    active: wp.array[int],
    halted: wp.array[wp.int32],
    elapsed: wp.array[int],
    pos: wp.array2d[wp.vec3],
    vel: wp.array2d[wp.vec3],
    acc: wp.array2d[wp.vec2],
    goals: wp.array2d[wp.vec2],
    # State in/out:
    prev_acc: wp.array2d[wp.vec2],
    in_since: wp.array2d[int],
    success_last: wp.array2d[int],
    last_dist: wp.array2d[float],
    increased: wp.array2d[int],
    # State out (accumulated):
    smooth: wp.array2d[wp.float64],
    overshoots: wp.array2d[int],
    corrections: wp.array2d[int],
):
    w, m = wp.tid()
    if active[w] == 0:
        return
    a = acc[w, m]
    # A halted world (stopped at a collision, as a real system stops on a lag error) does not move: no effort.
    if halted[w] == 0:
        v = vel[w, m]
        smooth[w, m] += wp.float64(smooth_term(wp.vec2(v[0], v[1]), a, prev_acc[w, m], dt))
    prev_acc[w, m] = a
    p = pos[w, m]
    dist = wp.length(wp.vec2(p[0], p[1]) - goals[w, m])
    # The cycle at which the mover entered the goal region: its reach time if the env counts the goal at step end.
    if dist <= threshold:
        if in_since[w, m] < 0:
            in_since[w, m] = elapsed[w] + 1
    else:
        in_since[w, m] = -1
    o, c, s, inc = corrective_update(dist, threshold, success_last[w, m], last_dist[w, m], increased[w, m])
    overshoots[w, m] += o
    corrections[w, m] += c
    success_last[w, m] = s
    increased[w, m] = inc
    last_dist[w, m] = dist


@wp.kernel
def trajectory_world_kernel(
    # State in:
    active: wp.array[int],
    world_pairs: wp.array[wp.int32],
    world_walls: wp.array[wp.int32],
    # State in/out:
    prev: wp.array2d[int],
    elapsed: wp.array[int],
    # State out (accumulated):
    events: wp.array2d[int],
):
    w = wp.tid()
    if active[w] == 0:
        return
    elapsed[w] += 1
    count_rise(int(world_pairs[w]), w, EV_MOVER_MOVER, prev, events)
    count_rise(int(world_walls[w]), w, EV_MOVER_WALL, prev, events)


@wp.kernel
def push_world_kernel(
    # Model:
    tiles: wp.array2d[wp.int32],
    col_shared: Collision,
    qadr: wp.array[int],
    dadr: wp.array[int],
    radius: wp.array2d[float],  # [1 or W, M]: the env's collision sizes (per world once randomised)
    half: wp.array2d[wp.vec2],
    margins: wp.array[wp.vec2],  # [1 or W]: (mover-mover margin, wall margin)
    dt: float,
    num_contact_pairs: int,
    # State in:
    active: wp.array[int],
    qpos: wp.array2d[float],
    qvel: wp.array2d[float],
    acc: wp.array2d[wp.vec2],
    # State in/out (contacts of this cycle, cleared here once read):
    contacts: wp.array2d[int],
    prev_acc: wp.array2d[wp.vec2],
    prev: wp.array2d[int],
    elapsed: wp.array[int],
    # State out (accumulated):
    smooth: wp.array[wp.float64],
    events: wp.array2d[int],
):
    w = wp.tid()
    contact_mo = 0
    contact_oo = 0
    if num_contact_pairs > 0:
        contact_mo = contacts[w, 0]
        contacts[w, 0] = 0
    if num_contact_pairs > 1:
        contact_oo = contacts[w, 1]
        contacts[w, 1] = 0
    if active[w] == 0:
        return
    elapsed[w] += 1
    col = world_collision(col_shared, margins, w)
    rr = model_row(radius.shape[0], w)
    hr = model_row(half.shape[0], w)
    num_movers = qadr.shape[0]
    walls = int(0)
    pairs = int(0)
    effort = float(0.0)
    for k in range(num_movers):
        p, yaw = free_joint_xy_yaw(qpos, w, qadr[k])
        if hits_wall(tiles, col, p, yaw, radius[rr, k], half[hr, k]):
            walls += 1
        for j in range(k + 1, num_movers):
            pj, yawj = free_joint_xy_yaw(qpos, w, qadr[j])
            if movers_collide(col, pj - p, yaw, radius[rr, k], half[hr, k], yawj, radius[rr, j], half[hr, j]):
                pairs += 1
        a = acc[w, k]
        v = wp.vec2(qvel[w, dadr[k]], qvel[w, dadr[k] + 1])
        effort += smooth_term(v, a, prev_acc[w, k], dt)
        prev_acc[w, k] = a
    smooth[w] += wp.float64(effort)
    count_rise(pairs, w, EV_MOVER_MOVER, prev, events)
    count_rise(walls, w, EV_MOVER_WALL, prev, events)
    count_rise(contact_mo, w, EV_MOVER_OBSTACLE, prev, events)
    count_rise(contact_oo, w, EV_OBJECT_OBSTACLE, prev, events)
