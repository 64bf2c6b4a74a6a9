"""Where a push env step spends its time: per-kernel GPU times of one eager env step, grouped by who launched them.

The env step is run eagerly (no graph) under Warp's CUDA activity timing, so every kernel shows up with its own GPU
time; kernels are grouped into mujoco-warp's (by module name), magwarp's, and the torch remainder (the env's task
code between Warp launches is not timed per kernel: it is the step's wall time minus the Warp kernels). CUDA only.

    python benchmarks/profile_push.py --device cuda:0 --envs magwarp/PushBox-v0 --num-envs 65536 --solvers Newton,CG
"""

from __future__ import annotations

import argparse
import collections
import sys
import time

import torch
import warp as wp

from common import header_line, machine_info, print_table, provenance, write_json


def magwarp_kernel_names() -> set[str]:
    """Keys of every Warp kernel defined in magwarp's physics and metric modules (the rest are mujoco-warp's)."""
    import importlib
    import pkgutil

    import magwarp.physics

    names = set()
    for mod in pkgutil.iter_modules(magwarp.physics.__path__, "magwarp.physics."):
        for obj in vars(importlib.import_module(mod.name)).values():
            if isinstance(obj, wp.Kernel):
                names.add(obj.key)
    return names


def profile(env_id: str, num_envs: int, solver: str, device: str, steps: int, top: int,
            physics_dt: float = 0.001) -> tuple[dict, list[dict]]:
    import gymnasium as gym

    import magwarp  # noqa: F401

    env = gym.make_vec(env_id, num_envs=num_envs, device=device, solver=solver, physics_dt=physics_dt)
    env.backend.use_graph = False
    env.use_step_graph = False  # every kernel launched eagerly, so each is timed
    env.reset(seed=0)
    space = env.single_action_space
    low, high = (torch.as_tensor(v, device=env.device) for v in (space.low, space.high))
    gen = torch.Generator(device=env.device).manual_seed(0)
    actions = [low + (high - low) * torch.rand((num_envs, *space.shape), generator=gen, device=env.device)
               for _ in range(steps)]
    env.step(actions[0])  # loads every module
    torch.cuda.synchronize()
    wp.timing_begin(cuda_filter=wp.TIMING_KERNEL, synchronize=True)
    t = time.perf_counter()
    for a in actions:
        env.step(a)
    torch.cuda.synchronize()
    wall_ms = (time.perf_counter() - t) / steps * 1e3
    results = wp.timing_end()
    per_kernel: dict[str, float] = collections.defaultdict(float)
    launches: dict[str, int] = collections.Counter()
    for r in results:
        per_kernel[r.name] += r.elapsed / steps
        launches[r.name] += 1
    ours = magwarp_kernel_names()
    groups = collections.defaultdict(float)
    for name, ms in per_kernel.items():
        groups["magwarp" if any(name.startswith(k) or k in name for k in ours) else "mujoco_warp"] += ms
    summary = {"env": env_id, "num_envs": num_envs, "solver": solver, "physics_dt": physics_dt,
               "eager_wall_ms": wall_ms,
               "mujoco_warp_ms": groups["mujoco_warp"], "magwarp_kernels_ms": groups["magwarp"],
               "launches_per_step": sum(launches.values()) / steps,
               "solver_niter_max": int(env.backend.data.solver_niter.numpy().max())}
    kernels = [{"env": env_id, "solver": solver, "kernel": k[:70], "ms_per_step": v, "launches": launches[k] // steps}
               for k, v in sorted(per_kernel.items(), key=lambda kv: -kv[1])[:top]]
    return summary, kernels


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default="cuda:0")
    p.add_argument("--envs", default="magwarp/PushBox-v0")
    p.add_argument("--num-envs", type=int, default=65536)
    p.add_argument("--solvers", default="Newton,CG")
    p.add_argument("--steps", type=int, default=5)
    p.add_argument("--physics-dt", type=float, default=0.001, help="the push envs' physics step (s)")
    p.add_argument("--top", type=int, default=15, help="kernels listed per configuration")
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    if not args.device.startswith("cuda"):
        print("profile_push.py times CUDA kernels; run it with --device cuda:N", file=sys.stderr)
        return 2
    wp.config.quiet = True
    info = machine_info(args.device)
    print(header_line(info))
    summaries, kernels = [], []
    for env_id in args.envs.split(","):
        for solver in args.solvers.split(","):
            s, k = profile(env_id, args.num_envs, solver, args.device, args.steps, args.top, args.physics_dt)
            summaries.append(s)
            kernels.extend(k)
    print_table(kernels, ["env", "solver", "kernel", ("ms_per_step", "ms/step"), "launches"])
    print_table(summaries, ["env", "num_envs", "solver", "physics_dt", ("eager_wall_ms", "eager wall ms"),
                            ("mujoco_warp_ms", "mjw kernels ms"),
                            ("magwarp_kernels_ms", "magwarp kernels ms"), ("launches_per_step", "launches"),
                            ("solver_niter_max", "max solver iters")])
    if args.json:
        stamp = provenance(info)
        write_json(args.json, {"summary": [{**r, **stamp} for r in summaries], "kernels": kernels})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
