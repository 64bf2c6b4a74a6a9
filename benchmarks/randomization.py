"""Cost of domain randomisation and the sim2real models: env-steps/s with every event term, action latency and the
sensor model on, against none, per env and num_envs, on CPU and CUDA.

    python benchmarks/randomization.py                                    # cpu (+cuda:0 when present), default sizes
    python benchmarks/randomization.py --device cuda:0 --num-envs 4096,16384,65536 --json randomization_gpu.json

Envs: the trajectory-planning env (B0, the planar simulator: :mod:`magwarp.envs.planar_randomization`) and Push-Box
(mujoco-warp: :mod:`magwarp.envs.randomization`). Settings: ``off`` (no terms), ``terms`` (every event term of the env's
backend, drawn at every reset, one of them also every 10 steps), ``full`` (the terms, plus an action latency drawn in
0..5 cycles at every reset and sensor bias, white noise and 5 % dropped readings). Autoreset runs the reset hook in
every step (for the worlds that finished, often none), so the reset terms' draws and model writes are paid at every
step: that is the cost shown. The planar payload (the preset's) sits on the mover's vertical axis: off it, gravity's
torque tilts the mover, and its attitude dynamics (which a level mover skips) run every cycle, a physics cost of about
3x on the CPU. The trajectory env runs its fused step in every setting (interval terms fire on the host before the
step; the table's "step path" column says which step ran); "physics ms" is the simulator's step alone (the body
terms switch its kernels to the general variant, which reads each world's parameters). Timing as in
env_throughput.py (random actions from a bank, autoreset on, ``check_inputs`` off). Target: ``full`` costs at most
10 % at 65,536 envs on the GPU.

"launches" (the trajectory env): the device launches of one fused env step, counted on the host over the same
kernels run eagerly (Warp launches, the simulator's too, plus torch ops that launch a kernel; views and no-op
conversions not counted), at 256 envs (the count does not depend on the size); on CUDA, "graph kernels" counts the
kernels the profiler sees in one replay of the step's graph (None where the profiler reports none).
"""

from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from common import finish, start_run  # noqa: E402
from env_throughput import raw_env_row  # noqa: E402

from magwarp.envs.randomization import PRESETS  # noqa: E402

# every field of each backend: the "sim2real" preset plus the fields it leaves out
PUSH_TERMS = PRESETS["sim2real"]["push"] + [
    {"field": "floor_friction", "dist": {"uniform": [-0.2, 0.2]}, "op": "add", "mode": "interval",
     "interval_steps": 10},
    {"field": "mover_inertia", "dist": {"uniform": [0.9, 1.1]}, "op": "scale"},
    {"field": "stiffness_lin", "dist": {"uniform": [0.7, 1.3]}, "op": "scale"},
    {"field": "stiffness_rot", "dist": {"uniform": [0.7, 1.3]}, "op": "scale"},
    {"field": "a_max", "dist": {"uniform": [0.9, 1.0]}, "op": "scale"},
    {"field": "v_max", "dist": {"uniform": [0.9, 1.0]}, "op": "scale"},
    {"field": "collision_radius", "dist": {"uniform": [-0.005, 0.0]}, "op": "add"},
    {"field": "wall_margin", "dist": {"uniform": [0.0, 0.002]}, "op": "add"},
]
PLANAR_TERMS = PRESETS["sim2real"]["planar"] + [
    {"field": "mover_inertia", "dist": {"uniform": [0.9, 1.1]}, "op": "scale"},
    {"field": "j_max", "dist": {"uniform": [0.9, 1.0]}, "op": "scale", "mode": "interval", "interval_steps": 10},
    {"field": "collision_radius", "dist": {"uniform": [-0.005, 0.0]}, "op": "add"},
]
SIM2REAL = {"actuation": {"latency_range": [0, 5]},
            "sensors": {"pos_bias_std": 0.001, "vel_bias_std": 0.01, "pos_noise_std": 0.0005, "vel_noise_std": 0.005,
                        "dropout_prob": 0.05}}
ENVS = {
    "magwarp/TrajectoryPlanningB0-v0": {"off": {}, "terms": {"randomization": PLANAR_TERMS},
                                        "full": {"randomization": PLANAR_TERMS, **SIM2REAL}},
    "magwarp/PushBox-v0": {"off": {}, "terms": {"randomization": PUSH_TERMS},
                           "full": {"randomization": PUSH_TERMS, **SIM2REAL}},
}
#: settings that split "full" into its parts (``--settings``): the terms with latency only, with the sensors only
PARTS = {env_id: {"latency": {**s["terms"], "actuation": SIM2REAL["actuation"]},
                  "sensors": {**s["terms"], "sensors": SIM2REAL["sensors"]}} for env_id, s in ENVS.items()}


#: torch ops that launch no kernel (views, allocations, conversions to the same dtype)
NO_KERNEL_OPS = {"aten::view", "aten::expand", "aten::expand_as", "aten::as_strided", "aten::reshape", "aten::slice",
                 "aten::select", "aten::alias", "aten::unsqueeze", "aten::squeeze", "aten::permute", "aten::t",
                 "aten::empty", "aten::empty_like", "aten::empty_strided", "aten::unbind", "aten::detach",
                 "aten::_reshape_alias", "aten::resolve_conj", "aten::resolve_neg", "aten::lift_fresh", "aten::to"}


def kernel_times(env_id: str, device: str, num_envs: int, steps: int = 10, **env_kwargs) -> tuple[dict, dict]:
    """CUDA time per env step of each kernel (us, summed over its launches) in the env's step at ``num_envs``, from the
    profiler's device trace over ``steps`` steps (graph replays included): where a setting's extra time goes. Also
    each kernel's launch count and median and longest launch (us): a term firing every N steps shows there."""
    import collections

    import gymnasium as gym
    import torch
    from torch.profiler import ProfilerActivity, profile

    import magwarp  # noqa: F401  (registers the ids)

    env = gym.make_vec(env_id, num_envs=num_envs, device=device, check_inputs=False, **env_kwargs).unwrapped
    env.reset(seed=0)
    gen = torch.Generator(device=env.device).manual_seed(0)
    actions = [torch.rand((num_envs, *env.single_action_space.shape), device=env.device, generator=gen) * 2 - 1
               for _ in range(steps)]
    for a in actions[:3]:
        env.step(a)
    torch.cuda.synchronize()
    with profile(activities=[ProfilerActivity.CUDA]) as prof:
        for a in actions:
            env.step(a)
        torch.cuda.synchronize()
    cuda = torch.autograd.DeviceType.CUDA
    total: collections.Counter = collections.Counter()
    launches: dict[str, list[float]] = collections.defaultdict(list)
    for e in prof.profiler.kineto_results.events():
        if e.device_type() == cuda:
            total[e.name()[:60]] += (e.duration_ns() / 1000.0) / steps
            launches[e.name()[:60]].append(e.duration_ns() / 1000.0)
    stats = {k: {"launches": len(v), "median_us": float(sorted(v)[len(v) // 2]), "max_us": max(v)}
             for k, v in launches.items()}
    return dict(total.most_common()), stats


def count_launches(env_id: str, device: str, num_envs: int = 256, **env_kwargs) -> dict:
    """Device launches of one env step of the trajectory env (see the module doc): ``launches`` (Warp + torch),
    ``warp_launches``, ``torch_kernels``, ``launch_names`` and, on CUDA, ``graph_kernels``."""
    import collections

    import gymnasium as gym
    import torch
    import warp as wp
    from torch.profiler import ProfilerActivity, profile

    import magwarp  # noqa: F401  (registers the ids)

    if "TrajectoryPlanningEnv" not in str(gym.spec(env_id).vector_entry_point):  # the planar simulator's envs only
        return {}
    env = gym.make_vec(env_id, num_envs=num_envs, device=device, check_inputs=False, **env_kwargs).unwrapped
    env.reset(seed=0)
    action = torch.zeros((num_envs, *env.single_action_space.shape), device=env.device)
    for _ in range(3):  # loads the modules; records the step graph on CUDA
        env.step(action)
    out: dict = {}
    if env.sim.device.is_cuda and env.step_path == "fused graph":
        try:
            torch.cuda.synchronize()
            with profile(activities=[ProfilerActivity.CUDA]) as prof:
                for _ in range(4):
                    env.step(action)
                torch.cuda.synchronize()
            cuda = torch.autograd.DeviceType.CUDA
            raw = [(e.name(), e.device_type()) for e in prof.profiler.kineto_results.events()]  # the device trace
            kernels = [name for name, kind in raw if kind == cuda and not name.startswith(("Memcpy", "Memset"))]
            out["graph_kernels"] = len(kernels) / 4 if kernels else None
        except Exception as e:  # noqa: BLE001 - a profiler without CUPTI: the host count still stands
            print(f"  (no CUDA kernel count: {type(e).__name__}: {e})", flush=True)
            out["graph_kernels"] = None
    # the same kernels eagerly, counted on the host
    fused = env._fused_step
    graph, env.sim._use_graph = fused.graph if fused is not None else None, False
    if fused is not None:
        fused.graph = False
    names: collections.Counter = collections.Counter()
    launch, launch_tiled = wp.launch, wp.launch_tiled

    def counted(kernel, *args, **kwargs):
        names[f"warp:{kernel.key}"] += 1
        return launch(kernel, *args, **kwargs)

    def counted_tiled(kernel, *args, **kwargs):  # (launch_tiled calls Warp's own launch, not wp.launch)
        names[f"warp:{kernel.key}"] += 1
        return launch_tiled(kernel, *args, **kwargs)

    wp.launch, wp.launch_tiled = counted, counted_tiled
    try:
        with profile(activities=[ProfilerActivity.CPU]) as prof:
            env.step(action)
    finally:
        wp.launch, wp.launch_tiled = launch, launch_tiled
        env.sim._use_graph = True
        if fused is not None:
            fused.graph = graph
    for e in prof.events():
        top = e.cpu_parent is None or not e.cpu_parent.name.startswith("aten::")
        if e.name.startswith("aten::") and top and e.name not in NO_KERNEL_OPS:
            names[f"torch:{e.name}"] += 1
    warp_n = sum(v for k, v in names.items() if k.startswith("warp:"))
    torch_n = sum(v for k, v in names.items() if k.startswith("torch:"))
    out.update(launches=warp_n + torch_n, warp_launches=warp_n, torch_kernels=torch_n,
               launch_names=" ".join(f"{k}x{v}" for k, v in sorted(names.items())))
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default=None, help="cpu or cuda:N (default: cpu, plus cuda:0 when present)")
    p.add_argument("--env", default=None, help=f"one env id (default: {', '.join(ENVS)})")
    p.add_argument("--num-envs", default=None, help="comma-separated sizes (default: 64,256 on CPU, 4096,65536 on GPU)")
    p.add_argument("--steps", type=int, default=20)
    p.add_argument("--register-rows", default=None, choices=("all", "f32", "sizes", "none"),
                   help="which per-world rows the general register kernel holds (magwarp.kernels.options.REGISTER_ROWS;"
                        " default: the library's); each setting compiles its own kernel")
    p.add_argument("--small-world-kernel", default=None, choices=("registers", "movers"),
                   help="the fused small-world step's launch shape (magwarp.kernels.options.SMALL_WORLD_KERNEL: one "
                        "thread per world, or per mover; default: the library's)")
    p.add_argument("--small-world-block", type=int, default=None,
                   help="threads per block of the movers shape (SMALL_WORLD_BLOCK; default: the library's)")
    p.add_argument("--small-world-maxreg", type=int, default=None,
                   help="register cap of the movers shape (SMALL_WORLD_MAXREG, 0: none; default: the library's)")
    p.add_argument("--small-world-rows", default=None, choices=("shared", "registers"),
                   help="where the movers shape's general variant keeps the body rows (SMALL_WORLD_ROWS)")
    p.add_argument("--kernel-times", type=int, default=0, metavar="N",
                   help="also profile each setting's step at N envs on CUDA: per-kernel time per step (us)")
    p.add_argument("--settings", default="off,terms,full",
                   help="comma-separated settings (off, terms, full; latency and sensors: the terms with that part of "
                        "full alone); off is always run first, as the base of the cost")
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    wanted = ["off"] + [s for s in args.settings.split(",") if s and s != "off"]
    unknown = [s for s in wanted if s not in ("off", "terms", "full", "latency", "sensors")]
    if unknown:
        p.error(f"--settings: unknown setting(s) {', '.join(unknown)} (known: off, terms, full, latency, sensors)")
    from magwarp.kernels import options as kernel_options

    # the tuning knobs given on the command line (each default: the library's)
    for value, module, name in ((args.register_rows, kernel_options, "REGISTER_ROWS"),
                                (args.small_world_kernel, kernel_options, "SMALL_WORLD_KERNEL"),
                                (args.small_world_block, kernel_options, "SMALL_WORLD_BLOCK"),
                                (args.small_world_maxreg, kernel_options, "SMALL_WORLD_MAXREG"),
                                (args.small_world_rows, kernel_options, "SMALL_WORLD_ROWS")):
        if value is not None:
            setattr(module, name, value)
    if args.env is not None and args.env not in ENVS:
        p.error(f"--env must be one of {', '.join(ENVS)}, got {args.env!r}")
    info, devices = start_run(args.device)
    rows: list[dict] = []
    for device in devices:
        sizes = ([int(s) for s in args.num_envs.split(",")] if args.num_envs else
                 ([64, 256] if device == "cpu" else [4096, 16384, 65536]))
        for env_id in [args.env] if args.env else list(ENVS):
            settings = {name: {**ENVS[env_id], **PARTS[env_id]}[name] for name in wanted}
            counts = {name: count_launches(env_id, device, **kwargs) for name, kwargs in settings.items()}
            for name, c in counts.items():
                if c:
                    graph = f"; graph kernels: {c['graph_kernels']}" if "graph_kernels" in c else ""
                    print(f"  {device} {env_id} {name}: {c['launches']} launches per step "
                          f"({c['launch_names']}{graph})", flush=True)
            times, launch_stats = {}, {}
            if args.kernel_times and device != "cpu":
                for name, kwargs in settings.items():
                    try:
                        times[name], launch_stats[name] = kernel_times(env_id, device, args.kernel_times, **kwargs)
                    except Exception as e:  # noqa: BLE001 - a profiler without CUPTI: the timings still stand
                        print(f"  (no kernel times: {type(e).__name__}: {e})", flush=True)
                        times[name], launch_stats[name] = {}, {}
                    top = ", ".join(f"{k} {v:.1f}" for k, v in list(times[name].items())[:10])
                    print(f"  {device} {env_id} {name} at {args.kernel_times} envs, us per step: "
                          f"total {sum(times[name].values()):.1f}; {top}", flush=True)
                    print("    launches (count/median us/max us): " + ", ".join(
                        f"{k[:32]} {v['launches']}/{v['median_us']:.1f}/{v['max_us']:.1f}"
                        for k, v in launch_stats[name].items()), flush=True)
            for n in sizes:
                base = None
                for name, kwargs in settings.items():
                    res = raw_env_row(env_id, n, device, args.steps, **kwargs)
                    base = res if name == "off" else base
                    cost = 100.0 * (res["step_ms"] / base["step_ms"] - 1.0)
                    rows.append({"env": env_id, "device": device, "num_envs": n, "randomization": name,
                                 "cost_pct": cost, **res, **counts[name],
                                 "register_rows": kernel_options.REGISTER_ROWS,
                                 "small_world_kernel": kernel_options.SMALL_WORLD_KERNEL,
                                 "small_world_block": kernel_options.SMALL_WORLD_BLOCK,
                                 "small_world_maxreg": kernel_options.SMALL_WORLD_MAXREG,
                                 "small_world_rows": kernel_options.SMALL_WORLD_ROWS,
                                 "kernel_us": times.get(name) if n == args.kernel_times else None,
                                 "kernel_launches": launch_stats.get(name) if n == args.kernel_times else None})
                    path = f", step path: {res['path']}" if "path" in res else ""
                    print(f"  {device} {env_id} num_envs={n} {name}: {res['env_steps_per_s']:.4g} env-steps/s "
                          f"({cost:+.1f} %{path})", flush=True)
    columns = ["env", "device", "num_envs", "randomization", ("step_ms", "ms/step"), ("env_steps_per_s", "env-steps/s"),
               ("cost_pct", "cost % vs off"), ("sim_ms", "physics ms"), ("launches", "launches/step"),
               ("graph_kernels", "graph kernels"), ("path", "step path")]
    return finish(rows, columns, info, args.json)


if __name__ == "__main__":
    raise SystemExit(main())
