"""Large swarms (issue #18): agent-steps/s and memory of the swarm env, beside the bare simulator step of the same
movers, at 100 to 100k movers in one world and at many worlds of 100 movers.

The scripted planner (:class:`magwarp.swarm.planner.SwarmPlanner`: one-way lanes where they fit, ORCA steering,
then the provably collision-free safety filter of :mod:`magwarp.swarm.safety`) also runs 80 s (2000 steps) in one
world of 256, 1024 (64 x 64 tiles at 25%: the issue's target setting) and 4096 movers, from a reset, goals streaming
all along. Its quality:

* ``goal share``: the share of movers that reached their first goal (the goal drawn at reset) within the horizon of
  40 s (1000 steps; the issue's "reaches >= 95% of goals", each mover's first goal being its task while the goal
  streams keep every other mover busy) and within the whole window (80 s). A free mover at the planner's cruise of
  1.5 m/s crosses the 64 x 64 layout (15.4 m) in 10 s: 40 s is four crossings, 80 s eight;
* ``t95``: the time by which 95% of the movers had reached their first goal (nan: not within the window), and the
  makespan (every mover);
* collisions (collided movers) per 1000 goals, deadlocked movers at the end (still and away from the goal for 25
  steps), goals per second per mover, and the planner's step time (planner + env step, one world).

One env step = 40 control cycles (acceleration commands held), per-mover collision stops, local observations (8
nearest movers within 1 m, 8 wall rays), per-mover rewards, goal streams and respawns. One agent-step = one mover
through one env step. Layouts are full square grids with about 0.25 movers per tile (the issue's planner regime);
actions steer every mover towards its goal (a saturated proportional rule, so movers travel, reach goals and
collide as in a run), computed on the device.

    python benchmarks/swarm.py                       # CPU (+ cuda:0 when present), full sizes
    python benchmarks/swarm.py --small               # CPU-friendly sizes (smoke check)
    python benchmarks/swarm.py --device cuda:0 --json benchmarks/results/swarm_gpu.json
    python benchmarks/swarm.py --device cuda:0 --planner-only     # the planner's quality rows alone (256/1024/4096)
    python benchmarks/swarm.py --device cpu --planner-only --planner-movers 1024 --json /tmp/planner_cpu.json
    python benchmarks/swarm.py --device cuda:0 --fused-sweep --json benchmarks/results/swarm_fused_gpu.json
    python benchmarks/swarm.py --device cpu --fused-sweep --small       # the same rows at CPU sizes (smoke check)

The fused env step is timed two ways on the same env: as one CUDA graph replay (``fused_env_ms``, the default on
CUDA: :attr:`~magwarp.swarm.SwarmEnv.step_path` ``"graph"``) and with the same launches issued one by one from Python
(``fused_eager_env_ms``, ``graph=False``); on the CPU both are the eager step. Before timing, a graph env and an
eager env step the same worlds with the same actions and every output and state field is compared
(``graph_match``: bit for bit). ``fused_env_ms`` minus the steering rule (``env_only_ms``) gives
``env_only_agent_steps_per_s``, the issue's number; the ``old`` (per-cycle) env runs eagerly, as in earlier rows.

Each fused row also splits the eager env step (``step_split``, each phase between device synchronisations inside real
steps): physics (stop mask, command copy, the fused motion's graph), observations (one kernel scanning each world's
movers: on CUDA a block per world; grid binning first above 256 movers, 128 on the CPU), rewards/resets (per-mover
outcome kernel, goal streams, respawns), the rest (action check, NaN guard, info) and the steering rule's own time
(``policy_ms``, which ``fused_env_ms`` includes; ``env_only_agent_steps_per_s`` leaves it out: the issue's target of
5e8 agent-steps/s is about the env). It also times the observation alone with each neighbour search (``obs_grid_ms``,
``obs_world_ms``, on CUDA ``obs_world_staged_ms``) and checks that they write the same rows bit for bit
(``obs_searches_match``); ``--obs-search`` picks the one the timed envs use. Likewise the respawn placement alone
with each search of the placers (``place_grid_ms``, ``place_world_ms``, ``place_searches_match``; ``--place-search``).

``--fused-sweep``: the training regime (many worlds of 64, 100 and 256 movers, 1024 to 16384 worlds): agent-steps/s
of the env with the per-cycle step (``fused=False``: three or four launches per cycle, then the stop hook) and with
the fused step (``fused=True``, :mod:`magwarp.swarm.fused`: one launch per env step), and the fused motion alone
(``sim.step``: the 40 cycles and the stops). Each row also gives its ratio to the memory-bandwidth floor: the
agent-steps/s the device would reach if an env step only moved, once, the bytes it cannot avoid per mover (the
simulator state read and written once, the action read, the observation written), at the device-to-device copy
bandwidth measured by the script (a large torch copy). Before timing, the fused and per-cycle envs step the same
worlds with the same actions and every state and output field is compared (``match``: bit for bit; ``max_pos_diff``).

Memory: the device memory the env (or simulator) holds after construction and a few steps (CUDA: the change of
free device memory, which counts Warp's and torch's allocations; CPU: the change of resident set size).
"""

from __future__ import annotations

import argparse
import gc
import math
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import numpy as np  # noqa: E402
import torch  # noqa: E402
import warp as wp  # noqa: E402

from common import header_line, machine_info, print_table, provenance, write_json  # noqa: E402

ONE_WORLD = (100, 1_000, 10_000, 100_000)
PLANNER = (256, 1024, 4096)  # movers of one world for the scripted planner's quality (1024: 64 x 64 tiles at 25%)
SMALL_PLANNER = (64,)
PLANNER_STEPS = 2000  # 80 s of simulated time (the window)
PLANNER_HORIZON = 1000  # 40 s: the goal share's horizon
GOAL_SHARE = 0.95  # t95: the time by which this share of the movers had reached their first goal
MANY_WORLDS = (64, 1024, 8192)  # worlds of 100 movers
SMALL_ONE_WORLD = (100, 1_000)
SMALL_MANY_WORLDS = (4, 16)
OCCUPANCY = 0.25
CYCLES = 40


def _sync(device: str) -> None:
    wp.synchronize_device(device)


def _rss_mb() -> float:
    with open("/proc/self/statm", encoding="utf-8") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def _used_mb(device: str) -> float:
    gc.collect()
    if device.startswith("cuda"):
        torch.cuda.synchronize(torch.device(device))
        torch.cuda.empty_cache()  # cached blocks of earlier rows would hide this row's allocations
        free, total = torch.cuda.mem_get_info(torch.device(device))
        return (total - free) / 2**20
    return _rss_mb()


def _layout(movers: int):
    from magwarp.layout import Layout

    side = int(math.ceil(math.sqrt(movers / OCCUPANCY)))
    return Layout.grid(side, side)


def _time(step, device: str, steps: int) -> tuple[float, float]:
    """Median and spread (ms) of one step over 5 batches of ``steps`` steps, after 3 warm-up steps."""
    for _ in range(3):
        step()
    _sync(device)
    samples = []
    for _ in range(5):
        t = time.perf_counter()
        for _ in range(steps):
            step()
        _sync(device)
        samples.append((time.perf_counter() - t) / steps * 1e3)
    arr = np.asarray(samples)
    return float(np.median(arr)), float(arr.std())


def seek_goals(env, gain: float = 4.0) -> torch.Tensor:
    """Accelerations towards the goals with velocity damping, saturated at the mover's limit: a fair load."""
    sim = env.sim
    err = env.goals - sim.pos[..., :2]
    return gain * (gain * err - 2.0 * sim.vel[..., :2])


def bench_sim(movers: int, worlds: int, device: str, steps: int) -> dict:
    from magwarp.sim import Simulator
    from magwarp.swarm.placement import Placer

    gc.collect()
    before = _used_mb(device)
    lay = _layout(movers)
    starts = Placer(lay, movers, worlds, device=device).sample()
    sim = Simulator(lay, movers, worlds, start_xy=starts.cpu().numpy(), device=device, check_inputs=False,
                    stop_on_collision=False)
    gen = torch.Generator(device=sim.torch_device).manual_seed(0)
    cmds = torch.rand((4, worlds, movers, 2), generator=gen, device=sim.torch_device) * 2.0 - 1.0
    k = [0]

    def step():
        sim.cmd.copy_(cmds[k[0] % 4])
        k[0] += 1
        sim.step(CYCLES)

    ms, std = _time(step, device, steps)
    mem = _used_mb(device) - before
    del sim
    return {"sim_ms": ms, "sim_std_ms": std, "sim_mb": mem}


def bench_env(movers: int, worlds: int, device: str, steps: int) -> dict:
    from magwarp.swarm import SwarmEnv

    gc.collect()
    before = _used_mb(device)
    t0 = time.perf_counter()
    env = SwarmEnv(worlds, num_movers=movers, layout=_layout(movers), device=device, seed=0, check_inputs=False)
    build_s = time.perf_counter() - t0
    totals = {"collisions": 0, "goals": 0}

    def step():
        _, _, _, _, info = env.step(seek_goals(env))
        totals["last"] = info

    ms, std = _time(step, device, steps)
    mem = _used_mb(device) - before
    info = totals["last"]
    row = {"env_ms": ms, "env_std_ms": std, "env_mb": mem, "build_s": build_s,
           "goals_per_step": float(info["goal_reached"].sum()),
           "collided_per_step": float(info["agent_terminated"].sum()),
           "obs_dim": int(env.single_observation_space.shape[-1])}
    del env
    return row


def first_goal_times(metrics) -> torch.Tensor:
    """Per mover of every world, the step (from 1) at which it reached its first goal; ``inf`` where it did not."""
    nth = metrics.tracker.t["nth_goal_step"].flatten().to(torch.float64)
    return torch.where(nth >= 0, nth, math.inf)


def bench_planner(movers: int, device: str, steps: int, horizon: int = PLANNER_HORIZON, traffic: str = "auto",
                  seed: int = 0) -> dict:
    """The scripted planner in one world for ``steps`` steps: the first-goal share within ``horizon`` steps and
    within the window, t95, makespan, goals, collisions per 1000 goals, deadlocks, and its step time."""
    from magwarp.swarm import SwarmEnv
    from magwarp.swarm.metrics import SwarmMetrics
    from magwarp.swarm.planner import SwarmPlanner

    env = SwarmEnv(1, num_movers=movers, layout=_layout(movers), device=device, seed=seed, check_inputs=False)
    planner = SwarmPlanner(env, traffic=traffic)
    metrics = SwarmMetrics(env)
    env.reset()
    _sync(device)
    t = time.perf_counter()
    for _ in range(steps):
        _, _, _, _, info = env.step(planner())
        metrics.update(info)
    _sync(device)
    elapsed = time.perf_counter() - t
    res = metrics.result()
    res["planner_step_ms"] = elapsed / steps * 1e3
    first = first_goal_times(metrics)
    res["horizon_s"] = min(horizon, steps) * metrics.step_time
    res["goal_share"] = float((first <= horizon).double().mean())
    res["goal_share_window"] = float(torch.isfinite(first).double().mean())
    t95 = float(first.quantile(GOAL_SHARE)) if torch.isfinite(first).double().mean() >= GOAL_SHARE else math.inf
    res["t95_s"] = t95 * metrics.step_time if math.isfinite(t95) else math.nan
    res["traffic"] = planner.traffic
    return {"device": device, "movers": movers, "tiles": int(_layout(movers).num_tiles), "seed": seed,
            **{f"planner_{k}" if not k.startswith("planner") else k: v for k, v in res.items()}}


FUSED_MOVERS = (64, 100, 256)
FUSED_WORLDS = (1024, 4096, 8192, 16384)
SMALL_FUSED_MOVERS = (64, 100)
SMALL_FUSED_WORLDS = (2, 8)
COMPARE_STEPS = 6


def copy_bandwidth(device: str) -> float:
    """Device memory bandwidth (bytes/s) as a large copy achieves it (read + write counted)."""
    n = (1 << 28) if device.startswith("cuda") else (1 << 24)
    src = torch.ones(n, dtype=torch.float32, device=device)
    dst = torch.empty_like(src)
    for _ in range(3):
        dst.copy_(src)
    _sync(device)
    reps = 20
    t = time.perf_counter()
    for _ in range(reps):
        dst.copy_(src)
    _sync(device)
    return 2.0 * src.numel() * 4 * reps / (time.perf_counter() - t)


def floor_bytes(env) -> int:
    """Bytes per agent-step an env step cannot avoid: the per-mover simulator state read and written once, the
    action read, the observation written."""
    sim = env.sim
    per = 0
    for arr in vars(sim.state).values():
        if isinstance(arr, wp.array) and arr.shape[:2] == (sim.num_worlds, sim.num_movers):
            per += arr.size * wp.types.type_size_in_bytes(arr.dtype) // (sim.num_worlds * sim.num_movers)
    obs = int(np.prod(env.single_observation_space.shape[1:])) * 4
    return 2 * per + 2 * 4 + obs


def compare_fused(movers: int, worlds: int, device: str, steps: int = COMPARE_STEPS) -> dict:
    """Step a per-cycle and a fused env on the same worlds with the same actions; compare every field."""
    from magwarp.swarm import SwarmEnv

    envs = [SwarmEnv(worlds, num_movers=movers, layout=_layout(movers), device=device, seed=0, check_inputs=False,
                     fused=f) for f in (False, True)]
    match, max_diff, flagged, flag_diff = True, 0.0, 0, 0
    names = ("pos", "quat", "vel", "omega", "acc", "cmd", "flags", "flags_any", "partner", "world_pairs",
             "world_walls", "halted", "cycles")
    for _ in range(steps):
        action = seek_goals(envs[0])
        outs = [env.step(action.clone()) for env in envs]
        for name in names:
            a, b = getattr(envs[0].sim, name), getattr(envs[1].sim, name)
            match &= bool(torch.equal(a, b))
        match &= bool(torch.equal(envs[0].stopped, envs[1].stopped))
        match &= bool(torch.equal(outs[0][0], outs[1][0])) and bool(torch.equal(outs[0][1], outs[1][1]))
        max_diff = max(max_diff, float((envs[0].sim.pos - envs[1].sim.pos).abs().max()))
        flagged += int((envs[0].sim.flags_any != 0).sum())
        flag_diff += int((envs[0].sim.flags_any != envs[1].sim.flags_any).sum())
    del envs
    return {"match": match, "max_pos_diff": max_diff, "compare_steps": steps, "compare_flagged": flagged,
            "compare_flags_differing": flag_diff}


def _tensors(out, prefix: str = "") -> dict:
    """The tensors of a step's returns (nested dicts flattened), by name."""
    if isinstance(out, torch.Tensor):
        return {prefix: out}
    if isinstance(out, dict):
        items = out.items()
    elif isinstance(out, (tuple, list)):
        items = enumerate(out)
    else:
        return {}
    found = {}
    for k, v in items:
        found.update(_tensors(v, f"{prefix}/{k}"))
    return found


def compare_graph(movers: int, worlds: int, device: str, steps: int = COMPARE_STEPS + 4) -> dict:
    """Step a graph env and an eager env (``graph=False``) on the same worlds with the same actions; compare every
    returned tensor and state field bit for bit (``graph_match``; ``graph_path``: the graph env's step path)."""
    from magwarp.swarm import SwarmEnv

    envs = [SwarmEnv(worlds, num_movers=movers, layout=_layout(movers), device=device, seed=0, check_inputs=False,
                     graph=g) for g in (False, True)]
    names = ("pos", "quat", "vel", "omega", "acc", "cmd", "flags_any")
    match, first_diff, respawned = True, None, 0
    for t in range(steps):
        action = seek_goals(envs[0])
        outs = [_tensors(env.step(action.clone())) for env in envs]
        state = [{**{n: getattr(env.sim, n) for n in names}, "goals": env.goals, "stopped": env.stopped,
                  "pending": env.respawn_pending} for env in envs]
        for a, b in ((outs[0], outs[1]), (state[0], state[1])):
            for key in a:
                if not torch.equal(a[key], b[key]):
                    match = False
                    first_diff = first_diff or f"step {t}: {key}"
        respawned += int(outs[0]["/4/agent_terminated"].sum())
    path = envs[1].step_path
    del envs
    return {"graph_match": match, "graph_first_diff": first_diff, "graph_compare_steps": steps,
            "graph_compare_respawns": respawned, "graph_path": path}


def kernel_breakdown(step, steps: int = 5, top: int = 12) -> list[dict]:
    """CUDA time per env step of the ``top`` costliest kernels and copies (torch's profiler, which sees Warp's
    kernels too, graph replays included): where the env step's time goes."""
    from torch.profiler import ProfilerActivity, profile

    with profile(activities=[ProfilerActivity.CUDA]) as prof:
        for _ in range(steps):
            step()
        torch.cuda.synchronize()
    events = []
    for evt in prof.key_averages():
        us = getattr(evt, "device_time_total", None)
        us = getattr(evt, "cuda_time_total", 0.0) if us is None else us
        if us > 0:
            events.append({"name": evt.key[:120], "ms_per_step": us / 1e3 / steps, "calls_per_step": evt.count / steps})
    events.sort(key=lambda e: -e["ms_per_step"])
    total = sum(e["ms_per_step"] for e in events)
    for e in events:
        e["share"] = e["ms_per_step"] / total if total > 0 else 0.0
    return events[:top]


SPLIT = {"physics": ("_apply_action",), "task": ("_evaluate", "_end_step"), "obs": ("_get_obs",)}


def step_split(env, device: str, steps: int, env_ms: float) -> dict:
    """Where a (fused) env step's time goes, measured inside real steps: each phase of ``env.step`` runs between two
    device synchronisations (so its time counts its launches and its device work, nothing overlapped):
    ``physics_ms`` (the action's stop mask, the command copy and the simulator's step graph), ``task_ms`` (rewards,
    goal counts, goal streams and respawns: ``_evaluate`` and ``_end_step``) and ``obs_ms`` (grid binning and the
    observation kernel); ``rest_ms``: the unsynchronised env step (``env_ms``) less those and the steering rule
    (``policy_ms``, timed alone; the env step timings include it): the action check, NaN guard and info, minus
    what the phases overlapped in the unsynchronised step. ``env_only_ms``: the env step without the policy."""
    totals = dict.fromkeys(SPLIT, 0.0)

    def timed(fn, key):
        def run(*args, **kwargs):
            _sync(device)
            t = time.perf_counter()
            out = fn(*args, **kwargs)
            _sync(device)
            totals[key] += time.perf_counter() - t
            return out
        return run

    for key, names in SPLIT.items():
        for name in names:
            setattr(env, name, timed(getattr(env, name), key))
    try:
        for _ in range(3):
            env.step(seek_goals(env))
        totals.update(dict.fromkeys(SPLIT, 0.0))
        for _ in range(steps):
            env.step(seek_goals(env))
    finally:
        for names in SPLIT.values():
            for name in names:
                delattr(env, name)  # the class's methods again
    out = {f"{key}_ms": value / steps * 1e3 for key, value in totals.items()}
    out["policy_ms"], _ = _time(lambda: seek_goals(env), device, steps)
    out["env_only_ms"] = env_ms - out["policy_ms"]
    out["rest_ms"] = out["env_only_ms"] - sum(out[f"{key}_ms"] for key in SPLIT)
    return out


def obs_searches(env, device: str, steps: int) -> dict:
    """The observation alone (``env._get_obs()``: what the step's ``obs`` phase runs) with each search of
    :class:`~magwarp.swarm.LocalObservations` on the env's current state: ``obs_<search>_ms`` (on CUDA also
    ``obs_world_staged_ms``: the block-per-world kernel with its rows staged in shared memory), and
    ``obs_searches_match``: every search wrote the same rows and neighbour indices bit for bit (the device's own build,
    fast math included)."""
    from magwarp.kernels.neighbors import MAX_WORLD_BLOCK, SEARCHES

    local, out, rows = env.local, {}, {}
    default = local.search, local.staged
    variants = [(search, False) for search in SEARCHES if search == "grid" or env.num_movers <= MAX_WORLD_BLOCK]
    if local.tiled and env.num_movers <= MAX_WORLD_BLOCK:
        variants.append(("world", True))  # the block's rows staged in shared memory, stored together
    try:
        for search, staged in variants:
            local.search, local.staged = search, staged
            name = search + ("_staged" if staged else "")
            out[f"obs_{name}_ms"], _ = _time(env._get_obs, device, steps)
            rows[name] = (env._get_obs().clone(), local.index.clone())
    finally:
        local.search, local.staged = default
    first = next(iter(rows.values()))
    out["obs_searches_match"] = all(torch.equal(r[0], first[0]) and torch.equal(r[1], first[1]) for r in rows.values())
    out["obs_search"] = default[0] + ("_staged" if default[1] and local.tiled and default[0] == "world" else "")
    return out


def place_searches(env, device: str, steps: int) -> dict:
    """The respawn placement alone (what the step's ``_respawn`` places: the movers that want a respawn, two rounds,
    their spots held) with each search of :class:`~magwarp.swarm.Placer` from the env's current state, on copies:
    ``place_<search>_ms``, ``place_movers`` (movers asked per call) and ``place_searches_match`` (the same spots and
    the same movers left, bit for bit; every call starts from the same random streams)."""
    from magwarp.swarm.placement import SEARCHES

    placer = env.respawn_placer
    if placer is None:
        return {}
    want = env._want_respawn.clone()
    start = env.sim.pos[..., :2].contiguous()
    default, calls, out, results = placer.search, placer._calls, {}, {}
    try:
        for search in SEARCHES:
            placer.search = search
            xy = start.clone()

            def place():
                placer._calls = calls  # the same random streams every call
                xy.copy_(start)
                placer.place_async(xy, want, rounds=env.config.respawn_rounds, hold=True)

            out[f"place_{search}_ms"], _ = _time(place, device, steps)
            place()
            results[search] = (xy.clone(), wp.to_torch(placer._todo).clone())
    finally:
        placer.search, placer._calls = default, calls
    first = next(iter(results.values()))
    out["place_searches_match"] = all(torch.equal(r[0], first[0]) and torch.equal(r[1], first[1])
                                      for r in results.values())
    out["place_search"] = default
    out["place_movers"] = int(want.sum())
    return out


def bench_fused_row(movers: int, worlds: int, device: str, steps: int, bandwidth: float,
                    breakdown: bool = False, obs_search: str | None = None, place_search: str | None = None,
                    obs_merge: bool = False, place_lanes: int | None = None, place_scan: str | None = None) -> dict:
    from magwarp.swarm import SwarmEnv

    row: dict = {"device": device, "movers": movers, "worlds": worlds, "agents": movers * worlds, "steps": steps}
    for fused in (False, True):
        gc.collect()
        # the per-cycle ("old") env eagerly, as in earlier rows; the fused env by graph replay (CUDA) and eagerly
        env = SwarmEnv(worlds, num_movers=movers, layout=_layout(movers), device=device, seed=0, check_inputs=False,
                       fused=fused, graph=fused)
        if obs_search is not None:
            env.local.search, env.local.staged = obs_search.split("_")[0], obs_search.endswith("_staged")
        env.local.merge = env.local.merge or obs_merge
        for placer in (env.placer, env.respawn_placer):
            if placer is not None and place_search is not None:
                placer.search = place_search
            if placer is not None and place_lanes is not None:
                placer.lanes = place_lanes
            if placer is not None and place_scan is not None:
                placer.scan = place_scan
            if placer is not None:
                row["place_scan"] = placer.scan
        key = "fused" if fused else "old"

        def step():
            env.step(seek_goals(env))

        row[f"{key}_env_ms"], row[f"{key}_env_std_ms"] = _time(step, device, steps)
        if fused:  # the same env, the same launches issued one by one (graph=False)
            row["fused_step_path"] = env.step_path
            env.graph = False
            row["fused_eager_env_ms"], row["fused_eager_env_std_ms"] = _time(step, device, steps)
        row[f"{key}_motion_ms"], _ = _time(lambda: env.sim.step(CYCLES), device, steps)
        if fused and device.startswith("cuda"):  # the motion alone without the tiled kernel's register cap
            from magwarp.swarm.fused import launch_block

            row["fused_max_registers"] = launch_block(movers)[2]
            saved = os.environ.get("MAGWARP_SWARM_MAX_REGISTERS")
            os.environ["MAGWARP_SWARM_MAX_REGISTERS"] = "0"
            env.sim._graphs.clear()  # recaptured with the uncapped kernel
            try:
                row["fused_motion_uncapped_ms"], _ = _time(lambda: env.sim.step(CYCLES), device, steps)
            finally:
                if saved is None:
                    del os.environ["MAGWARP_SWARM_MAX_REGISTERS"]
                else:
                    os.environ["MAGWARP_SWARM_MAX_REGISTERS"] = saved
                env.sim._graphs.clear()
        if fused:  # the eager env step's split: physics, observations, rewards/resets, rest
            row.update(step_split(env, device, steps, row["fused_eager_env_ms"]))
            row.update(obs_searches(env, device, steps))
            row.update(place_searches(env, device, steps))
            env.graph = True  # the profile of the graph step (a capture first, then replays)
            if breakdown and device.startswith("cuda"):
                try:
                    step()
                    step()
                    row["fused_kernels"] = kernel_breakdown(step)
                except Exception as exc:  # noqa: BLE001 - a profiler missing on the machine must not end the sweep
                    row["fused_kernels"] = [{"error": repr(exc)}]
        row["floor_bytes_per_agent_step"] = floor_bytes(env)
        del env
    agents = movers * worlds
    for key in ("old", "fused"):
        row[f"{key}_agent_steps_per_s"] = agents / (row[f"{key}_env_ms"] * 1e-3)
        row[f"{key}_motion_agent_steps_per_s"] = agents / (row[f"{key}_motion_ms"] * 1e-3)
    row["fused_eager_agent_steps_per_s"] = agents / (row["fused_eager_env_ms"] * 1e-3)
    row["graph_speedup"] = row["fused_eager_env_ms"] / row["fused_env_ms"]
    row["eager_env_only_ms"] = row["env_only_ms"]  # step_split's: the eager step less the policy
    row["env_only_ms"] = row["fused_env_ms"] - row["policy_ms"]  # the graph step less the policy
    row["env_only_agent_steps_per_s"] = agents / (row["env_only_ms"] * 1e-3)
    row["eager_env_only_agent_steps_per_s"] = agents / (row["eager_env_only_ms"] * 1e-3)
    row["speedup"] = row["old_env_ms"] / row["fused_env_ms"]
    row["bandwidth_gb_s"] = bandwidth / 1e9
    row["floor_agent_steps_per_s"] = bandwidth / row["floor_bytes_per_agent_step"]
    row["fused_of_floor"] = row["fused_agent_steps_per_s"] / row["floor_agent_steps_per_s"]
    row["fused_motion_of_floor"] = row["fused_motion_agent_steps_per_s"] / row["floor_agent_steps_per_s"]
    row["env_only_of_floor"] = row["env_only_agent_steps_per_s"] / row["floor_agent_steps_per_s"]
    return row


def run_fused_sweep(args) -> list[dict]:
    """Old vs fused env step at many worlds of 64-256 movers, after a bit-for-bit comparison per mover count."""
    device = args.device or ("cuda:0" if wp.is_cuda_available() else "cpu")
    small = args.small or not device.startswith("cuda")
    movers_list = args.fused_movers or (SMALL_FUSED_MOVERS if small else FUSED_MOVERS)
    worlds_list = args.fused_worlds or (SMALL_FUSED_WORLDS if small else FUSED_WORLDS)
    bandwidth = copy_bandwidth(device)
    print(f"  {device}: copy bandwidth {bandwidth / 1e9:.0f} GB/s", flush=True)
    rows = []
    for movers in movers_list:
        check = compare_fused(movers, min(worlds_list[0], 256), device)
        print(f"  {device} {movers} movers: fused matches per-cycle: {check['match']} "
              f"(max |dpos| {check['max_pos_diff']:.3g} m, {check['compare_flagged']} collision flags, "
              f"{check['compare_flags_differing']} differing)", flush=True)
        check.update(compare_graph(movers, min(worlds_list[0], 256), device))
        print(f"  {device} {movers} movers: graph step ({check['graph_path']}) matches the eager step: "
              f"{check['graph_match']} ({check['graph_compare_steps']} steps, {check['graph_compare_respawns']} "
              f"respawns{'; first difference ' + check['graph_first_diff'] if check['graph_first_diff'] else ''})",
              flush=True)
        for worlds in worlds_list:
            steps = args.steps or (20 if device.startswith("cuda") else 3)
            row = bench_fused_row(movers, worlds, device, steps, bandwidth, breakdown=worlds == worlds_list[-1],
                                  obs_search=args.obs_search, place_search=args.place_search,
                                  obs_merge=args.obs_merge, place_lanes=args.place_lanes,
                                  place_scan=args.place_scan)
            row.update(check)
            rows.append(row)
            print(f"  {device} {worlds} x {movers}: old {row['old_env_ms']:.3f} ms, fused {row['fused_env_ms']:.3f} "
                  f"ms ({row['fused_step_path']}; {row['fused_agent_steps_per_s']:.3g} agent-steps/s, "
                  f"{row['env_only_agent_steps_per_s']:.3g} without the policy, {row['fused_of_floor']:.2f} of the "
                  f"floor), fused eager {row['fused_eager_env_ms']:.3f} ms ({row['graph_speedup']:.2f}x)",
                  flush=True)
            if "fused_motion_uncapped_ms" in row:
                print(f"    motion alone: {row['fused_motion_ms']:.3f} ms with the kernel capped at "
                      f"{row['fused_max_registers']} registers, {row['fused_motion_uncapped_ms']:.3f} ms uncapped",
                      flush=True)
            print(f"    eager split: physics {row['physics_ms']:.3f} ms (motion alone {row['fused_motion_ms']:.3f}), "
                  f"observations {row['obs_ms']:.3f}, rewards/resets {row['task_ms']:.3f}, rest {row['rest_ms']:.3f} "
                  f"(policy {row['policy_ms']:.3f} aside): {row['eager_env_only_agent_steps_per_s']:.3g} "
                  f"agent-steps/s without the policy", flush=True)
            alone = ", ".join(f"{k} {row[f'obs_{k}_ms']:.3f} ms" for k in ("grid", "world", "world_staged")
                              if f"obs_{k}_ms" in row)
            print(f"    observation alone by search: {alone} (env uses {row['obs_search']}; same rows: "
                  f"{row['obs_searches_match']})", flush=True)
            if "place_search" in row:
                print(f"    respawn placement alone ({row['place_movers']} movers) by search: grid "
                      f"{row['place_grid_ms']:.3f} ms, world {row['place_world_ms']:.3f} ms (env uses "
                      f"{row['place_search']}; same spots: {row['place_searches_match']})", flush=True)
    return rows


def run(args) -> list[dict]:
    devices = [args.device] if args.device else (["cpu", "cuda:0"] if wp.is_cuda_available() else ["cpu"])
    rows = []
    for device in devices:
        gpu = device.startswith("cuda")
        small = args.small or not gpu and not args.full
        one = SMALL_ONE_WORLD if small else ONE_WORLD
        many = SMALL_MANY_WORLDS if small else MANY_WORLDS
        configs = [] if args.planner_only else [(m, 1) for m in one] + [(100, w) for w in many]
        for movers, worlds in configs:
            steps = args.steps or (20 if gpu else max(1, int(2e4 // (movers * worlds))))
            row = {"device": device, "movers": movers, "worlds": worlds, "agents": movers * worlds, "steps": steps,
                   "tiles": int(_layout(movers).num_tiles)}
            row.update(bench_sim(movers, worlds, device, steps))
            row.update(bench_env(movers, worlds, device, steps))
            row["agent_steps_per_s"] = movers * worlds / (row["env_ms"] * 1e-3)
            row["sim_agent_steps_per_s"] = movers * worlds / (row["sim_ms"] * 1e-3)
            row["env_over_sim"] = row["env_ms"] / row["sim_ms"]
            row["env_mb_per_1k_agents"] = row["env_mb"] / (movers * worlds / 1000)
            rows.append(row)
            print(f"  {device} {worlds} x {movers}: env {row['env_ms']:.3f} ms, sim {row['sim_ms']:.3f} ms", flush=True)
        if not args.no_planner:
            sizes = args.planner_movers or (SMALL_PLANNER if small and not args.planner_only else PLANNER)
            steps = args.planner_steps or (PLANNER_STEPS if not small or args.planner_only else 100)
            for movers in sizes:
                for seed in args.seeds:
                    rows.append(bench_planner(movers, device, steps, min(PLANNER_HORIZON, steps), args.traffic, seed))
                    r = rows[-1]
                    print(f"  {device} planner {movers} (seed {seed}, {r['planner_traffic']}): goal share "
                          f"{r['planner_goal_share']:.3f} in {r['planner_horizon_s']:.0f} s, {r['planner_goals']} "
                          f"goals, {r['planner_collisions']} collisions", flush=True)
    return rows


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", help="cpu or cuda:N (default: cpu, and cuda:0 when present)")
    p.add_argument("--small", action="store_true", help="small sizes on every device (a smoke check)")
    p.add_argument("--full", action="store_true", help="full sizes on the CPU too (slow)")
    p.add_argument("--steps", type=int, help="timed steps per batch (default: by size)")
    p.add_argument("--no-planner", action="store_true", help="skip the scripted planner's quality rows")
    p.add_argument("--planner-only", action="store_true", help="only the scripted planner's quality rows")
    p.add_argument("--planner-steps", type=int, help=f"steps of the planner runs (default {PLANNER_STEPS}; the goal "
                   f"share's horizon is {PLANNER_HORIZON} steps or the whole run if shorter)")
    p.add_argument("--planner-movers", type=int, nargs="+", help=f"planner sizes (default {PLANNER}; with --small "
                   f"and without --planner-only {SMALL_PLANNER})")
    p.add_argument("--traffic", default="auto", choices=("auto", "lanes", "free"), help="the planner's traffic rule")
    p.add_argument("--seeds", type=int, nargs="+", default=[0], help="planner worlds' seeds (one run each)")
    p.add_argument("--fused-sweep", action="store_true", help="old vs fused env step at many worlds of 64-256 movers "
                   "(the training regime), with the memory-bandwidth floor")
    p.add_argument("--fused-movers", type=int, nargs="+", help=f"--fused-sweep's movers per world (default "
                   f"{FUSED_MOVERS}; CPU/--small {SMALL_FUSED_MOVERS})")
    p.add_argument("--fused-worlds", type=int, nargs="+", help=f"--fused-sweep's world counts (default {FUSED_WORLDS}; "
                   f"CPU/--small {SMALL_FUSED_WORLDS})")
    p.add_argument("--obs-search", choices=("grid", "world", "world_staged"), help="--fused-sweep: the "
                   "observation's neighbour search in the timed envs (default: LocalObservations' choice: world, up to "
                   "256 movers per world on CUDA and 128 on the CPU, else grid; world_staged: CUDA's block per world "
                   "with its rows staged in shared memory); every row also times the observation alone with each")
    p.add_argument("--obs-merge", action="store_true", help="--fused-sweep: the world search merges candidates into "
                   "the slots with no branch (LocalObservations.merge) in the timed envs (the CUDA default since "
                   "2026-12-06; this forces it on the CPU too)")
    p.add_argument("--place-lanes", type=int, default=None, help="--fused-sweep: the placers' rounds in the lane "
                   "shape with this many lanes per listed mover (Placer.lanes; benchmarks/swarm_place.py times them)")
    p.add_argument("--place-scan", choices=("serial", "chunked"), help="--fused-sweep: how the "
                   "placers' rounds check their tries in the timed envs (Placer.scan; default: the device's)")
    p.add_argument("--place-search", choices=("grid", "world"), help="--fused-sweep: the placers' search in the timed "
                   "envs (default: Placer's choice: world up to 160 movers per world on CUDA and 64 on the CPU, else "
                   "grid); every row also times the respawn placement alone with each")
    p.add_argument("--json", help="output JSON (default: benchmarks/results/swarm_<cpu|gpu>.json, "
                   "swarm_fused_<cpu|gpu>.json with --fused-sweep)")
    args = p.parse_args(argv)
    wp.config.quiet = True
    wp.init()
    info = machine_info(args.device or ("cuda:0" if wp.is_cuda_available() else "cpu"))
    print(header_line(info))
    if args.fused_sweep:
        rows = run_fused_sweep(args)
        stamp = provenance(info)
        for r in rows:
            r.update(stamp)
        for r in rows:
            for e in r.get("fused_kernels", []):
                if "error" not in e:
                    print(f"    {r['worlds']} x {r['movers']}: {e['ms_per_step']:.3f} ms/step ({e['share']:.0%}) "
                          f"x{e['calls_per_step']:.0f} {e['name']}")
        print_table(rows, ["device", "worlds", "movers", "agents", ("old_env_ms", "old ms"),
                           ("fused_env_ms", "fused graph ms"), ("fused_eager_env_ms", "fused eager ms"),
                           ("graph_speedup", "graph speedup"), ("speedup", "speedup"),
                           ("old_agent_steps_per_s", "old agent-steps/s"),
                           ("fused_agent_steps_per_s", "fused agent-steps/s"),
                           ("fused_motion_agent_steps_per_s", "fused motion agent-steps/s"),
                           ("physics_ms", "physics ms"), ("obs_ms", "obs ms"), ("task_ms", "rewards/resets ms"),
                           ("rest_ms", "rest ms"), ("policy_ms", "policy ms"), ("obs_grid_ms", "obs grid ms"),
                           ("obs_world_ms", "obs world ms"), ("obs_world_staged_ms", "obs staged ms"),
                           ("obs_searches_match", "obs same"),
                           ("env_only_agent_steps_per_s", "env agent-steps/s (no policy)"),
                           ("eager_env_only_agent_steps_per_s", "eager env agent-steps/s (no policy)"),
                           ("floor_agent_steps_per_s", "floor agent-steps/s"), ("fused_of_floor", "fused/floor"),
                           ("match", "match"), ("graph_match", "graph match")])
        default = "gpu" if any(r["device"].startswith("cuda") for r in rows) else "cpu"
        path = args.json or os.path.join(os.path.dirname(os.path.abspath(__file__)), "results",
                                         f"swarm_fused_{default}.json")
        print("wrote", write_json(path, rows))
        return
    rows = run(args)
    stamp = provenance(info)
    for r in rows:
        r.update(stamp)
    cols = ["device", "worlds", "movers", "agents", ("env_ms", "env ms"), ("sim_ms", "sim ms"),
            ("env_over_sim", "env/sim"), ("agent_steps_per_s", "agent-steps/s"), ("env_mb", "env MB"),
            ("sim_mb", "sim MB"), ("goals_per_step", "goals/step"), ("collided_per_step", "collided/step")]
    if any("env_ms" in r for r in rows):
        print_table([r for r in rows if "env_ms" in r], cols)
    plan = [r for r in rows if "planner_goals" in r]
    if plan:
        print_table(plan, ["device", "movers", "tiles", "seed", ("planner_traffic", "traffic"),
                           ("planner_steps", "steps"), ("planner_goal_share", "goal share"),
                           ("planner_horizon_s", "in s"), ("planner_goal_share_window", "share, window"),
                           ("planner_t95_s", "t95 s"), ("planner_makespan", "makespan s"), ("planner_goals", "goals"),
                           ("planner_throughput_per_mover", "goals/s/mover"), ("planner_collisions", "collisions"),
                           ("planner_collisions_per_1000_goals", "coll/1000 goals"),
                           ("planner_deadlocked", "deadlocked"), ("planner_step_ms", "step ms")])
    default = "gpu" if any(r["device"].startswith("cuda") for r in rows) else "cpu"
    path = args.json or os.path.join(os.path.dirname(os.path.abspath(__file__)), "results", f"swarm_{default}.json")
    print("wrote", write_json(path, rows))


if __name__ == "__main__":
    main()
