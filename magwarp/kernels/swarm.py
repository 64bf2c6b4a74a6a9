"""Per-mover kernels of the swarm env's step: collision stops, the step's command, outcome and respawns.

:func:`stop_collided` runs after every control cycle (a simulator cycle hook, inside the step graph): a mover
flagged in this cycle (mover-mover or wall) is marked stopped, and every stopped mover has its x/y velocity,
acceleration and command zeroed, so it stays where it collided (z and attitude stay under the impedance hold).

Around the simulator's step, one launch each over every mover: :func:`command_unless_stopped` (the action, zero
for stopped movers; it also counts the env's steps on the device), :func:`evaluate_movers` (collision flags, reward,
goal and job counts, the movers that want a new goal or a respawn, the positions the respawn placer starts from and
the goal counts ``info`` returns) and :func:`apply_respawns` (the placed movers moved to their spots, at rest; the
pending respawns ``info`` returns), with the progress reward :func:`goal_distances` (each mover's distance to its
goal once the step's goals and respawns are placed, and at resets: the next step's ``d_before``), then one over the worlds, :func:`finish_worlds` (the world's reward, flags, NaN
guard and step count). Every per-step counter lives on the device, so the whole env step can be one CUDA graph
(:mod:`magwarp.swarm.env`); the copies and torch ops these kernels replace (the positions' copy, ``info``'s clones,
the reward's sum, the NaN guard's five ops) were folded in for that step (fewer nodes per replay, fewer launches
eagerly).
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
    reward_progress: float  # per metre of goal distance closed during the step (0: off, the sparse reward)


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
    d_before: wp.array2d(dtype=wp.float32),
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
    collected_out: wp.array2d(dtype=wp.int64),
    xy: wp.array2d(dtype=wp.vec2),
):
    """One mover's step outcome: its collision flags (bit 1 mover, bit 2 wall), ``collided`` (a flag while not
    waiting to respawn), ``reached`` (within ``threshold`` of its goal, active, not collided, no goal pending), its
    reward (collision, else goal, else per step, plus with a nonzero ``reward_progress`` that many times the goal
    distance closed during the step, ``d_before`` (:func:`goal_distances` at the step's start) minus its distance now;
    0 while waiting), its goal count (and with stations, where
    ``job_done`` has rows, the delivered job and its job count), and what it asks of the placers: a new goal
    (``reached`` or a goal still pending) and a respawn (``collided`` or still pending). ``collected_out`` (where it
    has rows): a copy of the new goal count (``info["collected_goals"]``); ``xy`` (where it has rows): the mover's
    x/y position (where the respawn placer starts from)."""
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
    if rule.reward_progress != 0.0:  # off: the sparse reward, bit for bit
        r = r + rule.reward_progress * (d_before[w, m] - dist)
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
    count = collected[w, m]
    if got:
        count = count + wp.int64(1)
        collected[w, m] = count
    if collected_out.shape[0] > 0:
        collected_out[w, m] = count
    if xy.shape[0] > 0:
        xy[w, m] = wp.vec2(p[0], p[1])
    if job_done.shape[0] > 0:
        done = got and carrying[w, m]
        job_done[w, m] = done
        if done:
            jobs[w, m] = jobs[w, m] + wp.int64(1)


@wp.kernel
def goal_distances(
    # State in:
    pos: wp.array2d(dtype=wp.vec3),
    goals: wp.array2d(dtype=wp.vec2),
    # State out:
    dist: wp.array2d(dtype=wp.float32),
):
    """Each mover's x/y distance to its goal (as :func:`evaluate_movers` measures it): the next step's ``d_before``
    for the progress reward, refreshed after the step's new goals and respawns and at every reset."""
    w, m = wp.tid()
    p = pos[w, m]
    g = goals[w, m]
    dist[w, m] = wp.length(wp.vec2(p[0] - g[0], p[1] - g[1]))


@wp.kernel
def apply_respawns(
    # State in:
    want: wp.array2d(dtype=wp.bool),
    left: wp.array2d(dtype=wp.int32),
    xy: wp.array2d(dtype=wp.vec2),
    # State out:
    pos: wp.array2d(dtype=wp.vec3),
    vel: wp.array2d(dtype=wp.vec3),
    acc: wp.array2d(dtype=wp.vec2),
    cmd: wp.array2d(dtype=wp.vec2),
    stopped: wp.array2d(dtype=wp.int32),
    respawn_pending: wp.array2d(dtype=wp.bool),
    pending_out: wp.array2d(dtype=wp.bool),
):
    """Movers that asked for a respawn (``want``) and got a spot (``left`` zero: the placer's own unplaced marks,
    read directly instead of a bool copy): moved to ``xy`` (z kept), at rest (velocity, acceleration and command
    zeroed), no longer stopped; those left unplaced stay pending. ``pending_out`` (where it has rows): a copy of the
    new ``respawn_pending`` (``info["respawn_pending"]``)."""
    w, m = wp.tid()
    asked = want[w, m]
    unplaced = left[w, m] != 0
    respawn_pending[w, m] = asked and unplaced
    if pending_out.shape[0] > 0:
        pending_out[w, m] = asked and unplaced
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
    steps: wp.array(dtype=wp.int64),
):
    """The step's command: the action, zero for stopped movers (pending respawns ignore their command). Thread (0, 0)
    also advances the env's device step count ``steps[0]`` (where it has a row; no thread of this launch reads it):
    the step number :func:`finish_worlds` reports for a non-finite world."""
    w, m = wp.tid()
    if w == 0 and m == 0 and steps.shape[0] > 0:
        steps[0] = steps[0] + wp.int64(1)
    c = action[w, m]
    if stopped[w, m] != 0:
        c = wp.vec2(0.0)
    cmd[w, m] = c


@wp.kernel
def finish_worlds(
    # Model:
    end_on_collision: int,  # 1: a world ends at its first collision (on_collision="end")
    max_steps: wp.int64,  # episode length in steps, <= 0: none
    # State in:
    agent_reward: wp.array2d(dtype=wp.float32),
    collided: wp.array2d(dtype=wp.bool),
    sim_nonfinite: wp.array(dtype=wp.int32),
    obs_nonfinite: wp.array(dtype=wp.int32),
    steps: wp.array(dtype=wp.int64),
    # State out:
    num_steps: wp.array(dtype=wp.int64),
    reward: wp.array(dtype=wp.float32),
    terminated: wp.array(dtype=wp.bool),
    truncated: wp.array(dtype=wp.bool),
    nonfinite: wp.array(dtype=wp.bool),
    nonfinite_step: wp.array(dtype=wp.int64),
    done: wp.array(dtype=wp.bool),
):
    """One thread per world, after the observation: the world's reward (its movers' rewards summed in mover order),
    ``terminated`` (a collision with ``end_on_collision``), ``truncated`` (the episode's ``max_steps``-th step and not
    terminated), the NaN guard (``nonfinite``: the simulator's record ``sim_nonfinite >= 0`` or a non-finite
    observation row ``obs_nonfinite``; such a world is rewarded 0 and terminated, ``nonfinite_step``: the env's step
    count ``steps[0]`` there, -1 elsewhere), its episode's step count advanced and ``done`` (terminated or
    truncated: the autoreset's mask). The torch ops it replaces (sum, zeros, comparisons, ``where``) ran one launch
    each."""
    w = wp.tid()
    total = float(0.0)
    ended = bool(False)
    for m in range(agent_reward.shape[1]):
        total += agent_reward[w, m]
        if end_on_collision != 0 and collided[w, m]:
            ended = True
    n = num_steps[w] + wp.int64(1)
    num_steps[w] = n
    trunc = max_steps > wp.int64(0) and n >= max_steps and not ended
    bad = sim_nonfinite[w] >= 0 or obs_nonfinite[w] != 0
    step = wp.int64(-1)
    if bad:
        total = 0.0
        step = steps[0]
    reward[w] = total
    terminated[w] = ended or bad
    truncated[w] = trunc
    nonfinite[w] = bad
    nonfinite_step[w] = step
    done[w] = ended or bad or trunc
