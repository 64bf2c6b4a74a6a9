"""RL env throughput: env-steps per second against num_envs (one env step = 40 cycles of 1 ms), on CPU and CUDA,
beside MagBotSim's ``env.step()`` measured in the same run, and the cost of the adapters over the raw tensor env.

    python benchmarks/env_throughput.py                          # B0 on cpu (+cuda:0), adapters, MagBotSim
    python benchmarks/env_throughput.py --device cuda:0 --num-envs 4096,65536,1048576 --json out.json --plot out.png
    python benchmarks/env_throughput.py --devices cuda:0 --envs magwarp/TrajectoryPlanningB0-v0 --compare-eager \
        --no-magbotsim --adapters-at 0 --json b0.json      # the B0 step: fused graph vs torch step vs ceiling

For the trajectory-planning envs each row also shows the env's own physics (its simulator's step alone, "physics
ms"), the bare-kernel ceiling of a B0 step at the same size (:mod:`ceiling`, "ceiling ms"), ``env/physics`` (step
time over physics time) and ``env/ceiling`` (env-steps/s as a fraction of the ceiling's), all from the same run;
"path" is the env's :attr:`step_path` (``--compare-eager`` adds rows of the torch step, ``fused=False``, and on CUDA of
the fused kernels launched one by one, ``graph=False``).

Actions are uniform random in the action space, drawn on the device from a pre-generated bank (so the timing is the
env's, not the random generator's). Autoreset is on and included. ``check_inputs`` is off in the timed loop (it is a
device sync per step on a GPU); the row ``check_inputs=on`` shows its cost at one size.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import numpy as np  # noqa: E402
import torch  # noqa: E402
import warp as wp  # noqa: E402

from common import print_table, provenance, start_run, write_json  # noqa: E402


def _sync(device) -> None:
    if torch.device(device).type == "cuda":
        torch.cuda.synchronize(device)


def time_steps(step, actions: torch.Tensor, steps: int, device) -> dict:
    for i in range(3):
        step(actions[i % len(actions)])
    _sync(device)
    samples = []
    chunk = max(1, steps // 5)
    for r in range(5):
        t = time.perf_counter()
        for i in range(chunk):
            step(actions[(r * chunk + i) % len(actions)])
        _sync(device)
        samples.append((time.perf_counter() - t) / chunk)
    return {"step_ms": float(np.median(samples) * 1e3), "std_ms": float(np.std(samples) * 1e3)}


def raw_env_row(env_id: str, num_envs: int, device: str, steps: int, check_inputs: bool = False, **env_kwargs) -> dict:
    import gymnasium as gym

    import magwarp  # noqa: F401  (registers the ids)

    env = gym.make_vec(env_id, num_envs=num_envs, device=device, check_inputs=check_inputs, **env_kwargs)
    env.reset(seed=0)
    space = env.single_action_space
    gen = torch.Generator(device=env.device).manual_seed(0)
    low = torch.as_tensor(space.low, device=env.device)
    high = torch.as_tensor(space.high, device=env.device)
    actions = low + (high - low) * torch.rand((8, num_envs, *space.shape), generator=gen, device=env.device)
    backend = getattr(env, "backend", None)
    snapshots = []

    def env_step(a):
        env.step(a)
        if backend is not None and len(snapshots) < 8:  # states the env really visits, for the raw comparison
            snapshots.append([t.clone() for t in _physics_state(backend)])

    res = time_steps(env_step, actions, steps, device)
    res["env_steps_per_s"] = num_envs / (res["step_ms"] / 1e3)
    if getattr(env.unwrapped, "step_path", None) is not None:
        res["path"] = env.unwrapped.step_path
    if backend is not None:
        res["raw_mjw_ms"] = raw_mujoco_warp_ms(backend, steps, device, snapshots)
        res["x_raw_mjw"] = res["step_ms"] / res["raw_mjw_ms"]
    sim = getattr(env, "sim", None)
    if sim is not None:
        # The physics alone (the graph the env replays, plus a reset so that no world sits halted after a
        # collision), to show what the env's torch work adds.
        def physics(a):
            sim.reset()
            sim.set_command(a.view(num_envs, -1, 2))
            sim.step(env.num_cycles)

        sim.check_inputs = False
        res["sim_ms"] = time_steps(physics, actions, steps, device)["step_ms"]
        res["x_physics"] = res["step_ms"] / res["sim_ms"]
    return res


_CEILINGS: dict[tuple[str, int], dict] = {}


def with_ceiling(res: dict, num_envs: int, device: str, steps: int) -> dict:
    """``res`` with the B0 bare-kernel ceiling at ``num_envs`` (measured once per size and device in a run) and the
    env's fraction of it."""
    from ceiling import ceiling_ms

    key = (device, num_envs)
    if key not in _CEILINGS:
        _CEILINGS[key] = ceiling_ms(num_envs, device, steps)
    c = _CEILINGS[key]
    return {**res, "ceiling_ms": c["ceiling_ms"], "x_ceiling": c["ceiling_ms"] / res["step_ms"]}


def _physics_state(backend) -> list[torch.Tensor]:
    """The mujoco-warp state one env step starts from: positions, velocities, applied forces, solver warm start."""
    d = backend.data
    return [wp.to_torch(a) for a in (d.qpos, d.qvel, d.qfrc_applied, d.qacc_warmstart)]


def raw_mujoco_warp_ms(backend, steps: int, device, snapshots: list[list[torch.Tensor]]) -> float:
    """Bare ``mujoco_warp.step`` x num_cycles on the env's own model and data, one graph, each step started from a
    state the env visited (``snapshots``: positions, velocities, the applied control forces held over the step,
    solver warm start). Stepping on from one state instead would measure other physics: with no resets the movers
    leave the objects behind and the contact solver idles. What the push env adds (mover control, checks, task
    code, resets) is the env time over this."""
    import contextlib

    import mujoco_warp as mjw

    state = _physics_state(backend)
    stream = wp.Stream(backend.device) if backend.device.is_cuda else None
    with wp.ScopedDevice(backend.device), (wp.ScopedStream(stream) if stream else contextlib.nullcontext()):
        with wp.ScopedCapture(device=backend.device, force_module_load=False) as cap:
            for _ in range(backend.control.num_cycles):
                mjw.step(backend.model, backend.data)

    replay_stream = wp.stream_from_torch(torch.cuda.current_stream(backend.torch_device)) if stream else None

    def raw_step(snap):
        for dst, src in zip(state, snap):
            dst.copy_(src)
        wp.capture_launch(cap.graph, stream=replay_stream)

    return time_steps(raw_step, snapshots, steps, device)["step_ms"]


def adapter_rows(env_id: str, num_envs: int, device: str, steps: int) -> list[dict]:
    """The same workload through each adapter that is importable (the numpy SB3 adapter pays its host copies)."""
    import gymnasium as gym

    rows = []

    def make():
        return gym.make_vec(env_id, num_envs=num_envs, device=device, check_inputs=False)

    try:
        from magwarp.envs.adapters.sb3 import SB3VecEnv

        venv = SB3VecEnv(make())
        venv.reset()
        rng = np.random.default_rng(0)
        acts = rng.uniform(venv.action_space.low, venv.action_space.high,
                           (8, num_envs, *venv.action_space.shape)).astype(np.float32)

        def sb3_step(a):
            venv.step_async(a)
            venv.step_wait()

        res = time_steps(sb3_step, acts, steps, device)
        rows.append({"adapter": "sb3 VecEnv (numpy)", **res, "env_steps_per_s": num_envs / (res["step_ms"] / 1e3)})
    except ImportError as e:
        print(f"sb3 adapter skipped: {e}", file=sys.stderr)
    try:
        from magwarp.envs.adapters.torchrl import TorchRLEnv

        for multi in (False, True):
            tenv = TorchRLEnv(make(), multi_agent=multi)
            td = tenv.reset()
            acts = [tenv.full_action_spec.rand() for _ in range(8)]

            def trl_step(a):
                nonlocal td
                td.update(a)
                td = tenv.step_and_maybe_reset(td)[1]

            res = time_steps(trl_step, acts, steps, device)
            name = "torchrl EnvBase" + (" (multi-agent)" if multi else "")
            rows.append({"adapter": name, **res, "env_steps_per_s": num_envs / (res["step_ms"] / 1e3)})
    except ImportError as e:
        print(f"torchrl adapter skipped: {e}", file=sys.stderr)
    return rows


def plot(rows: list[dict], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 5))
    series: dict[str, list] = {}
    for r in rows:
        if r.get("adapter") in (None, "raw") and not r.get("check_inputs"):
            name = f"MagBotSim {r['magbotsim_env']}" if r["engine"] == "magbotsim" else f"magwarp {r['env']}"
            name += f" [{r['path']}]" if r.get("path") else ""
            series.setdefault(f"{name} ({r['device']})", []).append((r["num_envs"], r["env_steps_per_s"]))
    for name, pts in sorted(series.items()):
        pts.sort()
        x, y = zip(*pts)
        style = "s--" if name.startswith("magbotsim") else "o-"
        ax.plot(x, y, style, label=name)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("num_envs")
    ax.set_ylabel("env steps per second (1 step = 40 x 1 ms cycles)")
    ax.set_title("RL env throughput: magwarp (batched) vs MagBotSim (one env per process)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    print(f"wrote {path}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", "--devices", default=None,
                   help="cpu or cuda:N (default: cpu, plus cuda:0 when present)")
    p.add_argument("--envs", default="magwarp/TrajectoryPlanningB0-v0,magwarp/PushBox-v0,magwarp/PushT-v0",
                   help="comma-separated magwarp env ids")
    p.add_argument("--push-num-envs", default=None, help="sizes for push envs (default: 1..64 on CPU, up to 16384 on GPU)")
    p.add_argument("--num-envs", default=None, help="comma-separated sizes (default: 1..4096 on CPU, up to 1M on GPU)")
    p.add_argument("--push-solvers", default="auto",
                   help="comma-separated MuJoCo solvers to time the push envs with: auto, Newton or CG, optionally "
                        "with an iteration cap as SOLVER:N (e.g. Newton:4)")
    p.add_argument("--steps", type=int, default=50)
    p.add_argument("--compare-eager", action="store_true",
                   help="trajectory envs: also time the torch step (fused=False) and, on CUDA, the fused kernels "
                        "without the graph (graph=False) at every size")
    p.add_argument("--adapters-at", type=int, default=4096, help="num_envs at which adapters are compared")
    p.add_argument("--no-magbotsim", action="store_true")
    p.add_argument("--magbotsim-steps", type=int, default=200)
    p.add_argument("--json", default=None)
    p.add_argument("--plot", default=None)
    args = p.parse_args(argv)
    info, devices = start_run(args.device)
    rows: list[dict] = []
    for device in devices:
        sizes = ([int(s) for s in args.num_envs.split(",")] if args.num_envs else
                 ([1, 64, 1024, 4096] if device == "cpu" else [4096, 16384, 65536, 262144, 1048576, 2097152]))
        push_sizes = ([int(x) for x in args.push_num_envs.split(",")] if args.push_num_envs else
                      ([1, 16, 64] if device == "cpu" else [1024, 4096, 16384]))
        for env_id in args.envs.split(","):
            is_push = "/Push" in env_id
            for solver in (args.push_solvers.split(",") if is_push else [None]):
                extra = {}
                if solver:
                    name, _, cap = solver.partition(":")
                    extra = {"solver": name, **({"solver_iterations": int(cap)} if cap else {})}
                for n in (push_sizes if is_push else sizes):
                    variants = [{}]
                    if args.compare_eager and "Trajectory" in env_id:  # the same kernels uncaptured, the torch step
                        variants += ([{"graph": False}] if device.startswith("cuda") else []) + [{"fused": False}]
                    for variant in variants:
                        res = raw_env_row(env_id, n, device, args.steps, **extra, **variant)
                        if "Trajectory" in env_id:
                            res = with_ceiling(res, n, device, args.steps)
                        rows.append({"engine": "magwarp", "env": env_id, "device": device, "num_envs": n,
                                     "adapter": "raw", **extra, **res})
                        if solver:
                            rows[-1]["solver"] = solver
                        print(f"  {env_id} {solver or ''} {res.get('path', '')} {device} num_envs={n}: "
                              f"{res['env_steps_per_s']:.4g} env-steps/s", flush=True)
            if is_push or args.adapters_at <= 0:
                continue
            n = args.adapters_at
            res = raw_env_row(env_id, n, device, args.steps, check_inputs=True)
            rows.append({"engine": "magwarp", "env": env_id, "device": device, "num_envs": n, "adapter": "raw",
                         "check_inputs": True, **res})
            for r in adapter_rows(env_id, n, device, args.steps):
                rows.append({"engine": "magwarp", "env": env_id, "device": device, "num_envs": n, **r})
    if not args.no_magbotsim:
        import magbotsim_ref as ref

        if ref.magbotsim_available():
            mapping = {"magwarp/TrajectoryPlanningB0-v0": "LongHorizonGlobalTrajectoryPlanningEnvB0-v0",
                       "magwarp/PushBox-v0": "StateBasedPushBoxEnv-v0", "magwarp/PushT-v0": "StateBasedPushTEnv-v0"}
            for env_id in args.envs.split(","):
                if env_id in mapping:
                    res = ref.env_steps_per_s(mapping[env_id], steps=args.magbotsim_steps)
                    rows.append({"engine": "magbotsim", "env": env_id, "magbotsim_env": mapping[env_id], "device": "cpu",
                                 "num_envs": 1, "adapter": "raw",
                                 "step_ms": res["step_ms_mean"], "env_steps_per_s": res["steps_per_s"]})
    print_table(rows, ["engine", "env", "device", "num_envs", "solver", "adapter", "path", "check_inputs",
                       ("step_ms", "ms/step"), ("sim_ms", "physics ms"), ("ceiling_ms", "ceiling ms"),
                       ("x_physics", "env/physics"), ("x_ceiling", "env/ceiling"), ("raw_mjw_ms", "raw mjw ms"),
                       ("x_raw_mjw", "x raw mjw"), ("env_steps_per_s", "env-steps/s")])
    if args.json:
        stamp = provenance(info)
        write_json(args.json, [{**r, **stamp} for r in rows])
    if args.plot:
        plot(rows, args.plot)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
