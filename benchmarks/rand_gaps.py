"""Where the randomisation's cost on B0 goes, between the kernels as well as in them (#24): per setting, the env step
(``env.step`` in a loop, as env_throughput.py times it), the step's CUDA graph replayed alone (no Python step work),
and from the profiler's device trace the kernels' summed time and the span from the first kernel's start to the last
one's end per step (span - sum: the gaps between kernels in the graph).

    python benchmarks/rand_gaps.py --device cuda:0 --num-envs 65536 --json rand_gaps_gpu.json

Settings: those of randomization.py (off, terms, latency, sensors, full) plus ``full_nofire``: full with the reset-mode
terms' firing left out of the step (what the firing costs in the env step; the draws then do not happen, so it is a
measurement, not an env configuration).

The reset work (the firing, the sensors' new biases, the new starts and goals) scales with the share of worlds that
finish in a step: ``reset %`` is that share under the timed random actions (uniform over the action space, as
env_throughput.py and randomization.py step), and ``--planner-resets`` also prints it under the env's scripted
planner (a policy that reaches its goals: the regime of a trained policy and of evaluation), untimed.
"""

from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from common import finish, start_run  # noqa: E402
from env_throughput import time_steps  # noqa: E402
from randomization import ENVS, PARTS  # noqa: E402

ENV_ID = "magwarp/TrajectoryPlanningB0-v0"


def profile_span(env, actions, steps: int) -> dict:
    """Kernel time summed per step and the device span per step (first start to last end over ``steps`` steps)."""
    import torch
    from torch.profiler import ProfilerActivity, profile

    with profile(activities=[ProfilerActivity.CUDA]) as prof:
        for i in range(steps):
            env.step(actions[i % len(actions)])
        torch.cuda.synchronize()
    cuda = torch.autograd.DeviceType.CUDA
    events = [e for e in prof.profiler.kineto_results.events() if e.device_type() == cuda]
    if not events:
        return {}
    busy = sum(e.duration_ns() for e in events) / 1000.0 / steps
    span = (max(e.start_ns() + e.duration_ns() for e in events) - min(e.start_ns() for e in events)) / 1000.0 / steps
    return {"kernel_us": busy, "span_us": span, "gap_us": span - busy, "kernels_per_step": len(events) / steps}


def reset_share(env, act, steps: int = 50) -> float:
    """The mean share of worlds that finish per step over ``steps`` steps of ``act(obs, i)`` (untimed)."""
    import torch

    obs, done = env._last_obs, []
    for i in range(steps):
        obs, _, terminated, truncated, _ = env.step(act(obs, i))
        done.append((terminated | truncated).float().mean())
    env._last_obs = obs
    return float(torch.stack(done).mean())


def row(device: str, num_envs: int, name: str, steps: int, planner: bool = False, fire: str | None = None) -> dict:
    import gymnasium as gym
    import torch

    import magwarp  # noqa: F401
    from magwarp.envs.planar_randomization import PlanarRandomizer

    kwargs = {**ENVS[ENV_ID], **PARTS[ENV_ID]}["full" if name == "full_nofire" else name]
    original = PlanarRandomizer.reset_in_step
    if name == "full_nofire":
        PlanarRandomizer.reset_in_step = lambda self, mask: None
    try:
        env = gym.make_vec(ENV_ID, num_envs=num_envs, device=device, check_inputs=False, **kwargs).unwrapped
        if fire is not None and getattr(env, "randomizer", None) is not None:
            from fire_cost import CANDIDATES, apply

            apply(env.randomizer, CANDIDATES[fire])  # before the first step: the step graph captures it
        env._last_obs, _ = env.reset(seed=0)
        gen = torch.Generator(device=env.device).manual_seed(0)
        shape = (8, num_envs, *env.single_action_space.shape)
        actions = torch.rand(shape, generator=gen, device=env.device) * 2 - 1
        from magwarp.kernels.options import STEP_BRANCHES

        res = {"env": ENV_ID, "device": device, "num_envs": num_envs, "setting": name, "fire": fire or "default",
               "branches": STEP_BRANCHES}
        res["step_ms"] = time_steps(env.step, actions, steps, device)["step_ms"]
        fused = env._fused_step
        graphs = [g for g in getattr(fused, "_graphs", []) if g is not None]
        if len(graphs) == 2:
            slot = [0]

            def replay(_):
                graphs[slot[0]].graph.replay()
                slot[0] ^= 1

            res["replay_ms"] = time_steps(replay, actions, steps, device)["step_ms"]
        if device != "cpu":
            res.update(profile_span(env, actions, min(steps, 50)))
        res["reset_pct"] = 100.0 * reset_share(env, lambda obs, i: actions[i % len(actions)])
        if planner:
            policy = env.scripted_policy()
            res["planner_reset_pct"] = 100.0 * reset_share(env, lambda obs, i: policy(obs))
        return res
    finally:
        PlanarRandomizer.reset_in_step = original


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default=None)
    p.add_argument("--num-envs", default="65536")
    p.add_argument("--steps", type=int, default=200)
    p.add_argument("--settings", default="off,terms,latency,sensors,full,full_nofire")
    p.add_argument("--planner-resets", action="store_true",
                   help="also the share of worlds finishing per step under the env's scripted planner (untimed)")
    p.add_argument("--fire", default=None,
                   help="the reset firing's candidate (benchmarks/fire_cost.py's CANDIDATES, e.g. grid: Warp's 256 "
                        "threads a block; default: the library's, 64 a block on CUDA)")
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    info, devices = start_run(args.device)
    rows = []
    for device in devices:
        for n in [int(s) for s in args.num_envs.split(",")]:
            base = None
            for name in args.settings.split(","):
                r = row(device, n, name, args.steps, args.planner_resets, args.fire)
                base = r if name == "off" else base
                if base is not None:
                    r["cost_pct"] = 100.0 * (r["step_ms"] / base["step_ms"] - 1.0)
                rows.append(r)
                print("  " + ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"
                                       for k, v in r.items()), flush=True)
    columns = ["device", "num_envs", "setting", "fire", ("step_ms", "env ms/step"), ("cost_pct", "cost %"),
               ("replay_ms", "graph replay ms"), ("kernel_us", "kernel us/step"), ("span_us", "span us/step"),
               ("gap_us", "gaps us/step"), ("kernels_per_step", "kernels/step"), ("reset_pct", "reset %"),
               ("planner_reset_pct", "reset % (planner)")]
    return finish(rows, columns, info, args.json)


if __name__ == "__main__":
    raise SystemExit(main())
