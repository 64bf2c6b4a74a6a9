"""MagBots throughput: env-steps/s of the MagBot envs against num_envs on CPU and CUDA, beside MagBotSim's MagBot
example envs (MuJoCo C, their Python IK and couplings every cycle) stepped in the same run on the CPU.

    python benchmarks/magbots.py                                   # cpu 1..64 envs (+ cuda:0 4k..64k when present)
    python benchmarks/magbots.py --device cuda:0 --num-envs 4096,16384,65536 --json benchmarks/results/magbots_gpu.json
    python benchmarks/magbots.py --num-envs 1,4 --steps 5 --magbotsim-steps 5       # smoke check

Envs (``--envs``, default all): ``pose`` = ``magwarp/PlatformPose-v0`` (``--action-modes`` mover, pose),
``pickplace`` = ``magwarp/PlatformPickPlace-v0``, ``gripper`` = ``magwarp/GripperPickPlace-v0`` (mover actions),
``coop`` = ``magwarp/CoopPush-v0`` (no MagBotSim counterpart). The JSON is rewritten after every row, so a run cut
short keeps what it measured.
One env step = 40 control cycles of 1 ms. magwarp: :func:`env_throughput.raw_env_row` (actions uniform random in the
action space from a pre-generated bank on the device, autoreset on and included: random accelerations break the
mechanisms' limits now and then, so resets happen; ``check_inputs`` off; "raw mjw ms" is the bare mujoco-warp step of
the same model and states). The pick-and-place rows carry their contacts (product on the rack or plate, object on
the tiles). MagBotSim, headless (its constructors' viewer switched off), ``env.step(..., num_cycles=40)`` tracking
moving set poses: ``SixDPlatformMagBotExampleEnv`` (two platforms; the reference of ``pose``),
``SixDPlatformMagBotApplicationExampleEnv`` (its pick-and-place application, one platform and a product; the
reference of ``pickplace``) and ``GripperMagBotApplicationExampleEnv`` (its pick-and-place gripper, three movers;
the reference of ``gripper``: a different mechanism from magwarp's two-mover jaw, so that column compares the cost
of one gripper MagBot per world). ``x MagBotSim`` divides MagBot-steps/s (platforms or grippers) by the reference's.
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

#: benchmark name -> (env id, default action modes, MagBotSim reference env)
ENVS = {
    "pose": ("magwarp/PlatformPose-v0", ("mover", "pose"), "SixDPlatformMagBotExampleEnv"),
    "pickplace": ("magwarp/PlatformPickPlace-v0", ("mover",), "SixDPlatformMagBotApplicationExampleEnv"),
    "gripper": ("magwarp/GripperPickPlace-v0", ("mover",), "GripperMagBotApplicationExampleEnv"),
    # MagBotSim has no cooperative push: its row stands alone (two movers and a heavy box per world)
    "coop": ("magwarp/CoopPush-v0", (None,), None),
}


def magwarp_row(env_id: str, num_envs: int, device: str, steps: int, action_mode: str) -> dict:
    """The push/trajectory benchmark's row (random actions, autoreset, and the bare mujoco-warp step beside it)."""
    kwargs = {} if action_mode is None else {"action_mode": action_mode}
    res = raw_env_row(env_id, num_envs, device, steps, **kwargs)
    res["magbots_per_env"] = 1
    res["magbot_steps_per_s"] = res["env_steps_per_s"]
    return res


def _headless(cls):
    """Build a MagBotSim example env without its passive viewer."""
    from magbotsim.basic_magbot_env import BasicMagBotEnv

    original = BasicMagBotEnv.__init__

    @functools.wraps(original)
    def headless(self, *args, **kwargs):
        kwargs.update(render_mode=None, use_mj_passive_viewer=False)
        original(self, *args, **kwargs)

    BasicMagBotEnv.__init__ = headless
    try:
        t0 = time.perf_counter()
        env = cls()
        return env, time.perf_counter() - t0
    finally:
        BasicMagBotEnv.__init__ = original


def _reference(name: str):
    """(env class, magbots per env, ``step(env, t)``): MagBotSim's example env and the moving set poses it tracks
    (the examples' own motions, or a slow circle and bob where the example has a scripted sequence)."""
    from magbotsim.envs_without_rl_api.magbots import (gripper_application_example,
                                                      sixD_platform_application_example_env,
                                                      sixD_platform_example_env)

    if name == "SixDPlatformMagBotExampleEnv":
        poses = np.array([[0.56, 0.36, 0.24, 0.0, 0.0, 0.0], [1.32, 0.36, 0.2661825, 0.0, 0.0, np.deg2rad(-45.0)]])

        def step(env, t):  # platform 0 circles and bobs, platform 1 waves its tilt
            poses[0, :3] = [0.48 + 0.08 * np.cos(t), 0.36 + 0.08 * np.sin(t), 0.03 * np.sin(3.5 * t) + 0.24]
            poses[1, 3:5] = [np.cos(2.0 * t), np.sin(2.0 * t)]
            env.step(platform_setposes=poses.copy(), num_cycles=40)

        return sixD_platform_example_env.SixDPlatformMagBotExampleEnv, 2, step
    if name == "SixDPlatformMagBotApplicationExampleEnv":
        pose = np.array([[0.56133, 0.36, 0.205, 0.0, 0.0, 0.0]])

        def step(env, t):  # the application's first set pose, circled slowly with the product on its rack
            pose[0, :3] = [0.56133 + 0.05 * np.cos(t), 0.36 + 0.05 * np.sin(t), 0.205 + 0.01 * np.sin(2.0 * t)]
            env.step(platform_setposes=pose.copy(), num_cycles=40)

        return sixD_platform_application_example_env.SixDPlatformMagBotApplicationExampleEnv, 1, step
    if name == "GripperMagBotApplicationExampleEnv":
        params = gripper_application_example.GripperMagBotsAPM4330Params()
        z_offset = (params.z_p_max - 0.01 - params.z_p_min) / 2
        z0 = z_offset + params.z_p_min + params.n + 0.001
        pose = np.array([[0.6, 0.6, z0, 0.0, 0.0, 0.0, 0.0]])

        def step(env, t):  # the example env's circle and bob, around the application's gripper
            pose[0, :3] = [0.6 + 0.08 * np.cos(t), 0.6 + 0.08 * np.sin(t), z_offset * np.sin(2.0 * t) + z0]
            env.step(gripper_setposes=pose.copy(), single_track=False, num_cycles=40)

        return gripper_application_example.GripperMagBotApplicationExampleEnv, 1, step
    raise ValueError(f"no MagBotSim reference named {name!r}")


def magbotsim_row(name: str, steps: int, warmup: int = 3) -> dict:
    """MagBotSim's example env ``name``, headless, ``steps`` env steps of 40 cycles (median per step)."""
    cls, magbots, step = _reference(name)
    env, build_s = _headless(cls)
    t_sim = 0.0
    samples = []
    for i in range(warmup + steps):
        t = time.perf_counter()
        step(env, t_sim)
        if i >= warmup:
            samples.append(time.perf_counter() - t)
        t_sim += 0.04
    env.close()
    step_ms = float(np.median(samples) * 1e3)
    return {"step_ms": step_ms, "std_ms": float(np.std(samples) * 1e3), "env_steps_per_s": 1e3 / step_ms,
            "magbots_per_env": magbots, "magbot_steps_per_s": magbots * 1e3 / step_ms, "build_s": build_s}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default=None, help="cpu or cuda:N (default: cpu, plus cuda:0 when present)")
    p.add_argument("--num-envs", default=None, help="comma-separated sizes (default: 1,4,16,64 on CPU; "
                                                    "4096,16384,65536 on CUDA)")
    p.add_argument("--envs", default=",".join(ENVS), help=f"comma-separated: {', '.join(ENVS)}")
    p.add_argument("--action-modes", default="mover,pose", help="PlatformPose's, comma-separated: mover, pose")
    p.add_argument("--steps", type=int, default=50)
    p.add_argument("--no-magbotsim", action="store_true")
    p.add_argument("--magbotsim-steps", type=int, default=100)
    p.add_argument("--json", default=None, help="default: benchmarks/results/magbots_<device>.json")
    args = p.parse_args(argv)
    names = [n for n in args.envs.split(",") if n]
    unknown = sorted(set(names) - set(ENVS))
    if unknown:
        p.error(f"unknown --envs {unknown}; choose from {list(ENVS)}")
    info, devices = start_run(args.device)
    rows: list[dict] = []
    path = args.json or os.path.join(os.path.dirname(os.path.abspath(__file__)), "results",
                                     f"magbots_{(args.device or 'cpu').replace(':', '')}.json")
    stamp = provenance(info)

    def save():
        write_json(path, [{**r, **stamp} for r in rows])

    for device in devices:
        sizes = ([int(s) for s in args.num_envs.split(",")] if args.num_envs else
                 ([1, 4, 16, 64] if device == "cpu" else [4096, 16384, 65536]))
        for name in names:
            env_id, modes, _ = ENVS[name]
            for mode in (args.action_modes.split(",") if name == "pose" else modes):
                for n in sizes:
                    row = {"engine": "magwarp", "bench": name, "env": env_id, "action_mode": mode or "-",
                           "device": device, "num_envs": n}
                    try:
                        res = magwarp_row(env_id, n, device, args.steps, mode)
                    except (RuntimeError, MemoryError) as e:  # e.g. out of device memory: keep the other rows
                        print(f"  {env_id} {mode} {device} num_envs={n}: failed ({e})", flush=True)
                        rows.append({**row, "error": str(e).splitlines()[0] if str(e) else type(e).__name__})
                        continue
                    rows.append({**row, **res})
                    save()
                    print(f"  {env_id} {mode} {device} num_envs={n}: {res['env_steps_per_s']:.4g} env-steps/s",
                          flush=True)
    refs: dict[str, dict] = {}
    if not args.no_magbotsim:
        for name in names:
            ref = ENVS[name][2]
            if ref is None:
                continue
            try:
                res = magbotsim_row(ref, args.magbotsim_steps)
            except ImportError as e:
                print(f"  MagBotSim not available ({e}); skipped", flush=True)
                break
            refs[name] = res
            rows.append({"engine": "magbotsim", "bench": name, "env": ref, "action_mode": "set pose",
                         "device": "cpu", "num_envs": 1, **res})
            print(f"  MagBotSim {ref}: {res['env_steps_per_s']:.4g} env-steps/s", flush=True)
    for r in rows:
        if r["bench"] in refs and "magbot_steps_per_s" in r:
            r["x_magbotsim"] = r["magbot_steps_per_s"] / refs[r["bench"]]["magbot_steps_per_s"]
    print_table(rows, ["engine", "env", "action_mode", "device", "num_envs", ("step_ms", "ms/step"),
                       ("raw_mjw_ms", "raw mjw ms"),
                       ("env_steps_per_s", "env-steps/s"), ("magbot_steps_per_s", "MagBot-steps/s"),
                       ("x_magbotsim", "x MagBotSim (MagBot-steps)"),
                       *([("error", "error")] if any("error" in r for r in rows) else [])])
    save()
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
