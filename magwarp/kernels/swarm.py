"""Per-mover kernels of the swarm env's step: collision stops, the step's command, outcome and respawns.

:func:`stop_collided` runs after every control cycle (a simulator cycle hook, inside the step graph): a mover
flagged in this cycle (mover-mover or wall) is marked stopped, and every stopped mover has its x/y velocity,
acceleration and command zeroed, so it stays where it collided (z and attitude stay under the impedance hold).

Around the simulator's step, one launch each over every mover: :func:`command_unless_stopped` (the action, zero
for stopped movers), :func:`evaluate_movers` (collision flags, reward, goal and job counts, and the movers that want
a new goal or a respawn) and :func:`apply_respawns` (the placed movers moved to their spots, at rest).
"""

import warp as wp

from magwarp.kernels.options import MODULE_OPTIONS

wp.set_module_options({"enable_backward": False, **MODULE_OPTIONS})


@wp.kernel
def stop_collided(
    # State in:
    flags: wp.array2d(dtype=wp.int32),
    # State out:
    stopped: wp.array2d(dtype=wp.int32),
    vel: wp.array2d(dtype=wp.vec3),
    acc: wp.array2d(dtype=wp.vec2),
    cmd: wp.array2d(dtype=wp.vec2),
):
    w, m = wp.tid()
    s = stopped[w, m]
    if flags[w, m] != 0 and s == 0:
        s = 1
        stopped[w, m] = 1
    if s != 0:
        v = vel[w, m]
        vel[w, m] = wp.vec3(0.0, 0.0, v[2])
        acc[w, m] = wp.vec2(0.0)
        cmd[w, m] = wp.vec2(0.0)


@wp.struct
class SwarmRewards:
    """The swarm env's per-mover reward rule."""

    threshold: float  # goal reached within this distance (m)
    reward_goal: float
    reward_collision: float
    reward_per_step: float


@wp.kernel
def evaluate_movers(
    # Model:
    rule: SwarmRewards,
    # State in:
    flags_any: wp.array2d(dtype=wp.int32),
    pos: wp.array2d(dtype=wp.vec3),
    goals: wp.array2d(dtype=wp.vec2),
    respawn_pending: wp.array2d(dtype=wp.bool),
    goal_pending: wp.array2d(dtype=wp.bool),
    carrying: wp.array2d(dtype=wp.bool),
    # State out:
    agent_reward: wp.array2d(dtype=wp.float32),
    mover_col: wp.array2d(dtype=wp.bool),
    wall_col: wp.array2d(dtype=wp.bool),
    collided: wp.array2d(dtype=wp.bool),
    reached: wp.array2d(dtype=wp.bool),
    job_done: wp.array2d(dtype=wp.bool),
    want_goal: wp.array2d(dtype=wp.bool),
    want_respawn: wp.array2d(dtype=wp.bool),
    collected: wp.array2d(dtype=wp.int64),
    jobs: wp.array2d(dtype=wp.int64),
):
    """One mover's step outcome: its collision flags (bit 1 mover, bit 2 wall), ``collided`` (a flag while not
    waiting to respawn), ``reached`` (within ``threshold`` of its goal, active, not collided, no goal pending), its
    reward (collision, else goal, else per step; 0 while waiting), its goal count (and with stations, where
    ``job_done`` has rows, the delivered job and its job count), and what it asks of the placers: a new goal
    (``reached`` or a goal still pending) and a respawn (``collided`` or still pending)."""
    w, m = wp.tid()
    flags = flags_any[w, m]
    mc = (flags & 1) != 0
    wc = (flags & 2) != 0
    active = not respawn_pending[w, m]
    hit = (mc or wc) and active
    p = pos[w, m]
    g = goals[w, m]
    dist = wp.length(wp.vec2(p[0] - g[0], p[1] - g[1]))
    got = dist <= rule.threshold and active and not hit and not goal_pending[w, m]
    r = rule.reward_per_step
    if hit:
        r = rule.reward_collision
    elif got:
        r = rule.reward_goal
    if not active:
        r = 0.0
    agent_reward[w, m] = r
    mover_col[w, m] = mc
    wall_col[w, m] = wc
    collided[w, m] = hit
    reached[w, m] = got
    want_goal[w, m] = got or goal_pending[w, m]
    want_respawn[w, m] = hit or respawn_pending[w, m]
    if got:
        collected[w, m] = collected[w, m] + wp.int64(1)
    if job_done.shape[0] > 0:
        done = got and carrying[w, m]
        job_done[w, m] = done
        if done:
            jobs[w, m] = jobs[w, m] + wp.int64(1)


@wp.kernel
def apply_respawns(
    # State in:
    want: wp.array2d(dtype=wp.bool),
    left: wp.array2d(dtype=wp.bool),
    xy: wp.array2d(dtype=wp.vec2),
    # State out:
    pos: wp.array2d(dtype=wp.vec3),
    vel: wp.array2d(dtype=wp.vec3),
    acc: wp.array2d(dtype=wp.vec2),
    cmd: wp.array2d(dtype=wp.vec2),
    stopped: wp.array2d(dtype=wp.int32),
    respawn_pending: wp.array2d(dtype=wp.bool),
):
    """Movers that asked for a respawn (``want``) and got a spot (not ``left``): moved to ``xy`` (z kept), at rest
    (velocity, acceleration and command zeroed), no longer stopped; those left unplaced stay pending."""
    w, m = wp.tid()
    asked = want[w, m]
    unplaced = left[w, m]
    respawn_pending[w, m] = asked and unplaced
    if asked and not unplaced:
        q = xy[w, m]
        p = pos[w, m]
        pos[w, m] = wp.vec3(q[0], q[1], p[2])
        vel[w, m] = wp.vec3(0.0)
        acc[w, m] = wp.vec2(0.0)
        cmd[w, m] = wp.vec2(0.0)
        stopped[w, m] = 0


@wp.kernel
def command_unless_stopped(
    # State in:
    stopped: wp.array2d(dtype=wp.int32),
    action: wp.array2d(dtype=wp.vec2),
    # State out:
    cmd: wp.array2d(dtype=wp.vec2),
):
    """The step's command: the action, zero for stopped movers (pending respawns ignore their command)."""
    w, m = wp.tid()
    c = action[w, m]
    if stopped[w, m] != 0:
        c = wp.vec2(0.0)
    cmd[w, m] = c
