"""Soak test: 10^6 control cycles of a batched env driven by extreme *legal* actions, with memory (RSS) and the
NaN guard watched. A benchmark, not a CI test (it takes minutes on the CPU).

    python benchmarks/soak.py                                   # B0, 16 worlds, 10^6 cycles per world, cpu
    python benchmarks/soak.py --control jerk --worlds 64 --json benchmarks/results/soak_jerk_cpu.json
    python benchmarks/soak.py --device cuda:0 --worlds 4096 --cycles 10000000

Actions are at the action space's bounds (each mover's command has the largest legal norm, direction and sign
drawn at random every step; the simulator's norm clip keeps them legal), so the movers collide, hit walls and
autoreset all the time. Every ``--checkpoints``-th of the run it records the resident set size and the worlds the NaN
guard flagged (the guard's flags are accumulated on the device, read back only at the checkpoints). It passes when
no world ever turned non-finite and the RSS after the first checkpoint grows by less than ``--rss-slack-mb``.
Prints a table and writes JSON (device, date, versions, command).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import torch  # noqa: E402

from common import header_line, machine_info, print_table, provenance, write_json  # noqa: E402


def rss_mb() -> float:
    """Resident set size of this process (Linux /proc; else the peak from resource)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def extreme_actions(env, generator: torch.Generator) -> torch.Tensor:
    """Per mover: the action space's bound, in a random direction of the largest legal norm (norm-clipped by the
    simulator to a_max / j_max, so it is legal), with random sign flips along the axes."""
    n, m = env.num_envs, env.num_movers
    limit = float(env.single_action_space.high[0])
    angle = torch.rand(n, m, generator=generator, device=env.device) * (2 * torch.pi)
    corner = torch.rand(n, m, 1, generator=generator, device=env.device) < 0.5  # at the box corner (norm > limit)
    unit = torch.stack([angle.cos(), angle.sin()], -1)
    box = torch.sign(unit) * limit
    return torch.where(corner, box, unit * limit).reshape(n, 2 * m)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--env", default="magwarp/TrajectoryPlanningB0-v0")
    p.add_argument("--worlds", type=int, default=16)
    p.add_argument("--cycles", type=int, default=1_000_000, help="control cycles per world (default 10^6)")
    p.add_argument("--num-cycles", type=int, default=40, help="cycles per env step (default 40)")
    p.add_argument("--control", choices=["acceleration", "jerk"], default="acceleration")
    p.add_argument("--device", default="cpu")
    p.add_argument("--checkpoints", type=int, default=10)
    p.add_argument("--rss-slack-mb", type=float, default=20.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", default=None, help="default: benchmarks/results/soak_<control>_<device>.json")
    args = p.parse_args(argv)

    import gymnasium as gym

    import magwarp  # noqa: F401 - registers the env ids

    info = machine_info(args.device)
    env = gym.make_vec(args.env, num_envs=args.worlds, device=args.device, num_cycles=args.num_cycles,
                       learn_jerk=args.control == "jerk", check_inputs=False, seed=args.seed).unwrapped
    gen = torch.Generator(device=env.device)
    gen.manual_seed(args.seed)
    steps = -(-args.cycles // args.num_cycles)
    per_checkpoint = max(1, steps // args.checkpoints)
    env.reset(seed=args.seed)
    nonfinite = torch.zeros(args.worlds, dtype=torch.int64, device=env.device)
    episodes = torch.zeros((), dtype=torch.int64, device=env.device)
    collisions = torch.zeros((), dtype=torch.int64, device=env.device)
    with torch.no_grad():
        for _ in range(3):  # compile and capture before the first memory reading
            env.step(extreme_actions(env, gen))
        rows, start = [], time.perf_counter()
        rss0 = rss_mb()
        done_steps = 0
        while done_steps < steps:
            for _ in range(min(per_checkpoint, steps - done_steps)):
                obs, reward, terminated, truncated, step_info = env.step(extreme_actions(env, gen))
                nonfinite += step_info["nonfinite"]
                episodes += (terminated | truncated).sum()
                collisions += terminated.sum()
                done_steps += 1
            finite_obs = all(bool(torch.isfinite(v).all()) for v in obs.values())
            sim = env.sim
            finite_state = bool(torch.isfinite(sim.pos).all() and torch.isfinite(sim.vel).all())
            rows.append({"cycles_per_world": done_steps * args.num_cycles, "wall_s": time.perf_counter() - start,
                         "rss_mb": rss_mb(), "rss_growth_mb": rss_mb() - rss0, "episodes": int(episodes),
                         "collision_ends": int(collisions), "nan_worlds": int((nonfinite > 0).sum()),
                         "finite": finite_obs and finite_state and bool(torch.isfinite(reward).all())})
            print(f"  {rows[-1]['cycles_per_world']:>10,} cycles  {rows[-1]['wall_s']:7.1f} s  "
                  f"RSS {rows[-1]['rss_mb']:.1f} MB ({rows[-1]['rss_growth_mb']:+.1f})  episodes {int(episodes):,}  "
                  f"NaN worlds {rows[-1]['nan_worlds']}", flush=True)
    wall = time.perf_counter() - start
    growth_after_first = rows[-1]["rss_mb"] - rows[0]["rss_mb"]
    passed = all(r["finite"] and r["nan_worlds"] == 0 for r in rows) and growth_after_first < args.rss_slack_mb
    summary = {
        "env": args.env, "control": args.control, "device": args.device, "worlds": args.worlds,
        "cycles_per_world": steps * args.num_cycles, "env_steps": steps, "wall_s": wall,
        "world_cycles_per_s": steps * args.num_cycles * args.worlds / wall, "rss_start_mb": rss0,
        "rss_end_mb": rows[-1]["rss_mb"], "rss_growth_after_first_checkpoint_mb": growth_after_first,
        "episodes": int(episodes), "collision_ends": int(collisions), "nan_worlds": rows[-1]["nan_worlds"],
        "passed": passed, **provenance(info),
    }
    print(header_line(info))
    print_table(rows, ["cycles_per_world", "wall_s", "rss_mb", "rss_growth_mb", "episodes", "collision_ends",
                       "nan_worlds", "finite"])
    print(f"{'PASS' if passed else 'FAIL'}: {summary['cycles_per_world']:,} cycles x {args.worlds} worlds in "
          f"{wall:.0f} s ({summary['world_cycles_per_s']:,.0f} world-cycles/s), RSS {rss0:.1f} -> "
          f"{rows[-1]['rss_mb']:.1f} MB ({growth_after_first:+.1f} MB after the first checkpoint), "
          f"{summary['nan_worlds']} NaN worlds, {int(episodes):,} episodes")
    path = args.json or os.path.join(os.path.dirname(os.path.abspath(__file__)), "results",
                                     f"soak_{args.control}_{args.device.replace(':', '')}.json")
    write_json(path, {"summary": summary, "checkpoints": rows})
    print(f"wrote {path}")
    return 0 if passed else 1


if __name__ == "__main__":
    sys.exit(main())
