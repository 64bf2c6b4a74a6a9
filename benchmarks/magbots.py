"""MagBots throughput: env-steps/s of ``magwarp/PlatformPose-v0`` against num_envs on CPU and CUDA, beside
MagBotSim's 6D-platform example env (``SixDPlatformMagBotExampleEnv``: two platforms on four movers, its Python
IK and tilt coupling every cycle, MuJoCo C) stepped in the same run on the CPU.

    python benchmarks/magbots.py                                   # cpu 1..64 envs (+ cuda:0 4k..64k when present)
    python benchmarks/magbots.py --device cuda:0 --num-envs 4096,16384,65536 --json benchmarks/results/magbots_gpu.json
    python benchmarks/magbots.py --num-envs 1,4 --steps 5 --magbotsim-steps 5       # smoke check

One env step = 40 control cycles of 1 ms. magwarp: :func:`env_throughput.raw_env_row` (actions uniform random in the
action space from a pre-generated bank on the device, autoreset on and included: random accelerations break the
linkage's limits now and then, so resets happen; ``check_inputs`` off; "raw mjw ms" is the bare mujoco-warp step of
the same model and states). MagBotSim: ``env.step(platform_setposes, num_cycles=40)`` tracking its own
example's moving set poses, headless (its constructor's viewer switched off). Its env carries two platforms, so the
table also gives platform-steps/s.
"""

from __future__ import annotations

import argparse
import functools
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import numpy as np  # noqa: E402

from common import print_table, provenance, start_run, write_json  # noqa: E402
from env_throughput import raw_env_row  # noqa: E402

ENV_ID = "magwarp/PlatformPose-v0"


def magwarp_row(num_envs: int, device: str, steps: int, action_mode: str) -> dict:
    """The push/trajectory benchmark's row (random actions, autoreset, and the bare mujoco-warp step beside it)."""
    res = raw_env_row(ENV_ID, num_envs, device, steps, action_mode=action_mode)
    res["platforms_per_env"] = 1
    res["platform_steps_per_s"] = res["env_steps_per_s"]
    return res


def magbotsim_row(steps: int, warmup: int = 3) -> dict:
    """MagBotSim's 6D-platform example env, headless, ``steps`` env steps of 40 cycles (median per step)."""
    from magbotsim.basic_magbot_env import BasicMagBotEnv
    from magbotsim.envs_without_rl_api.magbots.sixD_platform_example_env import SixDPlatformMagBotExampleEnv

    original = BasicMagBotEnv.__init__

    @functools.wraps(original)
    def headless(self, *args, **kwargs):
        kwargs.update(render_mode=None, use_mj_passive_viewer=False)
        original(self, *args, **kwargs)

    BasicMagBotEnv.__init__ = headless
    try:
        t0 = time.perf_counter()
        env = SixDPlatformMagBotExampleEnv()
        build_s = time.perf_counter() - t0
    finally:
        BasicMagBotEnv.__init__ = original
    # the example's own motion: platform 0 circles and bobs, platform 1 waves its tilt
    poses = np.array([[0.56, 0.36, 0.24, 0.0, 0.0, 0.0], [1.32, 0.36, 0.2661825, 0.0, 0.0, np.deg2rad(-45.0)]])
    t_sim = 0.0
    samples = []
    for i in range(warmup + steps):
        poses[0, 0] = 0.48 + 0.08 * np.cos(t_sim)
        poses[0, 1] = 0.36 + 0.08 * np.sin(t_sim)
        poses[0, 2] = 0.03 * np.sin(3.5 * t_sim) + 0.24
        poses[1, 3] = np.cos(2.0 * t_sim)
        poses[1, 4] = np.sin(2.0 * t_sim)
        t = time.perf_counter()
        env.step(platform_setposes=poses.copy(), num_cycles=40)
        if i >= warmup:
            samples.append(time.perf_counter() - t)
        t_sim += 0.04
    env.close()
    step_ms = float(np.median(samples) * 1e3)
    return {"step_ms": step_ms, "std_ms": float(np.std(samples) * 1e3), "env_steps_per_s": 1e3 / step_ms,
            "platforms_per_env": 2, "platform_steps_per_s": 2e3 / step_ms, "build_s": build_s}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default=None, help="cpu or cuda:N (default: cpu, plus cuda:0 when present)")
    p.add_argument("--num-envs", default=None, help="comma-separated sizes (default: 1,4,16,64 on CPU; "
                                                    "4096,16384,65536 on CUDA)")
    p.add_argument("--action-modes", default="mover,pose", help="comma-separated: mover, pose")
    p.add_argument("--steps", type=int, default=50)
    p.add_argument("--no-magbotsim", action="store_true")
    p.add_argument("--magbotsim-steps", type=int, default=100)
    p.add_argument("--json", default=None, help="default: benchmarks/results/magbots_<device>.json")
    args = p.parse_args(argv)
    info, devices = start_run(args.device)
    rows: list[dict] = []
    for device in devices:
        sizes = ([int(s) for s in args.num_envs.split(",")] if args.num_envs else
                 ([1, 4, 16, 64] if device == "cpu" else [4096, 16384, 65536]))
        for mode in args.action_modes.split(","):
            for n in sizes:
                res = magwarp_row(n, device, args.steps, mode)
                rows.append({"engine": "magwarp", "env": ENV_ID, "action_mode": mode, "device": device, "num_envs": n,
                             **res})
                print(f"  {ENV_ID} {mode} {device} num_envs={n}: {res['env_steps_per_s']:.4g} env-steps/s", flush=True)
    if not args.no_magbotsim:
        try:
            res = magbotsim_row(args.magbotsim_steps)
        except ImportError as e:
            print(f"  MagBotSim not available ({e}); skipped", flush=True)
        else:
            rows.append({"engine": "magbotsim", "env": "SixDPlatformMagBotExampleEnv",
                         "action_mode": "platform set pose", "device": "cpu", "num_envs": 1, **res})
    ref = next((r for r in rows if r["engine"] == "magbotsim"), None)
    if ref is not None:
        for r in rows:
            r["x_magbotsim"] = r["platform_steps_per_s"] / ref["platform_steps_per_s"]
    print_table(rows, ["engine", "env", "action_mode", "device", "num_envs", ("step_ms", "ms/step"),
                       ("raw_mjw_ms", "raw mjw ms"),
                       ("env_steps_per_s", "env-steps/s"), ("platform_steps_per_s", "platform-steps/s"),
                       ("x_magbotsim", "x MagBotSim (platform-steps)")])
    path = args.json or os.path.join(os.path.dirname(os.path.abspath(__file__)), "results",
                                     f"magbots_{(args.device or 'cpu').replace(':', '')}.json")
    stamp = provenance(info)
    write_json(path, [{**r, **stamp} for r in rows])
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
